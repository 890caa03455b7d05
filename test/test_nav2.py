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

"""Driven as Nav2 drives a controller: planner and simulator as separate processes.

With config/diff_drive.yaml, untimed routes on ``reference_path`` and as ``follow_path`` goals,
Nav2-style costmaps.
"""
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path as FilePath
import threading
import time

from action_msgs.msg import GoalStatus
from diagnostic_msgs.msg import DiagnosticArray
from nav2_msgs.action import FollowPath
from nav_msgs.msg import OccupancyGrid, Odometry, Path
import numpy as np
import pytest
from rclpy.action import ActionClient

from nh_tracking.core.metrics import cross_track_error
from nh_tracking.examples.nav2 import nav2_costmap, polyline, route_msg
from nh_tracking.navigation.route_shape import closest_point
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.graph import wait_until
from nh_tracking.ros.planner_interface import LATCHED
from processes import domain_env, Peer, Process
from test_route import arc

pytestmark = [pytest.mark.timeout(240), pytest.mark.ros, pytest.mark.slow]
PARAMS = str(FilePath(__file__).resolve().parents[1] / 'config' / 'diff_drive.yaml')
SPEED, RADIUS, TOLERANCE = 0.5, 0.2, 0.25  # the params file's reference_speed, robot_radius
L_TURN = polyline((0, 0), (2, 0), (2, 2))  # a pose every 5 cm, a sharp 90-degree turn


class Robot:
    """This test's view of a planner and simulator: odometry, diagnostics, the action."""

    def __init__(self, peer: Peer) -> None:
        node = self.node = peer.node
        self.graph = peer.graph
        self.odometry: list[tuple[float, float, float, float, float]] = []  # t, x, y, yaw, v
        self.goal_states: list[str] = []
        self.blocked: list[float] = []
        node.create_subscription(Odometry, 'odom', self._on_odom, 100)
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 100)
        self.reference = node.create_publisher(Path, 'reference_path', LATCHED)
        self.costmap = node.create_publisher(OccupancyGrid, 'costmap', LATCHED)
        self.action = ActionClient(node, FollowPath, 'follow_path')
        self.feedback: list[tuple[float, float, float]] = []  # t, distance_to_goal, speed

    def _on_odom(self, m: Odometry) -> None:
        p, o = m.pose.pose.position, m.pose.pose.orientation
        self.odometry.append((time.monotonic(), p.x, p.y, 2 * np.arctan2(o.z, o.w),
                              m.twist.twist.linear.x))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if 'goal' in values:
                self.goal_states.append(values['goal'])
            if status.message.startswith('blocked'):
                self.blocked.append(time.monotonic())

    @property
    def track(self) -> np.ndarray:
        return np.array(self.odometry)

    def send_goal(self, poses: np.ndarray, **ids: str):
        """Send a follow_path goal; its goal handle once accepted."""
        sent = self.graph.call(
            self.action.send_goal_async, FollowPath.Goal(path=route_msg(poses), **ids),
            feedback_callback=lambda f: (
                self.feedback.append((time.monotonic(), f.feedback.distance_to_goal,
                                      f.feedback.speed))))
        assert wait_until(sent.done, 30.0)
        handle = sent.result()
        assert handle.accepted
        return handle

    def result_of(self, handle, timeout: float):
        """(status, result) of a goal, waited for."""
        future = self.graph.call(handle.get_result_async)
        assert wait_until(future.done, timeout), 'no result'
        return future.result().status, future.result().result


@contextmanager
def nav2_pair(*planner: str, sim: tuple[str, ...] = (), remap: tuple[str, ...] = ()
              ) -> Iterator[tuple[Robot, Process, Process]]:
    """Run planner and simulator from config/diff_drive.yaml (``planner``/``sim``: name:=value).

    ``remap``: the planner's remappings (from:=to).
    """
    env = domain_env()
    peer = Peer(env)
    processes = []
    try:
        robot = Robot(peer)
        for executable, extra, remaps in (('sim', sim, ()), ('planner', planner, remap)):
            processes.append(Process(executable, ['--ros-args', '--params-file', PARAMS, *[
                a for p in extra for a in ('-p', p)], *[a for r in remaps for a in ('-r', r)]],
                env))
        assert processes[1].wait_for('planning for unicycle', 60.0), processes[1].output
        assert wait_until(lambda: len(robot.odometry) > 10, 30.0)
        assert robot.action.wait_for_server(30.0)
        yield robot, processes[1], processes[0]
        for process in processes:
            assert 'Traceback' not in process.output, process.output
    finally:
        peer.close()
        for process in processes:
            process.kill()


