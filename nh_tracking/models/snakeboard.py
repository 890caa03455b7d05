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

"""The snakeboard: a board on two steerable wheel pairs that moves by shape changes alone."""
from __future__ import annotations

import math

import casadi as ca

from nh_tracking.core.lagrangian_data import LagrangianData
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.models.spec import ModelSpec, PhysicalParameter, positive, Scalar

STEERING_LIMIT = math.pi / 2  # at |phi| = pi/2 both axles are parallel: D changes rank


def snakeboard(m: float = 1.0,
               l: float = 0.5,  # noqa: E741 - the literature's name
               J: float = 0.1, J_r: float = 0.05, J_w: float = 0.01,
               actuated: bool = False) -> NonholonomicSystem:
    """Build the snakeboard of Ostrowski (Bloch §1.8): q = (x, y, theta, psi, phi).

    (x, y, theta): the board's centre and heading; psi: the rotor's angle on the board; phi: the
    wheel pairs' steering angle (front +phi, back -phi, coupled). m: mass, l: half the distance
    between the wheel pairs, J: the board's inertia, J_r: the rotor's, J_w: each wheel pair's
    about its vertical axis. Each wheel pair rolls without slipping sideways. Basis (global on
    the domain |phi| < pi/2): e1 = cos phi (cos theta, sin theta, 0, 0, 0) + sin phi / l
    d_theta (v1 is the forward speed at phi = 0), e2 = d_psi, e3 = d_phi. Driven by the rotor
    and steering torques only (r = 2 < k = 3); ``actuated=True`` gives the fully actuated model,
    with one control per basis field, that references are generated with.
    """
    positive(m=m, l=l, J=J, J_r=J_r, J_w=J_w)
    return NonholonomicSystem.from_data(
        lagrangian(m, l, J, J_r, J_w, actuated=actuated),
        domain={'phi': (-STEERING_LIMIT, STEERING_LIMIT)},
        controls=None if actuated else ['rotor_torque', 'steering_torque'],
        velocities=['forward', 'rotor', 'steering'],
        pose={'x': 'x', 'y': 'y', 'theta': 'yaw'},
        name='snakeboard_actuated' if actuated else 'snakeboard',
        parameters={'m': m, 'l': l, 'J': J, 'J_r': J_r, 'J_w': J_w},
    )


def lagrangian(m: Scalar, l: Scalar, J: Scalar, J_r: Scalar,  # noqa: E741
               J_w: Scalar, actuated: bool = False) -> LagrangianData:
    """Return the snakeboard's metric, wheel constraints, basis and torque directions.

    The physical parameters are numbers or CasADi symbols.
    """

    def metric(q: ca.SX) -> ca.SX:
        return ca.blockcat([
            [m, 0, 0, 0, 0], [0, m, 0, 0, 0], [0, 0, J + J_r + 2 * J_w, J_r, 0],
            [0, 0, J_r, J_r, 0], [0, 0, 0, 0, 2 * J_w]])

    def constraints(q: ca.SX) -> ca.SX:
        theta, phi = q[2], q[4]
        front = ca.horzcat(-ca.sin(theta + phi), ca.cos(theta + phi), l * ca.cos(phi), 0, 0)
        back = ca.horzcat(-ca.sin(theta - phi), ca.cos(theta - phi), -l * ca.cos(phi), 0, 0)
        return ca.vertcat(front, back)

    def basis(q: ca.SX) -> ca.SX:
        theta, phi = q[2], q[4]
        roll = ca.vertcat(ca.cos(phi) * ca.cos(theta), ca.cos(phi) * ca.sin(theta),
                          ca.sin(phi) / l, 0, 0)
        return ca.horzcat(roll, ca.SX([0, 0, 0, 1, 0]), ca.SX([0, 0, 0, 0, 1]))

    def torques(q: ca.SX) -> ca.SX:
        return ca.SX(ca.DM([[0, 0], [0, 0], [0, 0], [1, 0], [0, 1]]))

    return LagrangianData(['x', 'y', 'theta', 'psi', 'phi'], metric, constraints, basis=basis,
                          actuators=None if actuated else torques, angles=['theta', 'psi'])


SPEC = ModelSpec(
    'snakeboard', snakeboard,
    (PhysicalParameter('m', 1.0, 'kg', 'mass'),
     PhysicalParameter('l', 0.5, 'm', 'half the distance between the wheel pairs'),
     PhysicalParameter('J', 0.1, 'kg m^2', "the board's moment of inertia"),
     PhysicalParameter('J_r', 0.05, 'kg m^2', "the rotor's moment of inertia"),
     PhysicalParameter('J_w', 0.01, 'kg m^2', "each wheel pair's moment of inertia")),
    'a board propelled by rotor and steering torques only (underactuated)',
    start=((0.0, 0.0, 0.0, 0.0, 0.0), (0.5, 0.0, 0.0)), lagrangian=lagrangian)
