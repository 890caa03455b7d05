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

"""The command guard on small hand-computed cases: bounds, speed limits, acceleration, sweeps."""
import math

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.core.poses import PoseMap
from nh_tracking.planning.command_guard import (arc, Clearance, CommandGuard, free_distance,
                                                GuardAction, OccupiedCells, SpeedLimit,
                                                stopping_speed)
from nh_tracking.planning.guarded_plan import guard_controls
from nh_tracking.session.commanding import Commands

pytestmark = pytest.mark.unit

# a differential drive: v = (forward speed, yaw rate) is its body twist's (vx, wz)
UNICYCLE = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
BOUNDS = np.array([[-0.7, -3.0], [0.7, 3.0]])
AT_ORIGIN = np.zeros(4)  # (x, y, z, yaw): heading along +x


def guard(**changes) -> CommandGuard:
    values = {'bounds': BOUNDS, 'max_accel': 0.5, 'max_decel': 1.0, 'robot_radius': 0.2}
    values.update(changes)
    return CommandGuard(**values)


def actions(guarded) -> list[GuardAction]:
    return [note.action for note in guarded.notes]


def test_a_command_inside_every_limit_passes_unchanged():
    out = guard().velocity(np.array([0.5, 1.0]), UNICYCLE, np.array([0.5, 1.0]), 0.05)
    assert not out.changed
    np.testing.assert_array_equal(out.v, [0.5, 1.0])


def test_a_command_past_the_bounds_is_scaled_back_along_itself():
    # (0.89, 4.5): the yaw rate is 1.5x its bound, the speed 1.27x: scaled by 3 / 4.5
    out = guard().velocity(np.array([0.89, 4.5]), UNICYCLE, np.array([0.89, 4.5]), 0.05)
    np.testing.assert_allclose(out.v, [0.89 * 2 / 3, 3.0])
    assert actions(out) == [GuardAction.VELOCITY_BOUND]
    assert 'cut from 0.89 to 0.59 m/s' in out.notes[0].text


def test_bounds_that_exclude_zero_clip_each_component():
    bounds = np.array([[0.1, -1.0], [0.7, 1.0]])  # always forward
    out = guard(bounds=bounds).velocity(np.array([0.0, 2.0]), UNICYCLE, np.zeros(2), 0.05)
    np.testing.assert_allclose(out.v, [0.1, 1.0])


@pytest.mark.parametrize('limit, expected', [(SpeedLimit(40.0, True), 0.28),
                                             (SpeedLimit(0.3), 0.3), (SpeedLimit(0.0), 0.5)])
def test_a_speed_limit_caps_the_translational_speed_keeping_the_curvature(limit, expected):
    steady = np.array([expected, 2.0 * expected])  # the command before: already limited
    out = guard(speed_limit=limit).velocity(np.array([0.5, 1.0]), UNICYCLE, steady, 0.05)
    np.testing.assert_allclose(out.v, [expected, 2.0 * expected])
    assert actions(out) == ([GuardAction.SPEED_LIMIT] if expected < 0.5 else [])


def test_a_lowered_speed_limit_is_reached_at_max_decel():
    out = guard(speed_limit=SpeedLimit(40.0, True)).velocity(
        np.array([0.5, 0.0]), UNICYCLE, np.array([0.3, 0.0]), 0.05)
    assert out.v[0] == pytest.approx(0.28)  # 0.02 m/s less: within 0.05 s at 1 m/s^2
    out = guard(speed_limit=SpeedLimit(40.0, True)).velocity(
        np.array([0.5, 0.0]), UNICYCLE, np.array([0.6, 0.0]), 0.05)
    assert out.v[0] == pytest.approx(0.6 - 1.0 * 0.05)  # from 0.6, 0.05 s at 1 m/s^2
    assert actions(out) == [GuardAction.SPEED_LIMIT, GuardAction.ACCELERATION]


