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

"""One node per name: a node started twice under one fully qualified name finds its twin.

Each node publishes when it started (system time, ns) latched on ``~/instance`` and listens
there: a start that is not its own is a twin's, heard as soon as discovery joins them. The one
started first keeps the robot; the other yields (it commands nothing) while the twin is on the
graph. Both say so once, as an ERROR naming the name.
"""
from __future__ import annotations

import time

from builtin_interfaces.msg import Time
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from nh_tracking.core.settings import ValueEnum

INSTANCE_QOS = QoSProfile(depth=4, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                          reliability=ReliabilityPolicy.RELIABLE)


class TwinVerdict(ValueEnum):
    """What a node does about a twin."""

    ALONE = 'alone'
    KEEPS = 'keeps the robot'  # its twin started later
    YIELDS = 'yields'  # its twin started first: this node does not command


class TwinWatch:
    """Listens for ``node``'s twin; :attr:`verdict` says what it does about one.

    ``role``: what a node that yields does not do, in words.
    """

    def __init__(self, node: Node, role: str = 'command the robot') -> None:
        self.node, self.role = node, role
        self.verdict = TwinVerdict.ALONE
        self._seen = False  # the twin was seen on the graph (discovery is not instant)
        now = time.time_ns()
        self.started = Time(sec=now // 10**9, nanosec=now % 10**9)
        topic = node.resolve_topic_name('~/instance')
        node.create_subscription(Time, topic, self._on_instance, INSTANCE_QOS)
        node.create_publisher(Time, topic, INSTANCE_QOS).publish(self.started)

    @property
    def yields(self) -> bool:
        return self.verdict is TwinVerdict.YIELDS

    def _on_instance(self, other: Time) -> None:
        if other == self.started:  # its own
            return
        verdict = TwinVerdict.YIELDS if (other.sec, other.nanosec) < (
            self.started.sec, self.started.nanosec) else TwinVerdict.KEEPS
        if verdict is not self.verdict:
            self.verdict = verdict
            self.node.get_logger().error(self.describe())

    def check(self) -> TwinVerdict:
        """Return the verdict: back to ALONE once the twin, seen on the graph, has left it."""
        if self.verdict is not TwinVerdict.ALONE:
            own = (self.node.get_name(), self.node.get_namespace())
            twins = sum(entry == own for entry in self.node.get_node_names_and_namespaces()) - 1
            self._seen |= twins > 0
            if self._seen and twins <= 0:
                self.verdict, self._seen = TwinVerdict.ALONE, False
                self.node.get_logger().info(f'no other node named '
                                            f'{self.node.get_fully_qualified_name()} now')
        return self.verdict

    def describe(self) -> str:
        """Return the verdict in words, naming the twin ('' when alone)."""
        name = self.node.get_fully_qualified_name()
        if self.verdict is TwinVerdict.KEEPS:
            return (f'another node named {name} on the graph, started later: this one keeps the '
                    f'robot; stop the other')
        if self.verdict is TwinVerdict.YIELDS:
            return (f'another node named {name} was on the graph first: this one does not '
                    f'{self.role}; stop one of them')
        return ''
