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

"""Newton steps with a working set of inequality rows: warm replanning with limits.

An interior-point solve starts its barrier afresh at every replan (fatrop takes no
multipliers back), so even from the previous plan it spends several times the iterations near
an obstacle that the same plan takes without limits. Near the previous plan the set of active
limits rarely changes. Each Newton step here solves its QP (the Lagrangian's quadratic model
subject to the linearised limits) by a primal active-set method: the rows of a working set are
held at their bounds, which is one factorisation of one fixed-pattern KKT matrix
(:class:`.newton.NewtonStep`); a step that would break a free row stops at it and takes it in;
held rows whose multipliers have the wrong sign are let go. The steps go on until they stop
moving the plan, each starting from the last step's working set, the first from the rows the
guess (a previous plan within the limits) has at a bound. A local method: from the same guess
it may settle on other contact points with an obstacle than fatrop does — another local
minimum. Nothing globalises it: a budget exceeded, a step twice the last, a non-finite step,
the deadline or a saddle returns None, and the caller solves by interior point.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np

from nh_tracking.core.numeric import NumericFunction
from nh_tracking.solvers.newton import NewtonStep
from nh_tracking.solvers.nlp import Pace


@dataclass(frozen=True)
class WorkingSetOptions:
    """The working set's tuning: budgets, convergence tests and how rows are held."""

    max_steps: int = 12
    """Newton steps (a warm plan needs 2-5)."""
    max_factorisations: int = 24
    """In all: a set that needs more is not near the previous plan's."""
    diverging: float = 2.0
    """A step this many times longer than the last: diverging, given up."""
    slow: float = 0.3
    """Two steps in a row longer than this fraction of the one before, the set unchanged:
    converging linearly (an inexact factorisation), slower than the interior point."""
    wandered: float = 0.05
    """A first step longer than this (relative to the largest unknown): the guess was not near
    a stationary point, and the one the steps reach is checked to be a minimum."""
    step_tol: float = 1e-5
    """Converged once a step moves no unknown by more (relative to the largest); it is taken,
    and as the convergence is quadratic there the plan is then within about 1e-9 of the
    solution."""
    stationarity_tol: float = 1e-4
    """|Jᵀr + Gᵀλ|∞ at the step's start with its multipliers, for that test: about |H dw|."""
    contraction: float = 0.1
    """Or converged once two steps on the same set shrink quadratically, |dw₂| <= this |dw₁|,
    so far that the next, about |dw₂|³/|dw₁|², would move less than ``next_tol``."""
    next_tol: float = 1e-9
    """(Relative.) The plan is then as close as ``step_tol``'s, a factorisation sooner."""
    feasible_tol: float = 1e-8
    """... and g at the plan within this of the set (equalities, held rows, free rows' bounds):
    the quadratic estimate can be optimistic by over an order of magnitude, and this keeps an
    optimistic one from ending the solve short of admissible, for one evaluation of g. A
    tighter value costs replans past discs more factorisations (docs/performance.md)."""
    contradiction_tol: float = 1e-6
    """Settled steps with g further off the set: limits that cannot all hold."""
    near_bound: float = 1e-6
    """A row this close to a bound (or beyond) at a step's start is held there."""
    active_tol: float = 1e-9
    """A free row a step takes further beyond its bound than this stops it."""
    together: float = 1e-9
    """Rows reached within this fraction of a step of the first are held with it."""
    dual_tol: float = 1e-10
    """A held row whose multiplier has the wrong sign by more is let go."""

    def __post_init__(self) -> None:
        check_budgets(self, 'max_steps', 'max_factorisations')


def check_budgets(options: object, *budgets: str) -> None:
    """Refuse an options dataclass whose ``budgets`` are not whole numbers >= 1."""
    for name in budgets:
        value = getattr(options, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f'{type(options).__name__}.{name} must be an integer >= 1, '
                             f'got {value!r}')


DEFAULTS = WorkingSetOptions()
NO_ROWS = np.zeros(0, dtype=int)


@dataclass
class WorkingSetSolution:
    """A converged working-set solve: unknowns, multipliers of g, factorisations used."""

    w: np.ndarray
    multipliers: np.ndarray
    factorisations: int
    active: int  # inequality rows held at a bound
    limited: bool  # whether g has inequality rows at all
    minimum: bool  # checked a strict local minimum (the KKT matrix's inertia)
    minimum_check: Callable[[], bool] | None = None  # the same check, where it was not asked


