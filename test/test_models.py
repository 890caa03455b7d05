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

"""Built-in models reproduce the paper's printed (and errata-checked) equations."""
import casadi as ca
import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.core.lagrangian_data import POSE_AXES
from nh_tracking.core.poses import bases, PoseMap

pytestmark = pytest.mark.unit


@pytest.mark.parametrize('m, J, a', [(1.0, 4.0, 0.2), (2.5, 0.3, 0.9), (0.7, 1.1, -0.4)])
def test_sleigh_matches_eps_chaplygin(m, J, a):
    """Return EPSChaplygin and the admissibility equations (docs/theory.md C12).

    v1' = -eta v1 v2 + u1, v2' = eta v1^2 + u2, x1' = cos th v2/sqrt m,
    x2' = sin th v2/sqrt m, th' = v1/sqrt(I).
    """
    sleigh = nht.models.chaplygin_sleigh(m=m, J=J, a=a)
    inertia = J + m * a**2
    eta = a * np.sqrt(m) / inertia
    rng = np.random.default_rng(4)
    for _ in range(20):
        q, v, u = rng.normal(size=3), rng.normal(size=2), rng.normal(size=2)
        qdot, vdot = sleigh.dynamics(q, v, u)
        th = q[2]
        assert np.allclose(qdot, [np.cos(th) * v[1] / np.sqrt(m), np.sin(th) * v[1] / np.sqrt(m),
                                  v[0] / np.sqrt(inertia)], atol=1e-13)
        assert np.allclose(vdot, [-eta * v[0] * v[1] + u[0], eta * v[0] ** 2 + u[1]], atol=1e-13)
        # no slip across the blade (docs/theory.md C1): x2' cos th = x1' sin th
        assert abs(qdot[1] * np.cos(th) - qdot[0] * np.sin(th)) < 1e-14


def test_particle_matches_eqq3():
    """eqq3 with controls: v1' = u1, v2' = u2 - y/(1+y^2) v1 v2; x' = -y v2 (docs/theory.md C3)."""
    particle = nht.models.nonholonomic_particle()
    rng = np.random.default_rng(5)
    for _ in range(20):
        q, v, u = rng.normal(size=3) * 2, rng.normal(size=2), rng.normal(size=2)
        qdot, vdot = particle.dynamics(q, v, u)
        y = q[1]
        assert np.allclose(qdot, [-y * v[1], v[0], v[1]], atol=1e-13)
        assert np.allclose(vdot, [u[0], u[1] - y / (1 + y**2) * v[0] * v[1]], atol=1e-13)
        assert np.allclose(particle.metric_D(q), np.diag([1, 1 + y**2]), atol=1e-13)


def test_rolling_disk_rolls_without_slipping():
    disk = nht.models.rolling_disk(m=2.0, R=0.3, I_spin=0.2, I_turn=0.1)
    q, v = np.array([0.0, 1.0, 0.8, 2.0]), np.array([0.5, 3.0])
    qdot, vdot = disk.dynamics(q, v)
    assert np.allclose(qdot, [0.3 * np.cos(0.8) * 3.0, 0.3 * np.sin(0.8) * 3.0, 0.5, 3.0])
    assert np.allclose(vdot, 0.0)  # free disk: constant turn and spin rates
    assert np.allclose(disk.metric_D(q), np.diag([0.1, 2.0 * 0.09 + 0.2]))


def test_unicycle_velocities_are_the_body_twist():
    uni = nht.models.unicycle(m=3.0, J=0.5)
    qdot, vdot = uni.dynamics([1.0, 2.0, np.pi / 2], [0.4, -0.2], [1.0, 2.0])
    assert np.allclose(qdot, [0.0, 0.4, -0.2], atol=1e-15)
    assert np.allclose(vdot, [1.0, 2.0])
    assert np.allclose(uni.generalized_force([0, 0, 0], [1.0, 2.0]), [3.0, 0.0, 1.0])


