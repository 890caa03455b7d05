"""Solver faults to inject: a method that wraps the real one and breaks on purpose."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from nh_tracking.solvers import Method, Variational


@dataclass(frozen=True)
class Faulty(Method):
    """``fault``: "raise" (the solver raises) or "nan" (its plan holds NaN past knot 3)."""

    fault: str = "raise"
    real: Method = field(default_factory=Variational)
    name: ClassVar[str] = "faulty"

    def prepare(self, system, structure) -> None:
        self.real.prepare(system, structure)

    def solve(self, problem, guess=None, deadline=None):
        if self.fault == "raise":
            raise RuntimeError("injected solver fault")
        sol = self.real.solve(problem, guess, deadline)
        sol.q[3:] = float("nan")  # as if the dynamics had produced NaN
        return sol
