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

"""The nonholonomic particle: the paper's second example."""
from __future__ import annotations

import casadi as ca

from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.models.spec import ModelSpec


def nonholonomic_particle() -> NonholonomicSystem:
    """Build the nonholonomic particle (paper §2.2): unit mass in R^3 with x' + y z' = 0.

    q = (x, y, z); the paper's basis Y1 = d_y, Y2 = d_z - y d_x, which is *not* orthonormal
    (G_D = diag(1, 1 + y^2)).
    """

    def constraints(q: ca.SX) -> ca.SX:
        return ca.horzcat(1, 0, q[1])

    def basis(q: ca.SX) -> ca.SX:
        return ca.horzcat(ca.vertcat(0, 1, 0), ca.vertcat(-q[1], 0, 1))

    return NonholonomicSystem.from_constraints(
        ['x', 'y', 'z'], lambda q: ca.SX.eye(3), constraints, basis=basis,
        pose={'x': 'x', 'y': 'y', 'z': 'z'}, name='nonholonomic_particle',
    )


SPEC = ModelSpec('nonholonomic_particle', nonholonomic_particle, (),
                 "a unit mass in R^3 with x' + y z' = 0", start=((0.0, 0.0, 0.0), (1.0, 1.0)))
