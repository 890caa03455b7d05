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

"""Paths and trajectories made the planner's reference: topics and ``follow_path`` goals alike.

A Path whose poses all carry one stamp is a route (timed by the session); any other is timed by
its stamps. Whatever the session refuses comes back as :class:`~conversions.InputRejected`.
"""
from __future__ import annotations

from nav_msgs.msg import Path
import numpy as np
from trajectory_msgs.msg import MultiDOFJointTrajectory

from nh_tracking.navigation.reference_checks import ReferenceRejected
from nh_tracking.navigation.route import RouteHeadings
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.planner_host import PlannerHost


def take_path(node: PlannerHost, msg: Path | bytes, goal: bool = False) -> None:
    """Track ``msg``; ``goal``: a follow_path goal (progress is checked for timed ones too)."""
    stamps, poses = cv.path_to_arrays(msg, node.frame, node.now_ns())
    if stamps is not None:
        _take(node, stamps, poses, None, goal)
        return
    try:
        timed = node.live.following.set_route(poses)
    except ReferenceRejected as exc:
        raise cv.InputRejected(str(exc)) from None
    if timed is not None:  # (None: the route in force, re-sent)
        route = timed.route
        headings = ("the route's tangent (its poses carry no heading)"
                    if route.headings is RouteHeadings.TANGENT else 'its poses')
        cusps = f', {route.cusps} cusp(s) driven as stop and reverse' if route.cusps else ''
        node.get_logger().info(
            f'new route: {len(poses)} poses, {route.length:.2f} m in '
            f'{timed.times[-1] - timed.times[0]:.1f} s at up to '
            f'{abs(route.speeds).max():.2f} m/s, headings from {headings}{cusps}')
        node.live.wake()


def take_trajectory(node: PlannerHost, msg: MultiDOFJointTrajectory) -> None:
    _take(node, *cv.multidof_to_arrays(msg, node.frame, node.now_ns()), goal=False)


def _take(node: PlannerHost, stamps: np.ndarray, poses: np.ndarray,
          twists: np.ndarray | None, goal: bool) -> None:
    session = node.live
    try:
        times = (stamps - session.epoch_ns) * 1e-9  # [s] on the session's axis
        reference = session.following.set_reference(times, poses, twists, check_progress=goal)
    except ReferenceRejected as exc:
        raise cv.InputRejected(str(exc)) from None
    node.get_logger().info(f'new reference: {len(reference.t)} points over '
                           f'{reference.t[-1] - reference.t[0]:.2f} s')
    session.wake()
