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

"""New values of a model's physical parameters as new numbers in the same NLPs.

A member of a family (``create_parametrised(...).with_values(...)``) must be the model built
with those values, by the derivation with numbers and by the Lagrange–d'Alembert equations with
multipliers; and its plans must be those of that model, from the NLPs already built.
"""
import dataclasses

import numpy as np
import pytest
from test_estimation import PUSHED

import nh_tracking as nht
from nh_tracking import models
from nh_tracking.core import poses
from nh_tracking.core.poses import PoseMap
from nh_tracking.session.robot_state import RobotState
from nh_tracking.solvers import midpoint
from systems import basis_acceleration, lagrange_dalembert_acceleration


def _values(spec: models.ModelSpec, rng: np.random.Generator) -> dict[str, float]:
    """Random values within each parameter's range, within a factor of 1.5 of its default."""
    values = {}
    for p in spec.parameters:
        drawn = p.default * rng.uniform(0.67, 1.5) if p.default else rng.uniform(-0.3, 0.3)
        values[p.name] = float(np.clip(drawn, *p.bounds))
    return values


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('spec', [*models.MODELS.values(), PUSHED], ids=lambda s: s.name)
def test_a_family_member_is_the_model_built_with_its_values(spec):
    rng = np.random.default_rng(7)
    family = spec.create_parametrised()
    assert family.family.names == tuple(p.name for p in spec.parameters)
    for _ in range(3):
        values = _values(spec, rng)
        member, built = family.with_values(**values), spec.create(**values)
        assert member.family is family.family and member.parameters == built.parameters
        start_q, _ = spec.start
        for _ in range(4):
            q = np.array(start_q) + 0.2 * rng.normal(size=built.n)
            v, u = rng.normal(size=built.k), rng.normal(size=built.r)
            qdot, vdot = built.dynamics(q, v, u)
            assert np.allclose(np.concatenate(member.dynamics(q, v, u)),
                               np.concatenate([qdot, vdot]), rtol=1e-10, atol=1e-12)
            in_nlp = member.family.dynamics(q, v, u, member.family_values)  # what the NLPs use
            assert np.allclose(np.array(in_nlp[1]).ravel(), vdot, rtol=1e-10, atol=1e-12)
            assert np.allclose(member.rho(q), built.rho(q), rtol=1e-12, atol=1e-14)
            assert np.allclose(member.input_matrix(q), built.input_matrix(q), atol=1e-12)
            assert member.energy(q, v) == pytest.approx(built.energy(q, v), rel=1e-12)
            independent = lagrange_dalembert_acceleration(
                member, q, member.rho(q) @ v, member.generalized_force(q, u))
            assert np.allclose(basis_acceleration(member, q, v, vdot), independent,
                               rtol=1e-8, atol=1e-10)


@pytest.mark.solve
def test_bad_values_and_parameters_a_family_does_not_leave_symbolic_are_named():
    sleigh = models.create_parametrised('chaplygin_sleigh')
    for bad in (float('nan'), float('inf'), 'heavy', '5', True, None, [5.0]):
        with pytest.raises(ValueError, match='parameter J must be a finite number'):
            sleigh.with_values(J=bad)
    with pytest.raises(ValueError, match='make the model singular'):
        sleigh.with_values(m=0.0)
    assert sleigh.with_values(J=np.float32(5)).parameters['J'] == 5.0
    assert sleigh.with_values() is sleigh and sleigh.with_values(J=4) is sleigh  # no change
    fixed = models.create_parametrised('nonholonomic_particle')
    assert fixed.family.names == ()
    with pytest.raises(ValueError, match=r"\['m'\] are not symbolic"):
        fixed.with_values(m=2.0)
    plain = nht.models.ModelSpec.from_factory('plain_sleigh', nht.models.chaplygin_sleigh)
    assert plain.create_parametrised().family.names == ()  # no symbolic data: fixed values
    # data that is not the factory's model is not used: the planner would plan another robot
    odd = dataclasses.replace(PUSHED, lagrangian=lambda m, J: PUSHED.lagrangian(2 * m, J))
    assert odd.create_parametrised().family.names == ()
    with pytest.raises(ValueError, match='is not this model'):
        odd.create().parametrised(odd.lagrangian, ['m'])


