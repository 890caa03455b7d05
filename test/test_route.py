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

"""Untimed routes timed: against closed forms, their own limits, and the pose maps of models."""
import numpy as np
import pytest

from nh_tracking import models
from nh_tracking.core.poses import PoseMap
from nh_tracking.examples.nav2 import polyline
from nh_tracking.navigation.route import RouteHeadings, RouteSettings, time_route
from nh_tracking.navigation.route_shape import closest_point

pytestmark = pytest.mark.unit


def arc(radius: float, sweep: float, spacing=0.05) -> np.ndarray:
    """Poses along a circle about (0, radius) from the origin, heading 0 (unset)."""
    a = np.linspace(0.0, sweep, int(np.ceil(radius * sweep / spacing)) + 1)
    return np.c_[radius * np.sin(a), radius * (1 - np.cos(a)), 0 * a, 0 * a]


def test_a_straight_route_from_rest_takes_the_trapezoid_time():
    s = RouteSettings(reference_speed=0.5, max_accel=0.25)
    route = time_route(polyline((0, 0), (4, 0)), np.zeros(2), 0.0, s)
    # accelerate for v/a, cruise, decelerate for v/a: T = L/v + v/a
    assert route.times[-1] == pytest.approx(4 / 0.5 + 0.5 / 0.25, rel=1e-3)
    assert route.speeds[0] == 0 and route.speeds[-1] == 0 and route.speeds.max() == 0.5
    np.testing.assert_allclose(route.poses[-1, :2], [4, 0])


def test_on_an_arc_the_speed_keeps_the_lateral_acceleration():
    for radius, expected in ((0.4, np.sqrt(0.5 * 0.4)), (3.0, 0.5)):
        route = time_route(arc(radius, np.pi), np.zeros(2), 0.0, RouteSettings())
        middle = np.argmin(np.abs(route.times - route.times[-1] / 2))
        assert route.speeds[middle] == pytest.approx(expected, rel=0.02)
        assert route.headings is RouteHeadings.TANGENT  # unset headings on a turning route
        # the tangent's heading on a circle is the angle swept, a closed form
        swept = np.arctan2(route.poses[middle, 0], radius - route.poses[middle, 1])
        assert route.poses[middle, 3] == pytest.approx(swept, abs=0.01)


def test_speeds_keep_every_limit_on_random_routes():
    rng = np.random.default_rng(4)
    for _ in range(20):
        corners = np.cumsum(rng.uniform(-1.5, 1.5, (int(rng.integers(2, 7)), 2)), axis=0)
        s = RouteSettings(reference_speed=float(rng.uniform(0.1, 2.0)),
                          max_accel=float(rng.uniform(0.1, 2.0)),
                          max_lateral_accel=float(rng.uniform(0.1, 2.0)))
        start_speed = float(rng.uniform(0.0, 1.0))
        route = time_route(polyline(*corners), corners[0], start_speed, s)
        v = np.abs(route.speeds)
        gaps = np.hypot(*np.diff(route.poses[:, :2], axis=0).T)
        assert np.all(np.diff(route.times) > 0) and v[-1] == 0
        assert v.max() <= max(s.reference_speed, start_speed) + 1e-9
        # speed changes within max_accel: v1^2 - v0^2 = 2 a ds
        assert np.all(np.abs(np.diff(v ** 2)) <= 2 * s.max_accel * gaps + 1e-9)
        # each segment is covered at the mean of its end speeds, in the time given
        covered = 0.5 * (v[1:] + v[:-1]) * np.diff(route.times)
        moving = v[1:] + v[:-1] > 1e-9
        np.testing.assert_allclose(covered[moving], gaps[moving], rtol=1e-9)


def test_a_start_speed_is_kept_and_a_robot_beside_the_route_is_taken_to_it():
    s = RouteSettings()
    route = time_route(polyline((0, 0), (6, 0)), np.array([2.0, 0.05]), 0.5, s)
    np.testing.assert_allclose(route.poses[0, :2], [2.0, 0.0], atol=1e-12)
    assert route.speeds[0] == pytest.approx(0.5) and route.length == pytest.approx(4.0)
    # 3 m off (or a single pose far away): straight to the route first, never a jump
    for poses, length in ((polyline((0, 3), (3, 3)), 3.0 + 3.0), (np.array([[5.0, 0, 0, 0]]),
                                                                  5.0)):
        route = time_route(poses, np.zeros(2), 0.0, s)
        np.testing.assert_allclose(route.poses[0, :2], [0, 0], atol=1e-12)
        assert route.length == pytest.approx(length, rel=1e-6)
        assert np.abs(route.speeds).max() <= s.reference_speed
    # a loop ending where it starts is not finished before it begins
    loop = polyline((0, 0), (2, 0), (2, 2), (0, 2), (0, 0))
    assert time_route(loop, np.zeros(2), 0.0, s).length == pytest.approx(8.0)
    assert closest_point(loop[:, :2], np.zeros(2))[0] in (0, len(loop) - 2)


