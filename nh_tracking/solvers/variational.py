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

from collections.abc import Callable
import dataclasses
from dataclasses import dataclass
from functools import partial
from typing import ClassVar, Literal

from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.problem.attempts import Status
from nh_tracking.problem.limits import VIOLATION_TOL
from nh_tracking.problem.tracking_problem import Solution, TrackingProblem
from nh_tracking.solvers.base import Guess, Method, next_route, Structure, time_left
from nh_tracking.solvers.cache import builds_until, NotPrepared
from nh_tracking.solvers.duals import carried_multipliers
from nh_tracking.solvers.inequalities import Shape, start_violation
from nh_tracking.solvers.midpoint import BACKENDS, transcription, working_set_step
from nh_tracking.solvers.nlp import deadline_after
from nh_tracking.solvers.obstacles import clear_of_every_disc
from nh_tracking.solvers.routes import misses_after, Route, RTI_RESIDUAL, solve_route
from nh_tracking.solvers.working_set import WorkingSet

CONTINUATION_MIN_STEPS = 100  # cold solves with this many intervals or more start coarse
COARSE_STEPS = 50


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
    (none without limits), any other without obstacles (fatrop's NLP) by the same steps
    with a line search (:mod:`.line_search`); the interior point if they do not settle. False:
    always the interior point (a search from perturbed guesses, where Newton's method would
    converge to the saddle it looks past).
    """
    return solve_variational_until(problem, initial_guess, deadline_after(max_time), solver,
                                   compiled, iterations, newton)


@dataclass(frozen=True)
class Retry:
    """A row of :data:`RETRIES`: when a plan calls for another route, and which, from the first."""

    applies: Callable[[TrackingProblem, Solution, Route], bool]
    why: Callable[[Solution], str]
    route: Callable[[Route], Route]


RETRIES: tuple[Retry, ...] = (
    Retry(lambda problem, plan, first: not plan.success and first.solver == 'fatrop'
          and not first.soft,
          lambda plan: f'fatrop failed ({plan.message}) -> ipopt',
          lambda first: Route('ipopt')),
    Retry(lambda problem, plan, first: not plan.success and problem.limits.active
          and not first.soft and not plan.limit_check.through_disc,  # e.g. a goal in a disc
          lambda plan: f'{plan.route} failed ({plan.message}) -> soft limits',
          lambda first: Route(first.solver, first.compiled, soft=True)),
    Retry(lambda problem, plan, first: problem.system.domain.bounded
          and not problem.system.domain.contains(plan.q),
          lambda plan: f"{plan.route} left the model's domain -> the domain as bounds",
          lambda first: dataclasses.replace(first, domain=True)),
)


def solve_variational_until(problem: TrackingProblem, initial_guess: Guess | None,
                            stop: float | None, solver: str = 'fatrop',
                            compiled: bool = False, iterations: int = 0,
                            newton: bool = True) -> Solution:
    """:func:`solve_variational` with an absolute stop time (perf_counter clock) or None.

    A real-time iteration counts only if its plan is a trajectory of the model (admissibility
    residual <= :data:`RTI_RESIDUAL`) within the limits; otherwise (a jump in the reference,
    a limit becoming active) the solve converges, within the same deadline. With limits it
    always converges: one interior-point step there is only part of the correction. A plan
    that fails, or leaves the model's domain, is solved again by the first row of
    :data:`RETRIES` that applies, and so on down the rows, while time is left.
    """
    first = Route(solver, compiled, start_violation(problem) > VIOLATION_TOL, newton)
    earlier: list[Solution] = []  # what ran before the first route: on the same clock
    if iterations and initial_guess is not None and not problem.limits.active:
        quick = solve_route(problem, initial_guess, stop,
                            Route(solver, compiled, iterations=iterations))
        if quick.success and quick.details['admissibility_residual'] <= RTI_RESIDUAL:
            quick.working_set_misses = misses_after(initial_guess, quick.attempts)
            return quick
        if quick.success:  # not yet a trajectory of the model: the converged solve takes over
            quick.attempts[-1] = dataclasses.replace(quick.attempts[-1],
                                                     status=Status.HANDED_OVER)
        earlier.append(quick)
    if initial_guess is None and problem.steps >= CONTINUATION_MIN_STEPS:
        coarse = dataclasses.replace(problem, steps=COARSE_STEPS)
        coarse_plan = solve_variational_until(coarse, None, stop, solver, compiled,
                                              newton=newton)
        earlier.append(coarse_plan)
        if coarse_plan.success:
            q, v = coarse_plan.trajectory().sample(problem.grid)
            initial_guess = Guess(q, v, None)

    def run(route: Route) -> Solution:
        return clear_of_every_disc(lambda guess, every: solve_route(
            problem, guess, stop, dataclasses.replace(route, every=every)), initial_guess, stop,
            problem)

    result = run(first).follows(*earlier)
    for retry in RETRIES:
        if time_left(result, stop) and retry.applies(problem, result, first):
            result = next_route(result, retry.why(result), partial(run, retry.route(first)))
    result.working_set_misses = misses_after(initial_guess, result.attempts)
    return result


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
                                tr.limits.shape, compiled)
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
            working_set_step(system, structure.steps, structure.terminal, limits, self.compiled)

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
