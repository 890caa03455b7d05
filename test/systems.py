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

"""Test systems beyond the built-in models, and the independent Lagrange–d'Alembert reference."""
from __future__ import annotations

import casadi as ca
import numpy as np

import nh_tracking as nht


def inclined_knife_edge(m: float = 1.3, J: float = 0.4, alpha: float = 0.35,
                        g: float = 9.81) -> nht.NonholonomicSystem:
    """Knife edge on an inclined plane (Bloch §1.6), q = (x, y, phi), x pointing downhill.

    Built from its Lagrangian data alone: no basis given, so from_constraints chooses one.
    """
    return nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'phi'],
        metric=lambda q: ca.diag(ca.vertcat(m, m, J)),
        constraints=lambda q: ca.horzcat(ca.sin(q[2]), -ca.cos(q[2]), 0),
        potential=lambda q: -m * g * ca.sin(alpha) * q[0],
        angles=['phi'], pose={'x': 'x', 'y': 'y', 'phi': 'yaw'}, name='inclined_knife_edge',
    )


def rotor_sleigh(m: float = 1.0, J: float = 2.0, a: float = 0.3,
                 J_r: float = 0.5) -> nht.NonholonomicSystem:
    """Build a Chaplygin sleigh driven only by an internal rotor: q = (x, y, theta, psi), r = 1.

    psi is the rotor's angle on the body (its absolute angle theta + psi); the one control is
    the torque between body and rotor, a generalised force on psi alone.
    """
    def metric(q: ca.SX) -> ca.SX:
        s, c = ca.sin(q[2]), ca.cos(q[2])
        return ca.blockcat([[m, 0, -m * a * s, 0], [0, m, m * a * c, 0],
                            [-m * a * s, m * a * c, J + m * a ** 2 + J_r, J_r],
                            [0, 0, J_r, J_r]])

    return nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'theta', 'psi'], metric,
        lambda q: ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0, 0),
        actuators=lambda q: ca.DM([[0], [0], [0], [1]]), angles=['theta', 'psi'],
        pose={'x': 'x', 'y': 'y', 'theta': 'yaw'}, name='rotor_sleigh')


def roller_racer(m1: float = 1.0, I1: float = 0.2, m2: float = 0.5, I2: float = 0.1,
                 d1: float = 0.4, d2: float = 0.6, basis: bool = False) -> nht.NonholonomicSystem:
    """Build a roller racer: q = (x, y, theta, phi), driven only by its joint torque (r = 1).

    Two bodies on wheel pairs that cannot slip sideways, joined by a revolute joint d1 ahead
    of the first axle (x, y) and d2 ahead of the second; theta heads the first body, theta + phi
    the second; each body's mass sits at its axle. ``basis``: the hand-written fields (the
    first axle's rolling and the joint's turning, holding the second body's constraint).
    """
    def axle2(q: ca.SX) -> tuple[ca.SX, ca.SX]:
        return (q[0] + d1 * ca.cos(q[2]) - d2 * ca.cos(q[2] + q[3]),
                q[1] + d1 * ca.sin(q[2]) - d2 * ca.sin(q[2] + q[3]))

    def metric(q: ca.SX) -> ca.SX:
        jac = ca.jacobian(ca.vertcat(*axle2(q)), q)
        return (ca.diag(ca.vertcat(m1, m1, I1 + I2, I2)) + m2 * jac.T @ jac
                + I2 * ca.SX([[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1], [0, 0, 1, 0]]))

    def constraints(q: ca.SX) -> ca.SX:
        jac = ca.jacobian(ca.vertcat(*axle2(q)), q)
        heading2 = q[2] + q[3]
        return ca.vertcat(ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0, 0),
                          -ca.sin(heading2) * jac[0, :] + ca.cos(heading2) * jac[1, :])

    def fields(q: ca.SX) -> ca.SX:
        c, s = ca.cos(q[3]), ca.sin(q[3])  # (d2 > d1: d2 - d1 cos(phi) never vanishes)
        roll = ca.vertcat(ca.cos(q[2]) * (d2 - d1 * c), ca.sin(q[2]) * (d2 - d1 * c), -s, 0)
        turn = ca.vertcat(0, 0, d2, d1 * c - d2)
        return ca.horzcat(roll, turn)

    return nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'theta', 'phi'], metric, constraints, basis=fields if basis else None,
        actuators=lambda q: ca.DM([[0], [0], [0], [1]]), angles=['theta', 'phi'],
        domain={'phi': (-2.0, 2.0)}, pose={'x': 'x', 'y': 'y', 'theta': 'yaw'},
        name='roller_racer')


