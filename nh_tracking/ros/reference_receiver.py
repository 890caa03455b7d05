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

"""References on a thread of their own: a large one is read there, never where cmd_vel is sent.

``reference_path`` is taken as CDR bytes where :mod:`cdr` reads them (far faster than
building the message; figures in docs/performance.md), and the second delivery of a sample
(latched and volatile subscriptions) is dropped before it is read.
"""
from __future__ import annotations

from collections.abc import Callable

from nav_msgs.msg import Path
from rclpy.node import Node
from trajectory_msgs.msg import MultiDOFJointTrajectory

from nh_tracking.ros import cdr
from nh_tracking.ros.companion import CompanionNode, LEAN
from nh_tracking.ros.planner_interface import subscribe_latched


class ReferenceReceiver(CompanionNode):
    """Calls ``on_path(msg)`` / ``on_trajectory(msg)`` on its own thread, once per sample."""

    def __init__(self, owner: Node, on_path: Callable[[object], None],
                 on_trajectory: Callable[[object], None]) -> None:
        super().__init__(owner, 'references', **LEAN)
        self.subscriptions = subscribe_latched(
            self.node, Path, owner.resolve_topic_name('reference_path'), on_path,
            raw=cdr.agrees_with_rmw()) + subscribe_latched(
            self.node, MultiDOFJointTrajectory, owner.resolve_topic_name('reference_trajectory'),
            on_trajectory)
        self.start()
