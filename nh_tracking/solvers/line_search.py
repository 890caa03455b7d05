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

"""Newton's method with a filter line search: cold solves without obstacles.

Each Newton step is one CasADi call (:meth:`.newton.NewtonStep.direction`: assembly, sparse
LDLᵀ, and the merits at the full step), a fraction of an interior-point iteration (fatrop's
Riccati recursion, the stage blocks copied out of CasADi's evaluations, its line search; figures
in docs/performance.md). Globalised the way an interior-point solver without inequalities is
— a filter line search on (infeasibility, f) (Wächter & Biegler 2006, §2), the Hessian shifted
until each step curves up along itself (the inertia-free test of Chiang & Zavala 2016) — a cold
solve takes about as many iterations as fatrop.

Bounds on controls and velocities make it a sequential QP: each step's QP (the limits
linearised) is solved on a working set of the limit rows held at a bound, carried from step to
step and changed the primal-dual way (:func:`_qp_step`); the infeasibility in the filter counts
how far the limits are broken as well as the equalities. On such problems it takes fewer
factorisations than an interior point takes iterations from its barrier's start
(docs/performance.md). Obstacles are left to the interior point: from the reference, which runs
through them, the way round is too nonconvex for these steps (the Hessian needs more shifts than
allowed).

There is no restoration phase and no second-order correction: a step the filter still rejects
at ``alpha_min``, the iteration budget, too many shifts (a nonconvex stretch), a step that is
not finite, a final step that leaves the infeasibility above ``final_infeasibility`` (an
ill-conditioned KKT matrix whose LDLᵀ stalls the steps short of the solution), a stationary
point that is not a minimum, a working set that keeps cycling or steps that crawl
(``max_unsettled``, ``max_crawled``; all in :class:`LineSearchOptions`), or the deadline end
it unconverged, and the caller solves by interior point from the same guess (but not past its
deadline). A local method with another globalisation than fatrop's: on nonconvex problems it
may settle in another local minimum than fatrop from the same guess, lower or higher.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nh_tracking.solvers.newton import NewtonStep
from nh_tracking.solvers.nlp import DEADLINE, Iterate, Outcome, Pace
from nh_tracking.solvers.working_set import check_budgets, WorkingSet


@dataclass(frozen=True)
class LineSearchOptions:
    """The line search's tuning: its budget, the filter, the Hessian's shift, convergence.

    (Its working set holds and lets go of rows by :class:`.working_set.WorkingSetOptions`'
    defaults.)
    """

    max_iterations: int = 20
    """Newton steps at most, the last one counted (the paper's sleigh from the reference takes
    11, with a terminal cost 17)."""
    alpha_min: float = 1e-6
    """The shortest step tried before giving up to the interior point."""
    gamma_theta: float = 1e-5
    """A trial must improve the infeasibility by this margin, ..."""
    gamma_f: float = 1e-5
    """... or the cost."""
    armijo: float = 1e-4
    """Sufficient decrease of f, once nearly feasible and the step descends."""
    s_theta: float = 1.1
    """The switching rule between the two (IPOPT's values): this exponent, ..."""
    s_f: float = 2.3
    """... this one, ..."""
    delta: float = 1.0
    """... and this factor."""
    theta_max: float = 1e4
    """The largest infeasibility a trial may have, relative to max(1, the guess's)."""
    theta_min: float = 1e-4
    """Relative likewise: below it, f decides."""
    curvature: float = 1e-8
    """dwᵀ(H + shift I)dw >= this |dw|², or the Hessian is shifted."""
    max_shifted: int = 6
    """Shifted factorisations in all: past this the way is nonconvex, where this test lets the
    steps end on saddles and fatrop's inertia correction does better (solves that converge
    need few shifts); it also bounds the shift, 1e-4 * 100^6 at most."""
    shift_first: float = 1e-4
    """The shift's first try (IPOPT's inertia correction), ..."""
    shift_jump: float = 100.0
    """... its growth while no shift was needed the iteration before, ..."""
    shift_growth: float = 8.0
    """... its growth otherwise, ..."""
    shift_decay: float = 1 / 3
    """... and from one iteration's shift to the next's first try."""
    step_tol: float = 1e-6
    """Converged: an unshifted step moves no unknown by more (relative to the largest) ..."""
    feasibility_tol: float = 1e-6
    """... and no row is broken by more; the step is taken, and as Newton's convergence is
    quadratic, the plan is then within about 1e-12 of the solution ..."""
    final_infeasibility: float = 1e-9
    """... which the infeasibility after that step must show."""
    max_qp_factorisations: int = 2
    """Tries to settle a step's working set; then the last try is the step. With bounds the
    steps are given up early where they fail (then fatrop takes over, the attempt paid on top),
    which bounds what a failed attempt adds to fatrop's time (docs/performance.md)."""
    max_unsettled: int = 10
    """Unsettled steps in a row: the set cycles (converged solves stay below this)."""
    crawl: float = 0.05
    """Unsettled steps taken this short ..."""
    max_crawled: int = 2
    """... this many times: the QP's direction is poor."""

    def __post_init__(self) -> None:
        check_budgets(self, 'max_iterations', 'max_qp_factorisations')


DEFAULTS = LineSearchOptions()


@dataclass
class _Filter:
    """(infeasibility, f) pairs a trial must not be worse than in both (Wächter & Biegler).

    The infeasibility: |g|₁ of the equalities plus how far the bounds are broken.
    """

    options: LineSearchOptions
    theta_max: float
    theta_min: float
    pairs: list[tuple[float, float]]

    def accepts(self, theta: float, f: float, trial: tuple[float, float], alpha: float,
                slope: float) -> tuple[bool, bool]:
        """Whether the trial (infeasibility, f) at step length alpha is taken, and if by f."""
        theta_trial, f_trial = trial
        if not (np.isfinite(theta_trial) and np.isfinite(f_trial)) or \
                theta_trial > self.theta_max or any(
                    theta_trial >= t and f_trial >= g for t, g in self.pairs):
            return False, False
        o = self.options
        if theta <= self.theta_min and slope < 0 and \
                alpha * (-slope) ** o.s_f > o.delta * theta ** o.s_theta:
            return f_trial <= f + o.armijo * alpha * slope, True
        return (theta_trial <= (1 - o.gamma_theta) * theta
                or f_trial <= f - o.gamma_f * theta), False


def line_search_solve(step: NewtonStep, w: np.ndarray, p: np.ndarray, lower: np.ndarray,
                      upper: np.ndarray, stop: float | None,
                      options: LineSearchOptions | None = None) -> Outcome:
    """Solve min 1/2 |r|^2 s.t. lower <= g <= upper from w (see the module).

    The step's inequality rows are bounded by lower, upper; the others are equalities (g = 0). A
    guess may break the bounds (a cold start). The outcome's iterations are the factorisations
    (one a step without limits, more where the Hessian had to be shifted or the working set
    changed); its multipliers have CasADi's sign, as an NLP solver's. Not converged, it says
    why, with the last iterate (the plan, if the deadline is reached). ``options``: default
    :data:`DEFAULTS`.
    """
    o = DEFAULTS if options is None else options
    rows = WorkingSet(lower, upper, step.inequality)
    multipliers = np.zeros(len(lower))
    shift_last, shifted, short, factorisations = 0.0, 0, False, 0  # short: a small step left g
    (f,), (theta,) = step.merit(w, p, rows.lower, rows.upper)  # above
    scale = max(1.0, float(theta))
    search = _Filter(o, o.theta_max * scale, o.theta_min * scale, [])
    unsettled, crawled = 0, 0  # unsettled steps in a row, unsettled steps shorter than o.crawl
    pace = Pace(stop)
    for _ in range(o.max_iterations):
        if not pace.has_time_for_step():
            return Outcome(Iterate(w, multipliers), False, factorisations, DEADLINE,
                           ran_out=True)
        shift = 0.0
        while True:
            direction, tries, settled = _qp_step(step, rows, w, p, multipliers, shift,
                                                 o.max_qp_factorisations)
            dw, new_multipliers, (slope,), (curvature,), (infeasible,), (f_full,), \
                (theta_full,), _ = direction
            factorisations += tries
            if not (np.isfinite(curvature) and np.isfinite(dw).all()):
                return _unsettled(w, multipliers, factorisations, 'a step not finite')
            if curvature >= o.curvature * float(dw @ dw):
                break
            if shift == 0.0:
                shift = max(o.shift_first, o.shift_decay * shift_last)
            else:
                shift *= o.shift_growth if shift_last else o.shift_jump
            shifted += 1
            if shifted > o.max_shifted:
                return _unsettled(w, multipliers, factorisations, 'nonconvex')
        shift_last = shift
        small = shift == 0.0 and settled and infeasible <= o.feasibility_tol and \
            np.max(np.abs(dw)) <= o.step_tol * max(1.0, float(np.max(np.abs(w))))
        if small and theta_full <= o.final_infeasibility:
            w = w + dw
            if not step.minimum(w, p, *rows.arguments(), new_multipliers):
                return _unsettled(w, new_multipliers, factorisations, 'a saddle')
            return Outcome(Iterate(w, new_multipliers), True, factorisations,
                           'converged', minimum=True)
        if small and short:  # a second small step that leaves g above: the steps stall
            return _unsettled(w, multipliers, factorisations, 'stalled short of admissible')
        short = small
        unsettled = 0 if settled else unsettled + 1
        if unsettled > o.max_unsettled:
            return _unsettled(w, multipliers, factorisations, 'the working set cycles')
        alpha, trial = 1.0, (float(theta_full), float(f_full))
        while True:
            taken, by_cost = search.accepts(theta, f, trial, alpha, slope)
            if taken:
                break
            alpha /= 2
            if alpha < o.alpha_min:
                return _unsettled(w, multipliers, factorisations, 'no step accepted')
            f_trial, theta_trial = step.merit(w + alpha * dw, p, rows.lower, rows.upper)
            trial = (float(theta_trial[0]), float(f_trial[0]))
        crawled += not settled and alpha < o.crawl
        if crawled >= o.max_crawled:
            return _unsettled(w, multipliers, factorisations, 'crawling')
        if not by_cost:
            search.pairs.append(((1 - o.gamma_theta) * theta, f - o.gamma_f * theta))
        w = w + alpha * dw
        theta, f = trial
        multipliers = multipliers + alpha * (new_multipliers - multipliers)
    return _unsettled(w, multipliers, factorisations, 'iteration budget spent')


def _qp_step(step: NewtonStep, rows: WorkingSet, w: np.ndarray, p: np.ndarray,
             curvature: np.ndarray, shift: float,
             most: int) -> tuple[list[np.ndarray], int, bool]:
    """Return the step's direction with the limits linearised: its QP, by a primal-dual set.

    Each try holds every free row the last one took beyond a bound and lets go of every held
    row whose multiplier has the wrong sign, all at once (Hintermüller, Ito & Kunisch 2002): a
    cold start has dozens of rows to take in, which a primal active set takes one per
    factorisation. After ``most`` tries the direction is the last one's,
    unsettled: the filter judges it like any other, and it is never the last step. Returns
    :meth:`.newton.NewtonStep.direction`'s outputs, the tries and whether the set settled.
    Without inequality rows: one factorisation.
    """
    tries = 0
    while True:
        tries += 1
        direction = step.direction(w, p, *rows.arguments(), curvature, shift, rows.lower,
                                   rows.upper)
        if not rows.limited:
            return direction, tries, True
        changed = rows.hold_broken(direction[-1]) | rows.let_go(direction[1])
        if not changed or tries >= most:
            return direction, tries, not changed


def _unsettled(w: np.ndarray, multipliers: np.ndarray, iterations: int, why: str) -> Outcome:
    return Outcome(Iterate(w, multipliers), False, iterations, why)
