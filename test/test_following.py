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

"""Goals, progress, and the path in force of a session, without ROS: closed loops included."""
import time

import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.core.metrics import cross_track_error
from nh_tracking.core.poses import PoseMap
from nh_tracking.examples.nav2 import polyline
from nh_tracking.navigation.goal_checking import (GoalChecker, GoalSettings, GoalState,
                                                  PathProgress, ProgressChecker)
from nh_tracking.navigation.reference_checks import ReferenceRejected
from nh_tracking.navigation.route import RouteSettings
from nh_tracking.planning.receding_horizon import PlannerSettings, PlanStatus
from nh_tracking.session.tracking_session import TrackingSession
from test_route import arc


@pytest.mark.unit
def test_the_goal_checker_wants_the_pose_the_heading_the_rest_and_the_whole_path():
    checker = GoalChecker(GoalSettings())
    goal = np.array([1.0, 1.0, 0.0, 0.5])
    near = np.array([1.1, 0.9, 0.0, 0.6])
    assert checker.reached(near, goal, np.zeros(4), 0.1)
    assert not checker.reached(near, goal, np.array([0.3, 0, 0, 0]), 0.1)  # still moving
    assert not checker.reached(near, goal, np.array([0, 0, 0, 0.3]), 0.1)  # still turning
    assert not checker.reached(near + [0, 0, 0, 0.3], goal, np.zeros(4), 0.1)
    assert not checker.reached(near + [0.3, 0, 0, 0], goal, np.zeros(4), 0.1)
    assert not checker.reached(near, goal, np.zeros(4), 3.0)  # a loop: the end is ahead
    blind = GoalChecker(GoalSettings(), has_yaw=False)  # a model without a heading
    assert blind.reached(near + [0, 0, 0, 2], goal, np.zeros(4), 0.1)


@pytest.mark.unit
def test_progress_is_movement_of_a_radius_within_the_allowance():
    checker = ProgressChecker(GoalSettings(required_movement_radius=0.5,
                                           movement_time_allowance=10.0))
    assert all(checker.moving(np.array([0.06 * t, 0.0]), t) for t in np.arange(0, 20, 0.5))
    stuck = [checker.moving(np.array([5.0 + 0.01 * t, 0.0]), 20 + t) for t in range(15)]
    assert stuck[:11] == [True] * 11 and not any(stuck[11:])
    assert checker.moving(np.array([2.0, 0.0]), 36.0)  # it got going again


@pytest.mark.unit
def test_the_place_on_a_loop_goes_round_it():
    loop = polyline((0, 0), (2, 0), (2, 2), (0, 2), (0, 0))[:, :2]
    progress = PathProgress(loop)
    remaining = [progress.remaining(p + [0.02, -0.03]) for p in loop[::4]]
    assert remaining[0] == pytest.approx(8.0, abs=0.05)
    assert np.all(np.diff(remaining) < 0) and remaining[-1] < 0.05


class Loop:
    """A session on a clock of its own, its robot integrated on the model's dynamics."""

    def __init__(self, model='unicycle', dt=0.1, **settings):
        self.ns, self.dt = 0, dt
        self.logs: list[tuple[str, str]] = []
        self.session = TrackingSession(model, {}, PlannerSettings(**settings), lambda: self.ns,
                                       log=lambda level, text: self.logs.append((level, text)))
        self.session.planner.prepare()
        self.session.active = True
        system = self.session.system
        self.q, self.v = np.zeros(system.n), np.zeros(system.k)
        self.odometry()

    def odometry(self) -> None:
        pose_map = self.session.pose_map
        self.session.set_odometry(self.ns, pose_map.pose(self.q),
                                  pose_map.body_twist(self.q, self.v), time.perf_counter())

    def run(self, seconds: float) -> np.ndarray:
        """Close the loop; rows (t, x, y, yaw, forward speed)."""
        rows, pose_map = [], self.session.pose_map
        for _ in range(int(round(seconds / self.dt))):
            plan = self.session.replan().outcome.plan
            motion = nht.simulate(self.session.system, self.q, self.v, [0, self.dt], plan.u[:1])
            self.q, self.v = motion.q[-1], motion.v[-1]
            self.ns += int(self.dt * 1e9)
            self.odometry()
            pose = pose_map.pose(self.q)
            rows.append((self.ns * 1e-9, pose[0], pose[1], pose[3],
                         pose_map.body_twist(self.q, self.v)[0]))
        return np.array(rows)


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('model, route', [
    ('unicycle', polyline((0, 0), (2, 0), (2, 2))),  # a sharp 90-degree corner
    ('unicycle', np.vstack([polyline((0, 0), (1.5, 0)), arc(0.5, np.pi / 2)[1:] + [1.5, 0, 0, 0],
                            polyline((2, 0.5), (2, 2))[1:]])),
    ('rolling_disk', polyline((0, 0), (1.5, 0.5), (3, 0))),  # a model with a hidden rolling angle
    ('user_robots:CAR', np.vstack([polyline((0, 0), (2, 0)),  # a car's cusp: stop, reverse
                                   polyline((2, 0), (0.8, 0))[1:]])),
])
def test_a_route_is_tracked_to_rest_at_its_end(model, route):
    loop = Loop(model, epsilon=0.05)
    loop.session.following.set_route(route)
    rows = loop.run(14.0)
    error = cross_track_error(rows[:, 1:3], route[:, :2])
    status = loop.session.following.status
    cruise = rows[(rows[:, 0] > 2.0) & (rows[:, 0] < 3.0), 4]
    if model.endswith('CAR'):  # it backed up after the cusp
        assert rows[:, 4].min() < -0.4 and np.abs(rows[:, 3]).max() < 0.01
    print(f'\n{model}: cross-track after 2 s {error[rows[:, 0] > 2].max():.3f} m, speed '
          f'{cruise.min():.3f}-{cruise.max():.3f} m/s, {status.state} at '
          f'{np.hypot(*(rows[-1, 1:3] - route[-1, :2])):.4f} m from the end')
    assert error[rows[:, 0] > 2].max() <= 0.05
    assert np.all(np.abs(cruise - 0.5) <= 0.05)
    assert status.state is GoalState.ARRIVED
    assert np.hypot(*(rows[-1, 1:3] - route[-1, :2])) < 0.02 and abs(rows[-1, 4]) < 0.01


