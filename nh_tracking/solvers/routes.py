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

"""One solve of the variational NLP: an ordered table of backends, run by one loop.

:data:`ROUTES` lists (backend, when it runs, how). The first row that applies runs; Newton
steps that do not settle hand over to the next row that applies; the interior point, last,
always applies. Each run is an :class:`~nh_tracking.problem.attempts.Attempt` of the plan's
``attempts``. A new backend is one function from a :class:`Start` (the NLP, the guess as its
unknowns ``w0`` and parameters ``p``, the deadline's pace) to an :class:`~.nlp.Outcome` (the
primal-dual :class:`~.nlp.Iterate` it ended at, and flags its status is read from), or a
:class:`~nh_tracking.problem.attempts.Status` where it has none (handed over, paused), and one row.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
import time

import numpy as np

from nh_tracking.problem.attempts import Attempt, Backend, Status
from nh_tracking.problem.limits import plan_path, VIOLATION_TOL
from nh_tracking.problem.tracking_problem import Solution, TrackingProblem
from nh_tracking.solvers.base import Guess, unsolved
from nh_tracking.solvers.cache import NotPrepared
from nh_tracking.solvers.duals import carried_multipliers, multipliers_at
from nh_tracking.solvers.inequalities import assess_limits, Shape
from nh_tracking.solvers.line_search import line_search_solve
from nh_tracking.solvers.midpoint import (Transcription, transcription, working_set_step,
                                          WorkingSetStep)
from nh_tracking.solvers.newton import newton_steps
from nh_tracking.solvers.nlp import before, halfway, Iterate, Outcome, Pace
from nh_tracking.solvers.working_set import working_set_solve

PAUSE_AFTER, PAUSE = 3, 4  # working-set misses in a row, then one try in this many solves
RTI_RESIDUAL = 1e-3  # a real-time iteration's plan must be this close to admissible
RTI_EXTRA_STEPS = 4  # Gauss-Newton steps beyond the budget while a plan is not yet that close
NOT_FINITE = ('the NLP is not finite at the initial guess (the dynamics or cost give NaN or Inf '
              'there)')


def default_guess(problem: TrackingProblem) -> tuple[np.ndarray, np.ndarray]:
    """Return the reference itself (on q0's branch) as the first guess of the knots."""
    q, v = (a.copy() for a in problem.reference_samples[:2])
    q[0], v[0] = problem.q0, problem.v0
    return q, v


@dataclass(frozen=True)
class Route:
    """How one solve of the NLP runs: its interior point and the rows of g it has.

    ``soft``: limits as penalised slacks (IPOPT); ``newton``: Newton steps first where a row of
    :data:`ROUTES` takes them; ``every``: every disc at every point; ``domain``: the model's
    domain as bounds; ``iterations`` > 0: a real-time iteration (Gauss-Newton steps).
    """

    solver: str = 'fatrop'
    compiled: bool = False
    soft: bool = False
    newton: bool = False
    every: bool = False
    domain: bool = False
    iterations: int = 0


@dataclass
class Start:
    """What every row of :data:`ROUTES` reads: one solve's NLP, guess and budget."""

    problem: TrackingProblem
    tr: Transcription
    guess: Guess | None
    w0: np.ndarray
    p: np.ndarray
    pace: Pace
    stop: float | None
    route: Route
    warm: bool  # a guess within the limits (a previous plan): near the optimum and its set
    step: WorkingSetStep | None  # the Newton steps' KKT step, if a row may take them

    @property
    def searched(self) -> bool:
        """Whether Newton steps here would be a line search's (cold, no obstacles)."""
        return (self.route.newton and not self.warm and not len(self.problem.limits.obstacles)
                and self.tr.soft_index is None and self.route.solver == 'fatrop')

    @property
    def interior(self) -> Backend:
        """The interior point this NLP was built for."""
        return Backend.IPOPT if self.route.solver == 'ipopt' or self.tr.soft_index is not None \
            else Backend.FATROP

    @cached_property
    def bounds(self) -> dict[str, np.ndarray]:
        """The bounds of the constraints (and of the unknowns, for the interior point)."""
        return self.tr.bounds(self.problem)


def _real_time_iteration(start: Start) -> Outcome:
    """Gauss-Newton steps (no limits): the number asked, and a few more while not admissible."""
    iterations = start.route.iterations
    w, lam_g, read, taken = newton_steps(
        start.tr.newton, start.w0, start.p, iterations,  # type: ignore[arg-type]
        lambda read: float(read[3][0]), RTI_RESIDUAL, iterations + RTI_EXTRA_STEPS)
    finite = bool(np.isfinite(w).all())  # (a NaN at the guess spreads through)
    return Outcome(Iterate(w, lam_g), finite, taken,
                   'real-time iteration' if finite else NOT_FINITE, readout=read,
                   not_finite=not finite, to_convergence=False)


def _line_search(start: Start) -> Outcome:
    """Newton steps with a filter line search, leaving the interior point half the time left."""
    assert start.step is not None
    bounds = start.bounds
    held = line_search_solve(start.step.step, start.w0, start.p, bounds['lbg'], bounds['ubg'],
                             halfway(start.stop))
    held.handed_over = not held.success and before(start.stop)
    return held


def _warm_working_set(start: Start) -> Outcome | Status:
    """Newton steps on a working set of the limit rows, from the previous plan's multipliers.

    Where it keeps missing (a degenerate set: a robot turning on the spot at a disc's edge),
    past :data:`PAUSE_AFTER` misses in a row it is tried only every :data:`PAUSE`-th solve.
    """
    assert start.step is not None
    misses = working_set_misses(start.guess)
    if misses >= PAUSE_AFTER and (misses - PAUSE_AFTER) % PAUSE != PAUSE - 1:
        return Status.PAUSED
    step, bounds = start.step, start.bounds
    held = working_set_solve(step.step, step.constraints, start.w0, start.p, bounds['lbg'],
                             bounds['ubg'], step.nonconvex, start.pace, carried_multipliers(
                                 start.tr, start.problem, start.guess, start.p))
    return Status.HANDED_OVER if held is None else Outcome(
        Iterate(held.w, held.multipliers), True, held.factorisations,
        f'converged ({held.active} limit rows active)' if held.limited else 'converged',
        held.minimum, held.minimum_check)


def working_set_misses(guess: Guess | None) -> int:
    """Return the warm solves in a row up to ``guess`` whose working set did not settle."""
    return guess.working_set_misses if isinstance(guess, Guess) else 0


def misses_after(guess: Guess | None, attempts: list[Attempt]) -> int:
    """Return the working set's misses in a row after a solve from ``guess`` that ran these."""
    tried = [a.status for a in attempts if a.backend is Backend.WORKING_SET]
    if Status.CONVERGED in tried:
        return 0
    return working_set_misses(guess) + 1 if tried else working_set_misses(guess)


def _interior_point(start: Start) -> Outcome:
    """Solve by the interior point: fatrop, or IPOPT (soft limits: IPOPT).

    Not started from a guess where the NLP is not finite: fatrop never returns from there (its
    line search cannot recover).
    """
    tr = start.tr
    if not all(np.all(np.isfinite(a)) for a in tr.readout(start.w0, start.p)):
        return Outcome(Iterate(start.w0, np.zeros(0)), False, 0, NOT_FINITE,
                       not_finite=True)
    slacks = 0 if tr.soft_index is None else len(tr.soft_index)
    assert tr.nlp is not None
    return tr.nlp.solve(start.pace, start.warm, x0=np.concatenate([start.w0, np.zeros(slacks)]),
                        p=start.p, **start.bounds)


@dataclass(frozen=True)
class Row:
    """A row of :data:`ROUTES`: the backend, when it runs, and how.

    ``run`` returns the backend's outcome (``handed_over``: the next row that applies runs), or
    a status where it has none (the working set handed over, or was paused).
    """

    backend: Backend | None  # None: the NLP's interior point (:attr:`Start.interior`)
    applies: Callable[[Start], bool]
    run: Callable[[Start], Outcome | Status]  # a status: it handed over (or did not run)


# One solve of the NLP: the first row that applies runs; a row that hands over passes to the
# next that applies. The last always applies.
ROUTES: tuple[Row, ...] = (
    Row(Backend.GAUSS_NEWTON, lambda s: s.tr.nlp is None, _real_time_iteration),
    Row(Backend.LINE_SEARCH, lambda s: s.step is not None and s.searched, _line_search),
    Row(Backend.WORKING_SET, lambda s: s.step is not None and s.warm, _warm_working_set),
    Row(None, lambda s: True, _interior_point),
)


def solve_route(problem: TrackingProblem, initial_guess: Guess | None, stop: float | None,
                route: Route) -> Solution:
    """Solve the NLP ``route`` describes once, by the rows of :data:`ROUTES`."""
    sys = problem.system
    tr = transcription(sys, problem.steps, problem.terminal, stop is not None, route.solver,
                       route.compiled, Shape.of(problem.limits, route.soft, route.every,
                                                route.domain), route.iterations)
    q_g, v_g, u_g = (*default_guess(problem), None) if initial_guess is None else initial_guess[:3]
    q_g, v_g = np.array(q_g, dtype=float), np.array(v_g, dtype=float)
    q_g[0], v_g[0] = problem.q0, problem.v0
    if problem.terminal == 'equality':
        q_g[-1], v_g[-1] = problem.reference_samples[0][-1], problem.reference_samples[1][-1]
    p = tr.parameters(problem, q_g)  # each knot and midpoint keeps clear of the discs nearest it
    warm = initial_guess is not None and problem.limits.plan_violation(
        q_g, v_g, u_g, problem.h) <= VIOLATION_TOL
    w0 = tr.pack(q_g, v_g, u_g)
    start = Start(problem, tr, initial_guess, w0, p, Pace(stop), stop, route, warm, None)
    # the Newton steps' KKT step, built outside the timing (none from a guess with NaN: their
    # failing there would count against the structure)
    if route.newton and (warm or start.searched) and np.isfinite(w0).all():
        start.step = _held_step(problem, tr, route.compiled)
    began, attempts = time.perf_counter(), []
    for row in ROUTES:
        if not row.applies(start):
            continue
        tried = time.perf_counter()
        outcome = row.run(start)
        backend = row.backend or start.interior
        if isinstance(outcome, Status):  # handed over (or paused): the next row that applies
            attempts.append(Attempt(backend, outcome, 0, time.perf_counter() - tried))
            continue
        attempts.append(Attempt(backend, outcome.status, outcome.iterations,
                                time.perf_counter() - tried))
        if not outcome.handed_over:
            break
    # (the last row always runs, and never hands over)
    assert isinstance(outcome, Outcome) and not outcome.handed_over
    elapsed = time.perf_counter() - began
    if outcome.not_finite and backend is not Backend.GAUSS_NEWTON:
        return unsolved(problem, 'variational', NOT_FINITE, elapsed, q_g, v_g,
                        route.solver, attempts)
    w = outcome.iterate.w[:tr.unknowns]
    q, v, u, residual, cost, end_error = outcome.readout or tr.readout(w, p)
    q, v, u, max_residual = q.T.copy(), v.T.copy(), u.T.copy(), float(residual[0])
    lam_g = outcome.iterate.lam_g
    # The paper's multipliers are lambda^k = (h/2) c_k (c_k: multiplier of the stage form of
    # the admissibility constraint); the reported costates are lambda = -lambda^k / h. For
    # mu: u* = -B^T mu / eps, so mu = -eps u fully actuated, else minus the multiplier of
    # the discrete dynamics (written in h-scaled form).
    lam = -0.5 * lam_g[tr.admissibility_rows].reshape(problem.steps, sys.n)
    mu = (-problem.epsilon * u if sys.fully_actuated
          else -lam_g[tr.dynamics_rows].reshape(problem.steps, sys.k))
    success, message, violation, check = assess_limits(
        tr.limits, problem.limits, tr.soft_index is not None,
        outcome.success and bool(np.isfinite(w).all()), plan_path(q), v, u, problem.h,
        outcome.message)
    return Solution(
        t=problem.grid, q=q, v=v, u=u, cost=float(cost[0]), success=success,
        iterations=outcome.iterations, solve_time=elapsed,
        terminal_error=float(end_error[0]), method='variational',
        message=message, route=_route_name(backend, tr), local_minimum=outcome.minimum,
        # (the check of this NLP's rows; other rows' plans are not the nominal problem's)
        minimum_check=None if route.every or route.domain else outcome.minimum_check,
        costates=(lam, mu), multipliers=multipliers_at(tr, problem, lam_g, p),
        details={'admissibility_residual': max_residual, 'violation': violation},
        limit_check=check, attempts=attempts)


def _route_name(backend: Backend, tr: Transcription) -> str:
    """``Solution.route``'s words for the backend that made the plan."""
    if backend is Backend.IPOPT and tr.soft_index is not None:
        return 'ipopt (soft limits)'
    return backend.value


def _held_step(problem: TrackingProblem, tr: Transcription,
               compiled: bool) -> WorkingSetStep | None:
    """Return the Newton step of a warm solve or a line search (None: none yet, or soft)."""
    if tr.soft_index is not None:
        return None
    try:
        return working_set_step(problem.system, problem.steps, problem.terminal,
                                tr.limits.shape, compiled)
    except NotPrepared:  # built in the background (replanning, or out of time)
        return None