def test_a_cusp_is_a_stop_and_a_reverse_with_the_heading_kept():
    poses = polyline((0, 0), (2, 0), (0.5, 0))  # out and back: a car's three-point turn
    route = time_route(poses, np.zeros(2), 0.0, RouteSettings(route_headings='tangent'))
    assert route.cusps == 1
    cusp = int(np.argmin(np.abs(route.poses[:, 0] - 2.0)))
    assert route.speeds[cusp] == 0
    assert np.all(route.speeds[:cusp] >= 0) and np.all(route.speeds[cusp + 1:] <= 0)
    assert np.abs(route.poses[:, 3]).max() < 1e-9  # facing +x throughout: backing up
    assert np.all(route.twists[cusp + 1:-1, 0] < 0)


def test_headings_come_from_the_poses_when_they_carry_some():
    turning = arc(1.0, np.pi / 2)
    own = turning.copy()
    own[:, 3] = np.linspace(0.3, 0.9, len(own))
    assert time_route(own, np.zeros(2), 0.0, RouteSettings()).headings is RouteHeadings.POSES
    along_x = polyline((0, 0), (3, 0))  # identity orientations on a route along them
    assert time_route(along_x, np.zeros(2), 0.0, RouteSettings()).headings is \
        RouteHeadings.POSES
    for corner in ((0, 3), (-3, 0)):  # identity is unset: a route along y, or back along x
        route = time_route(polyline((0, 0), corner), np.zeros(2), 0.0, RouteSettings())
        assert route.headings is RouteHeadings.TANGENT and np.all(route.speeds >= 0)
        np.testing.assert_allclose(route.poses[:, 3], np.arctan2(corner[1], corner[0]))
    backing = along_x.copy()
    backing[:, 3] = np.pi  # set, all alike, facing back along the route: a reversing car
    route = time_route(backing, np.zeros(2), 0.0, RouteSettings())
    assert route.headings is RouteHeadings.POSES and np.all(route.speeds <= 0)
    forced = time_route(turning, np.zeros(2), 0.0, RouteSettings(route_headings='poses'))
    assert np.abs(forced.poses[:, 3]).max() == 0


def test_a_last_pose_with_a_heading_of_its_own_ends_the_route_with_a_turn_to_it():
    """Take NavFn's paths: every orientation unset but the goal's."""
    navfn = polyline((0, 0), (2, 0), (2, 2))
    navfn[-1, 3] = np.pi
    route = time_route(navfn, np.zeros(2), 0.0, RouteSettings())
    assert route.headings is RouteHeadings.TANGENT
    turn = route.speeds == 0
    turn[0] = False
    assert route.poses[-1, 3] == pytest.approx(np.pi)
    np.testing.assert_allclose(route.poses[turn][:, :2], [[2, 2]] * turn.sum(), atol=1e-12)
    assert np.abs(route.twists[turn, 3]).max() <= 1.0 + 1e-9  # TURN_RATE
    # the turn's rate is the derivative of its heading (trapezoid rule, closed form)
    covered = np.sum(np.diff(route.times[-turn.sum() - 1:])
                     * (route.twists[-turn.sum() - 1:-1, 3] + route.twists[-turn.sum():, 3]) / 2)
    assert covered == pytest.approx(np.pi / 2, rel=1e-3)


def test_a_grid_planners_staircase_is_driven_at_speed():
    steps = [(0.05 * (k // 2 + k % 2), 0.05 * (k // 2)) for k in range(121)]  # 90-degree jogs
    route = time_route(np.c_[np.array(steps), np.zeros((121, 2))], np.zeros(2), 0.0,
                       RouteSettings())
    assert np.median(np.abs(route.speeds)) >= 0.45


def test_a_route_reaches_the_pose_map_of_models_it_was_not_written_for():
    """The derived twists, projected onto D, agree with each model's own velocities."""
    route = time_route(arc(1.0, np.pi / 2), np.zeros(2), 0.3, RouteSettings())
    for name in ('unicycle', 'chaplygin_sleigh', 'rolling_disk'):
        pose_map = PoseMap(models.create(name))
        reference = pose_map.reference(route.times, route.poses, route.twists)
        assert np.all(np.isfinite(reference.v))
        # the body twist of each reference state is the route's own (no slip asked for)
        twists = np.array([pose_map.body_twist(q, v) for q, v in zip(reference.q, reference.v)])
        np.testing.assert_allclose(twists[:, [0, 3]], route.twists[:, [0, 3]], atol=1e-6)
