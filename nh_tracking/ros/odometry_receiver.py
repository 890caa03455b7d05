# Copyright 2026 nh_tracking maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""Odometry (and joint states) on a thread of their own: a lean node and its own executor.

rclpy rebuilds its wait set in Python on every wake-up, for every entity of every node in the
executor (a lifecycle planner has about 40 with their QoS event handlers); at odometry rates
that keeps the planner's executor busy, competing for the interpreter with the solver (figures
in docs/performance.md). Here each message wakes an executor that waits on one subscription,
and the callback may plan at once, on this thread, without a hand-off to the solver thread.
Not for a message that arrived while the last such plan was being made (DDS's reception stamp
says so): newer ones may wait behind it, and planning for each in turn would fall further behind
with every plan slower than the odometry; the solver thread plans for the latest instead. Joint
states, part of the same state, arrive on the same thread, so a state is never made of a pose
and joints half-written.
"""
from __future__ import annotations

from collections.abc import Callable

from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from nh_tracking.ros import cdr
from nh_tracking.ros.companion import CompanionNode, LEAN

# every message is looked at (a bad one is reported); the callback coalesces plans itself.
# Best effort: it hears reliable and best-effort (sensor-data) publishers alike; a reliable
# subscription hears no best-effort publisher, and odometry is replaced by the next anyway.
ODOM_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)


class OdometryReceiver(CompanionNode):
    """Calls ``callback(msg, info)`` on its own thread for each ``topic`` message ``owner`` gets.

    ``msg`` is the message's CDR bytes where :mod:`cdr` reads them (else the message). With
    ``joints``, each ``joint_states`` message goes to ``joints(msg)`` on the same thread.

    The topic name is resolved by ``owner`` (its namespace and remappings), so the receiver node
    takes no command-line arguments of its own.
    """

    def __init__(self, owner: Node, topic: str, callback: Callable[..., None],
                 joints: Callable[[JointState], None] | None = None) -> None:
        super().__init__(owner, 'odometry', **LEAN)
        self.subscription = self.node.create_subscription(
            Odometry, owner.resolve_topic_name(topic), callback, ODOM_QOS,
            raw=cdr.agrees_with_rmw())
        if joints is not None:
            self.node.create_subscription(JointState, owner.resolve_topic_name('joint_states'),
                                          joints, ODOM_QOS)
        self.start()
