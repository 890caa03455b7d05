"""Built-in nonholonomic systems: only their Lagrangian data; the dynamics are derived.

Each model is metric + constraints (+ basis) handed to ``NonholonomicSystem.from_constraints``;
nothing of the equations of motion is typed in here.
"""
from __future__ import annotations

import inspect
import math
from collections.abc import Callable

import casadi as ca

from nh_tracking.system import NonholonomicSystem


def _check(**values: float) -> None:
    for name, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"model parameter {name} must be a finite number > 0, got {value!r}")


def chaplygin_sleigh(m: float = 1.0, J: float = 4.0, a: float = 0.2) -> NonholonomicSystem:
    """The Chaplygin sleigh (paper §2.1): q = (x1, x2, theta), the paper's basis X1, X2.

    m: mass, J: inertia about the centre of mass, a: distance from the blade's contact point to
    the centre of mass (along the blade). v1 is the rotation (X1 = d_theta / sqrt(J + m a^2)), v2
    the motion along the blade (X2 = (cos, sin, 0) / sqrt(m)); u1 acts on v1 (a torque), u2 on
    v2 (a force along the blade) — docs/theory.md §6. Constraint: no slip across the blade,
    x2' cos theta = x1' sin theta (docs/theory.md C1).
    """
    _check(m=m, J=J)
    if not math.isfinite(a):
        raise ValueError(f"model parameter a must be finite, got {a!r}")
    inertia = J + m * a**2

    def metric(q: ca.SX) -> ca.SX:
        s, c = ca.sin(q[2]), ca.cos(q[2])
        return ca.blockcat(
            [[m, 0, -m * a * s], [0, m, m * a * c], [-m * a * s, m * a * c, inertia]]
        )

    def constraints(q: ca.SX) -> ca.SX:
        return ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0)

    def basis(q: ca.SX) -> ca.SX:
        x1 = ca.vertcat(0, 0, 1 / math.sqrt(inertia))
        x2 = ca.vertcat(ca.cos(q[2]), ca.sin(q[2]), 0) / math.sqrt(m)
        return ca.horzcat(x1, x2)

    return NonholonomicSystem.from_constraints(
        ["x1", "x2", "theta"], metric, constraints, basis=basis, angles=["theta"],
        controls=["torque", "force"], velocities=["rotation", "forward"],
        name="chaplygin_sleigh", parameters={"m": m, "J": J, "a": a},
    )


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
        name="nonholonomic_particle",
    )


def unicycle(m: float = 1.0, J: float = 1.0) -> NonholonomicSystem:
    """A dynamic unicycle (differential-drive robot), q = (x, y, theta).

    The basis is the body twist — v = (forward speed, yaw rate), as in a ROS Twist — so
    u = (linear, angular) acceleration; the wheels' force and torque are m u1 and J u2.
    """
    _check(m=m, J=J)

    def constraints(q: ca.SX) -> ca.SX:
        return ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0)

    def basis(q: ca.SX) -> ca.SX:
        return ca.horzcat(ca.vertcat(ca.cos(q[2]), ca.sin(q[2]), 0), ca.vertcat(0, 0, 1))

    return NonholonomicSystem.from_constraints(
        ["x", "y", "theta"], lambda q: ca.diag(ca.vertcat(m, m, J)), constraints,
        basis=basis, angles=["theta"], controls=["linear_acceleration", "angular_acceleration"],
        velocities=["linear", "angular"], name="unicycle", parameters={"m": m, "J": J},
    )


def rolling_disk(
    m: float = 1.0, R: float = 0.5, I_spin: float = 0.1, I_turn: float = 0.05
) -> NonholonomicSystem:
    """A vertical disk rolling without slipping, q = (x, y, theta, phi).

    theta is the heading, phi the rolling angle; rolling: x' = R cos(theta) phi',
    y' = R sin(theta) phi'. Basis: e1 = d_theta (turning), e2 = R (cos, sin) + d_phi (rolling),
    so v = (turn rate, spin rate).
    """
    _check(m=m, R=R, I_spin=I_spin, I_turn=I_turn)

    def constraints(q: ca.SX) -> ca.SX:
        c, s = ca.cos(q[2]), ca.sin(q[2])
        return ca.vertcat(ca.horzcat(1, 0, 0, -R * c), ca.horzcat(0, 1, 0, -R * s))

    def basis(q: ca.SX) -> ca.SX:
        c, s = ca.cos(q[2]), ca.sin(q[2])
        return ca.horzcat(ca.vertcat(0, 0, 1, 0), ca.vertcat(R * c, R * s, 0, 1))

    return NonholonomicSystem.from_constraints(
        ["x", "y", "theta", "phi"], lambda q: ca.diag(ca.vertcat(m, m, I_turn, I_spin)),
        constraints, basis=basis, angles=["theta", "phi"],
        controls=["turn_acceleration", "spin_acceleration"], velocities=["turn", "spin"],
        name="rolling_disk", parameters={"m": m, "R": R, "I_spin": I_spin, "I_turn": I_turn},
    )


MODELS: dict[str, Callable[..., NonholonomicSystem]] = {
    "chaplygin_sleigh": chaplygin_sleigh,
    "nonholonomic_particle": nonholonomic_particle,
    "unicycle": unicycle,
    "rolling_disk": rolling_disk,
}


def model_parameters(name: str) -> dict[str, float]:
    """The physical parameters a built-in model takes, with their defaults."""
    return {
        p.name: p.default for p in inspect.signature(_factory(name)).parameters.values()
    }


def create(name: str, **parameters: float) -> NonholonomicSystem:
    """A built-in model by name (as the ROS parameter ``model`` names it)."""
    accepted = model_parameters(name)
    unknown = set(parameters) - set(accepted)
    if unknown:
        raise ValueError(f"model {name} takes {sorted(accepted)}, not {sorted(unknown)}")
    return _factory(name)(**parameters)


def _factory(name: str) -> Callable[..., NonholonomicSystem]:
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown model {name!r}; known: {sorted(MODELS)}") from None
