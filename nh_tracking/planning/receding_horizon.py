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

"""Receding-horizon replanning: warm starts, a deadline, and a plan that is always usable.

Each call tracks the part of the reference from "now" on, from the measured state, warm-started
from the previous plan shifted to the new time. If the solve fails or misses its deadline (its
result is then discarded; the solver's iterations are bounded so it cannot run away) the
previous plan, shifted, stays in force; with no previous plan, a classical tracking law
(:mod:`nh_tracking.planning.fallback`) supplies one. Nothing here knows about ROS.
"""
from __future__ import annotations

from collections import deque
import dataclasses
from dataclasses import dataclass, field
import time
from typing import Any, cast

import numpy as np

from nh_tracking.core.settings import check_fields, setting, ValueEnum
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.planning.avoidance import Avoidance
from nh_tracking.planning.fallback import braking_plan, fallback, stop_plan
from nh_tracking.problem.detours import joined, stops_short_of_disc
from nh_tracking.problem.limits import (bounds_from_lists, in_the_plane, Limits, moved,
                                        obstacle_discs, VIOLATION_TOL)
from nh_tracking.problem.tracking_problem import (Solution, Terminal, terminal_error,
                                                  TrackingProblem)
from nh_tracking.solvers import Guess, make_method, Method, METHODS, sample_plan, Structure
from nh_tracking.solvers.cache import builds_deferred, builds_inline
from nh_tracking.solvers.inequalities import Shape, start_violation
from nh_tracking.solvers.nlp import deadline_after
from nh_tracking.solvers.obstacles import (clear_of_discs_left_out, MAX_OBSTACLES, obstacle_slots,
                                           touches_one_left_out)

DETOUR_EVERY = 5  # replans: while the reference runs through a disc, the ways round are tried
DETOUR_BUDGET = 0.5  # of what a replan has left: the most its detour solves may take
SWITCH_MARGIN = 0.05  # of the warm plan's cost: another way round must be this much cheaper
HISTORY = 10_000  # recent solves kept for statistics: a long-running node must not grow
NO_DISCS = np.zeros((0, 5))  # (x, y, r, vx, vy): a replan without obstacles


class PlanStatus(ValueEnum):
    """How the plan in force came about."""

    OPTIMAL = 'optimal'  # the solver converged in time
    SHIFTED = 'shifted'  # the solve failed or was late: the previous plan, shifted
    FALLBACK = 'fallback'  # no previous plan: the Kanayama tracking law rolled out
    STOP = 'stop'  # even the tracking law failed: hold the configuration at rest
    LEAST_VIOLATING = 'least-violating'  # the start breaks a limit: the plan breaking it least
    BRAKE = 'brake'  # the loop lost the robot's state (stale odometry): braking to rest


@dataclass(frozen=True)
class PlannerSettings:
    """What a replanning loop solves, and with which method.

    Each field is checked against its own declaration (:mod:`nh_tracking.core.settings`).
    """

    horizon: float = setting(3.0, 'planning horizon', 's', (0.05, 600.0))
    steps: int = setting(30, 'intervals on the horizon', '', (2, 2000))
    epsilon: float = setting(1.0, 'control weight eps', '', (1e-9, 1e9))
    omega: float = setting(10.0, 'terminal cost weight (terminal: cost)', '', (1e-9, 1e9))
    terminal: Terminal = setting('cost', 'terminal condition', choices=('cost', 'equality'))
    method: str = setting('variational', 'tracking method', choices=tuple(METHODS))
    max_solve_time: float = setting(0.25, "deadline of one replan's solves, its retries "
                                    'included; a later plan is discarded and the previous one '
                                    'kept', 's', (1e-6, 3600.0))
    wrap_angles: bool = setting(True, 'compare angles modulo 2 pi')
    compiled: bool = setting(False, 'variational NLP compiled to C (built in the background '
                             'while plans go on interpreted, then cached)')
    iterations: int = setting(0, 'variational solver iterations per replan: 0 = to '
                              'convergence, 1 = one real-time iteration on the previous plan',
                              '', (0, 100))
    u_min: tuple = setting((), 'lower bounds of the controls: one per control, or one for '
                           'all; empty: none')
    u_max: tuple = setting((), 'upper bounds of the controls (as u_min)')
    v_min: tuple = setting((), 'lower bounds of the quasi-velocities: one per velocity, or one '
                           'for all; empty: none')
    v_max: tuple = setting((), 'upper bounds of the quasi-velocities (as v_min)')
    robot_radius: float = setting(0.0, "the robot's radius: obstacles are kept this far clear",
                                  'm', (0.0, 100.0))

    def __post_init__(self) -> None:
        check_fields(self)
        self.solver()  # an option the method does not take is an error here, not later

    def solver(self) -> Method:
        """Return the method object these settings describe."""
        options: dict[str, object] = {'compiled': True} if self.compiled else {}
        if self.iterations:
            options['iterations'] = self.iterations
        return make_method(self.method, **options)

    def limits(self, system: NonholonomicSystem) -> dict[str, Any]:
        """Return the bounds of a problem of ``system``, or raise a ValueError naming them.

        The velocity bounds must allow standing still (v = 0): a robot that cannot stop
        cannot be braked, and a step from one sign to the other is no command to send.
        """
        velocity = bounds_from_lists(self.v_min, self.v_max, system.k, 'v')
        if velocity is not None and (np.any(np.asarray(velocity[0]) > 0.0)
                                     or np.any(np.asarray(velocity[1]) < 0.0)):
            raise ValueError(f'v_min/v_max must allow standing still (0 within them), got '
                             f'{list(self.v_min)} / {list(self.v_max)}')
        return {'control_bounds': bounds_from_lists(self.u_min, self.u_max, system.r, 'u'),
                'velocity_bounds': velocity, 'robot_radius': self.robot_radius}


