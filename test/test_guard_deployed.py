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

"""The command guard as deployed: planner and simulator processes, config/diff_drive.yaml.

Nav2's speed zones, a robot already past its bounds, a simulator paused and resumed far off
its route: what is commanded stays inside v_min/v_max (0.7 m/s, 3.0 rad/s) whatever the plan.
"""
import os
import signal
import threading
import time

from action_msgs.msg import GoalStatus
from geometry_msgs.msg import Twist
from nav2_msgs.msg import SpeedLimit
from nav_msgs.msg import OccupancyGrid, Odometry
import numpy as np
import pytest
from trajectory_msgs.msg import JointTrajectory

from nh_tracking import models
from nh_tracking.core.poses import PoseMap
from nh_tracking.examples.nav2 import LETHAL, nav2_costmap, polyline, route_msg
from nh_tracking.navigation.costmap import gap
from nh_tracking.planning.guarded_plan import replay
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.graph import wait_until
from nh_tracking.ros.planner_interface import LATCHED
from processes import busy_cores
from test_nav2 import nav2_pair, RADIUS

pytestmark = pytest.mark.timeout(240)
V_MAX, W_MAX, MAX_DECEL = 0.7, 3.0, 1.0  # diff_drive.yaml's bounds and the default max_decel
TOL = 1.01  # the acceptance's 1 %
STRAIGHT = polyline((0, 0), (8, 0))
UNICYCLE = models.unicycle(m=1.0, J=1.0)  # diff_drive.yaml's


def record_cmd_vel(robot) -> list[tuple[float, float, float]]:
    """(t, linear.x, angular.z) of every cmd_vel the planner publishes, from now on."""
    commands: list[tuple[float, float, float]] = []
    robot.node.create_subscription(Twist, 'cmd_vel', lambda m: commands.append(
        (time.monotonic(), m.linear.x, m.angular.z)), 100)
    return commands


def speed_after(robot, since: float) -> np.ndarray:
    track = robot.track
    return track[track[:, 0] > since, 4]


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('percentage, limit, capped', [(True, 40.0, 0.28), (False, 0.3, 0.3)])
def test_a_speed_zone_caps_the_speed_and_lifting_it_restores_the_route_speed(
        percentage, limit, capped):
    with nav2_pair(sim=('mode:=velocity',)) as (robot, planner, sim):
        zone = robot.node.create_publisher(SpeedLimit, 'speed_limit', LATCHED)
        commands = record_cmd_vel(robot)
        robot.reference.publish(route_msg(STRAIGHT, time.time_ns()))
        assert wait_until(lambda: robot.odometry[-1][4] > 0.45, 20.0), planner.output[-2000:]
        zone.publish(SpeedLimit(percentage=percentage, speed_limit=limit))
        limited = time.monotonic()
        settle = 1.0 + 0.5 / MAX_DECEL  # the acceptance: 1 s plus the deceleration time
        time.sleep(settle + 2.0)
        held = speed_after(robot, limited + settle)
        sent = np.array([c[1] for c in commands if c[0] > limited + settle])
        zone.publish(SpeedLimit(percentage=False, speed_limit=0.0))
        lifted = time.monotonic()
        assert wait_until(lambda: robot.odometry[-1][4] > 0.45, 10.0), planner.output[-2000:]
        restored = time.monotonic() - lifted
        print(f'\nspeed limit {limit:g}{" %" if percentage else " m/s"}: speed '
              f'{held.min():.3f}-{held.max():.3f} m/s from {settle:.1f} s on (cmd_vel at most '
              f'{sent.max():.3f}); back above 0.45 m/s {restored:.2f} s after it was lifted')
        assert len(held) > 20 and held.max() <= capped * TOL and held.min() >= capped * 0.8
        assert sent.max() <= capped * TOL
        assert 'speed limit in force: ' in planner.output


