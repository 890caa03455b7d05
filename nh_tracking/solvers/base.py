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

"""What every tracking method is: an object that carries its own options.

As in rockit and acados, the problem
(:class:`~nh_tracking.problem.tracking_problem.TrackingProblem`) is apart from how it is
transcribed and solved. A method is a frozen dataclass whose fields are its options (checked when
it is made); :meth:`Method.prepare` builds what depends only on the system and the problem's
structure (an NLP, a flow — seconds, so once), and :meth:`Method.solve` takes the numbers.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
import dataclasses
from dataclasses import dataclass
import time
from typing import ClassVar, NamedTuple

import numpy as np

from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.problem.attempts import Attempt
from nh_tracking.problem.detours import detour_guesses, joined
from nh_tracking.problem.tracking_problem import Solution, Terminal, TrackingProblem
from nh_tracking.solvers.cache import builds_until, NotPrepared
from nh_tracking.solvers.guess import Guess
from nh_tracking.solvers.inequalities import Shape
from nh_tracking.solvers.nlp import before, deadline_after


def time_left(previous: Solution, stop: float | None) -> bool:
    """Whether another route may start after ``previous``: neither it nor the clock ran out."""
    return not previous.ran_out_of_time and before(stop)


def next_route(failed: Solution, route: str, solve: Callable[[], Solution]) -> Solution:
    """Try another route after ``failed``; keep ``failed`` if its NLP is not prepared yet."""
    try:
        result = solve()
    except NotPrepared as exc:  # replanning: built in the background, ready next time
        failed.message = f'{failed.message}; {route} skipped: {exc}'
        return failed
    result.route = route
    result.follows(failed)
    return result


class Detoured(NamedTuple):
    """The cheapest plan round the obstacles, or None and the detours that failed.

    A plan found counts every detour tried in its time and attempts; where none was, the
    solve after them counts ``failed``.
    """

    plan: Solution | None
    failed: list[Solution]

    @property
    def spent(self) -> float:
        """Return the solve time [s] of every detour tried."""
        return self.plan.solve_time if self.plan is not None else \
            sum(plan.solve_time for plan in self.failed)


@dataclass(frozen=True)
class Structure:
    """The shape of a problem, which is what an NLP is built for: intervals, terminal kind.

    The time limit [s] its solves run against (replanning) or None, and the shape of its limits.
    ``replanned``: warm replans of it are expected from the first plan on (its Newton steps are
    built too); False for a shape a replanning loop may meet later (more obstacles), whose
    steps are then built in the background on first need.
    """

    steps: int
    terminal: Terminal
    deadline: float | None = None
    limits: Shape = Shape()
    replanned: bool = True


def unsolved(problem: TrackingProblem, method: str, message: str, elapsed: float = 0.0,
             q: np.ndarray | None = None, v: np.ndarray | None = None,
             route: str = '', attempts: list[Attempt] | None = None) -> Solution:
    """Return a failed solve's result: the plan it stopped at (default: held at the start)."""
    steps, system = problem.steps, problem.system
    return Solution(
        t=problem.grid, q=np.tile(problem.q0, (steps + 1, 1)) if q is None else q,
        v=np.tile(problem.v0, (steps + 1, 1)) if v is None else v,
        u=np.zeros((steps, system.r)), cost=float('inf'), success=False, iterations=0,
        solve_time=elapsed, terminal_error=float('inf'), method=method, message=message,
        route=route, attempts=[] if attempts is None else attempts)


def inside_domain(problem: TrackingProblem, solution: Solution) -> Solution:
    """``solution``, failed if its plan leaves the model's domain (where the model is not valid).

    Transcriptions do not bound the configurations: a plan may pass through r = 0 of a polar
    chart, where the dynamics are not defined, and still satisfy every constraint at its knots.
    """
    domain = problem.system.domain
    if not solution.success or not domain.bounded or domain.contains(solution.q):
        return solution
    outside = ~((solution.q > domain.lower) & (solution.q < domain.upper))
    knot, column = np.argwhere(outside)[0]
    solution.success = False
    name = domain.coordinates[column]
    solution.message = (f"the plan leaves the model's domain ({name} = "
                        f'{solution.q[knot, column]:.4g} at t = {solution.t[knot]:.3g} s, not in '
                        f'({domain.lower[column]:.4g}, {domain.upper[column]:.4g})); '
                        f'{solution.message}')
    return solution


