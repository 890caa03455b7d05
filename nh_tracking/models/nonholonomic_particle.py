"""The nonholonomic particle: the paper's second example."""
from __future__ import annotations

import casadi as ca

from nh_tracking.models.spec import ModelSpec
from nh_tracking.system import NonholonomicSystem


def nonholonomic_particle() -> NonholonomicSystem:
    """The nonholonomic particle (paper §2.2): unit mass in R^3 with x' + y z' = 0.

    q = (x, y, z); the paper's basis Y1 = d_y, Y2 = d_z - y d_x, which is *not* orthonormal
    (G_D = diag(1, 1 + y^2)).
    """

    def constraints(q: ca.SX) -> ca.SX:
        return ca.horzcat(1, 0, q[1])

    def basis(q: ca.SX) -> ca.SX:
        return ca.horzcat(ca.vertcat(0, 1, 0), ca.vertcat(-q[1], 0, 1))

    return NonholonomicSystem.from_constraints(
        ["x", "y", "z"], lambda q: ca.SX.eye(3), constraints, basis=basis,
        pose={"x": "x", "y": "y", "z": "z"}, name="nonholonomic_particle",
    )


SPEC = ModelSpec("nonholonomic_particle", nonholonomic_particle, (),
                 "a unit mass in R^3 with x' + y z' = 0", start=((0.0, 0.0, 0.0), (1.0, 1.0)))