@pytest.mark.ros
@pytest.mark.slow
def test_a_robot_faster_than_its_bounds_is_given_a_goal_and_slowed_into_them():
    # effort mode: coasting at 0.8 m/s (v_max 0.7) until the goal comes
    with nav2_pair(sim=('initial_state:=[0.0, 0.0, 0.0, 0.8, 0.0]',)) as (robot, planner, sim):
        assert robot.odometry[-1][4] == pytest.approx(0.8, abs=1e-3)
        handle = robot.send_goal(polyline((0.5, 0), (12, 0)))
        accepted = time.monotonic()
        time.sleep(3.0)
        slowed = speed_after(robot, accepted + 0.1 / MAX_DECEL + 0.5)  # + the first plan
        print(f'\nfrom 0.8 m/s: speed {slowed.min():.3f}-{slowed.max():.3f} m/s from 0.6 s '
              'after the goal was accepted')
        assert slowed.max() <= V_MAX * TOL
        robot.graph.call(handle.cancel_goal_async)
        status, _ = robot.result_of(handle, 20.0)
        assert status == GoalStatus.STATUS_CANCELED


def record_sequences(robot) -> tuple[list, dict]:
    """Every control_sequence (start [ns], offsets, efforts), and odometry by stamp [ns]."""
    sequences: list[tuple[int, np.ndarray, np.ndarray]] = []
    states: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    robot.node.create_subscription(JointTrajectory, 'control_sequence', lambda m: sequences.append(
        cv.controls_to_arrays(m, UNICYCLE.control_names)), 100)

    def on_odom(msg: Odometry) -> None:
        stamp, pose, twist = cv.odom_to_arrays(msg, 'odom')
        states[stamp] = (pose, twist)
    robot.node.create_subscription(Odometry, 'odom', on_odom, 100)
    return sequences, states


def replayed_speeds(sequences: list, states: dict) -> np.ndarray:
    """|v| (speed, yaw rate) at every knot of each sequence replayed from the odometry it began at.

    A sequence planned from odometry starts at its stamp; others (a brake) are left out.
    """
    pose_map, speeds = PoseMap(UNICYCLE), []
    for start, offsets, efforts in sequences:
        if start not in states:
            continue
        pose, twist = states[start]
        q0 = pose_map.configuration(pose)
        steps = np.diff(np.r_[offsets, offsets[-1] + offsets[-1] - offsets[-2]])
        speeds.append(np.abs(replay(pose_map, q0, pose_map.velocity(q0, twist), efforts,
                                    steps)[1]).max(axis=0))
    return np.array(speeds)


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('mode', ['effort', 'velocity'])
def test_a_simulator_paused_and_resumed_off_its_route_is_never_commanded_past_its_bounds(mode):
    with nav2_pair(sim=(f'mode:={mode}',)) as (robot, planner, sim):
        commands = record_cmd_vel(robot)
        sequences, states = record_sequences(robot)
        route = np.vstack([polyline((0, 0), (3, 0)), polyline((3, 0), (3, 3))[1:]])
        robot.reference.publish(route_msg(route, time.time_ns()))
        assert wait_until(lambda: robot.odometry[-1][1] > 1.0, 20.0), planner.output[-2000:]
        os.kill(sim.proc.pid, signal.SIGSTOP)  # the route's timing runs on without the robot
        time.sleep(5.0)
        os.kill(sim.proc.pid, signal.SIGCONT)
        time.sleep(6.0)
        sent = np.array(commands)
        print(f'\n{mode} mode, paused 5 s: {len(sent)} cmd_vel, linear up to '
              f'{np.abs(sent[:, 1]).max():.3f} m/s, angular up to {np.abs(sent[:, 2]).max():.3f} '
              f'rad/s; the robot at up to {np.abs(robot.track[:, 4]).max():.3f} m/s')
        replayed = replayed_speeds(sequences, states)
        print(f'{len(replayed)} control sequences replayed from their odometry: speed up to '
              f'{replayed[:, 0].max():.3f} m/s, yaw rate up to {replayed[:, 1].max():.3f} rad/s')
        assert len(sent) > 100 and len(replayed) > 50
        assert replayed[:, 0].max() <= V_MAX * TOL and replayed[:, 1].max() <= W_MAX * TOL
        assert np.abs(sent[:, 1]).max() <= V_MAX * TOL
        assert np.abs(sent[:, 2]).max() <= W_MAX * TOL
        assert np.abs(robot.track[:, 4]).max() <= V_MAX * TOL


