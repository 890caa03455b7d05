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

"""Simulation: conservation laws, constraint preservation, controls held per interval."""
import numpy as np
import pytest

import nh_tracking as nht
from systems import coupled_system, inclined_knife_edge


@pytest.mark.unit
@pytest.mark.parametrize('make, q0, v0', [
    (nht.models.chaplygin_sleigh, [0.0, 0.5, 0.0], [1 / 3, 1.0]),
    (nht.models.rolling_disk, [0.0, 0.0, 0.3, 0.0], [0.7, 2.0]),
    (inclined_knife_edge, [0.0, 0.0, 0.2], [0.5, 1.5]),
    (coupled_system, [0.1, -0.2, 0.3, 0.0], [0.8, -0.5]),
])
def test_free_motion_conserves_energy_and_constraints(make, q0, v0):
    system = make()
    t = np.linspace(0.0, 10.0, 201)
    traj = nht.simulate(system, q0, v0, t)
    energy = np.array([system.energy(q, v) for q, v in zip(traj.q, traj.v)])
    scale = max(abs(energy[0]), 0.5 * np.dot(v0, system.metric_D(q0) @ v0))
    assert np.abs(energy - energy[0]).max() / scale < 1e-6
    residual = max(np.abs(system.constraints(q) @ system.dynamics(q, v)[0]).max()
                   for q, v in zip(traj.q, traj.v))
    assert residual < 1e-9
    assert np.ptp(traj.q, axis=0).max() > 0.5  # it really moved


@pytest.mark.unit
def test_knife_edge_matches_its_closed_form_solution():
    """Bloch §1.6: with phi = w t and no initial speed along the blade.

    The speed is s = g sin(alpha)/w sin(wt), so x = g sin(alpha)/(4 w^2) (1 - cos 2wt) (it never
    slides further downhill than g sin(alpha)/(2 w^2)) and y = g sin(alpha)/(2 w) (t -
    sin(2wt)/(2w)).
    """
    alpha, w, g, J = 0.35, 2.0, 9.81, 0.4
    system = inclined_knife_edge(alpha=alpha, J=J, g=g)
    t = np.linspace(0.0, 2 * np.pi / w, 101)
    q0 = np.zeros(3)
    v0 = system.velocity_coordinates(q0, [0.0, 0.0, w])
    traj = nht.simulate(system, q0, v0, t)
    c = g * np.sin(alpha)
    assert np.allclose(traj.q[:, 0], c / (4 * w**2) * (1 - np.cos(2 * w * t)), atol=1e-8)
    assert np.allclose(traj.q[:, 1], c / (2 * w) * (t - np.sin(2 * w * t) / (2 * w)), atol=1e-8)
    assert np.allclose(traj.q[:, 2], w * t, atol=1e-8)


@pytest.mark.solve
@pytest.mark.slow
def test_controlled_energy_balance_with_zero_order_hold():
    """Work-energy: dE/dt = v^T G_D u.

    With u held per interval, E(T) - E(0) equals the integral of the power — computed here
    independently by a fine trapezoid sum.
    """
    sleigh = nht.models.chaplygin_sleigh()
    rng = np.random.default_rng(6)
    t = np.linspace(0.0, 2.0, 11)
    u = rng.normal(size=(10, 2))
    traj = nht.simulate(sleigh, [0, 0, 0], [0.2, 0.5], t, u)
    work = 0.0
    for i in range(10):
        fine = nht.simulate(sleigh, traj.q[i], traj.v[i], np.linspace(t[i], t[i + 1], 401),
                            np.tile(u[i], (400, 1)))
        power = fine.v @ u[i]  # G_D = I for the sleigh's orthonormal basis
        work += np.trapezoid(power, fine.t)
        assert np.allclose(fine.q[-1], traj.q[i + 1], atol=1e-8)
    gain = sleigh.energy(traj.q[-1], traj.v[-1]) - sleigh.energy(traj.q[0], traj.v[0])
    assert abs(gain - work) < 1e-5 * max(1.0, abs(work))


@pytest.mark.unit
def test_feedback_law_is_applied():
    """A damping law u = -k v brings v to rest as exp(-k t) on the unicycle (no Christoffel)."""
    uni = nht.models.unicycle()
    t = np.linspace(0.0, 3.0, 31)
    traj = nht.simulate(uni, [0, 0, 0], [1.0, 0.5], t, lambda s, q, v: -2.0 * v)
    assert np.allclose(traj.v[-1], np.array([1.0, 0.5]) * np.exp(-6.0), rtol=1e-6)
    assert traj.u.shape == (30, 2) and np.allclose(traj.u[0], [-2.0, -1.0])


@pytest.mark.unit
def test_bad_simulation_input_is_rejected():
    sleigh = nht.models.chaplygin_sleigh()
    with pytest.raises(ValueError, match='increasing'):
        nht.simulate(sleigh, [0, 0, 0], [0, 0], [0.0, 1.0, 1.0])
    with pytest.raises(ValueError, match='finite'):
        nht.simulate(sleigh, [0, np.nan, 0], [0, 0], [0.0, 1.0])
    with pytest.raises(ValueError, match=r'\(2, 2\)'):
        nht.simulate(sleigh, [0, 0, 0], [0, 0], [0.0, 1.0, 2.0], np.zeros((3, 2)))
    with pytest.raises(ValueError, match='control law must return 2 finite'):
        nht.simulate(sleigh, [0, 0, 0], [0, 0], [0.0, 1.0], lambda s, q, v: [np.inf, 0])


@pytest.mark.unit
def test_trajectory_sampling_interpolates_smoothly_and_holds():
    """The C2 cubic spline reproduces a cubic exactly; outside the samples values are held."""
    t = np.linspace(0.0, 2.0, 9)
    traj = nht.Trajectory(t=t, q=(t**3 - t)[:, None], v=(3 * t**2 - 1)[:, None],
                          u=np.zeros((8, 1)))
    times = np.array([0.1, 0.77, 1.5, 1.99])
    q, v = traj.sample(times)
    assert np.allclose(q.ravel(), times**3 - times) and np.allclose(v.ravel(), 3 * times**2 - 1)
    assert np.allclose(traj.at(0.77)[0], 0.77**3 - 0.77)
    q_out, _ = traj.sample([-1.0, 5.0])
    assert np.allclose(q_out.ravel(), [0.0, 6.0])
    with pytest.raises(ValueError, match='non-finite'):
        nht.Trajectory(t=[0.0, 1.0], q=[[0.0], [np.nan]], v=[[0.0], [0.0]], u=[[0.0]])