@pytest.mark.parametrize('previous, wanted, expected', [
    (0.0, 0.5, 0.05),   # max_accel 0.5 m/s^2 for 0.1 s
    (0.5, 0.0, 0.4),    # max_decel 1.0 m/s^2 for 0.1 s
    (-0.3, 0.3, -0.2),  # reversing: slowing down first, at max_decel
])
def test_acceleration_is_limited_from_the_command_before(previous, wanted, expected):
    out = guard().velocity(np.array([wanted, 0.0]), UNICYCLE, np.array([previous, 0.0]), 0.1)
    assert out.v[0] == pytest.approx(expected)
    assert actions(out) == [GuardAction.ACCELERATION]


def test_a_robot_past_its_bounds_is_never_commanded_past_them():
    out = guard().velocity(np.array([0.8, 0.0]), UNICYCLE, np.array([0.8, 0.0]), 0.05)
    assert out.v[0] == pytest.approx(0.7)


def test_a_speed_limit_in_percent_is_of_the_largest_speed_the_bounds_allow():
    # two planar components of 1 m/s each: the fastest corner goes sqrt(2) m/s
    planar = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0], [0.0, 0.0]])
    g = guard(bounds=np.array([[-1.0, -1.0], [1.0, 1.0]]))
    assert g.max_speed(planar) == pytest.approx(math.sqrt(2.0))
    assert guard(bounds=None).max_speed(planar) == math.inf
    assert g.max_speed(UNICYCLE) == pytest.approx(1.0)  # (only the first moves the robot)


@pytest.mark.parametrize('limit, percentage', [(-1.0, False), (101.0, True), (math.nan, False),
                                               (math.inf, False)])
def test_a_bad_speed_limit_is_refused(limit, percentage):
    with pytest.raises(ValueError, match='speed limit'):
        SpeedLimit(limit, percentage)


def test_an_arc_of_a_quarter_turn():
    # 1 m/s at pi/2 rad/s for 1 s: a quarter circle of radius 2/pi, here started facing +y
    end = arc(np.array([0.0, 0.0, 0.0, math.pi / 2]), np.array([1.0, 0.0, 0.0, math.pi / 2]),
              np.array([0.0, 1.0]))
    np.testing.assert_allclose(end, [[0.0, 0.0], [-2 / math.pi, 2 / math.pi]], atol=1e-12)
    straight = arc(AT_ORIGIN, np.array([0.5, 0.2, 0.0, 0.0]), np.array([2.0]))
    np.testing.assert_allclose(straight, [[1.0, 0.4]])


def test_the_free_distance_to_a_disc_and_to_a_costmap_cell():
    # a disc of radius 0.1 at 1 m ahead: a disc of radius 0.2 touches it after 0.7 m
    disc = Clearance(np.array([[1.0, 0.0, 0.1]]))
    assert free_distance(disc, AT_ORIGIN, np.array([0.5, 0, 0, 0]), 0.2, 2.0) == \
        pytest.approx(0.7, abs=0.011)
    # a cell of side 0.1 centred 1 m ahead counts as the disc through its corners
    cell = Clearance(cells=OccupiedCells(np.array([[1.0, 0.0]]), 0.1))
    assert free_distance(cell, AT_ORIGIN, np.array([0.5, 0, 0, 0]), 0.2, 2.0) == \
        pytest.approx(1.0 - 0.1 / math.sqrt(2) - 0.2, abs=0.011)
    # beside the line, or beyond the length checked: clear
    assert free_distance(disc, AT_ORIGIN, np.array([0.0, 0.5, 0, 0]), 0.2, 2.0) == math.inf
    assert free_distance(disc, AT_ORIGIN, np.array([0.5, 0, 0, 0]), 0.2, 0.5) == math.inf


