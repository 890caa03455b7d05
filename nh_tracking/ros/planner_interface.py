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

"""The planner's contract with the ROS graph beyond topic names: QoS and parameters.

The QoS it offers and expects, and its parameters (declared from the settings dataclasses,
plus the ROS-only ones).
"""
from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from nh_tracking.navigation.goal_checking import GoalSettings
from nh_tracking.navigation.route import RouteSettings
from nh_tracking.planning.command_guard import GuardSettings
from nh_tracking.planning.receding_horizon import PlannerSettings
from nh_tracking.ros.parameters import ParameterSpec, plain
from nh_tracking.session.interface import SessionSettings

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
# References, obstacles and costmaps are latched kinds of message: a transient-local
# subscription picks up the one a publisher still offers when this node (re)starts. Such a
# subscription cannot match a volatile publisher (DDS durability: offered must be at least
# requested), so a volatile one listens too; a sample both deliver is recognised by its
# publication stamp and sequence number. (BEST_AVAILABLE durability decides once, when the
# subscription is made: with no publisher yet it is transient-local, deaf to volatile ones.)
# Both as deep: a burst comes through both in the order it was sent (one that kept only the
# newest would hand it over before the other's older copies, and they would replace it).
LATCHED_OR_VOLATILE = (
    QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL,
               reliability=ReliabilityPolicy.RELIABLE),
    QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))


class FirstDelivery:
    """``self(info)`` is False for the second copy of a sample (both subscriptions get it).

    The two copies of a burst can interleave: the last :data:`REMEMBERED` samples are kept.
    """

    REMEMBERED = 64

    def __init__(self) -> None:
        self._seen: collections.deque[tuple[object, object]] = collections.deque(
            maxlen=self.REMEMBERED)

    def __call__(self, info: dict | None) -> bool:
        if not info:
            return True
        key = (info.get('source_timestamp'), info.get('publication_sequence_number'))
        if key in self._seen:
            return False
        self._seen.append(key)
        return True


def subscribe_latched(node: Node, msg_type: type, topic: str,
                      callback: Callable[[object], None], raw: bool = False) -> list:
    """Subscribe so latched and volatile publishers are heard; ``callback(msg)`` once a sample.

    ``raw``: ``msg`` is the CDR bytes, and the second copy is dropped before anything reads it.
    """
    first = FirstDelivery()
    # a volatile publisher cannot match the latched listener (the other one takes it): no warning
    quiet = SubscriptionEventCallbacks(incompatible_qos=lambda info: None)

    def deliver(msg: object, info: dict) -> None:
        if first(info):
            callback(msg)
    handler: Any = deliver  # (rclpy's typing knows only one-argument callbacks)
    return [node.create_subscription(msg_type, topic, handler, qos, event_callbacks=quiet,
                                     raw=raw) for qos in LATCHED_OR_VOLATILE]


SETTINGS = ParameterSpec.of(PlannerSettings)
SESSION = ParameterSpec.of(SessionSettings)
ROUTE = ParameterSpec.of(RouteSettings)
GOAL = ParameterSpec.of(GoalSettings)
GUARD = ParameterSpec.of(GuardSettings)
COSTMAP_THRESHOLD = plain(
    'costmap_threshold', 100, 'costmap cells of this cost and more are obstacles (100: '
    "Nav2's lethal cells only; its inflation is not taken for obstacle, the robot's radius is "
    'added once)', '', (1, 100), read_only=True)
JOINT_NAMES = plain(
    'joint_names', [], 'joints of joint_states that give coordinates a pose does not show, as '
    'coordinate:joint entries (e.g. phi:front_steering_joint); a coordinate not named is '
    'its own joint name', read_only=True)
ADAPT = plain(
    'adapt', [], 'physical parameters of the model to estimate online from the odometry and '
    'the controls sent (e.g. [m, J]); a moved estimate is a new number in the solver; empty: off',
    read_only=True)
NODE = (
    plain('frame_id', 'odom', 'fixed frame of references and odometry', read_only=True),
    plain('cmd_vel_stamped', False, 'publish TwistStamped on cmd_vel', read_only=True),
    plain('autostart', True, 'configure and activate at start-up (false: wait for a '
          'lifecycle manager)', read_only=True),
    plain('costmap_reach', 5.0, 'occupied costmap cells farther from the robot are ignored',
          'm', (0.1, 1000.0)),
    COSTMAP_THRESHOLD,
    JOINT_NAMES,
    ADAPT,
)
PARAMETERS = SETTINGS + SESSION + ROUTE + GOAL + GUARD + NODE
