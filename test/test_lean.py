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

"""Lean derived equations: as short as the same equations written by hand, and the same values.

The hand-written equations below come from each model's physics (Newton–Euler or the reduced
Lagrangian written out on paper), not from the package; they check the derived values and set the
instruction count the derivation must come within 1.5x of.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from nh_tracking import models
from nh_tracking.core import lean
from nh_tracking.models.snakeboard import snakeboard

pytestmark = pytest.mark.unit

Q, V, U = ca.SX.sym('q', 5), ca.SX.sym('v', 3), ca.SX.sym('u', 3)


def _sleigh(m: float, J: float, a: float) -> tuple[ca.SX, ca.SX]:
    """Sleigh: omega' = -(m a / I) v omega, v' = a omega^2; v = (sqrt(I) omega, sqrt(m) v)."""
    inertia = J + m * a * a
    eta = a * math.sqrt(m) / inertia
    qdot = ca.vertcat(ca.cos(Q[2]) * V[1] / math.sqrt(m), ca.sin(Q[2]) * V[1] / math.sqrt(m),
                      V[0] / math.sqrt(inertia))
    return qdot, ca.vertcat(U[0] - eta * V[0] * V[1], U[1] + eta * V[0] * V[0])


def _particle() -> tuple[ca.SX, ca.SX]:
    """Particle: x' = -y z', (1 + y^2) z'' + y y' z' = 0 (the reduced Lagrangian)."""
    y = Q[1]
    return (ca.vertcat(-y * V[1], V[0], V[1]),
            ca.vertcat(U[0], U[1] - y / (1 + y * y) * V[0] * V[1]))


def _unicycle() -> tuple[ca.SX, ca.SX]:
    return ca.vertcat(ca.cos(Q[2]) * V[0], ca.sin(Q[2]) * V[0], V[1]), U[:2]


def _rolling_disk(R: float) -> tuple[ca.SX, ca.SX]:
    return ca.vertcat(R * ca.cos(Q[2]) * V[1], R * ca.sin(Q[2]) * V[1], V[0], V[1]), U[:2]


def _snakeboard(m: float, l: float, J: float, J_r: float, J_w: float,  # noqa: E741
                actuated: bool) -> tuple[ca.SX, ca.SX]:
    """Snakeboard: e1's Lagrange–d'Alembert equation with the rotor equation substituted.

    (m c^2 + (J + 2 J_w) s^2 / l^2) v1' = -(s / l) tau_psi + (m - (J + 2 J_w) / l^2) s c v1 v3,
    v2' = tau_psi / J_r - (s / l) v1' - c v1 v3 / l, v3' = tau_phi / (2 J_w); c, s of phi.
    """
    c, s = ca.cos(Q[4]), ca.sin(Q[4])
    qdot = ca.vertcat(c * ca.cos(Q[2]) * V[0], c * ca.sin(Q[2]) * V[0], s / l * V[0], V[1], V[2])
    tau = (0, 0, 0) if actuated else (U[0], U[1])
    fwd = (-(s / l) * (tau[0] if not actuated else 0)
           + (m - (J + 2 * J_w) / l**2) * s * c * V[0] * V[2]) / (
        m * c * c + (J + 2 * J_w) * s * s / l**2)
    rotor = (0 if actuated else U[0] / J_r) - (s / l) * fwd - c * V[0] * V[2] / l
    steer = 0 if actuated else U[1] / (2 * J_w)
    vdot = ca.vertcat(fwd, rotor, steer)
    return qdot, vdot + U if actuated else vdot


CASES = [
    ('chaplygin_sleigh', {}, lambda p: _sleigh(1.0, 4.0, 0.2)),
    ('chaplygin_sleigh', {'m': 2.5, 'J': 0.7, 'a': -0.45}, lambda p: _sleigh(**p)),
    ('nonholonomic_particle', {}, lambda p: _particle()),
    ('unicycle', {'m': 3.0, 'J': 0.2}, lambda p: _unicycle()),
    ('rolling_disk', {'R': 0.31, 'I_turn': 0.02}, lambda p: _rolling_disk(0.31)),
    ('snakeboard', {}, lambda p: _snakeboard(1.0, 0.5, 0.1, 0.05, 0.01, False)),
    ('snakeboard', {'m': 4.0, 'l': 0.3, 'J': 0.3, 'J_r': 0.2, 'J_w': 0.04},
     lambda p: _snakeboard(**p, actuated=False)),
]


@pytest.mark.parametrize('name, parameters, by_hand', CASES)
def test_derived_dynamics_equal_and_as_short_as_the_hand_written(name, parameters, by_hand):
    system = models.create(name, **parameters)
    qdot, vdot = by_hand(parameters)
    q, v, u = Q[:system.n], V[:system.k], U[:system.r]
    hand = ca.Function('hand', [q, v, u], [qdot, vdot], {'cse': True})
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = np.concatenate([rng.uniform(-1.4, 1.4, system.n), rng.normal(size=system.k)])
        w = rng.normal(size=system.r)
        for derived, written in zip(system.dynamics_fn(x[:system.n], x[system.n:], w),
                                    hand(x[:system.n], x[system.n:], w)):
            np.testing.assert_allclose(np.array(derived), np.array(written), atol=1e-10)
    ratio = system.dynamics_fn.n_instructions() / hand.n_instructions()
    assert ratio <= 1.5, (name, system.dynamics_fn.n_instructions(), hand.n_instructions())
    if name == 'chaplygin_sleigh':
        assert system.dynamics_fn.n_instructions() <= 36


def test_the_fully_actuated_snakeboard_is_lean_too():
    system = snakeboard(actuated=True)
    hand = ca.Function('hand', [Q, V, U], list(_snakeboard(1.0, 0.5, 0.1, 0.05, 0.01, True)),
                       {'cse': True})
    x = np.array([0.3, -1.0, 2.0, 0.4, 0.9])
    for derived, written in zip(system.dynamics_fn(x, [0.7, -0.2, 1.1], [0.3, 0.1, -2.0]),
                                hand(x, [0.7, -0.2, 1.1], [0.3, 0.1, -2.0])):
        np.testing.assert_allclose(np.array(derived), np.array(written), atol=1e-10)
    assert system.dynamics_fn.n_instructions() <= 1.5 * hand.n_instructions()


def _draw(size: int):
    def draw(seed: int) -> list[np.ndarray]:
        return [np.random.default_rng(seed).uniform(-3, 3, (lean.SAMPLES, size))]
    return draw


def test_identities_fold_and_a_tiny_dependence_is_kept():
    x = ca.SX.sym('x', 2)
    f = ca.Function('f', [x], [ca.vertcat(
        x[1] * (ca.cos(x[0]) ** 2 + ca.sin(x[0]) ** 2),  # = x1: the angle x0 is spurious
        1e-9 * ca.sin(x[0]) + 2.0,                        # not constant: must stay
        ca.sin(x[0]) * x[1] - x[1] * ca.sin(x[0]) + 3.0)])  # = 3
    short = lean.lean(f, _draw(2))
    assert short.n_instructions() < f.n_instructions()
    assert not ca.depends_on(short(x)[0], x[0]) and ca.depends_on(short(x)[1], x[0])
    assert ca.SX(short(x)[2]).is_constant()
    for point in ([0.3, -2.0], [2.9, 0.1], [-1.0, 5.0]):
        np.testing.assert_allclose(np.array(short(point)), np.array(f(point)), rtol=1e-12)


def test_a_graph_that_would_change_is_kept_as_it_is():
    """floor(x / 100) is constant on the drawn samples' range only: the fresh check catches it."""
    x = ca.SX.sym('x')
    f = ca.Function('f', [x], [ca.floor(x / 100.0) * ca.sin(x) + x])

    def draw(seed: int) -> list[np.ndarray]:  # folds on [0, 1), checks on [100, 200)
        low = 0.0 if seed < 2 else 100.0
        return [np.random.default_rng(seed).uniform(low, low + 1, (lean.SAMPLES, 1))]

    assert lean.lean(f, draw) is f