def at_rest(robot: Robot, timeout: float) -> bool:
    return wait_until(lambda: abs(robot.odometry[-1][4]) < 0.01, timeout)


def speeds_on_straights(track: np.ndarray) -> np.ndarray:
    """Speeds where the robot is on a straight leg of L_TURN, clear of its ends and turn."""
    x, y = track[:, 1], track[:, 2]
    first = (x > 0.5) & (x < 1.2) & (np.abs(y) < 0.1)
    second = (y > 0.8) & (y < 1.5) & (np.abs(x - 2) < 0.1)
    return track[first | second, 4]


@pytest.mark.parametrize('mode, by', [('effort', 'reference_path'), ('velocity', 'reference_path'),
                                      ('effort', 'follow_path')])
def test_an_untimed_route_is_driven_at_its_speed_and_ends_at_rest_in_the_goal(mode, by):
    with nav2_pair(sim=(f'mode:={mode}',)) as (robot, planner, sim):
        start = time.monotonic()
        if by == 'reference_path':
            robot.reference.publish(route_msg(L_TURN, time.time_ns()))
            assert wait_until(lambda: 'arrived' in robot.goal_states, 40.0), planner.output
        else:
            status, result = robot.result_of(robot.send_goal(L_TURN), 40.0)
            assert status == GoalStatus.STATUS_SUCCEEDED
            assert result.error_code == FollowPath.Result.NONE
        arrived = time.monotonic() - start
        assert at_rest(robot, 10.0)
        track = robot.track
        moving = track[track[:, 0] > start]
        error = cross_track_error(moving[moving[:, 0] > start + 2.0, 1:3], L_TURN[:, :2])
        straights = speeds_on_straights(moving)
        end = np.hypot(*(track[-1, 1:3] - L_TURN[-1, :2]))
        overshoot = (moving[:, 2] - L_TURN[-1, 1]).max()
        print(f'\n{mode} by {by}: speed on the straights {straights.min():.3f}-'
              f'{straights.max():.3f} m/s, cross-track after 2 s {error.max():.3f} m, arrived '
              f'after {arrived:.1f} s, at rest {end:.3f} m from the goal, overshoot '
              f'{max(overshoot, 0):.3f} m, heading {track[-1, 3]:.3f} rad')
        assert "headings from the route's tangent" in planner.output
        assert len(straights) > 40 and np.all(np.abs(straights - SPEED) <= 0.1 * SPEED)
        assert error.max() <= 0.05
        assert end <= TOLERANCE and overshoot <= TOLERANCE / 2
        assert abs(track[-1, 3] - np.pi / 2) <= TOLERANCE


def test_a_goal_every_second_to_the_same_end_never_slows_the_robot():
    base = np.vstack([polyline((0, 0), (2.0, 0)), arc(1.0, np.pi / 4)[1:] + [2.0, 0, 0, 0]])
    end = base[-1, :2]
    along = np.r_[0.0, np.cumsum(np.hypot(*np.diff(base[:, :2], axis=0).T))]
    with nav2_pair() as (robot, planner, sim):
        start = time.monotonic()
        handles, status, result = [], None, None
        while time.monotonic() - start < 30.0:
            here = np.array(robot.odometry[-1][1:3])
            i, foot = closest_point(base[:, :2], here)
            # what a planner replanning at 1 Hz sends: from the robot along its plan to the end
            ahead = base[along > along[i] + np.hypot(*(foot - base[i, :2])) + 0.1]
            handles.append(robot.send_goal(np.vstack([np.r_[here, 0, 0], ahead])))
            future = robot.graph.call(handles[-1].get_result_async)
            if wait_until(future.done, 1.0):
                status, result = future.result().status, future.result().result
                break
        assert status == GoalStatus.STATUS_SUCCEEDED and result.error_code == 0, (
            status, result, planner.output[-3000:])
        track = robot.track
        middle = track[(track[:, 0] > start + 2.0) & (track[:, 0] < robot.feedback[-1][0] - 2.0)]
        distances = np.array([d for _, d, _ in robot.feedback])
        print(f'\n{len(handles)} goals, one a second: speed {middle[:, 4].min():.3f}-'
              f'{middle[:, 4].max():.3f} m/s between the first and last 2 s; distance_to_goal '
              f'{distances[0]:.2f} -> {distances[-1]:.2f} m over {len(distances)} feedbacks, '
              f'rising {max(np.diff(distances).max(), 0):.3f} m at most')
        assert len(handles) >= 4 and middle[:, 4].min() >= SPEED / 2
        assert distances[0] > 2.5 and distances[-1] < TOLERANCE
        assert np.all(np.diff(distances) < 0.02)  # it falls (a new route moves it by mm)
        assert np.hypot(*(track[-1, 1:3] - end)) <= TOLERANCE


