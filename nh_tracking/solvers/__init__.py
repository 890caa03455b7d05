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

"""``solve(problem, method=...)``: the tracking methods, by name or as objects, and global search.

Methods (:mod:`.base`): :class:`Variational` (discrete Lagrange–d'Alembert midpoint
transcription, §5; options ``backend``, ``compiled``), :class:`Pontryagin` (shooting, §4;
``budget``, ``fallback``), :class:`MultipleShooting` (direct RK4 baseline). A new method is a
:class:`Method` subclass in a module of its own and one entry in :data:`METHODS`.
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
import multiprocessing
import os

import numpy as np

from nh_tracking.problem import Solution, TrackingProblem
from nh_tracking.solvers.base import Guess, Method, Structure
from nh_tracking.solvers.multiple_shooting import MultipleShooting
from nh_tracking.solvers.pmp import Pontryagin
from nh_tracking.solvers.variational import Variational
from nh_tracking.trajectory import Trajectory

__all__ = ['METHODS', 'Method', 'MultipleShooting', 'Pontryagin', 'Structure', 'Variational',
           'make_method', 'solve']

METHODS: dict[str, type[Method]] = {m.name: m for m in (Variational, Pontryagin,
                                                        MultipleShooting)}
DISTINCT_RTOL = 1e-4  # two local minima are the same when their costs agree to this


def make_method(method: str | Method, **options: object) -> Method:
    """Return the method called ``method`` with ``options``, or ``method`` itself if it is one.

    An option the method does not take is an error naming the methods that do.
    """
    if isinstance(method, Method):
        if options:
            raise ValueError(f'give options to the method object, not with it: {options}')
        return method
    if method not in METHODS:
        raise ValueError(f'unknown method {method!r}; choose one of {list(METHODS)}')
    cls = METHODS[method]
    unknown = sorted(set(options) - set(cls.options()))
    if unknown:
        takers = {o: [n for n, m in METHODS.items() if o in m.options()] for o in unknown}
        raise ValueError(f"method {method!r} takes no option {', '.join(unknown)} (its "
                         f"options: {list(cls.options()) or 'none'}; "
                         + '; '.join(f"{o} is taken by {t or 'no method'}"
                                     for o, t in takers.items()) + ')')
    return cls(**options)


def solve(problem: TrackingProblem, method: str | Method = 'variational', *, starts: int = 1,
          initial_guess: Solution | Trajectory | None = None, seed: int = 0,
          processes: int | None = None, max_time: float | None = None,
          **options: object) -> Solution:
    """Solve ``problem`` with ``method`` (a name and its ``options``, e.g. ``compiled=True``.

    Or a :class:`Method`); with ``starts`` > 1, run that many initial guesses (``initial_guess`` or
    the default one, and random perturbations of it) in parallel processes and return the best,
    with the distinct local minima found in ``Solution.minima``. ``max_time`` bounds one solve's
    wall time (the solver then stops and reports failure).
    """
    solver = make_method(method, **options)
    if int(starts) != starts or starts < 1:
        raise ValueError(f'starts must be an integer >= 1, got {starts}')
    guess = None if initial_guess is None else sample_plan(problem, initial_guess)
    if starts == 1:
        return solver.solve(problem, guess, max_time)
    return _multi_start(problem, solver, guess, int(starts), seed, processes, max_time)


def sample_plan(problem: TrackingProblem, plan: Solution | Trajectory) -> Guess:
    """(q, v, u) of a previous plan or trajectory at this problem's knots (held past its end).

    Its angles moved by whole turns onto q0's branch: a warm start, or a shifted plan. Linear
    between knots: a guess needs no spline, and replanning runs this every cycle.
    """
    t = plan.t
    grid = np.clip(problem.grid, t[0], t[-1])
    i = np.clip(np.searchsorted(t, grid, side='right') - 1, 0, len(t) - 2)
    w = ((grid - t[i]) / (t[i + 1] - t[i]))[:, None]
    q = (1 - w) * plan.q[i] + w * plan.q[i + 1]
    v = (1 - w) * plan.v[i] + w * plan.v[i + 1]
    turns = np.round((problem.q0 - q[0]) / (2 * np.pi)) * problem.system.angle_mask
    mids = problem.grid[:-1] + 0.5 * problem.h
    idx = np.clip(np.searchsorted(t, mids, side='right') - 1, 0, len(plan.u) - 1)
    return q + 2 * np.pi * turns, v, plan.u[idx]


def random_guess(problem: TrackingProblem, rng: np.random.Generator) -> Guess:
    """Return the reference plus smooth random excursions that vanish at t0.

    A start in another basin.

    Amplitudes are large — several units in q, more than a turn and a half for angles, and
    in v — because local minima of tracking problems differ by whole windings: on the paper's
    sleigh, smaller excursions all fall back into the best basin and find nothing else.
    """
    sys = problem.system
    q, v = problem.reference_samples[:2]
    s = (problem.grid - problem.grid[0]) / problem.horizon

    def excursion(columns: int, scale: np.ndarray) -> np.ndarray:
        freq = rng.uniform(0.3, 2.0, size=(3, columns))
        amp = rng.normal(size=(3, columns)) * scale
        return np.einsum('jc,tjc->tc', amp, np.sin(np.pi * freq[None] * s[:, None, None]))
    q_scale = np.where(sys.angle_mask, 10.0, 6.0)
    return (q + excursion(sys.n, q_scale), v + excursion(sys.k, np.full(sys.k, 6.0)),
            np.zeros((problem.steps, sys.k)))


_POOL_PROBLEM: tuple[TrackingProblem, Method, float | None] | None = None


def _pool_solve(guess: Guess | None) -> Solution:
    assert _POOL_PROBLEM is not None  # set before the pool forks
    problem, method, max_time = _POOL_PROBLEM
    return method.solve(problem, guess, max_time)


def _multi_start(problem: TrackingProblem, method: Method, guess: Guess | None, starts: int,
                 seed: int, processes: int | None, max_time: float | None) -> Solution:
    global _POOL_PROBLEM
    rng = np.random.default_rng(seed)
    guesses = [guess] + [random_guess(problem, rng) for _ in range(starts - 1)]
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
    ok = sorted((s for s in solutions if s.success), key=lambda s: s.cost)
    if not ok:
        worst = solutions[0]
        worst.message = f'no start of {len(solutions)} converged: {worst.message}'
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
    return best