def test_what_the_samples_cannot_see_is_left_alone():
    """Found by an independent probe: walls, tiny terms, branches, half-line domains.

    A soft wall (fmax) the samples never reach stays in the energy; a 1e-12 term stays; two
    branches equal on the base samples but not on the redraws stay distinct; a coordinate on a
    half line is sampled on it.
    """
    import nh_tracking as nht

    wall = nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'th'], lambda q: ca.diag(ca.vertcat(1.0, 1.0, 0.2)),
        lambda q: ca.horzcat(ca.sin(q[2]), -ca.cos(q[2]), 0),
        lambda q: 50 * (ca.fmax(q[0] - 2.0, 0) ** 2 + ca.fmax(ca.fabs(q[1]) - 2.0, 0) ** 2),
        angles=['th'], name='walled')
    assert wall.energy([3.5, 0.0, 0.0], [0.0, 0.0]) == pytest.approx(50 * 1.5 ** 2)
    assert wall.dynamics([0.0, 3.0, 0.3], [0.0, 0.0])[1] != pytest.approx([0.0, 0.0])
    x = ca.SX.sym('x', 2)
    tiny = ca.Function('tiny', [x], [1e-12 * ca.sin(x[0]) * x[1]])
    short = lean.lean(tiny, _draw(2))
    assert float(short([1.0, 2.0])) == pytest.approx(2e-12 * np.sin(1.0), rel=1e-12)
    branches = ca.Function('b', [x], [ca.vertcat(ca.fmax(x[0] - 1, 0) + x[1],
                                                 ca.fmax(x[1] - 1, 0) + x[1])])

    def draw(seed: int) -> list[np.ndarray]:  # only the redraws reach the branches
        return [np.random.default_rng(seed).uniform(-1, 1 if seed == 0 else 2,
                                                    (lean.SAMPLES, 2))]

    np.testing.assert_allclose(np.array(lean.lean(branches, draw)([1.5, 0.5])).ravel(),
                               [1.0, 0.5])
    polar = nht.NonholonomicSystem.from_constraints(
        ['r', 'a', 'b'], lambda q: ca.diag(ca.vertcat(1.0, q[0] ** 2, 1.0)),
        lambda q: ca.horzcat(0, 1, -q[0]), domain={'r': (2.0, np.inf)}, name='half_line')
    assert np.all(np.isfinite(polar.dynamics([2.5, 0.1, 0.2], [0.3, -0.4])[1]))