def polar_knife(J: float = 0.5, r_max: float = 100.0) -> nht.NonholonomicSystem:
    """Build a knife edge in polar coordinates: q = (r, phi, theta), metric diag(1, r^2, J).

    The blade at (r cos phi, r sin phi) points along theta and cannot slip across it; valid for
    r in (0.2, r_max). Its constraint row (sin(theta - phi), -r cos(theta - phi), 0) has a
    length that grows with r: a rank check that scales rows by one constant over the domain
    sees a rank drop at small r that is not there.
    """
    return nht.NonholonomicSystem.from_constraints(
        ['r', 'phi', 'theta'], lambda q: ca.diag(ca.vertcat(1, q[0] ** 2, J)),
        lambda q: ca.horzcat(ca.sin(q[2] - q[1]), -q[0] * ca.cos(q[2] - q[1]), 0),
        angles=['phi', 'theta'], domain={'r': (0.2, r_max)}, name='polar_knife')


def polar_knife_past_the_origin() -> nht.TrackingProblem:
    """Return a polar knife asked along a line 0.1 m from the origin: r dips below its 0.2."""
    t = np.linspace(0.0, 6.0, 121)
    x, y = -1.5 + 0.5 * t, np.full_like(t, 0.1)
    q_ref = np.stack([np.hypot(x, y), np.unwrap(np.arctan2(y, x)), np.zeros_like(t)], axis=1)
    reference = nht.Trajectory(t, q_ref, np.tile([1.0, 0.0], (len(t), 1)),
                               np.zeros((len(t) - 1, 2)))
    return nht.TrackingProblem(polar_knife(), reference, q_ref[0], [0.5, 0.0], horizon=6.0,
                               steps=40, terminal='cost')


def euler_ball(m: float = 1.0, R: float = 0.2) -> nht.NonholonomicSystem:
    """Build a ball rolling without slipping: q = (x, y, phi, theta, psi), ZXZ Euler angles.

    The contact point does not slide: (xdot, ydot) = R (omega_y, -omega_x) with omega the
    spatial angular velocity. The angles are singular at theta = 0 and pi (gimbal lock), so
    the domain keeps theta in (0.1, pi - 0.1). Three torques on the Euler angles drive it.
    """
    inertia = 0.4 * m * R**2

    def omega(q: ca.SX) -> ca.SX:  # spatial angular velocity per (phidot, thetadot, psidot)
        phi, theta = q[2], q[3]
        return ca.vertcat(ca.horzcat(0, ca.cos(phi), ca.sin(phi) * ca.sin(theta)),
                          ca.horzcat(0, ca.sin(phi), -ca.cos(phi) * ca.sin(theta)),
                          ca.horzcat(1, 0, ca.cos(theta)))

    def metric(q: ca.SX) -> ca.SX:
        w = omega(q)
        return ca.diagcat(m * ca.SX.eye(2), inertia * w.T @ w)

    def constraints(q: ca.SX) -> ca.SX:
        w = omega(q)
        return ca.vertcat(ca.horzcat(1, 0, -R * w[1, :]), ca.horzcat(0, 1, R * w[0, :]))

    return nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'phi', 'theta', 'psi'], metric, constraints,
        angles=['phi', 'theta', 'psi'], domain={'theta': (0.1, np.pi - 0.1)},
        pose={'x': 'x', 'y': 'y'}, name='euler_ball')


