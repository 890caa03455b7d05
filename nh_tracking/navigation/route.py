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

"""Untimed routes (what Nav2's planners publish) timed into references a robot can follow.

A route (:mod:`route_shape`) is driven to its last pose, where it ends at rest: at
``reference_speed``, slower where ``v^2 * curvature`` would pass ``max_lateral_accel`` (or
where a caller's caps say), changing speed at most ``max_accel`` (a forward and a backward pass
over the speed limits); stopping at each cusp; then turning in place to a goal heading the
route's tangent does not reach.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nh_tracking.core.settings import check_fields, setting
from nh_tracking.navigation.route_shape import (EQUAL_HEADINGS, RouteHeadings, RouteShape,
                                                shape_route, wrap)

TURN_RATE, TURN_ACCEL = 1.0, 1.0  # [rad/s, rad/s^2] a turn in place to the goal's heading


@dataclass(frozen=True)
class RouteSettings:
    """How untimed routes are timed."""

    reference_speed: float = setting(0.5, 'speed along untimed routes (paths whose poses all '
                                     'carry one stamp, as Nav2 planners publish them); 0: '
                                     'such paths are refused', 'm/s', (0.0, 100.0))
    max_accel: float = setting(0.5, 'largest change of speed along a route', 'm/s^2',
                               (1e-3, 100.0))
    max_lateral_accel: float = setting(0.5, 'routes are slowed where speed^2 * curvature '
                                       'would pass this', 'm/s^2', (1e-3, 100.0))
    route_headings: str = setting('auto', "a route's headings: the poses' (poses), the "
                                  "route's tangent (tangent), or the poses' unless they are "
                                  'all equal on a route that turns (auto)',
                                  choices=tuple(h.value for h in RouteHeadings))

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class TimedRoute:
    """A route with times: what a planner tracks (body twists derived, not splined)."""

    times: np.ndarray  # (N,) [s] from the start
    poses: np.ndarray  # (N, 4) x, y, z, yaw
    twists: np.ndarray  # (N, 4) body vx, vy, vz, yaw rate
    speeds: np.ndarray  # (N,) [m/s] along the route, negative where it is driven backwards
    headings: RouteHeadings  # POSES or TANGENT: what was used
    cusps: int

    @property
    def length(self) -> float:
        return float(np.hypot(*np.diff(self.poses[:, :2], axis=0).T).sum())


def time_route(poses: np.ndarray, start: np.ndarray, start_speed: float,
               settings: RouteSettings) -> TimedRoute:
    """Return route ``poses`` (N, 4) timed from the robot at ``start`` (x, y) on.

    ``start_speed`` is the robot's speed along its heading (negative: backwards); the route
    starts from it where it points the way the route is driven.
    """
    return time_shape(shape_route(poses, start, RouteHeadings(settings.route_headings)),
                      start_speed, settings)


def time_shape(shape: RouteShape, start_speed: float, settings: RouteSettings,
               caps: np.ndarray | None = None) -> TimedRoute:
    """Return ``shape`` timed; ``caps``: speed limits [m/s] at its points besides the settings'."""
    if shape.at_goal:  # hold it
        poses = np.c_[shape.positions, shape.z, shape.yaw]
        return TimedRoute(np.array([0.0, 1.0]), np.repeat(poses, 2, axis=0), np.zeros((2, 4)),
                          np.zeros(2), RouteHeadings.POSES, 0)
    lengths, direction, gears, piece = shape.lengths, shape.direction, shape.gears, shape.piece
    speed = _speed_profile(lengths, shape.curvature, shape.cusp_at, start_speed * gears[0],
                           settings, caps)
    times = np.r_[0.0, np.cumsum(_durations(lengths, speed, settings.max_accel))]
    yaw = shape.yaw
    world = speed[:, None] * np.c_[np.cos(np.r_[direction, direction[-1]]),
                                   np.sin(np.r_[direction, direction[-1]])]
    c, s = np.cos(yaw), np.sin(yaw)
    yaw_rate = np.gradient(yaw, times) if len(times) > 2 else np.zeros(len(times))
    twists = np.c_[c * world[:, 0] + s * world[:, 1], -s * world[:, 0] + c * world[:, 1],
                   np.zeros(len(times)), yaw_rate]
    poses, signed = np.c_[shape.positions, shape.z, yaw], speed * gears[piece]
    if shape.goal is not None:
        times, poses, twists, signed = _turned_to(shape.goal, times, poses, twists, signed)
    return TimedRoute(times, poses, twists, signed, shape.headings, len(shape.cusp_at))


def _turned_to(goal: float, times: np.ndarray, poses: np.ndarray, twists: np.ndarray,
               speeds: np.ndarray) -> tuple[np.ndarray, ...]:
    """Return the route, then a turn in place to heading ``goal`` (:data:`TURN_RATE`...)."""
    angle = float(wrap(goal - poses[-1, 3]))
    if abs(angle) <= EQUAL_HEADINGS:
        return times, poses, twists, speeds
    a = TURN_ACCEL
    rate = min(TURN_RATE, np.sqrt(abs(angle) * a))  # the highest rate the turn reaches
    duration = abs(angle) / rate + rate / a
    t = np.linspace(0.0, duration, max(3, int(np.ceil(duration / 0.05)) + 1))[1:]
    up, down = np.minimum(t, rate / a), np.maximum(t - (duration - rate / a), 0.0)
    sign = np.sign(angle)
    extra = np.repeat(poses[-1:], len(t), axis=0)
    extra[:, 3] += sign * (a * up ** 2 / 2 + rate * (t - up) - a * down ** 2 / 2)
    turning = np.zeros((len(t), 4))
    turning[:, 3] = sign * (a * up - a * down)
    return (np.r_[times, times[-1] + t], np.vstack([poses, extra]),
            np.vstack([twists, turning]), np.r_[speeds, np.zeros(len(t))])


def _speed_profile(lengths: np.ndarray, curvature: np.ndarray, cusp_at: np.ndarray,
                   start_speed: float, settings: RouteSettings,
                   caps: np.ndarray | None) -> np.ndarray:
    """Speeds [m/s] >= 0 at the points: the fastest within the limits, at rest at each stop."""
    with np.errstate(divide='ignore'):
        cap = np.minimum(settings.reference_speed,
                         np.sqrt(settings.max_lateral_accel / curvature))
    if caps is not None:
        cap = np.minimum(cap, caps)
    a = settings.max_accel
    arc = np.r_[0.0, np.cumsum(lengths)]
    # a robot faster than the limits slows down from its speed at max_accel, not at once
    cap = np.maximum(cap, np.sqrt(np.maximum(start_speed ** 2 - 2 * a * arc, 0.0)))
    cap[0] = max(start_speed, 0.0)
    cap[-1] = 0.0
    cap[cusp_at] = 0.0
    speed = cap.copy()
    for j in range(len(lengths)):
        speed[j + 1] = min(speed[j + 1], np.sqrt(speed[j] ** 2 + 2 * a * lengths[j]))
    for j in range(len(lengths) - 1, -1, -1):
        speed[j] = min(speed[j], np.sqrt(speed[j + 1] ** 2 + 2 * a * lengths[j]))
    return speed


def _durations(lengths: np.ndarray, speed: np.ndarray, max_accel: float) -> np.ndarray:
    """Each segment's time at constant acceleration between its end speeds."""
    mean = speed[:-1] + speed[1:]
    rest_to_rest = 2.0 * np.sqrt(lengths / max_accel)  # (a segment whose ends are both stops)
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.where(mean > 1e-9, 2.0 * lengths / np.where(mean > 1e-9, mean, 1.0),
                        rest_to_rest)