def test_models_by_name_with_parameters():
    sleigh = nht.models.create('chaplygin_sleigh', m=2.0, J=1.0)
    assert sleigh.parameters == {'m': 2.0, 'J': 1.0, 'a': 0.2}
    assert nht.models.model_parameters('rolling_disk') == {
        'm': 1.0, 'R': 0.5, 'I_spin': 0.1, 'I_turn': 0.05}
    with pytest.raises(ValueError, match='unknown model'):
        nht.models.create('hovercraft')
    with pytest.raises(ValueError, match='takes'):
        nht.models.create('unicycle', mass=2.0)
    for bad in (0.0, -1.0, float('nan'), float('inf'), '1'):
        with pytest.raises(ValueError, match='model parameter m must be a number in'):
            nht.models.create('unicycle', m=bad)
        if not isinstance(bad, str):  # the factory alone checks too
            with pytest.raises(ValueError, match='must be a finite number > 0'):
                nht.models.unicycle(m=bad)


def test_every_model_spec_matches_its_factory_and_declares_its_pose():
    for name, spec in nht.models.MODELS.items():
        system = spec.create()
        assert system.name == name and system.parameters == spec.defaults
        assert system.pose is not None and 'x' in system.pose.values()
        assert all(p.unit and p.description for p in spec.parameters)
        q0, v0 = spec.start
        assert len(q0) == system.n and len(v0) == system.k