def test_cancel_brings_the_robot_to_rest_and_bad_goals_are_refused_with_the_reason():
    with nav2_pair() as (robot, planner, sim):
        handle = robot.send_goal(polyline((0, 0), (5, 0)))
        assert wait_until(lambda: robot.odometry[-1][4] > 0.4, 20.0)
        cancelled = time.monotonic()
        assert wait_until(robot.graph.call(handle.cancel_goal_async).done, 10.0)
        status, _ = robot.result_of(handle, 10.0)
        assert at_rest(robot, 3.0), robot.odometry[-1]
        print(f'\ncancelled: at rest {time.monotonic() - cancelled:.2f} s after the request')
        assert status == GoalStatus.STATUS_CANCELED
        bad = polyline((0, 0), (5, 0))
        bad[7, 1] = np.nan
        status, result = robot.result_of(robot.send_goal(bad), 10.0)
        assert status == GoalStatus.STATUS_ABORTED
        assert result.error_code == FollowPath.Result.INVALID_PATH
        assert 'pose 7' in result.error_msg and 'NaN' in result.error_msg
        status, result = robot.result_of(
            robot.send_goal(polyline((0, 0), (1, 0)), controller_id='DWB'), 10.0)
        assert result.error_code == FollowPath.Result.INVALID_CONTROLLER, result
        x = robot.odometry[-1][1]
        # pose stamps relative to a header stamped now: read as 1970, so refused
        t = np.arange(0, 4.0, 0.1)
        misread = msgs.path_msg('odom', (t * 1e9).astype(int), np.c_[x + 0.5 * t, 0 * t, 0 * t,
                                                                     0 * t])
        misread.header.stamp = msgs.time_msg(time.time_ns())
        robot.reference.publish(misread)
        assert planner.wait_for('it ended', 10.0), planner.output
        time.sleep(2.0)
        assert abs(robot.odometry[-1][1] - x) < 0.05 and 'header stamp of 0' in planner.output


def test_a_route_past_an_inflated_block_is_driven_without_collision():
    block = (1.85, 0.35, 2.15, 0.65)  # its near edge 0.35 m beside the route: room for r = 0.2
    with nav2_pair() as (robot, planner, sim):
        robot.costmap.publish(nav2_costmap([block], RADIUS))
        time.sleep(0.5)
        status, result = robot.result_of(robot.send_goal(polyline((0, 0), (4, 0))), 40.0)
        track = robot.track
        gap = (np.maximum(np.abs(track[:, 1] - 2.0) - 0.15, 0) ** 2
               + np.maximum(0.35 - track[:, 2], 0) ** 2) ** 0.5
        print(f'\npast a Nav2-inflated block: {status}, closest approach {gap.min():.3f} m '
              f'(robot radius {RADIUS} m), {np.abs(track[:, 2]).max():.3f} m off the route at '
              f'most, ended at x = {track[-1, 1]:.2f} m')
        assert status == GoalStatus.STATUS_SUCCEEDED and result.error_code == 0
        # its inflation was not taken for obstacle (then the robot had to keep 0.2 m further)
        assert np.abs(track[:, 2]).max() < 0.1
        assert gap.min() >= RADIUS - 0.01 and 'collision' not in sim.output


