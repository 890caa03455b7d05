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

"""Which obstacles one replan keeps clear of, and whether its plan is clear of all the others.

Each knot and midpoint of an NLP keeps clear of the discs nearest it, and its last resort (a
crowd) has a slot for every disc at every point: a bounded number, so each replan takes only
the discs that can bend its plan; the plan is then checked against every disc the planner
knows of (:func:`.obstacles.clear_of_discs_left_out`). A robot already inside a disc's
clearance (it drifted, or the disc was redrawn) has that disc shrunk for this replan, so the
prepared NLP still has a solution. Discs are (x, y, r, vx, vy) where they are at the replan's
start (moving ones: see :mod:`.limits`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.problem.limits import Limits, plan_path, plan_times, plane, VIOLATION_TOL
from nh_tracking.problem.tracking_problem import Solution, TrackingProblem
from nh_tracking.solvers.obstacles import clear_of_start, MAX_OBSTACLES, relevant_discs


@dataclass(frozen=True)
class Avoidance:
    """The obstacles (x, y, r, vx, vy) of one replanning step, for a robot of ``robot_radius``."""

    system: NonholonomicSystem
    obstacles: np.ndarray
    robot_radius: float
    reference: Trajectory | None
    horizon: float
    steps: int

    def from_start(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Return every obstacle, shrunk where the robot at (q, v) is inside its clearance."""
        if not len(self.obstacles):
            return self.obstacles
        axes = list(plane(self.system))
        return clear_of_start(self.obstacles, q[axes], (self.system.rho(q) @ v)[axes],
                              self.robot_radius, self.horizon / self.steps)

    def relevant(self, t: float, q: np.ndarray, discs: np.ndarray) -> np.ndarray:
        """Return those of ``discs`` that can bend a plan from q at t (nearest first)."""
        if not len(discs) or self.reference is None:
            return discs
        axes = list(plane(self.system))
        path = self.reference.sample(np.linspace(t, t + self.horizon, self.steps + 1))[0]
        return relevant_discs(discs, q[axes], path[:, axes], self.robot_radius, MAX_OBSTACLES,
                              self.horizon)

    def no_deeper(self, problem: TrackingProblem, sol: Solution, discs: np.ndarray) -> bool:
        """Whether a plan from a start that breaks a limit breaks none more than the start does.

        Over every disc, not only the problem's, and the problem's bounds, at knots and
        midpoints after the start (the robot's: a kept plan, shifted, may begin elsewhere): a
        least-violating plan minimises the summed violation, and driving through an obstacle
        and out can sum to less than braking inside it.
        """
        every, path, t = self.limits(discs), plan_path(sol.q), self.times
        start = max(problem.limits.violation(problem.q0[None], problem.v0[None], t=t[:1]),
                    float(np.max(-every.clearance(problem.q0[None], t[:1]), initial=0.0)))
        worst = max(problem.limits.violation(path[1:], sol.v[1:], sol.u, t[1:]),
                    float(np.max(-every.clearance(path[1:], t[1:]), initial=0.0)),
                    every.swept(path, t))  # (nor through one between its points)
        return worst <= start + VIOLATION_TOL

    @property
    def times(self) -> np.ndarray:
        """Return the times of a plan's knots and midpoints from the replan's start."""
        return plan_times(self.steps, self.horizon / self.steps)

    def limits(self, discs: np.ndarray) -> Limits:
        """Return ``discs`` grown by the robot's radius, to check plans against."""
        return Limits.of(self.system, None, None, discs, self.robot_radius)
