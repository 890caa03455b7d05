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

"""The Chaplygin sleigh: the paper's main example."""
from __future__ import annotations

import math

import casadi as ca

from nh_tracking.core.lagrangian_data import LagrangianData
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.models.spec import ModelSpec, PhysicalParameter, positive, Scalar


def chaplygin_sleigh(m: float = 1.0, J: float = 4.0, a: float = 0.2) -> NonholonomicSystem:
    """Build the Chaplygin sleigh (paper §2.1): q = (x1, x2, theta), the paper's basis X1, X2.

    m: mass, J: inertia about the centre of mass, a: distance from the blade's contact point to
    the centre of mass (along the blade). v1 is the rotation (X1 = d_theta / sqrt(J + m a^2)), v2
    the motion along the blade (X2 = (cos, sin, 0) / sqrt(m)); u1 acts on v1 (a torque), u2 on
    v2 (a force along the blade) — docs/theory.md §6. Constraint: no slip across the blade,
    x2' cos theta = x1' sin theta (docs/theory.md C1).
    """
    positive(m=m, J=J)
    if not math.isfinite(a):
        raise ValueError(f'model parameter a must be finite, got {a!r}')
    return NonholonomicSystem.from_data(
        lagrangian(m, J, a), controls=['torque', 'force'], velocities=['rotation', 'forward'],
        pose={'x1': 'x', 'x2': 'y', 'theta': 'yaw'}, name='chaplygin_sleigh',
        parameters={'m': m, 'J': J, 'a': a},
    )


def lagrangian(m: Scalar, J: Scalar, a: Scalar) -> LagrangianData:
    """Return the sleigh's metric, constraint and basis; parameters numbers or CasADi symbols."""
    inertia = J + m * a**2

    def metric(q: ca.SX) -> ca.SX:
        s, c = ca.sin(q[2]), ca.cos(q[2])
        return ca.blockcat(
            [[m, 0, -m * a * s], [0, m, m * a * c], [-m * a * s, m * a * c, inertia]]
        )

    def constraints(q: ca.SX) -> ca.SX:
        return ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0)

    def basis(q: ca.SX) -> ca.SX:
        x1 = ca.vertcat(0, 0, 1 / ca.sqrt(inertia))
        x2 = ca.vertcat(ca.cos(q[2]), ca.sin(q[2]), 0) / ca.sqrt(m)
        return ca.horzcat(x1, x2)

    return LagrangianData(['x1', 'x2', 'theta'], metric, constraints, basis=basis,
                          angles=['theta'])


SPEC = ModelSpec(
    'chaplygin_sleigh', chaplygin_sleigh,
    (PhysicalParameter('m', 1.0, 'kg', 'mass'),
     PhysicalParameter('J', 4.0, 'kg m^2', 'moment of inertia about the centre of mass'),
     PhysicalParameter('a', 0.2, 'm', "distance from the blade's contact point to the centre "
                       'of mass', (-1e6, 1e6))),
    'a rigid body on a blade that cannot slip sideways',
    start=((0.0, 0.5, 0.0), (1 / 3, 1.0)), lagrangian=lagrangian)