@pytest.mark.solve
@pytest.mark.parametrize('name, values', [('chaplygin_sleigh', {'m': 0.8, 'J': 5.2}),
                                          ('snakeboard', {'J': 0.02, 'J_r': 0.011})])
def test_new_values_plan_as_the_model_built_with_them_from_the_same_nlps(name, values):
    spec = models.spec(name)
    family = spec.create_parametrised()
    start_q, start_v = spec.start

    def plan(system: nht.NonholonomicSystem) -> nht.Solution:
        reference = nht.simulate(system, start_q, start_v, np.linspace(0.0, 2.0, 41))
        problem = nht.TrackingProblem(system, reference=reference,
                                      q0=np.array(start_q) + 0.05, v0=start_v, horizon=2.0,
                                      steps=20)
        result = nht.solve(problem, method='variational')
        assert result.success, result.message
        return result

    plan(family)
    nlps = {id(nlp) for nlp in midpoint._CACHE.held(family.family)}
    moved = family.with_values(**values)
    assert moved.family is family.family
    member = plan(moved)
    assert {id(nlp) for nlp in midpoint._CACHE.held(family.family)} == nlps != set()
    built = plan(spec.create(**values))
    assert np.allclose(member.q, built.q, atol=1e-7)
    assert np.allclose(member.u, built.u, atol=1e-6 * (1 + np.abs(built.u).max()))


@pytest.mark.unit
def test_with_parameters_checks_ranges_and_rebuilds_only_what_is_not_symbolic():
    sleigh = models.create_parametrised('chaplygin_sleigh')
    with pytest.raises(ValueError, match='model parameter m'):
        models.with_parameters(sleigh, 'chaplygin_sleigh', {'m': -1.0})
    assert models.with_parameters(sleigh, 'chaplygin_sleigh', dict(sleigh.parameters)) is sleigh
    assert models.with_parameters(sleigh, 'chaplygin_sleigh', {'J': 5.0}).family is sleigh.family
    rebuilt = models.with_parameters(models.create('chaplygin_sleigh'), 'chaplygin_sleigh',
                                     {'J': 5.0})
    assert rebuilt.family.names == ('m', 'J', 'a') and rebuilt.parameters['J'] == 5.0


@pytest.mark.unit
@pytest.mark.parametrize('name, values', [('chaplygin_sleigh', {'m': 0.8, 'J': 5.2}),
                                          ('rolling_disk', {'R': 0.7, 'I_spin': 0.3})])
def test_velocities_are_carried_to_new_values_keeping_qdot_or_its_projection(name, values):
    """The sleigh's D does not move with m and J: qdot is kept. The disk's moves with R."""
    rng = np.random.default_rng(3)
    old = models.create_parametrised(name)
    new = old.with_values(**values)
    qs = np.array(models.spec(name).start[0]) + 0.3 * rng.normal(size=(5, old.n))
    vs = rng.normal(size=(5, old.k))
    carried = poses.carried(old, new, qs, vs)
    for q, v, w in zip(qs, vs, carried):
        qdot, kept = old.rho(q) @ v, new.rho(q) @ w
        rho, g = new.rho(q), new.metric(q)
        assert rho.T @ g @ (qdot - kept) == pytest.approx(np.zeros(new.k), abs=1e-12)
        if name == 'chaplygin_sleigh':
            assert kept == pytest.approx(qdot, abs=1e-12)
            assert np.abs(w - v).max() > 0.05 * np.abs(v).max()  # while its v changes


@pytest.mark.unit
def test_the_latest_odometry_is_carried_to_a_model_with_new_values():
    """The plan right after a change starts from the robot's motion, not its old coordinates."""
    old = models.create_parametrised('chaplygin_sleigh')
    new = old.with_values(m=0.8, J=5.2)
    now = [1_000_000_000]
    robot = RobotState(PoseMap(old), lambda: now[0])
    before = robot.set_odometry(now[0], np.array([1.0, 2.0, 0.0, 0.7]),
                                np.array([0.9, 0.0, 0.0, 0.3]), 0.0)
    robot.set_pose_map(PoseMap(new))
    after = robot.latest
    assert after.q == pytest.approx(before.q)
    assert new.rho(after.q) @ after.v == pytest.approx(old.rho(before.q) @ before.v, abs=1e-12)
    assert np.abs(after.v - before.v).max() > 0.05 * np.abs(before.v).max()
