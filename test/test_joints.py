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

"""Hidden coordinates: joint states read, states observed, the shape a path implies."""
import math

import casadi as ca
import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.core.joints import joint_mapping, JointMap, JointReading, JointsRejected, observe
from nh_tracking.core.poses import PoseMap
from nh_tracking.session.robot_state import RobotState
from user_robots import car_like


def _wheeled_cart(r: float = 0.1, b: float = 0.3) -> nht.NonholonomicSystem:
    """Return a differential drive with its wheel angles in q, from its rolling constraints."""
    def constraints(q):
        th = q[2]
        return ca.vertcat(ca.horzcat(-ca.sin(th), ca.cos(th), 0, 0, 0),
                          ca.horzcat(ca.cos(th), ca.sin(th), b, -r, 0),
                          ca.horzcat(ca.cos(th), ca.sin(th), -b, 0, -r))
    return nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'theta', 'left', 'right'], lambda q: ca.diag(ca.DM([2, 2, 0.3, 0.01, 0.01])),
        constraints, angles=['theta', 'left', 'right'], name='wheeled_cart')


SYSTEMS = {  # the steered ones, a rolling angle, and a wheeled cart beyond the built-in models
    'car': lambda: car_like(L=0.8),
    'snakeboard': lambda: nht.models.create('snakeboard', l=0.3),  # noqa: E741
    'rolling_disk': lambda: nht.models.create('rolling_disk'), 'wheeled_cart': _wheeled_cart}


def _motion(system: nht.NonholonomicSystem, seconds: float = 12.0) -> nht.Trajectory:
    rng = np.random.default_rng(3)
    gains = rng.uniform(0.3, 0.8, system.r)
    q0 = np.zeros(system.n)
    v0 = np.full(system.k, 0.3)
    if system.name in ('car_like', 'snakeboard'):  # steered gently, inside the stops
        def law(s, q, v):
            steer = 0.4 * math.sin(0.6 * s)
            return [0.5 * (0.8 - v[0]) if system.name == 'car_like' else -v[1],
                    8.0 * (steer - q[-1]) - 2.0 * v[-1]]
        v0 = np.array([0.8, 0.0] if system.name == 'car_like' else [0.6, 0.0, 0.0])
    else:
        def law(s, q, v):
            return gains * np.sin(s * (1 + np.arange(system.r)))
    return nht.simulate(system, q0, v0, np.linspace(0.0, seconds, 601), law, rtol=1e-11)


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('name', SYSTEMS)
def test_with_joint_states_the_state_is_the_true_one(name):
    system = SYSTEMS[name]()
    pose_map = PoseMap(system)
    joints = JointMap(pose_map)
    motion = _motion(system)
    names = [system.coordinates[h] for h in pose_map.hidden]
    reading, previous, worst = JointReading.empty(system.n), None, 0.0
    for i, (t, q, v) in enumerate(zip(motion.t, motion.q, motion.v)):
        ns = int(round(t * 1e9))
        rates = system.rho(q)[pose_map.hidden] @ v
        # every other message without velocities: they are differenced
        reading = joints.read(ns, names, q[pose_map.hidden], rates if i % 2 else [], reading,
                              0.5)
        q_seen, v_seen, measured = observe(pose_map, ns, pose_map.pose(q),
                                           pose_map.body_twist(q, v), reading, 0.5, previous)
        previous = (ns, q_seen, v_seen)
        assert measured == pose_map.hidden
        wrapped = np.where(system.angle_mask, np.remainder(q_seen - q + np.pi, 2 * np.pi) - np.pi,
                           q_seen - q)
        worst = max(worst, np.abs(wrapped).max())
        if i % 2:
            assert np.allclose(v_seen, v, atol=1e-9)
    assert worst < 1e-9


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('name', ['car', 'snakeboard'])
def test_without_joint_states_a_steering_angle_is_dead_reckoned_and_wrong(name):
    system = SYSTEMS[name]()
    pose_map = PoseMap(system)
    motion = _motion(system)
    previous = None
    for t, q, v in zip(motion.t, motion.q, motion.v):
        ns = int(round(t * 1e9))
        state = observe(pose_map, ns, pose_map.pose(q), pose_map.body_twist(q, v), None, 0.5,
                        previous)
        previous = (ns, state[0], state[1])
    assert state[2] == [] and np.abs(motion.q[:, -1]).max() > 0.3
    assert np.abs(state[0][-1]) < 1e-9  # its rate moves no pose axis: held where it started


