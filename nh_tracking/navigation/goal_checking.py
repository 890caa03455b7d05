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

"""Whether a robot has arrived, and whether it is getting anywhere: Nav2's simple checkers.

A goal is reached when the robot is within ``xy_goal_tolerance`` and ``yaw_goal_tolerance`` of
the path's last pose, has passed along the path to within the same distance of its end (so a
path that ends where it starts is not done at once), and moves slower than
``stopped_velocity``. Progress is ``required_movement_radius`` covered within
``movement_time_allowance``; less, and the robot is blocked.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from nh_tracking.core.settings import check_fields, setting, ValueEnum
from nh_tracking.navigation.route_shape import closest_point

LOOK_AHEAD = 1.0  # [m] the robot's place on the path is looked for this far past the last one


class GoalState(ValueEnum):
    """Where the robot stands with the path in force."""

    NONE = 'none'  # no path
    FOLLOWING = 'following'
    ARRIVED = 'arrived'
    BLOCKED = 'blocked'  # no progress within the allowance


@dataclass(frozen=True)
class GoalSettings:
    """Nav2's goal and progress checkers' parameters, with their defaults."""

    xy_goal_tolerance: float = setting(0.25, 'the goal is reached within this distance of '
                                       "the path's last pose", 'm', (1e-4, 100.0))
    yaw_goal_tolerance: float = setting(0.25, '... and this heading error', 'rad',
                                        (1e-4, 2 * math.pi))
    stopped_velocity: float = setting(0.25, '... moving slower than this (m/s and rad/s)',
                                      'm/s', (0.0, 100.0))
    required_movement_radius: float = setting(0.5, 'a robot that moves less than this within '
                                              'movement_time_allowance is blocked', 'm',
                                              (0.0, 100.0))
    movement_time_allowance: float = setting(10.0, 'see required_movement_radius', 's',
                                             (0.1, 3600.0))

    def __post_init__(self) -> None:
        check_fields(self)

    def stuck(self) -> str:
        """Say what a blocked robot failed to do."""
        return (f'moved less than {self.required_movement_radius:g} m in '
                f'{self.movement_time_allowance:g} s')


class PathProgress:
    """The robot's place along a path: it moves forward only, so loops are followed around."""

    def __init__(self, positions: np.ndarray) -> None:
        self.positions = np.asarray(positions, dtype=float).reshape(-1, 2)
        self.arc = np.r_[0.0, np.cumsum(np.hypot(*np.diff(self.positions, axis=0).T))]
        self._segment = 0
        self._along: float | None = None  # [m] the robot's place, once looked for

    @property
    def length(self) -> float:
        return float(self.arc[-1])

    def remaining(self, position: np.ndarray) -> float:
        """Arc length [m] from the robot's place (updated from ``position``) to the end."""
        position = np.asarray(position, dtype=float)[:2]
        if len(self.positions) == 1:
            return 0.0
        first = self._segment
        if self._along is None:  # the first look reaches as far as the robot's distance asks
            reach = float(np.hypot(*(self.positions[0] - position))) + LOOK_AHEAD
        else:
            reach = self._along - self.arc[first] + LOOK_AHEAD
        i, foot = closest_point(self.positions[first:], position, reach)
        self._segment = first + i
        self._along = float(self.arc[self._segment]
                            + np.hypot(*(foot - self.positions[self._segment])))
        return float(self.arc[-1] - self._along)


class GoalChecker:
    """Nav2's SimpleGoalChecker with its stopped check, on a path's last pose."""

    def __init__(self, settings: GoalSettings, has_yaw: bool = True) -> None:
        self.settings, self.has_yaw = settings, has_yaw

    def reached(self, pose: np.ndarray, goal: np.ndarray, twist: np.ndarray,
                remaining: float) -> bool:
        """``pose``/``goal`` (x, y, z, yaw); ``twist`` (vx, vy, vz, wz); ``remaining`` [m]."""
        s = self.settings
        close = (math.hypot(*(pose[:2] - goal[:2])) <= s.xy_goal_tolerance
                 and remaining <= s.xy_goal_tolerance)
        turned = not self.has_yaw or abs(math.remainder(pose[3] - goal[3], 2 * math.pi)) \
            <= s.yaw_goal_tolerance
        stopped = math.hypot(*twist[:3]) <= s.stopped_velocity \
            and abs(twist[3]) <= s.stopped_velocity
        return close and turned and stopped


class ProgressChecker:
    """Nav2's SimpleProgressChecker: movement of a radius within an allowance, else blocked."""

    def __init__(self, settings: GoalSettings) -> None:
        self.settings = settings
        self._baseline: tuple[np.ndarray, float] | None = None

    def reset(self) -> None:
        self._baseline = None

    def moving(self, position: np.ndarray, now: float) -> bool:
        """Record ``position`` at ``now`` [s]; False once the robot has been stuck too long."""
        position = np.asarray(position, dtype=float)[:2]
        s = self.settings
        if self._baseline is None or \
                math.hypot(*(position - self._baseline[0])) > s.required_movement_radius:
            self._baseline = (position, now)
            return True
        return now - self._baseline[1] <= s.movement_time_allowance


@dataclass(frozen=True)
class GoalStatus:
    """What a FollowPath action's feedback and result say."""

    state: GoalState
    remaining: float = 0.0  # [m] along the path to its end
    speed: float = 0.0  # [m/s]


class GoalTracker:
    """One path's goal, judged from every state: arrived, blocked, or following."""

    def __init__(self, positions: np.ndarray, goal: np.ndarray, settings: GoalSettings,
                 has_yaw: bool, check_progress: bool) -> None:
        self.goal = np.asarray(goal, dtype=float)
        self.progress = PathProgress(positions)
        self.checker = GoalChecker(settings, has_yaw)
        self.watch = ProgressChecker(settings) if check_progress else None
        self.status = GoalStatus(GoalState.FOLLOWING, self.progress.length)

    def judge_by(self, settings: GoalSettings) -> None:
        """Judge by ``settings`` from now on (the progress made so far kept)."""
        self.checker.settings = settings
        if self.watch is not None:
            self.watch.settings = settings

    def update(self, pose: np.ndarray, twist: np.ndarray, now: float) -> GoalStatus:
        """Judge the state ``pose`` (x, y, z, yaw), body ``twist``, at ``now`` [s]."""
        remaining = self.progress.remaining(pose[:2])
        speed = float(math.hypot(*twist[:3]))
        state = self.status.state
        if state is not GoalState.ARRIVED:
            moving = self.watch is None or self.watch.moving(pose[:2], now)
            if self.checker.reached(pose, self.goal, twist, remaining):
                state = GoalState.ARRIVED
            else:
                state = GoalState.FOLLOWING if moving else GoalState.BLOCKED
        self.status = GoalStatus(state, remaining, speed)
        return self.status