def coupled_system() -> nht.NonholonomicSystem:
    """Build a made-up system with a configuration-dependent, non-diagonal metric.

    Two constraints that depend on q, and a potential: nothing in it is special, so nothing can
    cancel by luck.
    """

    def metric(q: ca.SX) -> ca.SX:
        a = ca.blockcat([
            [1 + 0.3 * ca.sin(q[1]), 0.2 * q[2], 0, 0.1],
            [0, 1.2, 0.3 * ca.cos(q[0]), 0],
            [0.1 * q[3], 0, 0.9, 0.2 * ca.sin(q[2])],
            [0, 0.1, 0, 1.1 + 0.2 * ca.cos(q[3])],
        ])
        return a.T @ a + 0.5 * ca.SX.eye(4)

    def constraints(q: ca.SX) -> ca.SX:
        return ca.vertcat(
            ca.horzcat(1, 0, q[1], ca.sin(q[3])),
            ca.horzcat(0, ca.cos(q[2]), 1, 0.5 * q[0]),
        )

    return nht.NonholonomicSystem.from_constraints(
        ['a', 'b', 'c', 'd'], metric, constraints,
        potential=lambda q: 0.5 * q[0] ** 2 + ca.cos(q[1]) + 0.3 * q[2] * q[3],
        name='coupled',
    )


def lagrange_dalembert_acceleration(system: nht.NonholonomicSystem, q: np.ndarray,
                                    qdot: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Qddot of the Lagrange–d'Alembert equations with multipliers, in full coordinates.

    d/dt(G qdot) - 1/2 d/dq(qdot^T G qdot) + dV/dq = force + mu^T lambda,  mu qdot = 0.
    Uses only the system's data G, mu, V (no basis, no connection): an independent derivation.
    """
    n = system.n
    qs, qds = ca.SX.sym('q', n), ca.SX.sym('qd', n)
    g = system.metric_fn(qs)
    mu = system.constraints_fn(qs)
    v_pot = system.potential_fn(qs)
    momentum = g @ qds
    rhs = (-ca.jacobian(momentum, qs) @ qds + 0.5 * ca.gradient(qds.T @ g @ qds, qs)
           - ca.gradient(v_pot, qs))
    drift = ca.jacobian(mu @ qds, qs) @ qds
    fn = ca.Function('lda', [qs, qds], [g, mu, rhs, drift])
    g_n, mu_n, rhs_n, drift_n = (np.array(x) for x in fn(q, qdot))
    m = mu_n.shape[0]
    kkt = np.block([[g_n, -mu_n.T], [mu_n, np.zeros((m, m))]])
    sol = np.linalg.solve(kkt, np.concatenate([rhs_n.ravel() + force, -drift_n.ravel()]))
    return sol[:n]


def basis_acceleration(system: nht.NonholonomicSystem, q: np.ndarray, v: np.ndarray,
                       vdot: np.ndarray) -> np.ndarray:
    """d/dt (rho(q) v) = (d rho/dq . qdot) v + rho vdot, with qdot = rho v."""
    qs = ca.SX.sym('q', system.n)
    vs = ca.DM(v)
    rho_v = system.rho_fn(qs) @ vs
    jac = np.array(ca.Function('j', [qs], [ca.jacobian(rho_v, qs)])(q))
    rho = system.rho(q)
    return jac @ (rho @ v) + rho @ vdot


def random_state(system: nht.NonholonomicSystem, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    q = rng.normal(size=system.n)
    q[system.angle_mask] = rng.uniform(-np.pi, np.pi, system.angle_mask.sum())
    return q, rng.normal(size=system.k), rng.normal(size=system.r)


ALL_SYSTEMS = {
    'chaplygin_sleigh': nht.models.chaplygin_sleigh,
    'chaplygin_sleigh_heavy': lambda: nht.models.chaplygin_sleigh(m=3.5, J=0.7, a=-0.6),
    'nonholonomic_particle': nht.models.nonholonomic_particle,
    'unicycle': lambda: nht.models.unicycle(m=2.0, J=0.3),
    'rolling_disk': nht.models.rolling_disk,
    'inclined_knife_edge': inclined_knife_edge,
    'coupled': coupled_system,
    'roller_racer': lambda: roller_racer(basis=True),
}