class WorkingSet:
    """Which inequality rows of g are held, and at which bound: -1 lower, 1 upper, 0 free.

    The inequality rows: ``rows``, or those whose bounds differ.

    Kept for the inequality rows alone (equalities are always held), and the step's
    arguments rebuilt only when the set changes: a replan asks for them at every
    factorisation, and with a large g these array operations would weigh on each one.
    Without inequality rows (``limited`` False) the set never changes: its methods return at
    once.
    """

    def __init__(self, lower: np.ndarray, upper: np.ndarray, rows: np.ndarray | None = None,
                 options: WorkingSetOptions | None = None) -> None:
        self.options = DEFAULTS if options is None else options
        self.rows = np.flatnonzero(lower != upper) if rows is None else rows
        self.limited = bool(len(self.rows))
        self.lower, self.upper = lower[self.rows], upper[self.rows]
        self.state = np.zeros(len(self.rows), dtype=np.int8)
        self._active = np.ones(len(lower))
        self._active[self.rows] = 0.0
        self._target = np.where(self._active == 1, lower, 0.0)

    def held(self) -> np.ndarray:
        """Which rows of g are held at a bound (equalities not counted)."""
        held = np.zeros(len(self._active), dtype=bool)
        held[self.rows] = self.state != 0
        return held

    def hold_reached(self, values: np.ndarray) -> None:
        """Hold the free rows at (or beyond) a bound at ``values``, or nearly at it.

        Nearly: an interior-point plan keeps its active rows about 1e-8 inside their bounds,
        and each one found later by a blocked step costs a factorisation.
        """
        if self.limited:
            value = values[self.rows]
            tol = self.options.near_bound
            self._hold(value <= self.lower + tol, value >= self.upper - tol)

    def residual(self, values: np.ndarray) -> float:
        """Return how far g (``values``) is off the set.

        Held rows (equalities: at 0) off their targets, free rows beyond their bounds.
        """
        held = self._active == 1
        off = float(np.max(np.abs(values[held] - self._target[held]), initial=0.0))
        free = self.state == 0
        value = values[self.rows[free]]
        beyond = np.maximum(self.lower[free] - value, value - self.upper[free])
        return max(off, float(np.max(beyond, initial=0.0)))

    def arguments(self) -> tuple[np.ndarray, np.ndarray]:
        """(active, target) of the KKT step: held rows at their bound, free rows switched off."""
        return self._active, self._target

    def blocking(self, now: np.ndarray, full: np.ndarray) -> tuple[float, np.ndarray]:
        """Return how far (0-1) from ``now`` to ``full`` (linearised rows) a step can go.

        And the free rows that stop it there (empty: none; positions among the inequality
        rows), the first that would leave their bounds — all of them, as rows reached together
        are held together.
        """
        if not self.limited:
            return 1.0, NO_ROWS
        now, full = now[self.rows], full[self.rows]
        free = self.state == 0
        tol = self.options.active_tol
        down = free & (full < self.lower - tol) & (full < now)
        up = free & (full > self.upper + tol) & (full > now)
        if not (down.any() or up.any()):
            return 1.0, NO_ROWS
        fraction = np.full(len(now), np.inf)
        fraction[down] = (self.lower[down] - now[down]) / (full[down] - now[down])
        fraction[up] = (self.upper[up] - now[up]) / (full[up] - now[up])
        first = float(np.clip(np.min(fraction), 0.0, 1.0))
        return first, np.flatnonzero(fraction <= first + self.options.together)

    def hold(self, positions: np.ndarray, full: np.ndarray) -> None:
        """Hold the free rows at ``positions`` (from :meth:`blocking`) at the bound passed."""
        below = full[self.rows[positions]] < self.lower[positions]
        self.state[positions] = np.where(below, -1, 1)
        self._changed()

    def hold_broken(self, reached: np.ndarray) -> bool:
        """Hold every free row a step takes beyond a bound (``reached``: g + G dw of the rows)."""
        if not self.limited:
            return False
        tol = self.options.active_tol
        return self._hold(reached < self.lower - tol, reached > self.upper + tol)

    def let_go(self, multipliers: np.ndarray) -> bool:
        """Free the held inequality rows whose multipliers have the wrong sign (True if any).

        All at once: a degenerate start (a robot turning on the spot at a disc's edge holds
        150 rows at the bound) would otherwise spend a factorisation on each.
        """
        if not self.limited:
            return False
        multiplier = multipliers[self.rows]
        tol = self.options.dual_tol
        wrong = (((self.state == -1) & (multiplier > tol))
                 | ((self.state == 1) & (multiplier < -tol)))
        if not wrong.any():
            return False
        self.state[wrong] = 0
        self._changed()
        return True

    def _hold(self, low: np.ndarray, high: np.ndarray) -> bool:
        """Hold the free rows of ``low`` at their lower bound, of ``high`` at their upper."""
        free = self.state == 0
        low, high = free & low, free & high
        if not (low.any() or high.any()):
            return False
        self.state[low], self.state[high] = -1, 1
        self._changed()
        return True

    def _changed(self) -> None:
        self._active[self.rows] = self.state != 0
        self._target[self.rows] = np.where(self.state == 1, self.upper,
                                           np.where(self.state == -1, self.lower, 0.0))


