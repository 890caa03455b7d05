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

"""A model's derived dynamics with some of its physical parameters left as CasADi symbols.

The family of :meth:`~nh_tracking.core.system.NonholonomicSystem.parametrised` with the parameters
named symbolic and the others fixed, as the functions a fit of them needs: ``ode(x, u, p)`` and
``velocity(q, qdot, p)``, a new value a new number, not a new model.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import functools

import casadi as ca
import numpy as np

from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.models.spec import ModelSpec


@dataclass(frozen=True)
class ParametricModel:
    """``ode(x, u, p)`` -> xdot with x = (q, v) and ``p`` the values of ``names``, in order.

    ``velocity(q, qdot, p)`` -> v: the quasi-velocities of qdot's G-orthogonal projection on D.
    ``values`` holds every physical parameter's number (those named: their starting values);
    ``system`` is the model with ``names`` symbolic, whose family the functions are.
    """

    spec: ModelSpec
    names: tuple[str, ...]
    values: dict[str, float]
    system: NonholonomicSystem
    ode: ca.Function

    @property
    def start(self) -> np.ndarray:
        return np.array([self.values[name] for name in self.names])

    @property
    def velocity(self) -> ca.Function:
        return self.system.family.velocity

    @property
    def coordinates(self) -> tuple[str, ...]:
        return self.system.coordinates

    @property
    def angle_mask(self) -> np.ndarray:
        return self.system.angle_mask

    @property
    def n(self) -> int:
        return self.system.n

    @property
    def k(self) -> int:
        return self.system.k

    @property
    def r(self) -> int:
        return self.system.r


def parametric_model(spec: ModelSpec, names: Sequence[str],
                     values: Mapping[str, float] | None = None) -> ParametricModel:
    """Derive ``spec``'s dynamics with ``names`` symbolic; the others at ``values`` or defaults.

    A ValueError names what is missing: a model without symbolic Lagrangian data (a plain
    factory), without a basis of D, or parameters it does not have.
    """
    names = tuple(names)
    known = [p.name for p in spec.parameters]
    if not names or len(set(names)) != len(names) or not set(names) <= set(known):
        raise ValueError(f'model {spec.name}: parameters to leave symbolic must be distinct '
                         f'names among {known}, got {list(names)}')
    if spec.lagrangian is None:
        raise ValueError(f'model {spec.name} gives no Lagrangian data with symbolic parameters '
                         '(ModelSpec.lagrangian); its parameters can only be fixed')
    checked = spec.check(**dict(values or {}))
    system = _family(spec, names, tuple((k, x) for k, x in checked.items() if k not in names))
    n, k = system.n, system.k
    x, u, p = ca.SX.sym('x', n + k), ca.SX.sym('u', system.r), ca.SX.sym('p', len(names))
    ode = ca.Function('ode', [x, u, p], [ca.vertcat(*system.family.dynamics(x[:n], x[n:], u, p))],
                      ['x', 'u', 'p'], ['xdot'])
    return ParametricModel(spec=spec, names=names, values=checked, system=system, ode=ode)


@functools.lru_cache(maxsize=8)
def _family(spec: ModelSpec, names: tuple[str, ...],
            fixed: tuple[tuple[str, float], ...]) -> NonholonomicSystem:
    """Return the model with ``names`` symbolic (at their defaults), the others ``fixed``.

    Kept: every fit of a window would otherwise derive it again.
    """
    try:
        system = spec.create(**dict(fixed))
        return system.parametrised(spec.lagrangian, names)  # type: ignore[arg-type]
    except ValueError as exc:
        raise ValueError(f'model {spec.name}: {exc}') from None
