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

"""Physical parameters estimated from a log of motion, against the truth that made the log.

The logs are simulated with the model built from the true parameters (DOP853 at tight
tolerances, controls held on each interval); the estimator fits its own midpoint discretisation
of the dynamics derived with the parameters symbolic.
"""
from collections.abc import Callable

import casadi as ca
import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.core.lagrangian_data import LagrangianData
from nh_tracking.estimation.adaptation import OnlineEstimator
from nh_tracking.models import ModelSpec, PhysicalParameter

RATE = 50.0  # Hz, as odometry comes
SECONDS = 10.0
NOISE = (0.002, 0.002)  # m, rad


def _pushed_lagrangian(m, J) -> LagrangianData:
    """Return a differential-drive robot driven by a force along its heading and a torque."""
    heading = lambda q: ca.vertcat(ca.cos(q[2]), ca.sin(q[2]), 0)  # noqa: E731
    return LagrangianData(
        ['x', 'y', 'theta'], lambda q: ca.diag(ca.vertcat(m, m, J)),
        lambda q: ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0),
        basis=lambda q: ca.horzcat(heading(q), ca.vertcat(0, 0, 1)),
        actuators=lambda q: ca.horzcat(heading(q), ca.vertcat(0, 0, 1)), angles=['theta'])


def _pushed_unicycle(m: float = 1.0, J: float = 1.0) -> nht.NonholonomicSystem:
    return nht.NonholonomicSystem.from_data(_pushed_lagrangian(m, J), name='pushed_unicycle',
                                            parameters={'m': m, 'J': J})


PUSHED = ModelSpec('pushed_unicycle', _pushed_unicycle,
                   (PhysicalParameter('m', 1.0, 'kg', 'mass'),
                    PhysicalParameter('J', 1.0, 'kg m^2', 'inertia')),
                   start=((0.0, 0.0, 0.0), (0.5, 0.0)), lagrangian=_pushed_lagrangian)