def test_a_disc_moving_toward_the_robot_is_met_sooner():
    # at 2 m coming at 1 m/s, the robot going at 1 m/s: they close at 2 m/s
    disc = Clearance(np.array([[2.0, 0.0, 0.1, -1.0, 0.0]]))
    distance = free_distance(disc, AT_ORIGIN, np.array([1.0, 0, 0, 0]), 0.2, 3.0)
    assert distance == pytest.approx((2.0 - 0.3) / 2, abs=0.011)


def test_a_robot_touching_an_obstacle_may_leave_but_not_go_deeper():
    disc = Clearance(np.array([[0.25, 0.0, 0.1]]))  # 0.05 m inside the robot's disc
    away = np.array([-0.3, 0.0, 0.0, 0.0])
    assert free_distance(disc, AT_ORIGIN, away, 0.2, 1.0) == math.inf
    assert free_distance(disc, AT_ORIGIN, -away, 0.2, 1.0) == 0.0


@pytest.mark.parametrize('distance, lookahead, decel, speed', [
    (0.2, 0.1, 1.0, -0.1 + math.sqrt(0.01 + 0.4)),  # 0.1 s at s, then s^2 / 2 braking
    (0.5, 0.0, 1.0, 1.0),  # sqrt(2 a d)
    (0.0, 0.1, 1.0, 0.0), (math.inf, 0.1, 1.0, math.inf)])
def test_the_stopping_speed(distance, lookahead, decel, speed):
    assert stopping_speed(distance, lookahead, decel) == pytest.approx(speed)
    if 0 < speed < math.inf:  # it travels exactly the distance
        assert speed * lookahead + speed ** 2 / (2 * decel) == pytest.approx(distance)


def test_a_command_toward_a_disc_is_slowed_then_stopped():
    wall = Clearance(np.array([[0.5, 0.0, 0.1]]))  # its edge 0.4 m, the robot's at 0.2 m
    g = guard()
    out = g.velocity(np.array([0.7, 0.0]), UNICYCLE, np.array([0.7, 0.0]), 0.05, AT_ORIGIN,
                     wall, 0.1)
    assert actions(out) == [GuardAction.OBSTACLE]
    assert out.v[0] == pytest.approx(stopping_speed(0.2, 0.1, 1.0), abs=0.02)
    assert 'slowed from 0.70 to 0.54 m/s' in out.notes[0].text
    near = Clearance(np.array([[0.295, 0.0, 0.1]]))  # 5 mm inside its margin already
    out = g.velocity(np.array([0.7, 0.0]), UNICYCLE, np.array([0.7, 0.0]), 0.05, AT_ORIGIN,
                     near, 0.1)
    np.testing.assert_array_equal(out.v, [0.0, 0.0])
    assert 'stopped 0.00 m before an obstacle' in out.notes[0].text
    # turning in place beside it, or driving away from it: allowed
    for v in ([0.0, 3.0], [-0.5, 0.0]):
        assert not g.velocity(np.array(v), UNICYCLE, np.array(v), 0.05, AT_ORIGIN, near,
                              0.1).changed


def test_commands_stop_short_of_discs_at_rest_where_the_plans_have_them():
    """A moving disc is the plans' to go round; one not seen for long is held where it got to."""
    commands = Commands()
    discs = np.array([[0.0, 0.0, 0.1, 0.0, 0.0],    # at rest
                      [5.0, 0.0, 0.1, 1.0, 0.0],    # moving, seen 0.5 s ago
                      [9.0, 0.0, 0.1, 1.0, 0.0]])   # moving, seen 10 s ago: held, at rest
    commands.set_obstacles(discs, np.array([-np.inf, 9.5, 0.0]), OccupiedCells(
        np.array([[3.0, 3.0]]), 0.05))
    clearance = commands.clearance(10.0)
    np.testing.assert_allclose(clearance.discs[:, :3], [[0.0, 0.0, 0.1], [11.0, 0.0, 0.1]])
    assert clearance(np.array([[3.0, 3.1]]))[0] == pytest.approx(0.1 - 0.05 / math.sqrt(2))