@pytest.mark.unit
def test_joint_states_are_read_by_name_mapped_merged_and_checked():
    board = nht.models.create('snakeboard')
    pose_map = PoseMap(board)
    assert joint_mapping([], pose_map) == {'psi': 3, 'phi': 4}
    joints = JointMap(pose_map, ['phi:steering_joint'])
    assert joint_mapping([' phi : steering joint '], pose_map)['steering joint'] == 4
    joints = JointMap(pose_map, ['phi:steering_joint'])
    empty = JointReading.empty(5)

    def read(ns, names, positions, velocities, previous):
        return joints.read(ns, names, positions, velocities, previous, 0.5)
    assert read(1, ['wheel_left', 'wheel_right'], [0.0, 1.0], [], empty) is None
    steering = read(10, ['wheel', 'steering_joint'], [np.nan, 0.2], [], empty)
    assert steering.positions[4] == 0.2 and np.isnan(steering.rates[4])
    both = read(20, ['psi'], [1.0], [2.0], steering)  # another publisher: merged
    assert both.positions[3:].tolist() == [1.0, 0.2] and both.stamps[3:].tolist() == [20, 10]
    assert both.fresh(20, 5e-9).tolist() == [3] and both.fresh(20, 1.0).tolist() == [3, 4]
    later = read(int(0.1e9) + 10, ['steering_joint', 'psi'], [0.3, 1.1], [np.nan, 0.5], both)
    assert later.rates[3:].tolist() == pytest.approx([0.5, 1.0])  # NaN velocity: differenced
    again = read(int(0.1e9) + 10, ['steering_joint'], [0.3], [], later)
    assert again.rates[4] == pytest.approx(1.0)  # the same stamp: the rate it had
    at_stop = read(int(0.2e9), ['steering_joint'], [np.pi / 2], [0.0], later)
    assert np.pi / 2 - 2e-3 < at_stop.positions[4] < np.pi / 2  # inside the domain
    for names, positions, message in [
            (['steering_joint'], [2.0], 'outside the model.s domain'),
            (['steering_joint'], [np.nan], 'position is nan'),
            (['psi', 'psi'], [0.0, 0.1], 'named twice')]:
        with pytest.raises(JointsRejected, match=message):
            read(30, names, positions, [], both)
    with pytest.raises(JointsRejected, match='out of order'):
        read(5, ['psi'], [0.0], [], both)
    restarted = read(5, ['psi'], [0.0], [], read(int(9e9), ['psi'], [3.0], [1.0], both))
    assert restarted.positions[3] == 0.0 and np.isnan(restarted.rates[3])  # a clock reset
    for entries, message in [(['phi'], 'not coordinate:joint_name'),
                             (['theta:yaw_joint'], "'theta' is not a hidden coordinate"),
                             (['psi:phi'], 'one joint to two coordinates')]:
        with pytest.raises(ValueError, match=message):
            joint_mapping(entries, pose_map)


@pytest.mark.unit
def test_joints_gone_stale_are_dead_reckoned_and_said_once():
    board = nht.models.create('snakeboard')
    now = [0]
    logs = []
    robot = RobotState(PoseMap(board), lambda: now[0], log=lambda *line: logs.append(line))
    pose, twist = np.zeros(4), np.array([0.5, 0.0, 0.0, 0.0])
    robot.set_odometry(0, pose, twist, 0.0)
    assert robot.hidden_status == 'psi, phi dead-reckoned (no joint_states for them)'
    for step in range(1, 6):
        now[0] = step * 100_000_000
        robot.set_joints(now[0], ['psi', 'phi'], [0.1, 0.2], [0.0, 0.0])
        robot.set_odometry(now[0], pose, twist, 0.0)
    assert robot.latest.q[3:].tolist() == [0.1, 0.2] and not robot.joints_lost
    now[0] += 2_000_000_000
    robot.set_odometry(now[0], pose, twist, 0.0)
    assert robot.joints_lost and 'psi, phi dead-reckoned (joint_states stale)' in \
        robot.hidden_status
    assert [level for level, _ in logs] == ['info', 'info', 'warn']
    assert robot.latest.q[4] == pytest.approx(0.2)  # carried on from the last measured value


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('name, length', [('car', 0.8), ('snakeboard', 0.3)])
def test_a_path_implies_the_steering_its_curvature_needs(name, length):
    """Against the geometry: tan(phi) = length * curvature of the path of the steered point."""
    system = SYSTEMS[name]()
    pose_map = PoseMap(system)
    motion = _motion(system)
    poses = np.array([pose_map.pose(q) for q in motion.q])
    reference = pose_map.reference(motion.t, poses, None, np.zeros(system.n))
    x, y = motion.q[:, 0], motion.q[:, 1]
    dx, dy = np.gradient(x, motion.t), np.gradient(y, motion.t)
    ddx, ddy = np.gradient(dx, motion.t), np.gradient(dy, motion.t)
    curvature = (dx * ddy - dy * ddx) / np.hypot(dx, dy) ** 3
    inner = slice(5, -5)
    geometric = np.arctan(length * curvature)
    assert np.abs(reference.q[inner, -1] - geometric[inner]).max() < 2e-3
    assert np.abs(reference.q[inner, -1] - motion.q[inner, -1]).max() < 2e-3
    steering_rate = reference.v[inner, -1]
    assert np.abs(steering_rate - motion.v[inner, -1]).max() < 0.02


