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

As in rockit and acados, the problem (:class:`~nh_tracking.problem.TrackingProblem`) is apart
from how it is transcribed and solved. A method is a frozen dataclass whose fields are its
options (checked when it is made); :meth:`Method.prepare` builds what depends only on the
system and the problem's structure (an NLP, a flow — seconds, so once), and
:meth:`Method.solve` takes the numbers.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from nh_tracking.problem import Solution, Terminal, TrackingProblem
from nh_tracking.system import NonholonomicSystem

Guess = tuple[np.ndarray, np.ndarray, np.ndarray]  # q (N+1, n), v (N+1, k), u (N, k)

IPOPT_OPTIONS: dict[str, Any] = {
    'ipopt.print_level': 0,
    'ipopt.sb': 'yes',
    'print_time': False,
    'ipopt.tol': 1e-10,
    'ipopt.constr_viol_tol': 1e-12,
    'ipopt.max_iter': 500,
}


def ipopt_options(max_time: float | None) -> dict[str, Any]:
    """IPOPT settings; ``max_time`` bounds the wall time of one solve (a replanning deadline)."""
    return IPOPT_OPTIONS if max_time is None else {**IPOPT_OPTIONS,
                                                   'ipopt.max_wall_time': float(max_time)}


@dataclass(frozen=True)
class Structure:
    """The shape of a problem, which is what an NLP is built for: intervals, terminal kind.

    And the deadline [s] its solves run against (replanning), or None.
    """

    steps: int
    terminal: Terminal
    deadline: float | None = None


class Method(ABC):
    """A tracking method; subclasses are frozen dataclasses (fields = options)."""

    name: ClassVar[str]

    @classmethod
    def options(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))  # type: ignore[arg-type]

    @abstractmethod
    def prepare(self, system: NonholonomicSystem, structure: Structure) -> None:
        """Build what solves of this structure need, so the first one is not slow."""

    @abstractmethod
    def solve(self, problem: TrackingProblem, guess: Guess | None = None,
              deadline: float | None = None) -> Solution:
        """Solve ``problem`` from ``guess`` (default: the reference).

        ``deadline`` [s] bounds the solve's wall time (it then stops and reports failure).
        """