def test_a_wall_across_the_route_fails_to_make_progress_in_time_without_collision():
    with nav2_pair('movement_time_allowance:=6.0') as (robot, planner, sim):
        robot.costmap.publish(nav2_costmap([(2.0, -2.0, 2.1, 2.0)], RADIUS))
        time.sleep(0.5)
        handle = robot.send_goal(polyline((0, 0), (4, 0)))
        stopped = threading.Event()

        def watch() -> None:
            wait_until(lambda: robot.odometry[-1][1] > 0.5 and abs(robot.odometry[-1][4]) < 0.05,
                       60.0)
            stopped.set()
        threading.Thread(target=watch, daemon=True).start()
        status, result = robot.result_of(handle, 60.0)
        ended = time.monotonic()
        assert stopped.wait(1.0)
        stop_time = next(t for t, x, _, _, v in robot.odometry if x > 0.5 and abs(v) < 0.05)
        print(f'\nwall: {result.error_msg!r} {ended - stop_time:.1f} s after the robot stopped, '
              f'at x = {robot.odometry[-1][1]:.2f} m (wall at 2.0 m); blocked said '
              f'{len(robot.blocked)} times')
        assert status == GoalStatus.STATUS_ABORTED
        assert result.error_code == FollowPath.Result.FAILED_TO_MAKE_PROGRESS
        assert ended - stop_time <= 6.0 + 2.0
        assert robot.odometry[-1][1] <= 2.0 - RADIUS and 'collision' not in sim.output
        # a route on reference_path into the same wall: "blocked" in the diagnostics
        sent = time.monotonic()
        robot.reference.publish(route_msg(polyline((robot.odometry[-1][1], 0), (4, 0))))
        assert wait_until(lambda: robot.blocked and robot.blocked[-1] > sent, 6.0 + 4.0)
        print(f'reference_path route into it: blocked {robot.blocked[-1] - sent:.1f} s after '
              'it was sent')
        removed = time.monotonic()  # the way clears: the kept route is driven on
        robot.costmap.publish(nav2_costmap([], RADIUS))
        assert wait_until(lambda: robot.odometry[-1][4] > 0.1, 3.0), robot.odometry[-1]
        print(f'wall removed: moving again after {time.monotonic() - removed:.1f} s')
        assert wait_until(lambda: robot.odometry[-1][1] > 4.0 - TOLERANCE, 20.0)
        assert 'collision' not in sim.output


def fuzzed_goal(rng: np.random.Generator) -> FollowPath.Goal:
    """Return a goal from a route or timed path with 0-2 of the faults a client may send."""
    poses = polyline((0, 0), tuple(rng.uniform(-3, 3, 2)), tuple(rng.uniform(-3, 3, 2)))
    poses[:, 3] = rng.uniform(-np.pi, np.pi) if rng.integers(2) else 0.0
    now = time.time_ns()
    stamps = [now] * len(poses) if rng.integers(2) else [
        now + int(i * 1e8) for i in range(len(poses))]
    msg = msgs.path_msg('odom', stamps, poses)
    ids = {}
    for _ in range(int(rng.integers(3))):
        if not msg.poses:
            break
        fault = int(rng.integers(8))
        pose = msg.poses[int(rng.integers(len(msg.poses)))]
        if fault == 0:
            pose.pose.position.y = float(rng.choice([np.nan, np.inf, 1e300]))
        elif fault == 1:
            pose.pose.orientation.w = 2.0
        elif fault == 2:
            msg.header.frame_id = 'map'
        elif fault == 3:
            msg.poses = msg.poses[:int(rng.integers(2))]  # empty, or one pose
        elif fault == 4:
            pose.header.stamp = msgs.time_msg(0)  # out of order, or in 1970
        elif fault == 5:
            msg.header.stamp = msgs.time_msg(now)
            for j, p in enumerate(msg.poses):  # relative stamps under a header of now
                p.header.stamp = msgs.time_msg(int(j * 1e8))
        elif fault == 6:
            ids[str(rng.choice(['controller_id', 'goal_checker_id', 'progress_checker_id']))] = \
                str(rng.choice(['', 'FollowPath', 'DWB', 'goal_checker', 'x' * 300]))
        else:
            pose.pose.position.x += 1e5  # far, but finite: a route 100 km long
    return FollowPath.Goal(path=msg, **ids)


