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

"""Beyond one local solve: a second look from a perturbed plan, and multi-start search.

A local method converges to *a* stationary point. From a symmetric start (a sleigh at rest
asked to slide sideways: turning left and right are equally good) that point is a saddle, or
the solver calls a reachable target infeasible. A second solve from a slightly perturbed copy
of the plan breaks the symmetry: a lower cost there proves the first point was no minimum.
Multi-start runs many guesses in parallel processes and keeps the distinct minima — counting
only plans that replay on the continuous dynamics, not artefacts of the time step.
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
import dataclasses
import multiprocessing
import os

import numpy as np

from nh_tracking.core.simulate import simulate
from nh_tracking.problem.tracking_problem import Solution, TrackingProblem
from nh_tracking.solvers.base import Guess, Method, Structure, time_left
from nh_tracking.solvers.replay import interval_gap, REPLAY_RTOL

DISTINCT_RTOL = 1e-4  # two local minima are the same when their costs agree to this
LOWER_RTOL = 1e-6  # a second look must beat the first cost by this to count
LOOK_SCALE = 0.05  # relative size of the second look's perturbation
MULTI_START_SCALE = 6.0  # local minima differ by whole windings: large excursions


def random_guess(problem: TrackingProblem, rng: np.random.Generator,
                 around: Guess | None = None, scale: float = MULTI_START_SCALE) -> Guess:
    """Return ``around`` (default: the reference) plus smooth random excursions vanishing at t0.

    ``scale`` is in units of the coordinates and velocities, angles get 5/3 of it: at the
    multi-start's default, several units and more than a turn and a half, because on the
    paper's sleigh smaller excursions all fall back into the best basin.
    """
    sys = problem.system
    q, v = problem.reference_samples[:2] if around is None else around[:2]
    u = None if around is None else around[2]
    s = (problem.grid - problem.grid[0]) / problem.horizon

    def excursion(columns: int, amplitude: np.ndarray) -> np.ndarray:
        freq = rng.uniform(0.3, 2.0, size=(3, columns))
        amp = rng.normal(size=(3, columns)) * amplitude
        return np.einsum('jc,tjc->tc', amp, np.sin(np.pi * freq[None] * s[:, None, None]))
    q_scale = scale * np.where(sys.angle_mask, 5 / 3, 1.0)
    return Guess(q + excursion(sys.n, q_scale), v + excursion(sys.k, np.full(sys.k, scale)),
                 np.zeros((problem.steps, sys.r)) if u is None else u)


def second_look(problem: TrackingProblem, method: Method, first: Solution,
                stop: float | None, seed: int) -> Solution:
    """Re-solve from a perturbed copy of ``first`` (or of the reference, if it failed).

    Before the call's ``stop`` (perf_counter clock, or None; past it, or ``first`` ran out of
    time: ``first`` as it is). The perturbation is scaled by the extent of the reference's
    motion (not by where it lies: a heading wound several turns, far coordinates) and kept
    inside the model's domain.
    """
    if not time_left(first, stop):
        return first
    if method.proves_minimum(problem, first, stop):
        first.local_minimum = True
        return first
    rng = np.random.default_rng(seed)
    base = Guess(first.q, first.v, first.u) if first.success else None
    guess = random_guess(problem, rng, base, LOOK_SCALE * motion_extent(problem))
    system = problem.system
    guess = Guess(system.domain.inside(guess.q, range(system.n)), guess.v, guess.u)
    second = method.globalised().solve_before(problem, guess, stop)
    total = first.solve_time + second.solve_time
    better = second.success and (not first.success or second.cost < first.cost - LOWER_RTOL * (
        1.0 + abs(first.cost)))
    if not better:
        first.solve_time = total
        first.attempts += second.attempts
        return first
    if first.success:
        second.message = (f'{second.message}; the first stationary point (cost '
                          f'{first.cost:.6g}) is not a minimum: a perturbed start went lower')
        second.details['saddle_cost'] = first.cost
    else:
        second.message = f'{second.message} (from a perturbed start; first: {first.message})'
    second.route = f'{second.route} -> perturbed restart'
    second.follows(first)
    return second


def replay_checked(problem: TrackingProblem, plan: Solution) -> Solution:
    """Return the plan, no success if an interval does not replay on the continuous dynamics."""
    if not plan.success:
        return plan
    gap = interval_gap(problem.system, plan.t, plan.q, plan.v, plan.u)
    plan.details['interval_gap'] = gap
    if gap > REPLAY_RTOL:
        plan.success = False
        strays = ('overflows' if np.isinf(gap) else f"strays by {gap:.3g} of the plan's size")
        plan.message = (f'{plan.message}; but it does not replay on the continuous dynamics '
                        f"(an interval's replay {strays}): steps of {problem.h:.3g} s are too "
                        'long for them (more steps, or a shorter horizon)')
    return plan


def motion_extent(problem: TrackingProblem) -> float:
    """1 + how far the reference moves over the horizon, in its largest coordinate."""
    q_ref = problem.reference_samples[0]
    return 1.0 + float(np.ptp(q_ref, axis=0).max())


def replay_gap(problem: TrackingProblem, plan: Solution) -> float:
    """Largest gap between the plan's knots and its controls replayed, relative to its size."""
    try:
        replayed = simulate(problem.system, plan.q[0], plan.v[0], plan.t, plan.u,
                            rtol=1e-8, atol=1e-10)
    except (RuntimeError, ValueError):
        return float('inf')
    x, y = np.hstack([plan.q, plan.v]), np.hstack([replayed.q, replayed.v])
    return float(np.abs(x - y).max() / (1.0 + np.abs(x).max()))


