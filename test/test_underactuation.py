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

"""Underactuated systems: r < k controls along actuator directions, projected onto D."""
import casadi as ca
import numpy as np
import pytest

import nh_tracking as nht
from systems import basis_acceleration, lagrange_dalembert_acceleration

T, N = 4.0, 40
OMEGA = 2 * np.pi / 2.0  # the rotor and steering torques' frequency


def _torques(t: np.ndarray) -> np.ndarray:
    """Return an open-loop gait: rotor and steering torques, held on each interval."""
    return np.c_[0.3 * np.sin(OMEGA * t), 0.06 * np.cos(OMEGA * t)]


def _lda_gap(system: nht.NonholonomicSystem, states) -> float:
    worst = 0.0
    for q, v, u in states:
        _, vdot = system.dynamics(q, v, u)
        independent = lagrange_dalembert_acceleration(system, q, system.rho(q) @ v,
                                                      system.generalized_force(q, u))
        worst = max(worst, np.abs(basis_acceleration(system, q, v, vdot) - independent).max())
    return worst


@pytest.mark.unit
def test_snakeboard_dynamics_match_lagrange_dalembert_with_its_torques():
    """Torques on psi and phi only; the independent derivation takes them as forces F u."""
    board = nht.models.snakeboard()
    assert (board.n, board.m, board.k, board.r) == (5, 2, 3, 2)
    assert board.control_names == ('rotor_torque', 'steering_torque')
    rng = np.random.default_rng(3)
    states = [(np.r_[rng.normal(size=4), rng.uniform(-1.4, 1.4)], rng.normal(size=3),
               rng.normal(size=2)) for _ in range(20)]
    assert _lda_gap(board, states) < 1e-11
    assert np.allclose(board.generalized_force(states[0][0], [1.0, 2.0]), [0, 0, 0, 1, 2])


@pytest.mark.unit
def test_actuators_on_a_system_beyond_the_built_in_models():
    """A q-dependent metric and constraints (n = 4, k = 2), driven by one q-dependent force."""
    from systems import coupled_system

    full = coupled_system()
    driven = nht.NonholonomicSystem.from_constraints(
        ['a', 'b', 'c', 'd'], lambda q: full.metric_fn(q), lambda q: full.constraints_fn(q),
        lambda q: full.potential_fn(q),
        actuators=lambda q: ca.vertcat(1.0, 0.3 * q[0], 0.0, ca.sin(q[1]) + 2.0),
        name='coupled_one_force')
    assert (driven.k, driven.r, driven.input_matrix(np.zeros(4)).shape) == (2, 1, (2, 1))
    rng = np.random.default_rng(5)
    states = [(rng.normal(size=4), rng.normal(size=2), rng.normal(size=1)) for _ in range(10)]
    assert _lda_gap(driven, states) < 1e-11


@pytest.mark.unit
def test_an_actuator_that_only_pushes_against_the_constraints_is_refused():
    sleigh = nht.models.chaplygin_sleigh()
    with pytest.raises(ValueError, match='actuators projected onto D'):
        nht.NonholonomicSystem.from_constraints(
            ['x', 'y', 'theta'], lambda q: sleigh.metric_fn(q),
            lambda q: ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0),
            actuators=lambda q: ca.vertcat(-ca.sin(q[2]), ca.cos(q[2]), 0), angles=['theta'])


@pytest.fixture(scope='module')
def snakeboard_case():
    """Drive the fully actuated snakeboard with only the rotor/steering torques: a reference.

    The underactuated one is asked to track it from a start 0.1 m and 0.1 rad off.
    """
    board, full = nht.models.snakeboard(), nht.models.snakeboard(actuated=True)
    t = np.linspace(0.0, T, N + 1)
    q0, v0 = np.zeros(5), np.array([0.5, 0.0, 0.0])
    torques = _torques(t[:-1])

    def held(s, q, v):
        return board.input_matrix(q) @ torques[min(int(s / (T / N) + 1e-9), N - 1)]
    reference = nht.simulate(full, q0, v0, t, held, rtol=1e-11, atol=1e-12)
    start = q0 + np.array([0.0, 0.1, 0.1, 0.0, 0.0])
    problem = nht.TrackingProblem(board, reference, start, v0, T, N, terminal='cost',
                                  omega=10.0)
    plans = {m: nht.solve(problem, m, second_look=False)
             for m in ('variational', 'multiple_shooting', 'pmp')}
    return board, reference, torques, problem, plans


@pytest.mark.solve
@pytest.mark.slow
def test_the_reference_is_what_the_torques_alone_produce(snakeboard_case):
    board, reference, torques, _, _ = snakeboard_case
    alone = nht.simulate(board, reference.q[0], reference.v[0], reference.t, torques)
    assert np.abs(alone.q - reference.q).max() < 1e-6


@pytest.mark.solve
@pytest.mark.slow
def test_snakeboard_tracks_with_rotor_and_steering_torques(snakeboard_case):
    """All three methods agree within 3 %; replayed, the plan tracks far better.

    Better than the reference's own torques from the offset start.
    """
    board, reference, torques, problem, plans = snakeboard_case
    assert all(p.success for p in plans.values()), {m: p.message for m, p in plans.items()}
    var = plans['variational'].cost
    assert abs(plans['multiple_shooting'].cost - var) / var < 0.03
    assert abs(plans['pmp'].cost - var) / var < 0.03
    assert plans['variational'].u.shape == (N, 2)

    def position_error(u: np.ndarray) -> np.ndarray:
        driven = nht.simulate(board, problem.q0, problem.v0, reference.t, u)
        return np.linalg.norm(driven.q[:, :2] - reference.q[:, :2], axis=1)

    open_loop, tracked = position_error(torques), position_error(plans['variational'].u)
    assert tracked[-1] < 0.5 * open_loop[-1] and tracked.mean() < 0.8 * open_loop.mean()


@pytest.mark.solve
@pytest.mark.slow
def test_snakeboard_pmp_control_replays_its_plan(snakeboard_case):
    from test_robustness import replay_gaps

    _, _, _, problem, plans = snakeboard_case
    gaps = replay_gaps(problem, plans['pmp'])
    assert gaps['law'] < 1e-6 and gaps['held'] < 0.05
    assert gaps['held'] < 0.5 * gaps['midpoint samples']  # those leave |phi| < pi/2


@pytest.mark.unit
def test_snakeboard_refuses_states_outside_its_domain():
    board = nht.models.snakeboard()
    reference = nht.Trajectory(t=[0.0, 1.0], q=np.zeros((2, 5)), v=np.zeros((2, 3)),
                               u=np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r'phi = 1\.8 not in \(-1\.5708, 1\.5708\)'):
        nht.TrackingProblem(board, reference, [0, 0, 0, 0, 1.8], np.zeros(3), 1.0, 10)
    with pytest.raises(RuntimeError, match="left the model's domain.*phi = 1.57"):
        nht.simulate(board, np.zeros(5), np.zeros(3), [0.0, 2.0], np.array([[0.0, 1.0]]))
