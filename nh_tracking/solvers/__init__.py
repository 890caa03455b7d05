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

import numpy as np

from nh_tracking.core.trajectory import Trajectory
from nh_tracking.problem.tracking_problem import Solution, TrackingProblem
from nh_tracking.solvers import search
from nh_tracking.solvers.base import Guess, Method, Structure
from nh_tracking.solvers.multiple_shooting import MultipleShooting
from nh_tracking.solvers.nlp import deadline_after
from nh_tracking.solvers.pmp import Pontryagin
from nh_tracking.solvers.variational import Variational

__all__ = ['METHODS', 'Guess', 'Method', 'MultipleShooting', 'Pontryagin', 'Structure',
           'Variational', 'make_method', 'solve']

METHODS: dict[str, type[Method]] = {m.name: m for m in (Variational, Pontryagin,
                                                        MultipleShooting)}


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
          second_look: bool = True, **options: object) -> Solution:
    """Solve ``problem`` with ``method``: a name and its ``options``, or a :class:`Method`.

    Options are keywords, e.g. ``compiled=True``. ``max_time`` [s] bounds the wall time of the
    call, every route and the second look included (it then stops and reports failure).
    ``second_look`` re-solves once from a perturbed copy of the plan, unless the method proves
    it a strict local minimum (:meth:`Method.proves_minimum`): a stationary point that is not a
    minimum (a saddle, typical of symmetric starts) is then reported and the better plan
    returned, and a failure from a degenerate start gets a second chance — about one warm
    solve more. With ``starts`` > 1, that many initial guesses (``initial_guess`` or the
    default one, and random perturbations of it) run in parallel processes; the best plan is
    returned with the distinct local minima found in ``Solution.minima`` — plans that do not
    replay on the continuous dynamics (time-step artefacts) are not counted as minima. A plan
    that leaves the model's domain, or whose intervals do not replay on the continuous
    dynamics, is no success.
    """
    solver = make_method(method, **options)
    if isinstance(starts, bool) or not isinstance(starts, (int, np.integer)) or starts < 1:
        raise ValueError(f'starts must be an integer >= 1, got {starts!r}')
    stop = deadline_after(max_time)  # one deadline: every route, retry and the second look
    guess = None if initial_guess is None else sample_plan(problem, initial_guess)
    if starts > 1:
        return search.replay_checked(problem, search.multi_start(
            problem, solver, guess, int(starts), seed, processes, max_time))
    solution = solver.solve_before(problem, guess, stop)
    if second_look:
        solution = search.second_look(problem, solver, solution, stop, seed)
    return search.replay_checked(problem, solution)


def sample_plan(problem: TrackingProblem, plan: Solution | Trajectory) -> Guess:
    """(q, v, u) of a previous plan or trajectory at this problem's knots (held past its end).

    Its angles moved by whole turns onto q0's branch: a warm start, or a shifted plan. Linear
    between knots: a guess needs no spline, and replanning runs this every cycle. A plan's
    multipliers come along, on their own time axis (the solver shifts them).
    """
    if not isinstance(plan, (Solution, Trajectory)):
        raise TypeError('initial_guess must be a Solution or a Trajectory (e.g. a previous '
                        f'plan), got {type(plan).__name__}')
    sys = problem.system
    widths = (plan.q.shape[1], plan.v.shape[1], plan.u.shape[1])
    if widths != (sys.n, sys.k, sys.r):
        raise ValueError(f'initial_guess has q, v, u of widths {widths}; {sys.name} needs '
                         f'({sys.n}, {sys.k}, {sys.r}): a plan of another system?')
    t = plan.t
    if t.shape == problem.grid.shape and np.array_equal(t, problem.grid):
        q, v, u = plan.q, plan.v, plan.u  # the same knots
    else:
        grid = np.minimum(np.maximum(problem.grid, t[0]), t[-1])
        i = np.minimum(t.searchsorted(grid, 'right') - 1, len(t) - 2)  # (grid >= t[0]: i >= 0)
        w = ((grid - t[i]) / (t[i + 1] - t[i]))[:, None]
        q = (1 - w) * plan.q[i] + w * plan.q[i + 1]
        v = (1 - w) * plan.v[i] + w * plan.v[i + 1]
        mids = problem.grid[:-1] + 0.5 * problem.h
        u = plan.u[np.minimum(np.maximum(t.searchsorted(mids, 'right') - 1, 0), len(plan.u) - 1)]
    turns = np.rint((problem.q0 - q[0]) / (2 * np.pi)) * sys.angle_mask
    if not isinstance(plan, Solution):
        return Guess(q + 2 * np.pi * turns, v, u)
    return Guess(q + 2 * np.pi * turns, v, u, plan.multipliers, plan.working_set_misses)