def _waves(t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.array([0.5 * np.sin(1.3 * t) + 0.3 * np.sin(0.4 * t),
                     0.5 * np.sin(1.3 * t + 1) + 0.3 * np.sin(0.8 * t)])


def _snakeboard_gait(t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotor torque in waves; the steering held near a wave by a PD torque (|phi| < 0.61)."""
    steering = 0.6 * np.sin(1.1 * t)
    return np.array([0.04 * np.sin(2.3 * t) + 0.02 * np.sin(0.7 * t),
                     0.02 * (-20 * (q[4] - steering) - 6 * v[2])])


def _log(spec: ModelSpec, truth: dict, law: Callable, seconds: float = SECONDS,
         start: tuple | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, q, u) of the true robot, ``law``'s control computed at each sample and held."""
    robot = spec.create(**truth)
    t = np.arange(0.0, seconds + 0.5 / RATE, 1 / RATE)
    q, v = (np.array(x, dtype=float) for x in (start or spec.start))
    qs, us = [q], []
    for k in range(len(t) - 1):
        u = law(t[k], q, v)
        step = nht.simulate(robot, q, v, t[k:k + 2], u[None, :])
        q, v = step.q[-1], step.v[-1]
        qs.append(q)
        us.append(u)
    return t, np.array(qs), np.array(us)


def _noisy(spec: ModelSpec, q: np.ndarray, seed: int) -> np.ndarray:
    angles = np.array([c in ('theta', 'psi', 'phi') for c in spec.parametrised(
        [spec.parameters[0].name]).coordinates])
    scale = np.where(angles, NOISE[1], NOISE[0])
    return q + np.random.default_rng(seed).normal(size=q.shape) * scale


CASES = [  # the spec, the truth (the start is the spec's defaults), the controls
    (nht.models.spec('chaplygin_sleigh'), {'m': 0.8, 'J': 5.2}, _waves),
    (nht.models.spec('snakeboard'), {'m': 1.2, 'J': 0.13, 'J_r': 0.04}, _snakeboard_gait),
    (PUSHED, {'m': 1.7, 'J': 0.6}, _waves),
]


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('spec, truth, law', CASES, ids=lambda c: getattr(c, 'name', ''))
def test_parameters_are_recovered_to_1_percent_without_noise_and_5_percent_with(
        spec, truth, law):
    t, q, u = _log(spec, truth, law)
    exact = nht.estimate_parameters(spec, t, q, u, list(truth))
    noisy = nht.estimate_parameters(spec, t, _noisy(spec, q, seed=1), u, list(truth))
    for estimate, bar in ((exact, 0.01), (noisy, 0.05)):
        assert estimate.excited, estimate.message
        errors = {n: abs(estimate.values[n] / truth[n] - 1) for n in truth}
        assert max(errors.values()) < bar, errors
        assert all(0 < estimate.std[n] < bar * truth[n] for n in truth), estimate.std
    for name in truth:  # the stated uncertainty covers the error
        assert abs(noisy.values[name] - truth[name]) < 5 * noisy.std[name] + 0.003 * truth[name]
    assert noisy.noise['theta'] == pytest.approx(NOISE[1], rel=0.3)


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('name', ['unicycle', 'rolling_disk'])
def test_parameters_that_do_not_enter_the_motion_are_not_excited(name):
    """Both take accelerations as controls: no log of (q, u) holds their masses."""
    spec = nht.models.spec(name)
    truth = {p.name: p.default * 1.3 for p in spec.parameters}
    t, q, u = _log(spec, truth, lambda t, q, v: np.array([0.3 * np.sin(t), 0.5 * np.cos(t)]))
    estimate = nht.estimate_parameters(name, t, q, u, list(truth))
    assert not estimate.excited
    assert estimate.values == spec.defaults | {}  # the starting values, kept
    assert 'not excited' in estimate.message


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('velocity', [(0.0, 0.0), (0.0, 1.0)], ids=['at rest', 'straight'])
def test_a_log_without_excitation_leaves_the_estimates_where_they_were(velocity):
    """The sleigh at rest, or sliding straight at constant speed: u = 0 tells nothing of m, J."""
    spec = nht.models.spec('chaplygin_sleigh')
    start = ((0.0, 0.0, 0.3), velocity)
    t, q, u = _log(spec, {'m': 0.8, 'J': 5.2}, lambda t, q, v: np.zeros(2), start=start)
    for seed in range(3):
        estimate = nht.estimate_parameters(spec, t, _noisy(spec, q, seed), u, ['m', 'J'],
                                           start={'m': 1.1, 'J': 3.0})
        assert not estimate.excited, estimate.message
        assert estimate.values == {'m': 1.1, 'J': 3.0}


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('spec, truth, law', CASES[:2], ids=lambda c: getattr(c, 'name', ''))
def test_odometry_outliers_do_not_throw_the_estimates_out(spec, truth, law):
    t, q, u = _log(spec, truth, law)
    q = _noisy(spec, q, seed=2)
    rng = np.random.default_rng(3)
    off = np.arange(7, len(t), 50)  # 1 message in 50, 1 m off in a random direction
    direction = rng.normal(size=(len(off), 2))
    q[off, :2] += direction / np.linalg.norm(direction, axis=1, keepdims=True)
    estimate = nht.estimate_parameters(spec, t, q, u, list(truth))
    assert estimate.excited, estimate.message
    assert estimate.outliers >= len(off)
    bounds = {p.name: p.bounds for p in spec.parameters}
    for name, value in estimate.values.items():
        assert abs(value / truth[name] - 1) < 0.05
        assert bounds[name][0] <= value <= bounds[name][1]


@pytest.mark.solve
def test_the_symbolic_dynamics_are_the_built_models_at_any_parameters():
    rng = np.random.default_rng(5)
    for spec in list(nht.models.MODELS.values()) + [PUSHED]:
        names = [p.name for p in spec.parameters]
        if not names:
            continue
        plant = spec.parametrised(names)
        values = {n: d * rng.uniform(0.5, 2.0) for n, d in spec.defaults.items()}
        built = spec.create(**values)
        for _ in range(5):
            q, v, u = rng.uniform(-1, 1, built.n), rng.normal(size=built.k), rng.normal(
                size=built.r)
            rate = plant.family.ode(np.r_[q, v], u, [values[n] for n in names])
            assert np.allclose(np.array(rate).ravel(), np.concatenate(built.dynamics(q, v, u)),
                               rtol=1e-12, atol=1e-12), spec.name


@pytest.mark.unit
def test_bad_logs_and_requests_get_one_clear_error():
    spec = nht.models.spec('chaplygin_sleigh')
    t = np.linspace(0, 1, 11)
    q, u = np.zeros((11, 3)), np.zeros((10, 2))
    cases = [
        ((spec, t, q, u, ['mass']), 'must be distinct names'),
        ((spec, t, q, u, ['m', 'm']), 'must be distinct names'),
        ((spec, t, q, u, []), 'must be distinct names'),
        ((spec, t[::-1], q, u, ['m']), 'strictly increasing'),
        ((spec, t, q[:, :2], u, ['m']), 'q must be a finite (11, 3)'),
        ((spec, t, np.where(q == 0, np.nan, q), u, ['m']), 'q must be a finite'),
        ((spec, t, q, u[:5], ['m']), 'u must be a finite (10, 2)'),
        (('no_such_model', t, q, u, ['m']), 'unknown model'),
        ((ModelSpec.from_factory('plain', _pushed_unicycle), t, q, u, ['m']),
         'no Lagrangian data'),
    ]
    for arguments, words in cases:
        with pytest.raises(ValueError, match=words.replace('(', r'\(').replace(')', r'\)')):
            nht.estimate_parameters(*arguments)
    with pytest.raises(ValueError, match='both estimated and fixed'):
        nht.estimate_parameters(spec, t, q, u, ['m'], fixed={'m': 2.0})
    with pytest.raises(ValueError, match='must be a number in'):
        nht.estimate_parameters(spec, t, q, u, ['m'], start={'J': -1.0})


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('moving', [True, False], ids=['excited', 'at rest'])
def test_online_estimates_reach_the_truth_in_20_s_and_stay_put_without_excitation(moving):
    """The mismatch of ``demo --adapt``: the robot's J 30 % above the model's, its m 20 % below."""
    spec = nht.models.spec('chaplygin_sleigh')
    truth = {'m': 0.8, 'J': 5.2}
    law = _waves if moving else (lambda t, q, v: np.zeros(2))
    start = None if moving else ((0.0, 0.0, 0.3), (0.0, 0.0))
    t, q, u = _log(spec, truth, law, seconds=20.0, start=start)
    q = _noisy(spec, q, seed=4)
    estimator = OnlineEstimator(spec, ['m', 'J'], spec.defaults)
    fits = []
    for k, tk in enumerate(t):
        estimator.add(tk, q[k], u[max(k - 1, 0)])  # the control since the last sample
        if estimator.due(tk):
            fits.append((tk, estimator.update()))
    assert len(fits) >= 5  # from 9 s on, every 2 s
    if moving:
        assert all(f.excited for _, f in fits)
        assert all(abs(estimator.values[n] / truth[n] - 1) < 0.05 for n in truth), \
            estimator.values
    else:
        assert not any(f.excited for _, f in fits)
        assert estimator.values == {n: spec.defaults[n] for n in truth}