def closest_approach(costmap: OccupancyGrid, track: np.ndarray) -> float:
    """Return the least distance from an odometry position to a lethal cell of ``costmap``."""
    info = costmap.info
    cost = np.array(costmap.data).reshape(info.height, info.width)
    rows, cols = np.nonzero(cost == LETHAL)
    cells = np.c_[info.origin.position.x + (cols + 0.5) * info.resolution,
                  info.origin.position.y + (rows + 0.5) * info.resolution]
    return min(gap(p, np.zeros((0, 3)), cells, info.resolution) for p in track[:, 1:3])


# lethal walls across a 6 m route, each shown once the robot is on its way: part of the way
# (room to go round on one side or the other), all of it, and close ahead
WALLS = [(3.0, -1.5, 3.1, 0.3), (3.0, -0.3, 3.1, 1.5), (2.5, -2.0, 2.6, 2.0),
         (1.2, -0.5, 1.3, 0.5), (4.0, -0.1, 4.4, 0.1)]


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('wall', WALLS)
def test_a_wall_shown_while_the_cpu_is_busy_is_never_touched(wall):
    with busy_cores(4), nav2_pair(sim=('mode:=velocity',)) as (robot, planner, sim):
        handle = robot.send_goal(polyline((0, 0), (6, 0)))
        assert wait_until(lambda: robot.odometry[-1][1] > 0.3, 30.0), planner.output[-2000:]
        costmap = nav2_costmap([wall], RADIUS, size=(160, 80))
        robot.costmap.publish(costmap)
        shown = time.monotonic()
        status, result = robot.result_of(handle, 90.0)
        track = robot.track
        closest = closest_approach(costmap, track)
        print(f'\nwall {wall} shown at x = {track[track[:, 0] <= shown][-1, 1]:.2f} m, '
              f'4 busy processes: goal {status} ({result.error_msg!r}), closest approach '
              f'{closest:.3f} m (robot radius {RADIUS} m), ended at '
              f'({track[-1, 1]:.2f}, {track[-1, 2]:.2f}) m, speed up to '
              f'{np.abs(track[:, 4]).max():.3f} m/s')
        assert closest >= RADIUS - 0.01 and 'collision' not in sim.output


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('mode', ['effort', 'velocity'])
def test_odometry_cut_while_moving_brings_the_robot_to_rest_within_its_stopping_distance(mode):
    """The planner's odometry cut at 0.5 m/s (the robot's own goes on): at rest in time.

    Its stopping distance: v (odom_timeout + a replan period), the time it takes to know and
    send a brake, then v^2 / (2 max_decel).
    """
    with nav2_pair('odom_timeout:=0.5', remap=('odom:=relayed_odom',),
                   sim=(f'mode:={mode}',)) as (robot, planner, sim):
        relay = robot.node.create_publisher(Odometry, 'relayed_odom', 10)
        cut = threading.Event()
        robot.node.create_subscription(Odometry, 'odom', lambda m: cut.is_set() or
                                       relay.publish(m), 100)
        robot.reference.publish(route_msg(STRAIGHT, time.time_ns()))
        assert wait_until(lambda: robot.odometry[-1][4] > 0.49, 20.0), planner.output[-2000:]
        cut.set()
        _, x, y, _, v = robot.odometry[-1]
        assert planner.wait_for('braking to rest, no plans', 5.0), planner.output[-2000:]
        assert wait_until(lambda: abs(robot.odometry[-1][4]) < 1e-3, 5.0)
        time.sleep(0.5)
        track = robot.track
        went = np.hypot(track[-1, 1] - x, track[-1, 2] - y)
        stopping = v * (0.5 + 0.1) + v ** 2 / (2 * MAX_DECEL)  # (replan_period 0.1 s)
        print(f'\n{mode} mode, odometry cut at {v:.3f} m/s: at rest {went:.3f} m on '
              f'(stopping distance {stopping:.3f} m)')
        assert went <= stopping + 0.1
        assert np.abs(track[-10:, 4]).max() < 1e-3  # still at rest
