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

"""Discrete variational (midpoint) transcription of the tracking problem (paper §5).

Unknowns are the knots x_k = (q_k, v_k), k = 1..N, of a curve on D. The discrete Lagrangian
is h L(q_{k+1/2}, v_{k+1/2}, v_{k,k+1}) — L written in (q, v, vdot) by eliminating the control,
u = vdot + Gamma(v, v) + grad V — and the discrete admissibility constraint is the corrected
Psi_d (docs/theory.md C13): (q_{k+1} - q_k)/h = rho(q_{k+1/2}) v_{k+1/2}, k = 0..N-1. An
underactuated system (r < k controls) cannot eliminate u: it stays an unknown of each interval,
with the discrete dynamics v_{k+1} - v_k = h (f(q_{k+1/2}, v_{k+1/2}) + B(q_{k+1/2}) u_k) as a
constraint.

The NLP is built once per (system, N, terminal kind); everything that changes between solves
(initial state, reference samples, h, eps, omega) is a parameter, so replanning only updates
numbers and warm-starts.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import time
from typing import ClassVar, Literal

import numpy as np

from nh_tracking.limits import plan_path
from nh_tracking.problem import Solution, TrackingProblem
from nh_tracking.solvers.base import (clear_of_every_disc, Guess, Method, next_route, Structure,
                                      time_left, unsolved)
from nh_tracking.solvers.cache import builds_until, NotPrepared
from nh_tracking.solvers.duals import carried_multipliers, multipliers_at
from nh_tracking.solvers.inequalities import judged, Shape, start_violation, VIOLATION_TOL
from nh_tracking.solvers.line_search import line_search_solve
from nh_tracking.solvers.midpoint import (BACKENDS, Transcription, transcription,
                                          working_set_step, WorkingSetStep)
from nh_tracking.solvers.newton import newton_steps
from nh_tracking.solvers.nlp import before, deadline_after, halfway, Outcome, Pace
from nh_tracking.solvers.working_set import working_set_solve, WorkingSet
from nh_tracking.system import NonholonomicSystem

PAUSE_AFTER, PAUSE = 3, 4  # working-set failures in a row, then one try in this many solves
RTI_RESIDUAL = 1e-3  # a real-time iteration's plan must be this close to admissible
RTI_EXTRA_STEPS = 4  # Gauss-Newton steps beyond the budget while a plan is not yet that close
CONTINUATION_MIN_STEPS = 100  # cold solves with this many intervals or more start coarse
COARSE_STEPS = 50
NOT_FINITE = ('the NLP is not finite at the initial guess (the dynamics or cost give NaN or Inf '
              'there)')


def default_guess(problem: TrackingProblem) -> tuple[np.ndarray, np.ndarray]:
    """Return the reference itself (on q0's branch) as the first guess of the knots."""
    q, v = (a.copy() for a in problem.reference_samples[:2])
    q[0], v[0] = problem.q0, problem.v0
    return q, v


def solve_variational(problem: TrackingProblem, initial_guess: Guess | None = None,
                      max_time: float | None = None, solver: str = 'fatrop',
                      compiled: bool = False, iterations: int = 0, newton: bool = True
                      ) -> Solution:
    """Solve the discrete variational NLP from (q (N+1, n), v (N+1, k)[, u (N, r)]) as guess.

    ``max_time`` [s] bounds the wall time of the whole solve, every route included. A fatrop
    failure is retried with IPOPT while time remains (the route says so). A cold solve on a
    fine grid starts from the plan of a coarse grid, interpolated (grid continuation): from the
    reference alone, fine grids spend most iterations backtracking. ``iterations`` > 0 with a
    guess: a real-time iteration — that many Newton steps on the guess (a warm-started previous
    plan), converged or not; without a guess the solve converges. ``newton``: a guess within
    the limits (a previous plan) is solved by Newton steps on a working set of the limit rows
    (none without limits), any other without obstacles (interpreted fatrop) by the same steps
    with a line search (:mod:`.line_search`); the interior point if they do not settle. False:
    always the interior point (a search from perturbed guesses, where Newton's method would
    converge to the saddle it looks past).
    """
    return solve_variational_until(problem, initial_guess, deadline_after(max_time), solver,
                                   compiled, iterations, newton)


def solve_variational_until(problem: TrackingProblem, initial_guess: Guess | None,
                            stop: float | None, solver: str = 'fatrop',
                            compiled: bool = False, iterations: int = 0,
                            newton: bool = True) -> Solution:
    """:func:`solve_variational` with an absolute stop time (perf_counter clock) or None.

    A real-time iteration counts only if its plan is a trajectory of the model (admissibility
    residual <= :data:`RTI_RESIDUAL`) within the limits; otherwise (a jump in the reference,
    a limit becoming active) the solve converges, within the same deadline. With limits it
    always converges: one interior-point step there is only part of the correction.
    """
    soft = start_violation(problem) > VIOLATION_TOL  # only the least-violating plan exists
    coarse_time = 0.0
    if iterations and initial_guess is not None and not problem.limits.active:
        quick = _solve_with(problem, initial_guess, stop, solver, compiled, False, iterations)
        if quick.success and quick.details['admissibility_residual'] <= RTI_RESIDUAL:
            return quick
        coarse_time = quick.solve_time
    if initial_guess is None and problem.steps >= CONTINUATION_MIN_STEPS:
        coarse = dataclasses.replace(problem, steps=COARSE_STEPS)
        coarse_plan = solve_variational_until(coarse, None, stop, solver, compiled,
                                              newton=newton)
        coarse_time += coarse_plan.solve_time
        if coarse_plan.success:
            q, v = coarse_plan.trajectory().sample(problem.grid)
            initial_guess = Guess(q, v, None)

    def route(solver: str, compiled: bool, soft: bool, newton: bool = False,
              domain: bool = False) -> Solution:
        return clear_of_every_disc(lambda guess, every: _solve_with(
            problem, guess, stop, solver, compiled, soft, newton=newton, every=every,
            domain=domain), initial_guess, stop, problem)

    result = route(solver, compiled, soft, newton)
    result.solve_time += coarse_time
    if not result.success and solver == 'fatrop' and not soft and time_left(result, stop):
        result = next_route(result, f'fatrop failed ({result.message}) -> ipopt',
                            lambda: route('ipopt', False, False))
    if not result.success and problem.limits.active and not soft and time_left(result, stop) and \
            not result.limit_check.through_disc:  # e.g. a terminal state inside an obstacle
        result = next_route(result, f'{result.route} failed ({result.message}) -> soft limits',
                            lambda: route(solver, compiled, True))
    domain = problem.system.domain
    if domain.bounded and not domain.contains(result.q) and time_left(result, stop):
        result = next_route(result, f"{result.route} left the model's domain -> the domain as "
                            'bounds', lambda: route(solver, compiled, soft, newton, True))
    return result


def _solve_with(problem: TrackingProblem, initial_guess: Guess | None, stop: float | None,
                solver: str, compiled: bool = False, soft: bool = False,
                iterations: int = 0, newton: bool = False, every: bool = False,
                domain: bool = False) -> Solution:
    sys = problem.system
    tr = transcription(sys, problem.steps, problem.terminal, stop is not None, solver,
                       compiled, Shape.of(problem.limits, soft, every, domain), iterations)
    q_g, v_g, u_g = (*default_guess(problem), None) if initial_guess is None else initial_guess[:3]
    q_g, v_g = np.array(q_g, dtype=float), np.array(v_g, dtype=float)
    q_g[0], v_g[0] = problem.q0, problem.v0
    if problem.terminal == 'equality':
        q_g[-1], v_g[-1] = problem.reference_samples[0][-1], problem.reference_samples[1][-1]
    p = tr.parameters(problem, q_g)  # each knot and midpoint keeps clear of the discs nearest it
    # a guess within the limits (a previous plan) is warm: near the optimum and its active set
    warm = initial_guess is not None and problem.limits.plan_violation(
        q_g, v_g, u_g, problem.h) <= VIOLATION_TOL
    # Newton steps first (built outside the timing): a working set from a warm guess, a line
    # search from a cold one without obstacles (only the interpreted fatrop's: :mod:`.line_search`)
    searched = (newton and not warm and not len(problem.limits.obstacles)
                and tr.soft_index is None and solver == 'fatrop' and not compiled)
    held_step = _held_step(problem, tr) if newton and (warm or searched) else None
    start, pace = time.perf_counter(), Pace(stop)
    w0 = tr.pack(q_g, v_g, u_g)
    read: list[np.ndarray] = []  # the plan read from the unknowns (a Newton step gives it)
    route = solver if tr.soft_index is None else 'ipopt (soft limits)'
    if tr.nlp is None:  # a real-time iteration without limits: Gauss-Newton steps
        w_new, lam_g, read, taken = newton_steps(
            tr.newton, w0, p, iterations,  # type: ignore[arg-type]
            lambda read: float(read[3][0]), RTI_RESIDUAL, iterations + RTI_EXTRA_STEPS)
        finite = bool(np.isfinite(w_new).all())  # (a NaN at the guess spreads through)
        outcome, route = Outcome({'x': w_new, 'lam_g': lam_g}, finite, taken, (
            'real-time iteration' if finite else NOT_FINITE)), 'gauss-newton'
    else:
        bounds = tr.bounds(problem)
        slacks = 0 if tr.soft_index is None else len(tr.soft_index)
        # (a guess with NaN gets no Newton steps: they would count as the structure failing)
        held = None
        if held_step is not None and np.isfinite(w0).all():
            if searched:  # not converged: the interior point, with at least half the time left
                held = line_search_solve(held_step.step, w0, p, bounds['lbg'], bounds['ubg'],
                                         halfway(stop))
                held = None if not held.success and before(stop) else held
            else:
                held = _working_set(held_step, w0, p, bounds, pace,
                                    carried_multipliers(tr, problem, initial_guess, p))
        if held is not None:
            outcome, route = held, f"newton ({'line search' if searched else 'working set'})"
        elif not all(np.all(np.isfinite(a)) for a in tr.readout(w0, p)):
            # fatrop never returns from a non-finite starting point (its line search cannot
            # recover): refuse to start, and say why (Newton steps from it give up at once)
            return unsolved(problem, 'variational', NOT_FINITE, time.perf_counter() - start, q_g,
                            v_g, solver)
        else:  # cold, or the working set did not settle: interior point (if the time is left)
            outcome = tr.nlp.solve(pace, warm, x0=np.concatenate([w0, np.zeros(slacks)]), p=p,
                                   **bounds)
    elapsed = time.perf_counter() - start
    w = np.array(outcome.result['x']).ravel()[:tr.unknowns]
    q, v, u, residual, cost, end_error = read or tr.readout(w, p)
    q, v, u, max_residual = q.T.copy(), v.T.copy(), u.T.copy(), float(residual[0])
    lam_g = np.array(outcome.result['lam_g']).ravel()
    # The paper's multipliers are lambda^k = (h/2) c_k (c_k: multiplier of the stage form of
    # the admissibility constraint); the reported costates are lambda = -lambda^k / h. For
    # mu: u* = -B^T mu / eps, so mu = -eps u fully actuated, else minus the multiplier of
    # the discrete dynamics (written in h-scaled form).
    lam = -0.5 * lam_g[tr.admissibility_rows].reshape(problem.steps, sys.n)
    mu = (-problem.epsilon * u if sys.fully_actuated
          else -lam_g[tr.dynamics_rows].reshape(problem.steps, sys.k))
    success, message, violation, check = judged(
        tr.limits, problem.limits, tr.soft_index is not None,
        outcome.success and bool(np.isfinite(w).all()), plan_path(q), v, u, problem.h,
        outcome.message)
    return Solution(
        t=problem.grid, q=q, v=v, u=u, cost=float(cost[0]), success=success,
        iterations=outcome.iterations, solve_time=elapsed,
        terminal_error=float(end_error[0]), method='variational',
        message=message, route=route, local_minimum=outcome.minimum,
        minimum_check=outcome.minimum_check,
        costates=(lam, mu), multipliers=multipliers_at(tr, problem, lam_g, p),
        details={'admissibility_residual': max_residual, 'violation': violation},
        limit_check=check)


def _held_step(problem: TrackingProblem, tr: Transcription) -> WorkingSetStep | None:
    """Return the working set's step of a warm solve (hard limits or none; None: none yet)."""
    if tr.soft_index is not None:
        return None
    try:
        return working_set_step(problem.system, problem.steps, problem.terminal,
                                tr.limits.shape)
    except NotPrepared:  # built in the background (replanning, or out of time)
        return None


def _working_set(step: WorkingSetStep, w0: np.ndarray, p: np.ndarray,
                 bounds: dict[str, np.ndarray], pace: Pace,
                 multipliers: np.ndarray | None) -> Outcome | None:
    """Replan by Newton steps on a working set of the limit rows (None: it did not settle).

    Where it keeps failing (a degenerate set: a robot turning on the spot at a disc's edge),
    it is tried only every PAUSE-th solve: each failure costs up to 24 factorisations.
    """
    step.tries += 1
    if step.failures >= PAUSE_AFTER and step.tries % PAUSE:
        return None
    held = working_set_solve(step.step, step.constraints, w0, p, bounds['lbg'], bounds['ubg'],
                             step.nonconvex, pace, multipliers)
    step.failures = 0 if held is not None else step.failures + 1
    return None if held is None else Outcome(
        {'x': held.w, 'lam_g': held.multipliers}, True, held.factorisations,
        f'converged ({held.active} limit rows active)' if held.limited else 'converged',
        held.minimum, held.minimum_check)


def proven_minimum(problem: TrackingProblem, plan: Solution, solver: str = 'fatrop',
                   compiled: bool = False, bounded: bool = False) -> bool:
    """Whether the KKT matrix's inertia at ``plan`` proves a strict local minimum.

    One factorisation, with the plan's multipliers and its limit rows at a bound held: the
    Lagrangian's Hessian curves up on the rows' tangent space. False where it cannot tell (a
    plan of other rows: soft limits, the domain as bounds; the step not built yet).
    """
    if not plan.success:
        return False
    if plan.local_minimum:  # the route checked it
        return True
    if plan.minimum_check is not None:  # the route can tell at once
        return plan.minimum_check()
    tr = transcription(problem.system, problem.steps, problem.terminal, bounded, solver,
                       compiled, Shape.of(problem.limits, False, False, False))
    try:
        held = working_set_step(problem.system, problem.steps, problem.terminal,
                                tr.limits.shape)
    except NotPrepared:
        return False
    p = tr.parameters(problem, plan.q)
    multipliers = carried_multipliers(tr, problem, Guess(plan.q, plan.v, plan.u,
                                                         plan.multipliers), p)
    if multipliers is None:
        return False
    w = tr.pack(plan.q, plan.v, plan.u)
    bounds = tr.bounds(problem)
    rows = WorkingSet(bounds['lbg'], bounds['ubg'])
    rows.hold_reached(held.constraints(w, p)[0])
    return held.step.minimum(w, p, *rows.arguments(), multipliers)


@dataclass(frozen=True)
class Variational(Method):
    """The paper's discrete variational (midpoint) transcription.

    Solved by ``backend`` (fatrop exploits the stage structure; IPOPT is the general fallback).
    ``compiled`` runs the NLP's derivatives as C, compiled once per structure and machine
    (:mod:`.compiled`). ``iterations`` > 0: real-time iterations — each warm-started solve
    takes that many Newton steps and stops, converged or not (0: to convergence). ``newton``:
    converged warm solves by Newton steps on a working set, cold ones without obstacles by Newton
    steps with a line search (see :func:`solve_variational`).
    """

    backend: Literal['fatrop', 'ipopt'] = 'fatrop'
    compiled: bool = False
    iterations: int = 0
    newton: bool = True
    name: ClassVar[str] = 'variational'

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f'variational backend must be one of {BACKENDS}, '
                             f'got {self.backend!r}')
        for option in ('compiled', 'newton'):
            if not isinstance(getattr(self, option), bool):
                raise TypeError(f'variational option {option} must be a bool, got '
                                f'{getattr(self, option)!r}')
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or \
                self.iterations < 0:
            raise ValueError(f'variational option iterations must be an integer >= 0, got '
                             f'{self.iterations!r}')

    def prepare(self, system: NonholonomicSystem, structure: Structure) -> None:
        # a solve without a guess converges, and so does every solve with limits
        rti = self.iterations if structure.limits == Shape() else 0
        for iterations in {rti, 0}:
            transcription(system, structure.steps, structure.terminal,
                          structure.deadline is not None, self.backend, self.compiled,
                          structure.limits, iterations)
        limits = structure.limits
        if self.newton and structure.replanned and not limits.soft:
            working_set_step(system, structure.steps, structure.terminal, limits)

    def proves_minimum(self, problem: TrackingProblem, plan: Solution,
                       stop: float | None = None) -> bool:
        if self.iterations:  # a real-time iteration's plan is not converged
            return False
        try:
            with builds_until(stop):
                return proven_minimum(problem, plan, self.backend, self.compiled,
                                      stop is not None)
        except NotPrepared:
            return False

    def globalised(self) -> Variational:
        return dataclasses.replace(self, newton=False)

    def solve_until(self, problem: TrackingProblem, guess: Guess | None,
                    stop: float | None) -> Solution:
        return solve_variational_until(problem, guess, stop, self.backend, self.compiled,
                                       self.iterations, self.newton)