@pytest.mark.solve
def test_a_route_sent_again_changes_nothing_and_a_new_one_keeps_the_speed():
    loop = Loop()
    following = loop.session.following
    route = polyline((0, 0), (6, 0))
    assert following.set_route(route) is not None
    reference = loop.session.planner.reference
    loop.run(3.0)
    assert following.set_route(route.copy()) is None  # Nav2 re-sending its path
    assert loop.session.planner.reference is reference
    speed = loop.run(0.1)[-1, 4]
    x = loop.q[0]
    again = polyline((x, 0.01), (6, 0))  # a new path from near the robot to the same goal
    timed = following.set_route(again)
    assert timed is not None and timed.route.speeds[0] == pytest.approx(speed, abs=0.02)
    rows = loop.run(3.0)
    assert rows[:, 4].min() > 0.45  # it never slowed down for it


@pytest.mark.solve
def test_timed_references_that_cannot_be_meant_are_refused_or_warned():
    loop = Loop()
    loop.ns = 100 * 10**9  # the clock at 100 s
    following, t = loop.session.following, np.linspace(0, 2, 11)
    poses = np.c_[0.25 * t, 0 * t, 0 * t, 0 * t]
    with pytest.raises(ReferenceRejected, match=r'ended 98 s ago.*header stamp of 0'):
        following.set_reference(t, poses, None)  # pose stamps read as absolute: 1970
    following.set_reference(t + 98.5, poses, None)
    assert loop.logs[-1][0] == 'warn' and 'starts 1.5 s before now' in loop.logs[-1][1]
    following.set_reference(t + 161.0, poses, None)
    assert 'starts 61 s after now' in loop.logs[-1][1]
    count = len(loop.logs)
    following.set_reference(t + 100.5, poses, None)  # on time: no word
    assert len(loop.logs) == count
    loop.session.following.route_settings = RouteSettings(reference_speed=0.0)
    with pytest.raises(ReferenceRejected, match='reference_speed is 0'):
        following.set_route(poses)


@pytest.mark.solve
def test_a_route_is_slowed_where_it_would_pass_the_velocity_bounds():
    loop = Loop(v_min=[-0.7, -2.0], v_max=[0.7, 2.0])  # the turn asks for 3 rad/s unbounded
    timed = loop.session.following.set_route(polyline((0, 0), (2, 0), (2, 2)))
    reference = loop.session.planner.reference
    assert np.abs(reference.v[:, 1]).max() <= 2.0 and np.abs(timed.twists[:, 3]).max() <= 2.0
    assert np.median(np.abs(timed.route.speeds)) == pytest.approx(0.5)  # the turn alone


@pytest.mark.solve
def test_a_route_is_slowed_into_the_velocity_bounds_and_a_cancel_brings_it_to_rest():
    loop = Loop(v_max=[0.3, 1.0])
    following = loop.session.following
    timed = following.set_route(polyline((0, 0), (4, 0)))
    assert 0.29 < np.abs(timed.twists[:, 0]).max() <= 0.3
    loop.run(4.0)
    assert loop.v[0] > 0.25
    speed = loop.session.command(loop.ns)[0]  # a cmd_vel sent: a halt slows from it
    following.halt()
    slowing = [loop.session.command(loop.ns + int(i * 0.05e9))[0] for i in range(1, 12)]
    # cmd_vel: slowing at max_decel (1 m/s^2) a command period (0.05 s) at a time, to rest
    assert np.allclose(np.diff([speed, *slowing]), np.maximum(-0.05, -np.array(
        [speed, *slowing[:-1]])), atol=1e-9) and slowing[-1] == 0.0
    rows = loop.run(3.0)
    assert abs(rows[-1, 4]) < 0.05 and following.status.state is GoalState.NONE


