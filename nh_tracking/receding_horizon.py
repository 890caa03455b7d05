"""Receding-horizon replanning: warm starts, a deadline, and a plan that is always usable.

Each call tracks the part of the reference from "now" on, from the measured state, warm-started
from the previous plan shifted to the new time. If the solve fails or misses its deadline (its
result is then discarded; the solver's iterations are bounded so it cannot run away) the
previous plan, shifted, stays in force; with no previous plan, a classical tracking law
(:mod:`nh_tracking.fallback`) supplies one. Nothing here knows about ROS.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from nh_tracking.fallback import fallback_plan, stop_plan
from nh_tracking.problem import Solution, TrackingProblem, terminal_error
from nh_tracking.solvers import METHODS, sample_plan, solve
from nh_tracking.solvers.multiple_shooting import shooting_transcription
from nh_tracking.solvers.variational import transcription
from nh_tracking.system import NonholonomicSystem
from nh_tracking.trajectory import Trajectory

Status = Literal["optimal", "shifted", "fallback"]


@dataclass(frozen=True)
class PlannerSettings:
    """What a replanning loop solves: horizon (s) on ``steps`` intervals, weights, method and
    the deadline of one solve, ``max_solve_time`` (s)."""

    horizon: float = 3.0
    steps: int = 30
    epsilon: float = 1.0
    omega: float = 10.0
    terminal: str = "cost"
    method: str = "variational"
    max_solve_time: float = 0.25
    wrap_angles: bool = True
    compiled: bool = False  # variational NLP as compiled C (built once per machine, cached)

    def __post_init__(self) -> None:
        checks = {
            "horizon": math.isfinite(self.horizon) and 0 < self.horizon <= 600,
            "steps": int(self.steps) == self.steps and 2 <= self.steps <= 2000,
            "epsilon": math.isfinite(self.epsilon) and self.epsilon > 0,
            "omega": math.isfinite(self.omega) and self.omega > 0,
            "terminal": self.terminal in ("cost", "equality"),
            "method": self.method in METHODS,
            "max_solve_time": math.isfinite(self.max_solve_time) and self.max_solve_time > 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"invalid planner settings: {', '.join(f'{b}={getattr(self, b)!r}' for b in bad)}")


@dataclass
class PlanOutcome:
    """One replanning step: the plan in force and how it came about."""

    plan: Solution
    status: Status
    solve_time: float
    deadline_missed: bool
    message: str
    reference: np.ndarray  # q_r at the plan's knots, for display


@dataclass
class PlannerStatistics:
    plans: int = 0
    optimal: int = 0
    shifted: int = 0
    fallbacks: int = 0
    deadline_misses: int = 0
    solve_times: list[float] = field(default_factory=list)
    plan_times: list[float] = field(default_factory=list)  # the t of each solve
    plan_durations: list[float] = field(default_factory=list)  # wall time of plan(), all in


class RecedingHorizonPlanner:
    """Replans a tracking problem of ``system`` from measured states, warm-started."""

    def __init__(self, system: NonholonomicSystem,
                 settings: PlannerSettings = PlannerSettings()) -> None:
        self.system = system
        self.settings = settings
        self.reference: Trajectory | None = None
        self.previous: Solution | None = None
        self.stats = PlannerStatistics()

    def prepare(self) -> None:
        """Build the solver for the current settings now, so the first plan is not late."""
        s = self.settings
        if s.method == "variational":
            transcription(self.system, s.steps, s.terminal, s.max_solve_time,
                          compiled=s.compiled)
        elif s.method == "multiple_shooting":
            shooting_transcription(self.system, s.steps, s.terminal, s.max_solve_time)

    def set_reference(self, reference: Trajectory) -> None:
        """Track ``reference`` (times on the planner's clock) from the next plan on."""
        if reference.q.shape[1] != self.system.n or reference.v.shape[1] != self.system.k:
            raise ValueError(f"reference has the wrong dimensions for {self.system.name}")
        self.reference = reference

    def update(self, **changes: object) -> PlannerSettings:
        """Change settings (validated); the warm start is kept."""
        self.settings = dataclasses.replace(self.settings, **changes)
        return self.settings

    def problem(self, t: float, q: np.ndarray, v: np.ndarray) -> TrackingProblem:
        if self.reference is None:
            raise ValueError("no reference to track yet")
        s = self.settings
        return TrackingProblem(self.system, self.reference, q, v, horizon=s.horizon,
                               steps=s.steps, epsilon=s.epsilon, terminal=s.terminal,
                               omega=s.omega, wrap_angles=s.wrap_angles, t0=t)

    def plan(self, t: float, q: np.ndarray, v: np.ndarray) -> PlanOutcome:
        """Plan from state (q, v) at time t. Raises ValueError only for bad input."""
        started = time.perf_counter()
        try:
            return self._plan(t, q, v)
        finally:
            self.stats.plan_durations.append(time.perf_counter() - started)

    def _plan(self, t: float, q: np.ndarray, v: np.ndarray) -> PlanOutcome:
        problem = self.problem(t, q, v)
        reference = problem.reference_samples[0]
        s = self.settings
        guess = self.previous
        if guess is not None and guess.q.shape[1] != self.system.n:
            guess = None
        try:
            sol = solve(problem, s.method, initial_guess=guess, max_time=s.max_solve_time,
                        compiled=s.compiled)
            error = "" if sol.success else f"solver: {sol.message}"
        except (ArithmeticError, RuntimeError, ValueError) as exc:  # a numerical failure
            sol, error = None, f"solver raised {type(exc).__name__}: {exc}"
        missed = sol is not None and sol.solve_time > s.max_solve_time
        if missed:  # a late plan describes a past that has moved on: do not use it
            error = (f"missed the deadline ({sol.solve_time * 1e3:.1f} ms > "
                     f"{s.max_solve_time * 1e3:.1f} ms)")
        finite = sol is not None and _finite(sol)
        if sol is not None and sol.success and not missed and not finite:
            error = "solver returned non-finite values"
        ok = sol is not None and sol.success and finite and not missed
        self.stats.plans += 1
        self.stats.deadline_misses += int(missed)
        if sol is not None:
            self.stats.solve_times.append(sol.solve_time)
            self.stats.plan_times.append(t)
        if ok:
            self.previous = sol
            self.stats.optimal += 1
            return PlanOutcome(sol, "optimal", sol.solve_time, missed,
                               f"{s.method}: cost {sol.cost:.4g} in {sol.iterations} iterations",
                               reference)
        solve_time = sol.solve_time if sol is not None else 0.0
        if self.previous is not None and self.previous.t[-1] > t:
            shifted = self._shifted(problem, self.previous)
            self.previous = shifted
            self.stats.shifted += 1
            return PlanOutcome(shifted, "shifted", solve_time, missed,
                               f"kept the previous plan, shifted ({error})", reference)
        try:
            plan, what = fallback_plan(problem), "tracking law fallback"
            if not _finite(plan):
                raise ValueError("the tracking law gave non-finite values")
        except (ArithmeticError, RuntimeError, ValueError) as exc:
            plan, what = stop_plan(problem, str(exc)), f"stopping, tracking law failed: {exc}"
        self.previous = plan  # the plan in force: shifted if the next solve fails too
        self.stats.fallbacks += 1
        return PlanOutcome(plan, "fallback", solve_time, missed, f"{what} ({error})",
                           reference)

    def preview(self, t: float, q: np.ndarray, v: np.ndarray) -> Solution:
        """A plan from (q, v) at t that leaves the replanning loop's state alone (a query)."""
        s = self.settings
        return solve(self.problem(t, q, v), s.method, initial_guess=self.previous,
                     max_time=s.max_solve_time, compiled=s.compiled)

    @staticmethod
    def _shifted(problem: TrackingProblem, previous: Solution) -> Solution:
        q, v, u = sample_plan(problem, previous)
        return dataclasses.replace(
            previous, t=problem.grid, q=q, v=v, u=u, route="shifted", minima=[],
            terminal_error=terminal_error(problem, q[-1], v[-1]), costates=None)


def _finite(sol: Solution) -> bool:
    return all(np.all(np.isfinite(a)) for a in (sol.q, sol.v, sol.u))
