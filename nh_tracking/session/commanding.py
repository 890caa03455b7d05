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

"""A session's commands: every velocity and control sequence it sends, through the guard.

Holds what the guard needs beyond the planner's limits — ``max_decel``, the speed limit in
force, the obstacles with the costmap's cells, the command before — and remembers what it did
last (``notes``, for diagnostics). Thread-safe; nothing here knows ROS.
"""
from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np

from nh_tracking.core.poses import PoseMap
from nh_tracking.navigation.route import RouteSettings
from nh_tracking.planning.command_guard import (Clearance, CommandGuard, GuardNote, GuardSettings,
                                                NO_CELLS, OccupiedCells, SpeedLimit)
from nh_tracking.planning.guarded_plan import guard_controls
from nh_tracking.planning.receding_horizon import PlanOutcome, RecedingHorizonPlanner
from nh_tracking.problem.limits import bounds, moved, obstacle_discs
from nh_tracking.problem.tracking_problem import Solution
from nh_tracking.session.interface import SessionSettings

NOTE_LIFETIME = 2.0  # [s] what the guard did is reported this long after
COMMAND_MEMORY = 0.5  # [s] a base holds a velocity command this long (diff_drive_controller's
#                       cmd_vel_timeout): a later one is ramped from it, an older one is gone


