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

"""Solver faults to inject: a method that wraps the real one and breaks on purpose."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from nh_tracking.solvers import Method, Variational


@dataclass(frozen=True)
class Faulty(Method):
    """``fault``: "raise" (the solver raises) or "nan" (its plan holds NaN past knot 3)."""

    fault: str = 'raise'
    real: Method = field(default_factory=Variational)
    name: ClassVar[str] = 'faulty'

    def prepare(self, system, structure) -> None:
        self.real.prepare(system, structure)

    def solve_until(self, problem, guess, stop):
        if self.fault == 'raise':
            raise RuntimeError('injected solver fault')
        sol = self.real.solve_until(problem, guess, stop)
        sol.q[3:] = float('nan')  # as if the dynamics had produced NaN
        return sol