def working_set_solve(step: NewtonStep, constraints: NumericFunction, w: np.ndarray,
                      p: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                      nonconvex: np.ndarray, pace: Pace,
                      multipliers: np.ndarray | None = None,
                      options: WorkingSetOptions | None = None) -> WorkingSetSolution | None:
    """Solve min 1/2 |r|^2 s.t. lower <= g <= upper from w, or None (see the module).

    ``constraints``: (w, p) -> g. Rows with lower == upper are equalities, held throughout.
    A plan converged with a row of ``nonconvex`` held (clearance: the way round an obstacle,
    where saddles are generic), or reached from a guess far from it (a first step longer than
    ``options.wandered``: a push, a jump of the reference), is checked to be a minimum, not a
    saddle (a factorisation more); plans continued from a nearby guess (the
    previous plan, shifted) are not, and carry the check instead. Without inequality rows the
    set never changes: the steps are Newton's on the KKT system, and g is not looked at.
    ``multipliers``: estimates at w (the previous plan's, :mod:`.duals`) for the first step's
    Hessian; without them it is Gauss-Newton's, and the steps end only by the first test
    (``options.step_tol``), not by the quadratic estimate, which needs a first step in
    Newton's regime.
    """
    o = DEFAULTS if options is None else options  # (:class:`WorkingSetOptions`)
    rows = WorkingSet(lower, upper, options=o)
    factorisations, wandered, settled, slow = 0, False, False, 0  # settled: the last set too
    estimated = multipliers is not None  # the first step had the Lagrangian's curvature
    multipliers = np.zeros(len(lower)) if multipliers is None else multipliers
    moved = np.inf
    guessed: np.ndarray | None = None
    at_w: np.ndarray | None = None  # g at w, if the last convergence test read it
    for _ in range(o.max_steps):
        curvature = multipliers
        if not rows.limited:
            now = lower  # (g unused without limits)
        else:
            now = constraints(w, p)[0] if at_w is None else at_w
        rows.hold_reached(now)  # a limit reached, or broken by the last step's curvature
        guessed = rows.held() if guessed is None else guessed  # the guess's contacts
        changed, offset = False, np.zeros_like(w)
        while True:
            if factorisations >= o.max_factorisations or not pace.has_time_for_step():
                return None
            w_full, multipliers, full, stationarity = step(w, p, *rows.arguments(), curvature)
            factorisations += 1
            fraction, stopping = rows.blocking(now, full)
            target = w_full - w
            if len(stopping):  # stop at the first free rows the step would break; hold them
                offset += fraction * (target - offset)
                now = now + fraction * (full - now)
                rows.hold(stopping, full)
                changed = True
                continue
            offset, now = target, full
            if not rows.let_go(multipliers):
                break
            changed = True
        if not np.all(np.isfinite(offset)):
            return None
        w = w + offset
        scale = max(1.0, float(np.max(np.abs(w))))
        tolerance = o.step_tol * scale
        moved, last = float(np.max(np.abs(offset))), moved
        wandered = wandered or (last == np.inf and moved > o.wandered * scale)
        if moved > o.diverging * max(last, tolerance):
            return None  # far from the previous plan's optimum: Newton without a line search
        slow = slow + 1 if settled and not changed and moved > max(o.slow * last, tolerance) else 0
        if slow >= 2:
            return None
        # converging quadratically: the step after this one would move less than next_tol
        quadratic = estimated and settled and moved <= o.contraction * last and \
            moved**3 <= o.next_tol * scale * last**2
        settled = not changed
        # (never on the first step: it is the reference the second is measured against)
        converged = not changed and last < np.inf and \
            stationarity[0] <= o.stationarity_tol and moved <= tolerance
        at_w = None
        if not (converged or changed) and quadratic:  # (quadratic: a second step at least)
            at_w = constraints(w, p)[0]
            converged = rows.residual(at_w) <= o.feasible_tol
        if converged and rows.limited and at_w is None:
            # held rows that cannot all hold (contradictory limits) still let the steps settle,
            # the regularised multipliers growing without bound: g tells
            converged = rows.residual(constraints(w, p)[0]) <= o.contradiction_tol
            if not converged:
                return None
        if converged:
            check = partial(step.minimum, w, p, *(a.copy() for a in rows.arguments()),
                            multipliers)
            checked = wandered or bool(np.any(nonconvex & rows.held() & ~guessed))
            if checked and not check():
                return None  # a saddle: the interior point finds the minimum beside it
            return WorkingSetSolution(w, multipliers, factorisations,
                                      int(np.count_nonzero(rows.state)),
                                      rows.limited, checked, None if checked else check)
    return None