@pytest.mark.unit
def test_a_path_at_rest_implies_nothing_and_a_rolling_angle_is_integrated():
    car = SYSTEMS['car']()
    pose_map = PoseMap(car)
    still = pose_map.reference(np.arange(4.0), np.zeros((4, 4)), None, np.array([0, 0, 0, 0.3]))
    assert np.allclose(still.q[:, 3], 0.3)  # the steering where it is
    disk = SYSTEMS['rolling_disk']()
    motion = _motion(disk)
    pose_map = PoseMap(disk)
    assert pose_map.implied.indices == []
    reference = pose_map.reference(motion.t, [pose_map.pose(q) for q in motion.q], None,
                                   motion.q[0])
    assert np.abs(reference.q[:, 3] - motion.q[:, 3]).max() < 1e-3


@pytest.mark.unit
def test_a_continuous_joint_reported_wrapped_is_unwrapped():
    """A rolling angle in (-pi, pi] at 10 rad/s, 50 Hz, no velocity: continuous, rate 10."""
    disk = SYSTEMS['rolling_disk']()
    pose_map = PoseMap(disk)
    joints = JointMap(pose_map)
    reading = JointReading.empty(disk.n)
    angles = 10.0 * np.arange(0.0, 1.0, 0.02)
    for i, angle in enumerate(angles):
        wrapped = math.remainder(angle, 2 * math.pi)
        reading = joints.read(int(i * 2e7), ['phi'], [wrapped], [], reading, 0.5)
        assert reading.positions[3] == pytest.approx(angle)
        assert i == 0 or reading.rates[3] == pytest.approx(10.0)


@pytest.mark.unit
def test_partly_recovered_joints_are_still_reported_lost_and_stale_ones_refused():
    board = nht.models.create('snakeboard')
    now = [1_000_000_000]
    robot = RobotState(PoseMap(board), lambda: now[0])
    pose, twist = np.zeros(4), np.zeros(4)
    robot.set_joints(now[0], ['psi', 'phi'], [0.1, 0.2], [])
    robot.set_odometry(now[0], pose, twist, 0.0)
    now[0] += 1_000_000_000
    robot.set_joints(now[0], ['phi'], [0.2], [])
    robot.set_odometry(now[0], pose, twist, 0.0)
    assert robot.joints_lost
    assert robot.hidden_status == 'phi from joint_states; psi dead-reckoned (joint_states stale)'
    with pytest.raises(JointsRejected, match='older than odom_timeout'):
        robot.set_joints(now[0] - 600_000_000, ['phi'], [0.2], [])


@pytest.mark.unit
@pytest.mark.parametrize('speed', [1.0, 0.02, 0.002])
def test_a_slow_path_implies_the_steering_a_fast_one_does(speed):
    """A circle of radius 1 for a car of wheelbase 0.5: phi = atan(0.5) at any speed."""
    car = car_like(L=0.5)
    pose_map = PoseMap(car)
    t = np.linspace(0.0, 2.0 / speed, 201)
    angle = speed * t
    poses = np.stack([np.sin(angle), 1 - np.cos(angle), 0 * t, angle], axis=1)
    reference = pose_map.reference(t, poses, None, np.zeros(4))
    assert np.abs(reference.q[5:-5, 3] - math.atan(0.5)).max() < 1e-3


@pytest.mark.unit
def test_a_turn_on_the_spot_implies_a_steering_inside_the_stops_that_settles():
    """No steering turns a board on the spot: held during the turn, straight once it drives.

    (About the corner the spline through the poses rings, and the steering with it.)
    """
    board = SYSTEMS['snakeboard']()
    pose_map = PoseMap(board)
    t = np.linspace(0.0, 4.0, 161)
    spin = np.clip(t, 0, 1)  # a turn in place for 1 s, then straight ahead
    ahead = np.clip(t - 1, 0, None) * 0.5
    poses = np.stack([ahead * np.cos(1.0), ahead * np.sin(1.0), 0 * t, spin], axis=1)
    reference = pose_map.reference(t, poses, None, np.zeros(5))
    assert np.isfinite(reference.v).all() and np.abs(reference.q[:, 4]).max() < np.pi / 2
    assert np.all(reference.q[:40, 4] == reference.q[0, 4])  # held through the turn
    assert np.abs(reference.q[t >= 1.5, 4]).max() < 0.01