class Method(ABC):
    """A tracking method; subclasses are frozen dataclasses (fields = options)."""

    name: ClassVar[str]

    @classmethod
    def options(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))  # type: ignore[arg-type]

    @abstractmethod
    def prepare(self, system: NonholonomicSystem, structure: Structure) -> None:
        """Build what solves of this structure need, so the first one is not slow."""

    def solve(self, problem: TrackingProblem, guess: Guess | None = None,
              deadline: float | None = None) -> Solution:
        """Solve ``problem`` from ``guess`` (default: the reference).

        Without a guess, where the reference runs through obstacles, from the reference pushed
        round them each way (:mod:`nh_tracking.problem.detours`): the cheapest plan found.
        ``deadline`` [s, > 0] bounds the solve's wall time, every route and NLP build included (it
        then stops and reports failure; a build goes on in the background, ready for a later call).
        A plan that leaves the model's domain is no success.
        """
        return self.solve_before(problem, guess, deadline_after(deadline))

    def solve_before(self, problem: TrackingProblem, guess: Guess | None,
                     stop: float | None) -> Solution:
        """:meth:`solve` against an absolute ``stop`` (perf_counter clock) or None."""
        started = time.perf_counter()
        try:
            with builds_until(stop):
                detoured = Detoured(None, []) if guess is not None else \
                    self.round_obstacles(problem, stop)
                solution = detoured.plan if detoured.plan is not None else \
                    self.solve_until(problem, guess, stop).follows(*detoured.failed)
        except NotPrepared as exc:
            solution = unsolved(problem, self.name, str(exc), time.perf_counter() - started)
        return inside_domain(problem, solution)

    def round_obstacles(self, problem: TrackingProblem, stop: float | None) -> Detoured:
        """Return the cheapest plan from a detour guess (None: none, or none succeeded).

        Against an absolute ``stop`` or None.
        """
        if problem.limits.plane is None or \
                problem.limits.clearance(problem.q0[None], [0.0]).min(initial=0.0) < 0.0:
            return Detoured(None, [])  # (from inside a disc: only the least-violating plan)
        q, v = joined(problem)
        best, tried = None, []
        for knots, sides in detour_guesses(problem, q):
            plan = inside_domain(problem, self.globalised().solve_until(
                problem, Guess(knots, v, None), stop))
            tried.append(plan)
            if plan.success and (best is None or plan.cost < best[0].cost):
                best = plan, sides
            if not before(stop):
                break
        if best is None:
            return Detoured(None, tried)
        plan, sides = best
        ways = ', '.join('left' if side > 0 else 'right' for side in sides)
        plan.route = f'{plan.route} (the cheapest way round the obstacles: {ways})'
        plan.follows(*(other for other in tried if other is not plan))  # (its attempts last)
        return Detoured(plan, [])

    def globalised(self) -> Method:
        """Return this method without local shortcuts, for guesses that are not near a minimum.

        A search (perturbed or random starts) looks for a lower minimum than the one it has; a
        shortcut that converges to the nearest stationary point (Newton steps) would defeat it.
        """
        return self

    def proves_minimum(self, problem: TrackingProblem, plan: Solution,
                       stop: float | None = None) -> bool:
        """Whether ``plan``, converged, is a strict local minimum (second-order conditions).

        False where the method cannot tell cheaply, or not before ``stop`` (an absolute
        perf_counter time, or None); a search then looks again.
        """
        return False

    @abstractmethod
    def solve_until(self, problem: TrackingProblem, guess: Guess | None,
                    stop: float | None) -> Solution:
        """:meth:`solve` against an absolute stop time (``time.perf_counter`` clock) or None."""