@dataclass
class PlanOutcome:
    """One replanning step: the plan in force and how it came about."""

    plan: Solution
    status: PlanStatus
    solve_time: float
    deadline_missed: bool
    message: str
    reference: np.ndarray  # q_r at the plan's knots, for display


def _recent() -> deque:
    return deque(maxlen=HISTORY)


@dataclass
class PlannerStatistics:
    """Counts since the start, and the last :data:`HISTORY` solves' timings."""

    plans: int = 0
    optimal: int = 0
    shifted: int = 0
    fallbacks: int = 0  # tracking law or stop plans
    deadline_misses: int = 0
    solve_times: deque[float] = field(default_factory=_recent)
    plan_times: deque[float] = field(default_factory=_recent)  # the t of each solve
    plan_durations: deque[float] = field(default_factory=_recent)  # wall time of plan()


class RecedingHorizonPlanner:
    """Replans a tracking problem of ``system`` from measured states, warm-started."""

    def __init__(self, system: NonholonomicSystem,
                 settings: PlannerSettings = PlannerSettings()) -> None:
        self.system = system
        self.settings = settings
        self.reference: Trajectory | None = None
        self.obstacles = np.zeros((0, 3))  # discs (x, y, r) or (x, y, r, vx, vy): front end's
        # when (planner clock; one for all, or one each) the discs were where they are said to
        # be; None: at every plan's start (moving ones move on over its horizon only)
        self.obstacles_time: float | np.ndarray | None = None
        self.previous: Solution | None = None
        self.limits = settings.limits(system)
        self.stats = PlannerStatistics()
        self.method = settings.solver()
        self.prepared = False  # once prepared, its loop never stops to build a structure

    def prepare(self) -> None:
        """Build the solver for the current settings now, so the first plan is not late.

        Every shape of its limits it meets in replanning: without obstacles, with each knot's
        and midpoint's nearest discs, and with room for every disc at every point (a crowd's
        last resort), if its model has a pose in the plane, where obstacles are; the Newton
        steps of warm replans without obstacles and with the nearest discs (the others' are
        built in the background when first needed, which keeps the planner's start short).
        The soft forms, for a start that breaks a limit (a robot pushed into an obstacle), are
        built when first needed: rare, and building every form up front would hold the
        interpreter for seconds after each parameter change.
        """
        s = self.settings
        bounds = Limits.of(self.system, self.limits['control_bounds'],
                           self.limits['velocity_bounds'], (), 0.0)
        slots = {0} if self.method.name == 'pmp' or not in_the_plane(self.system) else {
            obstacle_slots(count, every) for count in range(MAX_OBSTACLES + 1)
            for every in (False, True)}
        now = obstacle_slots(min(len(self.obstacles), MAX_OBSTACLES))
        for count in sorted(slots):
            shape = dataclasses.replace(Shape.of(bounds), slots=count)
            self.method.prepare(self.system, Structure(s.steps, s.terminal, s.max_solve_time,
                                                       shape, count == now or count == 0))
        self.prepared = True

    def set_reference(self, reference: Trajectory) -> None:
        """Track ``reference`` (times on the planner's clock) from the next plan on."""
        if reference.q.shape[1] != self.system.n or reference.v.shape[1] != self.system.k:
            raise ValueError(f'reference has the wrong dimensions for {self.system.name}')
        self.reference = reference

    def update(self, **changes: Any) -> PlannerSettings:
        """Change settings (validated); the warm start is kept."""
        settings = dataclasses.replace(self.settings, **changes)
        self.limits = settings.limits(self.system)
        self.settings, self.method = settings, settings.solver()
        self.prepared = False
        return self.settings

    def avoidance(self, t: float) -> Avoidance:
        """Return the obstacles of a replanning step at t, with what to do with them.

        Moving discs where they will be at t (:func:`.limits.moved`).
        """
        s = self.settings
        seen = t if self.obstacles_time is None else self.obstacles_time
        discs = NO_DISCS if not len(self.obstacles) else moved(obstacle_discs(self.obstacles),
                                                               t - np.asarray(seen))
        return Avoidance(self.system, discs, self.limits['robot_radius'], self.reference,
                         s.horizon, s.steps)

    def problem(self, t: float, q: np.ndarray, v: np.ndarray,
                obstacles: np.ndarray | None = None) -> TrackingProblem:
        """Return the problem from (q, v) at t, with ``obstacles`` (default: the relevant)."""
        if self.reference is None:
            raise ValueError('no reference to track yet')
        s = self.settings
        if obstacles is None:
            avoidance = self.avoidance(t)
            obstacles = avoidance.relevant(t, q, avoidance.from_start(q, v))
        return TrackingProblem(self.system, self.reference, q, v, horizon=s.horizon,
                               steps=s.steps, epsilon=s.epsilon, terminal=s.terminal,
                               omega=s.omega, wrap_angles=s.wrap_angles, t0=t,
                               obstacles=obstacles, **self.limits)

    def plan(self, t: float, q: np.ndarray, v: np.ndarray) -> PlanOutcome:
        """Plan from state (q, v) at time t. Raises ValueError only for bad input."""
        started = time.perf_counter()
        try:
            return self._plan(t, q, v)
        finally:
            self.stats.plan_durations.append(time.perf_counter() - started)

    def _plan(self, t: float, q: np.ndarray, v: np.ndarray) -> PlanOutcome:
        avoidance = self.avoidance(t)
        discs = avoidance.from_start(q, v)
        problem = self.problem(t, q, v, avoidance.relevant(t, q, discs))
        reference = problem.reference_samples[0]
        s = self.settings
        guess = self.previous
        if guess is not None and guess.q.shape[1] != self.system.n:
            guess = None
        try:
            with builds_deferred() if self.prepared else builds_inline():  # never stalls
                sol = clear_of_discs_left_out(
                    self._within_budget, problem,
                    None if guess is None else sample_plan(problem, guess), discs)
                if guess is not None and len(problem.limits.obstacles) and \
                        self.stats.plans % DETOUR_EVERY == 0:
                    sol = self._other_way_round(problem, sol, discs)
            error = '' if sol.success else f'solver: {sol.message}'
        except (ArithmeticError, RuntimeError, ValueError) as exc:  # a numerical failure
            sol, error = None, f'solver raised {type(exc).__name__}: {exc}'
        missed = sol is not None and sol.solve_time > s.max_solve_time
        if missed and sol is not None:  # a late plan describes a past gone by: unused
            error = (f'missed the deadline ({sol.solve_time * 1e3:.1f} ms > '
                     f'{s.max_solve_time * 1e3:.1f} ms)')
        finite = sol is not None and _finite(sol)
        if sol is not None and sol.success and not missed and not finite:
            error = 'solver returned non-finite values'
        ok = sol is not None and sol.success and finite and not missed
        self.stats.plans += 1
        self.stats.deadline_misses += int(missed)
        if sol is not None:
            self.stats.solve_times.append(sol.solve_time)
            self.stats.plan_times.append(t)
        if ok and sol is not None:
            self.previous = sol
            self.stats.optimal += 1
            return PlanOutcome(sol, PlanStatus.OPTIMAL, sol.solve_time, missed,
                               f'{s.method}: cost {sol.cost:.4g} in {sol.iterations} iterations',
                               reference)
        solve_time = sol.solve_time if sol is not None else 0.0
        if (sol is not None and finite and not missed and sol.limit_check.least_violating
                and start_violation(problem) > VIOLATION_TOL
                and avoidance.no_deeper(problem, sol, discs)):
            self.previous = sol  # inside an obstacle, say: the way out beats the old plan
            return PlanOutcome(sol, PlanStatus.LEAST_VIOLATING, solve_time, missed,
                               sol.message, reference)
        if self.previous is not None and self.previous.t[-1] > t:
            shifted = self._shifted(problem, self.previous)
            if avoidance.no_deeper(problem, shifted, discs):
                self.previous = shifted
                self.stats.shifted += 1
                return PlanOutcome(shifted, PlanStatus.SHIFTED, solve_time, missed,
                                   f'kept the previous plan, shifted ({error})', reference)
            # made before an obstacle appeared or the limits changed: it would drive into them
            error = f'{error}; the previous plan breaks the limits in force'
        plan, what = fallback(problem, avoidance.limits(discs))
        status = PlanStatus.STOP if plan.route == 'stop' else PlanStatus.FALLBACK
        self.previous = plan  # the plan in force: shifted if the next solve fails too
        self.stats.fallbacks += 1
        return PlanOutcome(plan, status, solve_time, missed, f'{what} ({error})', reference)

    def _within_budget(self, problem: TrackingProblem, guess: Guess | None,
                       spent: float) -> Solution:
        """Solve with what is left of the replan's one solve budget after ``spent`` [s].

        (At least a microsecond: a solve begun past the budget reports its deadline.)
        """
        return self.method.solve(problem, guess, max(self.settings.max_solve_time - spent, 1e-6))

    def _other_way_round(self, problem: TrackingProblem, warm: Solution,
                         discs: np.ndarray) -> Solution:
        """Return the plan round the obstacles another way if it is cheaper by SWITCH_MARGIN.

        Tried where the warm plan stops short of a disc the reference runs through: a warm
        start stays in its local minimum, and pressed against the disc's near side a robot
        would wait there for good. The margin keeps it from dithering between two ways of
        about the same cost. Within :data:`DETOUR_BUDGET` of what is left of the replan's solve
        budget; a plan not taken keeps its own solve time (its detours' in ``details``).
        ``discs``: every obstacle, which a plan taken must keep clear of.
        """
        left = DETOUR_BUDGET * (self.settings.max_solve_time - warm.solve_time)
        q, _ = joined(problem)
        if left <= 0.0 or not stops_short_of_disc(problem, q, warm.q):
            return warm
        detoured = self.method.round_obstacles(problem, deadline_after(left))
        other = detoured.plan
        if other is None or touches_one_left_out(problem, other, discs) or not (
                not warm.success or other.cost < (1.0 - SWITCH_MARGIN) * warm.cost):
            warm.details['detour_time'] = detoured.spent
            return warm
        return other.follows(warm)

    def brake(self, t: float, q: np.ndarray, v: np.ndarray, why: str,
              decel: float | None = None) -> PlanOutcome:
        """Plan braking to rest from the last state known, (q, v) at t, at ``decel`` [m/s^2].

        For when the loop loses the robot's state: an effort-driven robot given no command
        coasts on (zero effort is not a stop).
        """
        problem = self.problem(t, q, v)
        try:
            plan, status = braking_plan(problem, decel), PlanStatus.BRAKE
        except (ArithmeticError, RuntimeError, ValueError) as exc:
            plan, status = stop_plan(problem, str(exc)), PlanStatus.STOP
        self.previous = plan
        self.stats.fallbacks += 1
        return PlanOutcome(plan, status, 0.0, False, f'{plan.message} ({why})',
                           problem.reference_samples[0])

    def preview(self, t: float, q: np.ndarray, v: np.ndarray) -> Solution:
        """Return a plan from (q, v) at t that leaves the replanning loop's state alone."""
        s = self.settings
        problem = self.problem(t, q, v)
        guess = None if self.previous is None else sample_plan(problem, self.previous)
        return self.method.solve(problem, guess, s.max_solve_time)

    @staticmethod
    def _shifted(problem: TrackingProblem, previous: Solution) -> Solution:
        q, v, u = sample_plan(problem, previous)[:3]
        return dataclasses.replace(
            previous, t=problem.grid, q=q, v=v, u=cast(np.ndarray, u),  # (sampled: never None)
            route='shifted', minima=[], local_minimum=False,
            terminal_error=terminal_error(problem, q[-1], v[-1]),
            costates=None, minimum_check=None, attempts=[])


def _finite(sol: Solution) -> bool:
    return bool(np.isfinite(sol.q).all() and np.isfinite(sol.v).all() and np.isfinite(sol.u).all())