def test_fuzzed_follow_path_goals_each_get_a_result_and_the_planner_carries_on(graph):
    from nh_tracking.ros.graph import parameters
    from nh_tracking.ros.planner_node import PlannerNode
    from nh_tracking.ros.simulator_node import SimulatorNode
    from test_ros import unique_namespace
    from test_ros_reliability import _finite_message, _record_outputs

    ns = unique_namespace()
    sim = graph.add(SimulatorNode, namespace=ns, parameter_overrides=parameters(model='unicycle'))
    planner = graph.add(PlannerNode, namespace=ns, parameter_overrides=parameters(
        model='unicycle', steps=20, horizon=2.0))
    published = _record_outputs(planner)
    client = ActionClient(graph.plain_node('fuzzer', ns), FollowPath, 'follow_path')
    assert client.wait_for_server(30.0)
    rng, results = np.random.default_rng(7), []
    for _ in range(60):
        sent = graph.call(client.send_goal_async, fuzzed_goal(rng))
        assert wait_until(sent.done, 30.0)
        handle = sent.result()
        assert handle.accepted
        results.append(graph.call(handle.get_result_async))
        time.sleep(float(rng.uniform(0.0, 0.3)))  # preempted by the next, or ended
    # (the last one may still run)
    assert wait_until(graph.call(handle.cancel_goal_async).done, 10.0)
    assert wait_until(lambda: all(r.done() for r in results), 60.0)
    codes = [(r.result().status, r.result().result.error_code) for r in results]
    known = {FollowPath.Result.NONE, FollowPath.Result.INVALID_CONTROLLER,
             FollowPath.Result.INVALID_PATH, FollowPath.Result.FAILED_TO_MAKE_PROGRESS}
    print(f'\n60 fuzzed goals: {sorted((s, c) for s, c in set(codes))} (status, error code); '
          f'planner rejected {planner.problems.rejected_inputs} inputs, '
          f'{planner.problems.errors} errors')
    assert all(c in known for _, c in codes)
    assert {c for _, c in codes} >= {FollowPath.Result.INVALID_PATH, FollowPath.Result.NONE}
    assert planner.problems.errors == 0 and sim.problems.errors == 0
    assert all(_finite_message(m) for msgs_ in published.values() for m in msgs_)
    plans = planner.planner.stats.plans
    assert wait_until(lambda: planner.planner.stats.plans > plans, 10.0)  # still planning


def test_the_nav2_demo_arrives_and_draws_it(tmp_path):
    from nh_tracking.examples.nav2 import run_nav2_demo

    summary = run_nav2_demo(tmp_path, log=lambda line: None)
    assert summary['error_code'] == 0 and summary['max_cross_track_error_after_2s'] <= 0.05
    assert summary['fallbacks'] == 0 and (tmp_path / 'nav2.png').stat().st_size > 10_000


def test_deactivation_and_an_invalid_goal_bring_the_robot_to_rest(graph):
    """What Nav2's controller_server does: a goal that ends unfinished stops the robot."""
    from nh_tracking.examples.nav2 import SETTINGS
    from nh_tracking.ros.graph import parameters
    from nh_tracking.ros.planner_node import PlannerNode
    from nh_tracking.ros.simulator_node import SimulatorNode
    from test_ros import unique_namespace

    ns = unique_namespace()
    graph.add(SimulatorNode, namespace=ns, parameter_overrides=parameters(model='unicycle'))
    planner = graph.add(PlannerNode, namespace=ns, parameter_overrides=parameters(**SETTINGS))
    node = graph.plain_node('nav2', ns)
    odometry: list[tuple[float, float]] = []  # x, speed
    node.create_subscription(Odometry, 'odom', lambda m: odometry.append(
        (m.pose.pose.position.x, m.twist.twist.linear.x)), 100)
    client = ActionClient(node, FollowPath, 'follow_path')
    assert client.wait_for_server(30.0)

    def goal(poses: np.ndarray):
        sent = graph.call(client.send_goal_async, FollowPath.Goal(
            path=route_msg(poses), goal_checker_id='general_goal_checker'))
        assert wait_until(sent.done, 10.0) and sent.result().accepted
        return graph.call(sent.result().get_result_async)

    def at_rest(timeout: float) -> bool:
        return wait_until(lambda: abs(odometry[-1][1]) < 0.02, timeout)

    first = goal(polyline((0, 0), (6, 0)))
    assert wait_until(lambda: odometry and odometry[-1][1] > 0.4, 20.0)
    planner.trigger_deactivate()  # effort mode: zero cmd_vel alone would leave it coasting
    assert at_rest(4.0), odometry[-1]
    assert wait_until(first.done, 5.0) and first.result().status == GoalStatus.STATUS_ABORTED
    x = odometry[-1][0]
    planner.trigger_activate()
    wait_until(lambda: False, 2.0)
    assert abs(odometry[-1][0] - x) < 0.02  # the aborted goal's route is not taken up again
    goal(polyline((x, 0), (x + 4, 0)))
    assert wait_until(lambda: odometry[-1][1] > 0.4, 20.0)
    bad = polyline((0, 0), (1, 0))
    bad[3, 0] = np.nan
    invalid = goal(bad)  # preempts the running goal, then fails: nothing drives the robot
    assert wait_until(invalid.done, 5.0)
    assert invalid.result().result.error_code == FollowPath.Result.INVALID_PATH
    assert at_rest(4.0), odometry[-1]
    print(f'\ndeactivated at 0.5 m/s and after an invalid goal: at rest; x = '
          f'{odometry[-1][0]:.2f} m')