@pytest.mark.parametrize('potential, q, expected', [
    (lambda q: 5 * ca.exp(-((q[0] - 6) ** 2 + q[1] ** 2) / 0.5), [5.5, 0.1, 0.4], 'bump'),
    (lambda q: 3 * ca.tanh((q[0] - 6) / 0.3), [6.5, 0.0, 0.2], 'step'),
    (lambda q: 1e6 * q[0] ** 2 + 1e-6 * ca.sin(q[1]), [0.0, 0.3, 1.0], 'scales'),
    (lambda q: 0.5 * (q[2] - ca.atan2(ca.sin(q[2]), ca.cos(q[2]))) ** 2, [0.0, 0.0, 9.5],
     'winding')])
def test_features_the_samples_miss_are_kept(potential, q, expected):
    """Keep what a second probe found folded away.

    A bump at x = 6 (samples mostly |x| < 2.5), a saturating step, a 1e-6 term beside a 1e6
    one, a winding penalty past the sampled angles.
    """
    import nh_tracking as nht
    import nh_tracking.core.lean as module

    def build(name: str):
        return nht.NonholonomicSystem.from_constraints(
            ['x', 'y', 'th'], lambda q: ca.SX.eye(3),
            lambda q: ca.horzcat(ca.sin(q[2]), -ca.cos(q[2]), 0), potential, angles=['th'],
            name=name)

    lean_system = build(f'lean_{expected}')
    original = module.lean
    try:
        module.lean = lambda f, draw: f
        plain = build(f'plain_{expected}')
    finally:
        module.lean = original
    for v in ([0.0, 0.0], [0.4, -0.7]):
        np.testing.assert_allclose(lean_system.dynamics(q, v)[1], plain.dynamics(q, v)[1],
                                   rtol=1e-9, atol=1e-15)
        assert lean_system.energy(q, v) == pytest.approx(plain.energy(q, v), rel=1e-9, abs=1e-15)
