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

"""Families of systems that differ only in the values of some physical parameters.

A family's dynamics take those parameters as an input, so whatever is built from them (the
variational NLPs, cached per family) serves every member: a new value is a new number.
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
import functools
import math
import numbers

import casadi as ca
import numpy as np


@dataclass(eq=False)
class DynamicsFamily:
    """The dynamics of the systems that differ only in the values of the parameters ``names``.

    Those are an input ``p`` here (empty when none is symbolic), so the NLPs built from these
    functions — cached per family — serve every member: a new value is a new number in the
    next solve. ``dynamics(q, v, u, p)`` -> (qdot, vdot); ``rho(q, p)``; ``input_matrix(q, p)``;
    ``velocity(q, qdot, p)`` -> v of qdot's G-orthogonal projection on D; :attr:`ode` the
    dynamics on the state x = (q, v).
    """

    names: tuple[str, ...]
    dynamics: ca.Function
    rho: ca.Function
    input_matrix: ca.Function
    velocity: ca.Function

    @functools.cached_property
    def ode(self) -> ca.Function:
        """The dynamics on the state x = (q, v) as one column function: (x, u, p) -> xdot."""
        n, k, r = (self.dynamics.size1_in(i) for i in range(3))
        x, u = ca.SX.sym('x', n + k), ca.SX.sym('u', r)
        p = ca.SX.sym('p', self.dynamics.size1_in(3))
        return ca.Function('ode', [x, u, p], [ca.vertcat(*self.dynamics(x[:n], x[n:], u, p))],
                           ['x', 'u', 'p'], ['xdot'])

    def singular_at(self, p: Sequence[float], configurations: np.ndarray) -> np.ndarray | None:
        """Return a configuration where the dynamics at values ``p`` are not finite, or None."""
        k, r = self.dynamics.size1_in(1), self.dynamics.size1_in(2)
        for q, v, u in sample_states(configurations, k, r):
            state = (self.rho(q, p), *self.dynamics(q, v, u, p))
            if not all(np.all(np.isfinite(np.array(part))) for part in state):
                return q
        return None


def sample_states(configurations: np.ndarray, k: int,
                  r: int) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Yield (q, v, u) at each configuration: random velocities and controls, seeded."""
    rng = np.random.default_rng(0)
    for q in configurations:
        yield q, rng.normal(size=k), rng.normal(size=r)


def finite(x: object, what: str) -> float:
    """Return ``x`` as a float; a ValueError naming ``what`` if it is not a finite real number."""
    if isinstance(x, bool) or not isinstance(x, numbers.Real) or not math.isfinite(x):
        raise ValueError(f'{what} must be a finite number, got {x!r}')
    return float(x)
