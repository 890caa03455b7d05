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

"""A vertical disk rolling without slipping."""
from __future__ import annotations

import casadi as ca

from nh_tracking.core.lagrangian_data import LagrangianData
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.models.spec import ModelSpec, PhysicalParameter, positive, Scalar


def rolling_disk(
    m: float = 1.0, R: float = 0.5, I_spin: float = 0.1, I_turn: float = 0.05
) -> NonholonomicSystem:
    """Build a vertical disk rolling without slipping, q = (x, y, theta, phi).

    theta is the heading, phi the rolling angle; rolling: x' = R cos(theta) phi',
    y' = R sin(theta) phi'. Basis: e1 = d_theta (turning), e2 = R (cos, sin) + d_phi (rolling),
    so v = (turn rate, spin rate).
    """
    positive(m=m, R=R, I_spin=I_spin, I_turn=I_turn)
    return NonholonomicSystem.from_data(
        lagrangian(m, R, I_spin, I_turn), controls=['turn_acceleration', 'spin_acceleration'],
        velocities=['turn', 'spin'], pose={'x': 'x', 'y': 'y', 'theta': 'yaw'},
        name='rolling_disk', parameters={'m': m, 'R': R, 'I_spin': I_spin, 'I_turn': I_turn},
    )


def lagrangian(m: Scalar, R: Scalar, I_spin: Scalar, I_turn: Scalar) -> LagrangianData:
    """Return the disk's metric, rolling constraints and basis (numbers or CasADi symbols)."""

    def constraints(q: ca.SX) -> ca.SX:
        c, s = ca.cos(q[2]), ca.sin(q[2])
        return ca.vertcat(ca.horzcat(1, 0, 0, -R * c), ca.horzcat(0, 1, 0, -R * s))

    def basis(q: ca.SX) -> ca.SX:
        c, s = ca.cos(q[2]), ca.sin(q[2])
        return ca.horzcat(ca.vertcat(0, 0, 1, 0), ca.vertcat(R * c, R * s, 0, 1))

    return LagrangianData(['x', 'y', 'theta', 'phi'],
                          lambda q: ca.diag(ca.vertcat(m, m, I_turn, I_spin)), constraints,
                          basis=basis, angles=['theta', 'phi'])


SPEC = ModelSpec(
    'rolling_disk', rolling_disk,
    (PhysicalParameter('m', 1.0, 'kg', 'mass'),
     PhysicalParameter('R', 0.5, 'm', 'wheel radius'),
     PhysicalParameter('I_spin', 0.1, 'kg m^2', 'inertia about the wheel axle'),
     PhysicalParameter('I_turn', 0.05, 'kg m^2', 'inertia about the vertical axis')),
    'a coin rolling upright; its rolling angle is not seen in a pose',
    start=((0.0, 0.0, 0.0, 0.0), (1.0, 1.0)), lagrangian=lagrangian)
