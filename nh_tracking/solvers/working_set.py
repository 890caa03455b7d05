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

"""Gauss-Newton steps with a working set of inequality rows: warm replanning with limits.

An interior-point solve starts its barrier afresh at every replan (fatrop takes no
multipliers back), so even from the previous plan it spends 7-10 iterations near an obstacle
where the same plan without limits takes 2. Near the previous plan the set of active limits
rarely changes. Each Gauss-Newton step here solves its QP (the Gauss-Newton model subject to
the linearised limits) by a primal active-set method: the rows of a working set are held at
their bounds, which is one factorisation of one fixed-pattern KKT matrix
(:class:`.newton.NewtonStep`); a step that would break a free row stops at it and takes
it in; a held row whose multiplier has the wrong sign is let go, one at a time. The steps go on
until they stop moving the plan, each starting from the last step's working set. Started from
a plan within the limits (a previous plan), the active limits of which start the set. Nothing
globalises this: a budget exceeded, a non-finite step or the deadline returns None, and the
caller solves by interior point, as before.
"""
from __future__ import annotations

from dataclasses import dataclass
import time

import numpy as np

from nh_tracking.numeric import NumericFunction
from nh_tracking.solvers.newton import NewtonStep

MAX_STEPS = 12  # Gauss-Newton steps (linear convergence: a warm plan needs 2-5)
MAX_FACTORISATIONS = 24  # in all: a set that needs more is not near the previous plan's
DIVERGING = 2.0  # a step this many times longer than the last: diverging, given up
STEP_TOL = 1e-7  # converged once a step moves no unknown by more (relative to the largest;
# the convergence is superlinear: the plan is then within about 1e-9 of the solution)
STATIONARITY_TOL = 1e-6  # |gradient of the Lagrangian| of a converged plan
ACTIVE_TOL = 1e-9  # a row this close to a bound (or beyond) is held there from the start
DUAL_TOL = 1e-10  # a held row whose multiplier has the wrong sign by more is let go


@dataclass
class WorkingSetSolution:
    """A converged working-set solve: unknowns, multipliers of g, factorisations used."""

    w: np.ndarray
    multipliers: np.ndarray
    factorisations: int
    active: int  # inequality rows held at a bound


class _WorkingSet:
    """Which rows of g are held, and at which bound: 2 equality, -1 lower, 1 upper, 0 free."""

    def __init__(self, lower: np.ndarray, upper: np.ndarray) -> None:
        self.lower, self.upper = lower, upper
        self.held = np.where(lower == upper, 2, 0).astype(np.int8)

    def hold_reached(self, values: np.ndarray) -> None:
        """Hold the free rows at (or beyond) a bound at ``values``."""
        free = self.held == 0
        self.held[free & (values <= self.lower + ACTIVE_TOL)] = -1
        self.held[free & (values >= self.upper - ACTIVE_TOL)] = 1

    def arguments(self) -> tuple[np.ndarray, np.ndarray]:
        """(active, target) of the KKT step: held rows at their bound, free rows switched off."""
        target = np.where(self.held == 1, self.upper, np.where(self.held != 0, self.lower, 0.0))
        return (self.held != 0).astype(float), target

    def blocking(self, now: np.ndarray, full: np.ndarray) -> tuple[float, int]:
        """Return how far (0-1) from ``now`` to ``full`` (linearised rows) a step can go.

        And the free row that stops it (-1: none): the first that would leave its bounds.
        """
        free = self.held == 0
        fraction = np.full(len(now), np.inf)
        down = free & (full < self.lower - ACTIVE_TOL) & (full < now)
        up = free & (full > self.upper + ACTIVE_TOL) & (full > now)
        fraction[down] = (self.lower[down] - now[down]) / (full[down] - now[down])
        fraction[up] = (self.upper[up] - now[up]) / (full[up] - now[up])
        row = int(np.argmin(fraction))
        if not np.isfinite(fraction[row]):
            return 1.0, -1
        return float(np.clip(fraction[row], 0.0, 1.0)), row

    def hold(self, row: int, full: np.ndarray) -> None:
        self.held[row] = -1 if full[row] < self.lower[row] else 1

    def wrong_sign(self, multipliers: np.ndarray) -> int:
        """Return the held inequality row whose multiplier is most wrong (-1: none)."""
        at_lower, at_upper = self.held == -1, self.held == 1
        wrong = np.where(at_lower, multipliers, 0.0) - np.where(at_upper, multipliers, 0.0)
        row = int(np.argmax(wrong))
        return row if wrong[row] > DUAL_TOL else -1


def working_set_solve(step: NewtonStep, constraints: NumericFunction, w: np.ndarray,
                      p: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                      nonconvex: np.ndarray, stop: float | None) -> WorkingSetSolution | None:
    """Solve min 1/2 |r|^2 s.t. lower <= g <= upper from w, or None (see the module).

    ``constraints``: (w, p) -> g. Rows with lower == upper are equalities, held throughout.
    A plan converged with a row of ``nonconvex`` held (clearance: the way round an obstacle)
    is checked to be a minimum, not a saddle (a factorisation more, through a slow path).
    """
    rows = _WorkingSet(lower, upper)
    factorisations = 0
    multipliers, moved = np.zeros(len(lower)), np.inf
    for _ in range(MAX_STEPS):
        curvature = multipliers
        values = constraints(w, p)[0]
        rows.hold_reached(values)  # a limit reached, or broken by the last step's curvature
        changed, offset, now = False, np.zeros_like(w), values
        while True:
            if factorisations >= MAX_FACTORISATIONS:
                return None
            w_full, multipliers, full, stationarity = step(w, p, *rows.arguments(), curvature)
            factorisations += 1
            fraction, row = rows.blocking(now, full)
            target = w_full - w
            if row >= 0:  # stop at the first free row the step would break, and hold it
                offset += fraction * (target - offset)
                now = now + fraction * (full - now)
                rows.hold(row, full)
                changed = True
                continue
            offset, now = target, full
            row = rows.wrong_sign(multipliers)
            if row < 0:
                break
            rows.held[row], changed = 0, True
        if not np.all(np.isfinite(offset)):
            return None
        w = w + offset
        moved, last = float(np.max(np.abs(offset))), moved
        if moved > DIVERGING * last:
            return None  # far from the previous plan's optimum: Newton without a line search
        if (not changed and stationarity[0] <= STATIONARITY_TOL
                and moved <= STEP_TOL * max(1.0, float(np.max(np.abs(w))))):
            if np.any(nonconvex & (rows.held != 0)) and not step.minimum(
                    w, p, *rows.arguments(), multipliers):
                return None  # a saddle: the interior point finds the minimum beside it
            return WorkingSetSolution(w, multipliers, factorisations,
                                      int(np.count_nonzero(np.abs(rows.held) == 1)))
        if stop is not None and time.perf_counter() > stop:
            return None
    return None