def test_user_models_load_by_module_path_and_by_factory(tmp_path, monkeypatch):
    """The car-like robot of test/user_robots.py, by ``package.module:attribute``.

    As a ModelSpec, and as a bare factory whose keyword defaults become its parameters.
    """
    (tmp_path / 'user_robots_syntax.py').write_text('X = 1 / 0\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    car = nht.models.spec('user_robots:CAR')
    assert [p.name for p in car.parameters] == ['m', 'J', 'I_steer', 'L']
    system = nht.models.create('user_robots:CAR', L=0.8)
    assert system.parameters['L'] == 0.8 and system.pose['theta'] == 'yaw'
    bare = nht.models.spec('user_robots:car_like')
    assert bare.defaults == car.defaults and bare.create().n == 4
    with pytest.raises(ValueError, match="cannot load model 'user_robots:nothing'"):
        nht.models.spec('user_robots:nothing')
    with pytest.raises(ValueError, match="cannot load model 'no_such_module:X'"):
        nht.models.spec('no_such_module:X')
    with pytest.raises(ValueError, match='its factory raised NameError'):
        nht.models.create('user_robots:broken')
    with pytest.raises(ValueError, match='cannot load model .*ZeroDivisionError'):
        nht.models.spec('user_robots_syntax:X')  # a module that fails on import
    with pytest.raises(ValueError, match='neither a ModelSpec nor a factory'):
        nht.models.spec('user_robots:NOT_A_MODEL')


def test_user_models_load_from_an_entry_point(monkeypatch):
    """A package that registers ``car = user_robots:CAR`` in the group nh_tracking.models."""
    from importlib.metadata import EntryPoint

    import nh_tracking.models as registry

    def entry_points(group):
        assert group == 'nh_tracking.models'
        return [EntryPoint(name='car', value='user_robots:CAR', group=group)]

    monkeypatch.setattr(registry, 'entry_points', entry_points)
    assert registry.create('car', L=0.7).parameters['L'] == 0.7
    with pytest.raises(ValueError, match="from entry points: \\['car'\\]"):
        registry.spec('truck')


def test_a_system_without_pose_axes_says_how_to_give_them():

    plain = nht.NonholonomicSystem.from_constraints(
        ['a', 'b'], lambda q: ca.SX.eye(2), name='plain')
    with pytest.raises(ValueError, match='give pose=.* to NonholonomicSystem.from_constraints'):
        PoseMap(plain)
    knife = nht.NonholonomicSystem.from_constraints(  # its heading is called phi
        ['x', 'y', 'phi'], lambda q: ca.SX.eye(3),
        lambda q: ca.horzcat(ca.sin(q[2]), -ca.cos(q[2]), 0), angles=['phi'])
    with pytest.raises(ValueError, match='heading is not clear'):
        PoseMap(knife)  # never a heading silently hidden
    cart = nht.NonholonomicSystem.from_constraints(  # unambiguous names need no pose=
        ['x', 'y', 'theta'], lambda q: ca.SX.eye(3),
        lambda q: ca.horzcat(ca.sin(q[2]), -ca.cos(q[2]), 0), angles=['theta'])
    assert PoseMap(cart).rows == {'x': 0, 'y': 1, 'yaw': 2}
    with pytest.raises(ValueError, match="pose names \\['c'\\]"):
        nht.NonholonomicSystem.from_constraints(['a', 'b'], lambda q: ca.SX.eye(2),
                                                pose={'c': 'x'})


def test_numpy_interface_rejects_wrong_sizes():
    sleigh = nht.models.chaplygin_sleigh()
    with pytest.raises(ValueError, match='q must have 3 entries'):
        sleigh.dynamics([0, 0], [0, 0])
    with pytest.raises(ValueError, match='u must have 2 entries'):
        sleigh.dynamics([0, 0, 0], [0, 0], [1, 2, 3])


@pytest.mark.parametrize('name', sorted(nht.models.MODELS))
def test_rho_at_many_configurations_is_rho_at_each(name):
    """A reference's bases come in one call; each must be the basis at its configuration."""
    system = nht.models.create(name)
    qs = np.random.default_rng(7).uniform(-2.0, 2.0, (57, system.n))
    many = bases(system, qs)
    assert many.shape == (57, system.n, system.k)
    assert np.abs(many - np.array([system.rho(q) for q in qs])).max() < 1e-14
    posemap = PoseMap(system)  # and the projected velocities: one least squares per pose
    world = np.random.default_rng(8).normal(size=(57, 4))
    axes = [POSE_AXES.index(a) for a in POSE_AXES if a in posemap.rows]
    projected = posemap._project(many, posemap.pose_rows, world[:, axes])
    for q, w, v in zip(qs, world, projected):
        rows = system.rho(q)[posemap.pose_rows]
        rates = w[axes]
        assert np.allclose(v, np.linalg.lstsq(rows, rates, rcond=None)[0], atol=1e-12)


@pytest.mark.parametrize('name', [*sorted(nht.models.MODELS), 'car_like'])
def test_odometry_velocities_in_one_call_are_the_least_squares_ones(name):
    """Each odometry message's v is the least-squares one, however it is computed.

    The normal equations written out where the pose rows of rho keep full rank (every model but
    the snakeboard and a car's steering, which move no pose axis), lstsq's minimum norm elsewhere.
    """
    from user_robots import car_like

    system = car_like() if name == 'car_like' else nht.models.create(name)
    posemap = PoseMap(system)
    assert (posemap._projection is None) == (name in ('snakeboard', 'car_like'))  # steering
    rng = np.random.default_rng(11)
    axes = [POSE_AXES.index(a) for a in POSE_AXES if a in posemap.rows]
    checked = 0
    for q, body in zip(rng.uniform(-1.0, 1.0, (200, system.n)), rng.normal(size=(200, 4))):
        if not (system.domain.lower < q).all() or not (q < system.domain.upper).all():
            continue
        yaw = q[posemap.rows['yaw']] if posemap.has_yaw else 0.0
        c, s = np.cos(yaw), np.sin(yaw)
        world = np.array([c * body[0] - s * body[1], s * body[0] + c * body[1], *body[2:]])
        expected = np.linalg.lstsq(system.rho(q)[posemap.pose_rows], world[axes], rcond=None)[0]
        assert np.allclose(posemap.velocity(q, body), expected, atol=1e-12, rtol=1e-10)
        checked += 1
    assert checked > 50


def test_numeric_functions_are_shared_safely_between_threads():
    """The odometry, solver and executor threads all call rho: each call gets its own answer."""
    import threading

    system = nht.models.rolling_disk()
    configurations = np.random.default_rng(5).uniform(-2.0, 2.0, (4, 300, system.n))
    wrong = []

    def work(qs):
        for q in qs:
            if not np.array_equal(system.rho(q), np.array(system.rho_fn(q))):
                wrong.append(q)

    threads = [threading.Thread(target=work, args=(qs,)) for qs in configurations]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not wrong
    first = system.rho(configurations[0, 0])
    kept = first.copy()
    system.rho(configurations[0, 1])
    assert np.array_equal(first, kept)  # a later call leaves an earlier answer alone