def predicted(plan: Solution, t: float, q: np.ndarray,
              v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (q, v) at ``t`` as ``plan`` has it; the (q, v) given where it does not reach."""
    if not plan.t[0] <= t <= plan.t[-1]:
        return q, v
    q_at, v_at = plan.trajectory().sample(t)
    return q_at[0], v_at[0]


class Commands:
    """The guard's settings and inputs, and the last command it let pass."""

    def __init__(self) -> None:
        session = SessionSettings()
        self.settings = GuardSettings()
        self.max_accel = RouteSettings().max_accel  # [m/s^2] the routes'
        self.command_period = 1.0 / session.cmd_rate  # [s] between velocity commands
        self.sequence_period = session.replan_period  # [s] between control sequences
        self._speed_limit = SpeedLimit()
        self._lock = threading.Lock()
        self._discs = (np.zeros((0, 5)), np.zeros(0))  # (x, y, r, vx, vy), seen (session time)
        self._cells = NO_CELLS
        self._last: tuple[np.ndarray, float] | None = None  # v commanded, when
        self._notes: tuple[tuple[GuardNote, ...], float] = ((), -np.inf)

    @property
    def speed_limit(self) -> SpeedLimit:
        return self._speed_limit

    def set_speed_limit(self, limit: SpeedLimit) -> bool:
        """Take a new speed limit; whether it differs from the one in force."""
        with self._lock:
            changed, self._speed_limit = limit != self._speed_limit, limit
        return changed

    def set_obstacles(self, discs: np.ndarray, seen: np.ndarray,
                      cells: OccupiedCells = NO_CELLS) -> None:
        """Keep every command clear of ``discs`` (seen at ``seen``, session time) and ``cells``."""
        with self._lock:
            self._discs, self._cells = (obstacle_discs(discs), np.asarray(seen)), cells

    def guard(self, planner: RecedingHorizonPlanner) -> CommandGuard:
        """Return the guard of the limits in force for ``planner``'s model."""
        limits = planner.limits
        velocity = limits['velocity_bounds']
        return CommandGuard(None if velocity is None else bounds(velocity, planner.system.k, 'v'),
                            self.max_accel, self.settings.max_decel, limits['robot_radius'],
                            self._speed_limit)

    def clearance(self, t: float) -> Clearance:
        """Return what commands stop short of at ``t`` (session time): discs at rest, cells.

        A moving disc is the plans' to go round: stopping in its way does not keep clear of it.
        """
        with self._lock:
            (discs, seen), cells = self._discs, self._cells
        now = moved(discs, t - seen)  # (one not seen for long is held, at rest, where it got to)
        return Clearance(now[~now[:, 3:5].any(axis=1)], cells)

    def twist(self, planner: RecedingHorizonPlanner, pose_map: PoseMap, t: float,
              q_plan: np.ndarray, v_plan: np.ndarray, q_robot: np.ndarray, v_robot: np.ndarray,
              age: float) -> np.ndarray:
        """Return the body twist of the plan's ``v_plan`` at ``q_plan`` now (``t``), guarded.

        From the command before if it was sent within :data:`COMMAND_MEMORY`, else from the
        robot's velocity; the robot at ``q_robot`` (its state ``age`` s old) sweeps its disc
        ahead.
        """
        return self._guarded(planner, pose_map, t, v_plan, pose_map.twist_matrix(q_plan),
                             q_robot, v_robot, age)

    def halt(self, planner: RecedingHorizonPlanner, pose_map: PoseMap, t: float,
             q_robot: np.ndarray, v_robot: np.ndarray, age: float) -> np.ndarray:
        """Return the body twist that brings the robot to rest: no plan to follow now (``t``).

        The command before slowed at ``max_decel`` along itself, and stopped short of
        obstacles; zero once at rest, and zero if none was sent within :data:`COMMAND_MEMORY`
        (the base has stopped on its own: the robot's last known velocity is no command).
        """
        if self._recent(t) is None:
            self.stopped(t)
            return np.zeros(4)
        return self._guarded(planner, pose_map, t, np.zeros(len(v_robot)),
                             pose_map.twist_matrix(q_robot), q_robot, v_robot, age)

    def _recent(self, t: float) -> tuple[np.ndarray, float] | None:
        """Return (v, when) of the command before ``t`` if sent within COMMAND_MEMORY."""
        with self._lock:
            last = self._last
        return last if last is not None and 0.0 < t - last[1] <= COMMAND_MEMORY else None

    def _guarded(self, planner: RecedingHorizonPlanner, pose_map: PoseMap, t: float,
                 v: np.ndarray, matrix: np.ndarray, q_robot: np.ndarray, v_robot: np.ndarray,
                 age: float) -> np.ndarray:
        last, period = self._recent(t), self.command_period
        previous, dt = (v_robot, period) if last is None else (last[0], t - last[1])
        guarded = self.guard(planner).velocity(v, matrix, previous, dt, pose_map.pose(q_robot),
                                               self.clearance(t), period + max(age, 0.0))
        self._remember(guarded.v, t, guarded.notes)
        return matrix @ guarded.v

    def stopped(self, t: float) -> None:
        """Record a zero command sent at ``t`` (if any was sent before)."""
        with self._lock:
            self._last = None if self._last is None else (np.zeros_like(self._last[0]), t)

    def controls(self, planner: RecedingHorizonPlanner, pose_map: PoseMap,
                 outcome: PlanOutcome) -> PlanOutcome:
        """``outcome`` with its controls cut back to the limits (itself if none is broken)."""
        plan = outcome.plan
        started = time.perf_counter()
        u_bounds = planner.limits['control_bounds']
        if u_bounds is not None:
            u_bounds = bounds(u_bounds, planner.system.r, 'u')
        guarded = guard_controls(self.guard(planner), pose_map, plan.q[0], plan.v[0], plan.u,
                                 np.diff(plan.t), self.sequence_period,
                                 self.clearance(float(plan.t[0])), u_bounds)
        if not guarded.notes:
            return outcome
        self._remember(None, float(plan.t[0]), guarded.notes)
        changed = dataclasses.replace(plan, q=guarded.q, v=guarded.v, u=guarded.u)
        took = time.perf_counter() - started
        return dataclasses.replace(outcome, plan=changed, message=(
            f'{outcome.message}; guarded in {took * 1e3:.1f} ms: '
            f'{"; ".join(note.text for note in guarded.notes)}'))

    def _remember(self, v: np.ndarray | None, t: float, notes: tuple[GuardNote, ...]) -> None:
        with self._lock:
            if v is not None:
                self._last = (v, t)
            if notes:
                self._notes = (notes, t)

    def notes(self, t: float) -> tuple[GuardNote, ...]:
        """Return what the guard did within :data:`NOTE_LIFETIME` before ``t``."""
        with self._lock:
            notes, when = self._notes
        return notes if t - when <= NOTE_LIFETIME else ()
