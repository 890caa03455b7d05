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

"""The derived nonholonomic dynamics against an independent derivation, for every system."""
import casadi as ca
import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.core import geometry
from systems import (ALL_SYSTEMS, basis_acceleration, inclined_knife_edge,
                     lagrange_dalembert_acceleration, random_state)

pytestmark = pytest.mark.unit


@pytest.fixture(scope='module', params=sorted(ALL_SYSTEMS))
def system(request):
    return ALL_SYSTEMS[request.param]()


def test_dynamics_match_lagrange_dalembert_with_multipliers(system):
    """Check d/dt(rho v) of the adapted-basis equations against Lagrange–d'Alembert.

    The full-coordinate acceleration of the Lagrange–d'Alembert equations with multipliers,
    forced by G rho u.
    """
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(25):
        q, v, u = random_state(system, rng)
        _, vdot = system.dynamics(q, v, u)
        ours = basis_acceleration(system, q, v, vdot)
        ref = lagrange_dalembert_acceleration(system, q, system.rho(q) @ v,
                                              system.generalized_force(q, u))
        worst = max(worst, np.linalg.norm(ours - ref) / max(1.0, np.linalg.norm(ref)))
    assert worst < 1e-6


def test_basis_lies_in_the_distribution(system):
    rng = np.random.default_rng(2)
    for _ in range(25):
        q, _, _ = random_state(system, rng)
        mu, rho = system.constraints(q), system.rho(q)
        assert np.abs(mu @ rho).max() < 1e-12
        assert np.linalg.matrix_rank(rho) == system.k == system.n - system.m


@pytest.mark.parametrize('name', ['chaplygin_sleigh', 'nonholonomic_particle', 'unicycle',
                                  'rolling_disk'])
def test_default_basis_is_orthonormal_and_gives_the_same_motion(name):
    """Check that a model rebuilt without its basis gets a G-orthonormal one, same motion.

    rho^T G rho = I, and qddot agrees for the same qdot and force.
    """
    given = ALL_SYSTEMS[name]()
    rebuilt = nht.NonholonomicSystem.from_constraints(
        given.coordinates, given.metric_fn, given.constraints_fn, given.potential_fn,
        angles=given.angles)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q, v, u = random_state(given, rng)
        assert np.allclose(rebuilt.metric_D(q), np.eye(rebuilt.k), atol=1e-12)
        qdot = given.rho(q) @ v
        v2 = rebuilt.velocity_coordinates(q, qdot)
        assert np.allclose(rebuilt.rho(q) @ v2, qdot, atol=1e-12)
        force = given.generalized_force(q, u)
        u2 = np.linalg.solve(rebuilt.metric_D(q), rebuilt.rho(q).T @ force)
        a1 = basis_acceleration(given, q, v, given.dynamics(q, v, u)[1])
        a2 = basis_acceleration(rebuilt, q, v2, rebuilt.dynamics(q, v2, u2)[1])
        assert np.allclose(a1, a2, atol=1e-10)


def test_knife_edge_default_basis_is_orthonormal_and_well_conditioned():
    system = inclined_knife_edge()
    assert system.basis_condition > 0.5  # smooth kernel fields, no chart singularity sampled
    for phi in np.linspace(-np.pi, np.pi, 37):
        q = np.array([0.3, -1.0, phi])
        assert np.allclose(system.rho(q).T @ system.metric(q) @ system.rho(q), np.eye(2),
                           atol=1e-12)


def _christoffel_by_paper_relation(system, q):
    """Return Formula (relation): Gamma^C_AB = 1/2 (C^B_CA + C^A_CB + C^C_AB)."""
    qs = ca.SX.sym('q', system.n)
    c = geometry.structure_functions(system.metric_fn(qs), system.rho_fn(qs), qs)
    pairs = [c[a][b] for a in range(system.k) for b in range(system.k)]
    cn = np.array(ca.Function('c', [qs], [ca.horzcat(*pairs)])(q))
    struct = cn.reshape(system.k, system.k, system.k)  # struct[E, A, B] = C^E_AB
    k = system.k
    gamma = np.zeros((k, k, k))
    for cc in range(k):
        for a in range(k):
            for b in range(k):
                gamma[cc, a, b] = 0.5 * (struct[b, cc, a] + struct[a, cc, b] + struct[cc, a, b])
    return gamma


def test_koszul_agrees_with_paper_relation_in_orthonormal_basis_only():
    """Check (relation) for the sleigh's orthonormal X1, X2, not the particle's Y1, Y2.

    docs/theory.md C2.
    """
    sleigh = nht.models.chaplygin_sleigh()
    for th in (0.0, 0.7, 2.5):
        q = np.array([0.1, 0.2, th])
        assert np.allclose(sleigh.christoffel(q), _christoffel_by_paper_relation(sleigh, q),
                           atol=1e-14)
    particle = nht.models.nonholonomic_particle()
    q = np.array([0.0, 0.8, 0.0])
    assert not np.allclose(particle.christoffel(q), _christoffel_by_paper_relation(particle, q))


def test_sleigh_bracket_is_eta_x1():
    """[[X1, X2]] = eta X1 with eta = a sqrt(m) / (J + m a^2) (correct as printed)."""
    m, J, a = 2.0, 3.0, 0.5
    sleigh = nht.models.chaplygin_sleigh(m=m, J=J, a=a)
    qs = ca.SX.sym('q', 3)
    c = geometry.structure_functions(sleigh.metric_fn(qs), sleigh.rho_fn(qs), qs)
    val = np.array(ca.Function('c', [qs], [c[0][1]])([0.4, -0.3, 1.9])).ravel()
    assert np.allclose(val, [a * np.sqrt(m) / (J + m * a**2), 0.0], atol=1e-14)


@pytest.mark.parametrize('bad, message', [
    ({'metric': lambda q: ca.diag(ca.vertcat(1, -1, 1))}, 'positive definite'),
    ({'metric': lambda q: ca.SX.eye(2)}, 'shape'),
    ({'basis': lambda q: ca.horzcat(ca.vertcat(1, 0, 0), ca.vertcat(0, 0, 1))},
     'not in the constraint distribution'),
    ({'basis': lambda q: ca.horzcat(ca.vertcat(0, 0, 1), ca.vertcat(0, 0, 2))}, 'rank'),
    ({'constraints': lambda q: ca.SX.eye(3)}, 'm < 3'),
    ({'angles': ['psi']}, 'not coordinates'),
])
def test_bad_system_data_is_rejected_with_a_clear_error(bad, message):
    data = {
        'metric': lambda q: ca.SX.eye(3),
        'constraints': lambda q: ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0),
    }
    data.update(bad)
    with pytest.raises(ValueError, match=message):
        nht.NonholonomicSystem.from_constraints(['x', 'y', 'theta'], **data)


def test_holonomic_system_has_no_constraints_and_free_motion():
    system = nht.NonholonomicSystem.from_constraints(['x', 'y'], lambda q: 2 * ca.SX.eye(2))
    assert (system.m, system.k) == (0, 2)
    qdot, vdot = system.dynamics([1.0, 2.0], [0.3, -0.4], [0.5, 0.0])
    assert np.allclose(vdot, [0.5, 0.0]) and np.allclose(np.linalg.norm(qdot), 0.5 / np.sqrt(2))