_POOL_PROBLEM: tuple[TrackingProblem, Method, float | None] | None = None


def _pool_solve(guess: Guess | None) -> Solution:
    assert _POOL_PROBLEM is not None  # set before the pool forks
    problem, method, max_time = _POOL_PROBLEM
    solution = method.solve(problem, guess, max_time)
    if solution.success:
        solution.details['replay_gap'] = replay_gap(problem, solution)
    # (closures do not pickle)
    return dataclasses.replace(solution, control_law=None, minimum_check=None)


def multi_start(problem: TrackingProblem, method: Method, guess: Guess | None, starts: int,
                seed: int, processes: int | None, max_time: float | None) -> Solution:
    """Solve from ``guess`` and ``starts`` - 1 random excursions around it, in processes."""
    global _POOL_PROBLEM
    method = method.globalised()
    rng = np.random.default_rng(seed)
    guesses = [guess] + [random_guess(problem, rng, guess) for _ in range(starts - 1)]
    method.prepare(problem.system, Structure(problem.steps, problem.terminal, max_time))
    workers = max(1, min(starts, processes or os.cpu_count() or 1))
    _POOL_PROBLEM = (problem, method, max_time)
    try:
        # fork: workers inherit the built problem instead of re-building it from a pickle.
        context = multiprocessing.get_context('fork')
        with ProcessPoolExecutor(workers, mp_context=context) as pool:
            solutions = list(pool.map(_pool_solve, guesses))
    finally:
        _POOL_PROBLEM = None
    return _best_with_minima(solutions)


def _best_with_minima(solutions: list[Solution]) -> Solution:
    converged = [s for s in solutions if s.success]
    ok = sorted((s for s in converged if s.details['replay_gap'] <= REPLAY_RTOL),
                key=lambda s: s.cost)
    artefacts = len(converged) - len(ok)
    if not ok:
        worst = solutions[0]
        worst.success = False
        worst.message = (f'no start of {len(solutions)} converged to a plan that replays '
                         f'({artefacts} converged to time-step artefacts): {worst.message}')
        return worst
    minima: list[list[float]] = []
    for s in ok:
        if minima and abs(s.cost - minima[-1][0]) <= DISTINCT_RTOL * max(1.0, minima[-1][0]):
            minima[-1][1] += 1
        else:
            minima.append([s.cost, 1])
    best = ok[0]
    best.minima = [(float(c), int(n)) for c, n in minima]
    best.solve_time = sum(s.solve_time for s in solutions)
    best.attempts = [a for s in solutions for a in s.attempts]  # every start's, in turn
    best.details['artefacts'] = float(artefacts)
    return best
