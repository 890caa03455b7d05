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

"""The dynamic unicycle: a differential-drive robot."""
from __future__ import annotations

import casadi as ca

from nh_tracking.core.lagrangian_data import LagrangianData
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.models.spec import ModelSpec, PhysicalParameter, positive, Scalar


def unicycle(m: float = 1.0, J: float = 1.0) -> NonholonomicSystem:
    """Build a dynamic unicycle, a differential-drive robot: q = (x, y, theta).

    The basis is the body twist — v = (forward speed, yaw rate), as in a ROS Twist — so
    u = (linear, angular) acceleration; the wheels' force and torque are m u1 and J u2.
    """
    positive(m=m, J=J)
    return NonholonomicSystem.from_data(
        lagrangian(m, J), controls=['linear_acceleration', 'angular_acceleration'],
        velocities=['linear', 'angular'], pose={'x': 'x', 'y': 'y', 'theta': 'yaw'},
        name='unicycle', parameters={'m': m, 'J': J},
    )


def lagrangian(m: Scalar, J: Scalar) -> LagrangianData:
    """Return the unicycle's metric, constraint and body-twist basis.

    m and J do not enter the motion of v: the controls are accelerations.
    """

    def constraints(q: ca.SX) -> ca.SX:
        return ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0)

    def basis(q: ca.SX) -> ca.SX:
        return ca.horzcat(ca.vertcat(ca.cos(q[2]), ca.sin(q[2]), 0), ca.vertcat(0, 0, 1))

    return LagrangianData(['x', 'y', 'theta'], lambda q: ca.diag(ca.vertcat(m, m, J)),
                          constraints, basis=basis, angles=['theta'])


SPEC = ModelSpec(
    'unicycle', unicycle,
    (PhysicalParameter('m', 1.0, 'kg', 'mass'),
     PhysicalParameter('J', 1.0, 'kg m^2', 'moment of inertia about the vertical axis')),
    'a differential-drive robot; v is the body twist', start=((0.0, 0.0, 0.0), (1.0, 1.0)),
    lagrangian=lagrangian)