@pytest.mark.solve
def test_a_robot_that_cannot_get_on_is_blocked():
    loop = Loop(v_max=[0.3, 1.0], u_max=[0.0, 1.0], u_min=[-1.0, -1.0])  # no push forward
    following = loop.session.following
    following.goal_settings = GoalSettings(movement_time_allowance=2.0)
    following.set_route(polyline((0, 0), (4, 0)))
    loop.run(3.0)
    assert following.status.state is GoalState.BLOCKED


@pytest.mark.solve
def test_a_route_sent_again_after_arriving_is_driven_again_and_new_settings_retime_it():
    loop = Loop()
    following = loop.session.following
    patrol = polyline((0, 0), (2, 0), (2, 1), (0, 1), (0, 0))
    following.set_route(patrol)
    loop.run(16.0)
    assert following.status.state is GoalState.ARRIVED
    assert following.set_route(patrol) is not None  # a patrol sent again: round it again
    assert following.status.remaining == pytest.approx(6.0, abs=0.05)
    loop.run(2.0)
    slower = RouteSettings(reference_speed=0.2)
    following.configure(slower, GoalSettings(xy_goal_tolerance=0.1))
    reference = loop.session.planner.reference  # re-timed at once from where the robot is
    speeds = np.hypot(*np.diff(reference.q[:, :2], axis=0).T) / np.diff(reference.t)
    assert speeds[len(speeds) // 2] == pytest.approx(0.2, rel=0.02)
    assert following.goal_settings.xy_goal_tolerance == 0.1


@pytest.mark.solve
def test_progress_is_judged_across_path_updates_and_a_stop_is_never_refused():
    loop = Loop(v_max=[0.3, 1.0], u_max=[0.0, 1.0], u_min=[-1.0, -1.0])  # no push forward
    following = loop.session.following
    following.goal_settings = GoalSettings(movement_time_allowance=2.0)
    for k in range(6):  # a planner re-sending a slightly different path every 0.5 s
        following.set_route(polyline((0, 0.001 * k), (4, 0)))
        loop.run(0.5)
    assert following.status.state is GoalState.BLOCKED
    moving = Loop()
    moving.session.following.set_route(polyline((0, 0), (4, 0)))
    moving.run(3.0)
    moving.session.planner.update(v_max=[0.2, 1.0])  # lowered under the robot's 0.5 m/s
    moving.session.following.halt()
    assert moving.session.following.halted
    assert moving.session.following.status.state is GoalState.NONE
    assert moving.logs[-1][0] == 'warn' and 'held where it is' in moving.logs[-1][1]


@pytest.mark.solve
@pytest.mark.parametrize('model', ['chaplygin_sleigh', 'rolling_disk'])
def test_stale_odometry_brings_one_braking_plan_that_stops_an_effort_driven_robot(model):
    """Zero effort is no stop: a sleigh given none coasts on, so the brake is renewed."""
    loop = Loop(model, epsilon=0.05)
    loop.session.following.set_route(polyline((0, 0), (8, 0)))
    loop.run(3.0)
    speed = np.linalg.norm(loop.v)
    loop.ns += int(0.6e9)  # odom_timeout is 0.5 s: the last odometry is stale now
    braking = loop.session.replan()
    assert braking.outcome is not None and braking.outcome.status is PlanStatus.BRAKE
    assert 'stale' in braking.outcome.message
    plan = braking.outcome.plan
    rest = nht.simulate(loop.session.system, loop.q, loop.v, plan.t, plan.u)
    print(f'\n{model}: {speed:.3f} -> {np.linalg.norm(rest.v[-1]):.4f} (m/s, rad/s) over '
          f'{plan.t[-1] - plan.t[0]:.1f} s')
    assert np.linalg.norm(rest.v[-1]) < 0.01 * speed
    # braking along itself at max_decel (1 m/s^2), not harder
    twists = PoseMap(loop.session.system).twist_matrices(plan.q) @ plan.v[:, :, None]
    planned = np.hypot(twists[:, 0, 0], twists[:, 1, 0])
    assert (np.diff(planned) >= -1.0 * np.diff(plan.t) * 1.01).all() and planned[-1] < 1e-3
    sent = []
    loop.session.start(sent.append)  # what the robot is sent from here on
    loop.session.stop()
    for _ in range(3):  # planned once per stale episode, renewed at each replan
        again = loop.session.replan()
        assert again.outcome is None and 'stale' in again.reason
    assert len(sent) == 3 and all(result.outcome is braking.outcome for result in sent)
    loop.odometry()
    assert loop.session.replan().outcome.status is not PlanStatus.BRAKE