def test_a_sequence_whose_replay_keeps_to_its_limits_passes_as_it_is():
    """Within the replay's tolerance of a bound and clear of a disc far off: not cut back."""
    pose_map = PoseMap(nht.models.unicycle())
    q0, held = np.zeros(3), np.zeros((30, 2))  # no effort: the speed stays as it is
    far = Clearance(np.array([[0.0, 5.0, 0.1]]))
    passed = guard_controls(guard(), pose_map, q0, np.array([0.7 * 1.003, 0.0]), held,
                            np.full(30, 0.1), 0.1, far)
    assert not passed.notes and passed.u is held
    cut = guard_controls(guard(), pose_map, q0, np.array([0.8, 0.0]), held, np.full(30, 0.1),
                         0.1, far)
    assert [note.action for note in cut.notes] == [GuardAction.VELOCITY_BOUND]
    assert cut.v[1, 0] == pytest.approx(0.7, abs=1e-3) and cut.v[:, 0].max() == 0.8


def test_the_guard_on_a_model_pose_map():
    """A built-in unicycle: its twist matrix and what the guard makes of its commands."""
    unicycle = nht.models.unicycle()
    pose_map = PoseMap(unicycle)
    q, v = np.array([1.0, 2.0, 0.7]), np.array([0.9, 4.0])
    matrix = pose_map.twist_matrix(q)
    np.testing.assert_allclose(matrix @ v, [0.9, 0.0, 0.0, 4.0], atol=1e-12)
    out = guard().velocity(v, matrix, v, 0.05)
    assert np.all(np.abs(out.v) <= [0.7, 3.0])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-5, 5), min_size=2, max_size=2),
       st.lists(st.floats(-5, 5), min_size=2, max_size=2),
       st.floats(0.0, 100.0), st.booleans(), st.floats(1e-3, 0.5))
def test_no_command_leaves_the_bounds_or_passes_a_speed_limit_it_started_under(
        wanted, previous, limit, percentage, dt):
    g = guard(speed_limit=SpeedLimit(limit, percentage))
    out = g.velocity(np.array(wanted), UNICYCLE, np.array(previous), dt)
    assert np.all(out.v >= BOUNDS[0] - 1e-9) and np.all(out.v <= BOUNDS[1] + 1e-9)
    cap = g.speed_limit.cap(0.7)
    if abs(previous[0]) <= cap:  # a limit lowered under the robot is reached at max_decel
        assert abs(out.v[0]) <= cap + 1e-9
    if np.all(np.abs(previous) <= BOUNDS[1]):  # (else brought inside at once)
        assert abs(out.v[0] - previous[0]) <= 1.0 * dt + 1e-9  # max_decel > max_accel


def test_commands_ramp_from_the_one_before_while_a_base_holds_it_else_from_the_robot():
    """A late command (0.13 s, under load) ramps from the one before; after 0.6 s, from the robot.

    A base holds a velocity command COMMAND_MEMORY (0.5 s); later it has stopped on its own.
    """
    from nh_tracking.planning.receding_horizon import PlannerSettings, RecedingHorizonPlanner

    unicycle = nht.models.unicycle()
    planner = RecedingHorizonPlanner(unicycle, PlannerSettings(v_min=(-0.7, -3.0),
                                                               v_max=(0.7, 3.0)))
    pose_map, commands, q = PoseMap(unicycle), Commands(), np.zeros(3)

    def command(t: float, wanted: float, robot: float) -> float:
        return commands.twist(planner, pose_map, t, q, np.array([wanted, 0.0]), q,
                              np.array([robot, 0.0]), 0.0)[0]
    assert command(10.0, 0.1, 0.1) == pytest.approx(0.1)
    assert command(10.13, 0.6, 0.5) == pytest.approx(0.1 + 0.5 * 0.13)  # max_accel 0.5
    assert command(10.73, 0.6, 0.3) == pytest.approx(0.3 + 0.5 * 0.05)  # a period from 0.3
