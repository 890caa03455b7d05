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

"""A robot the package does not ship, written as a user would, in a module of their own.

The car-like robot (rear-wheel drive, front-wheel steering), loaded with ``model`` =
``user_robots:CAR`` by the library, the command line and the ROS nodes.
"""
import math

import casadi as ca

from nh_tracking import NonholonomicSystem
from nh_tracking.models import ModelSpec, PhysicalParameter


def car_like(m: float = 1.0, J: float = 0.5, I_steer: float = 0.05,
             L: float = 0.5) -> NonholonomicSystem:
    """Q = (x, y, theta, phi): rear axle position, heading, steering angle.

    Neither wheel slips sideways; basis: driving e1 = (L cos th cos phi, L sin th cos phi, sin phi,
    0) (smooth for every phi) and steering e2 = d_phi. The steering stops short of +-pi/2, where
    the front wheel would stand across the car.
    """

    def constraints(q):
        th, phi = q[2], q[3]
        rear = ca.horzcat(ca.sin(th), -ca.cos(th), 0, 0)
        front = ca.horzcat(ca.sin(th + phi), -ca.cos(th + phi), -L * ca.cos(phi), 0)
        return ca.vertcat(rear, front)

    def basis(q):
        th, phi = q[2], q[3]
        drive = ca.vertcat(L * ca.cos(th) * ca.cos(phi), L * ca.sin(th) * ca.cos(phi),
                           ca.sin(phi), 0)
        return ca.horzcat(drive, ca.vertcat(0, 0, 0, 1))

    return NonholonomicSystem.from_constraints(
        ['x', 'y', 'theta', 'phi'], lambda q: ca.diag(ca.vertcat(m, m, J, I_steer)),
        constraints, basis=basis, angles=['theta'], domain={'phi': (-math.pi / 2, math.pi / 2)},
        controls=['drive', 'steer'],
        pose={'x': 'x', 'y': 'y', 'theta': 'yaw'}, name='car_like',
        parameters={'m': m, 'J': J, 'I_steer': I_steer, 'L': L})


CAR = ModelSpec(
    'car_like', car_like,
    (PhysicalParameter('m', 1.0, 'kg', 'mass'),
     PhysicalParameter('J', 0.5, 'kg m^2', 'yaw inertia'),
     PhysicalParameter('I_steer', 0.05, 'kg m^2', 'steering inertia'),
     PhysicalParameter('L', 0.5, 'm', 'wheelbase')),
    'a car-like robot', start=((0.0, 0.0, 0.0, 0.0), (1.0, 0.0)))

NOT_A_MODEL = 42


def broken(m: float = 1.0) -> NonholonomicSystem:
    """Build nothing: a factory with a mistake in it, as users make them."""
    return undefined_name  # type: ignore[name-defined]  # noqa: F821
