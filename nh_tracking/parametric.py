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

The same derivation as :class:`~nh_tracking.system.NonholonomicSystem` (the geometry of
:mod:`nh_tracking.geometry` on the model's :class:`~nh_tracking.lagrangian_data.LagrangianData`),
but the parameters named are an input ``p`` of the functions, so a new value is a new number,
not a new model: what estimating them needs.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from nh_tracking import geometry
from nh_tracking.models.spec import ModelSpec


@dataclass(frozen=True)
class ParametricModel:
    """``ode(x, u, p)`` -> xdot with x = (q, v) and ``p`` the values of ``names``, in order.

    ``velocity(q, qdot, p)`` -> v: the quasi-velocities of qdot's G-orthogonal projection on D.
    ``values`` holds every physical parameter's number (those named: their starting values).
    """

    spec: ModelSpec
    names: tuple[str, ...]
    values: dict[str, float]
    coordinates: tuple[str, ...]
    angle_mask: np.ndarray
    n: int
    k: int
    r: int
    ode: ca.Function
    velocity: ca.Function

    @property
    def start(self) -> np.ndarray:
        return np.array([self.values[name] for name in self.names])


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
    p = ca.SX.sym('p', len(names))
    data = spec.lagrangian(**{**checked, **{name: p[i] for i, name in enumerate(names)}})
    n = len(data.coordinates)
    q = ca.SX.sym('q', n)
    try:
        metric, _, potential, rho, actuators = data.expressions(q)
    except ValueError as exc:
        raise ValueError(f'model {spec.name}: {exc}') from None
    k = rho.shape[1]
    inputs = geometry.input_matrix(metric, rho, actuators)
    r = inputs.shape[1]
    v, u = ca.SX.sym('v', k), ca.SX.sym('u', r)
    gamma = geometry.christoffel(metric, rho, q)
    vdot = geometry.acceleration(gamma, inputs, metric, rho, potential, q, v, u)
    x = ca.vertcat(q, v)
    ode = ca.Function('ode', [x, u, p], [ca.vertcat(rho @ v, vdot)], ['x', 'u', 'p'], ['xdot'])
    qdot = ca.SX.sym('qdot', n)
    projected = geometry.basis_coefficients(metric, rho, qdot)
    velocity = ca.Function('velocity', [q, qdot, p], [projected], ['q', 'qdot', 'p'], ['v'])
    coordinates = tuple(data.coordinates)
    return ParametricModel(
        spec=spec, names=names, values=checked, coordinates=coordinates,
        angle_mask=np.array([c in data.angles for c in coordinates]), n=n, k=k, r=r, ode=ode,
        velocity=velocity)
