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

"""Discs on and across the route through ROS: planner and simulator nodes, a tracker's markers.

A tracker publishes each disc on ``obstacles`` ten times a second, stamped, where it is; the
planner estimates the velocities of moving ones and keeps clear of where they will be.
Collisions are counted against the discs' true motion (not the planner's estimate), at every
odometry message.
"""
import threading

import numpy as np
import pytest
from visualization_msgs.msg import Marker, MarkerArray

pytestmark = pytest.mark.timeout(240)
ROBOT_RADIUS, INFLATION = 0.2, 0.05
SPEED, DISC_SPEED, DISC_RADIUS = 0.8, 0.3, 0.25  # [m/s], [m/s], [m]
CROSSINGS = 10


class Crossings:
    """Discs crossing a line along +x at DISC_SPEED, each timed to meet the reference there."""

    def __init__(self, seed: int, start: float) -> None:
        rng = np.random.default_rng(seed)
        self.x = 2.0 + 2.0 * np.arange(CROSSINGS)
        self.meet = start + self.x / SPEED + rng.uniform(-0.5, 0.5, CROSSINGS)  # absolute s
        self.side = rng.choice([-1.0, 1.0], CROSSINGS)  # +1: from y < 0 towards y > 0
        self.radius = np.full(CROSSINGS, DISC_RADIUS)

    def at(self, t: float) -> np.ndarray:
        """Return the discs' centres (CROSSINGS, 2) at time t."""
        return np.c_[self.x, self.side * DISC_SPEED * (t - self.meet)]


class Standing:
    """Discs (x, y, r) at rest: markers stamped 0."""

    def __init__(self, discs) -> None:
        self.discs = np.array(discs, dtype=float).reshape(-1, 3)
        self.radius = self.discs[:, 2]

    def at(self, t: float) -> np.ndarray:
        return self.discs[:, :2]


def markers(discs, stamp_ns: int) -> MarkerArray:
    """Return the discs as a tracker sends them: cylinders by id, where they are at the stamp."""
    out = []
    for i, ((x, y), r) in enumerate(zip(discs.at(stamp_ns * 1e-9), discs.radius)):
        marker = Marker(ns='tracked', id=i, type=Marker.CYLINDER, action=Marker.ADD)
        marker.header.frame_id = 'odom'
        if not isinstance(discs, Standing):
            marker.header.stamp.sec, marker.header.stamp.nanosec = divmod(stamp_ns, 10**9)
        marker.pose.position.x, marker.pose.position.y = float(x), float(y)
        marker.pose.orientation.w = 1.0
        marker.scale.x = marker.scale.y = 2 * float(r)
        marker.scale.z = 0.5
        out.append(marker)
    return MarkerArray(markers=out)


def drive(graph, discs_at_start, length: float):
    """Follow a line of ``length`` m at SPEED past discs; (track (t, x, y), start, planner, sim).

    ``discs_at_start(start)``: the discs, given the reference's start (absolute s); sent ten
    times a second. Until the robot is within 0.3 m of the end (bounded).
    """
    from nav_msgs.msg import Odometry, Path

    from nh_tracking import models
    from nh_tracking.poses import PoseMap
    from nh_tracking.ros import conversions as cv
    from nh_tracking.ros import messages as msgs
    from nh_tracking.ros.graph import parameters, wait_until
    from nh_tracking.ros.planner_node import LATCHED, PlannerNode
    from nh_tracking.ros.simulator_node import SimulatorNode
    from nh_tracking.trajectory import Trajectory
    from test_ros import unique_namespace

    ns = unique_namespace()
    sim = graph.add(SimulatorNode, namespace=ns, parameter_overrides=parameters(
        model='unicycle', robot_radius=ROBOT_RADIUS))
    planner = graph.add(PlannerNode, namespace=ns, parameter_overrides=parameters(
        model='unicycle', robot_radius=ROBOT_RADIUS + INFLATION))
    probe = graph.plain_node('tracker', ns)
    lock, odometry = threading.Lock(), []

    def on_odom(msg: Odometry) -> None:
        stamp, pose, _ = cv.odom_to_arrays(msg, 'odom')
        with lock:
            odometry.append((stamp * 1e-9, pose[0], pose[1]))

    probe.create_subscription(Odometry, 'odom', on_odom, 100)
    obstacles = probe.create_publisher(MarkerArray, 'obstacles', 10)
    reference_pub = probe.create_publisher(Path, 'reference_path', LATCHED)
    assert wait_until(lambda: obstacles.get_subscription_count() >= 2, 20.0)  # planner, sim
    start = probe.get_clock().now().nanoseconds * 1e-9 + 1.0
    discs = discs_at_start(start)
    probe.create_timer(0.1, lambda: obstacles.publish(
        markers(discs, probe.get_clock().now().nanoseconds)))
    t = np.linspace(0.0, length / SPEED, int(length / SPEED * 10) + 1)
    line = Trajectory(t=t, q=np.c_[SPEED * t, 0 * t, 0 * t],
                      v=np.c_[np.full_like(t, SPEED), 0 * t], u=np.zeros((len(t) - 1, 2)))
    reference_pub.publish(msgs.reference_message(line, PoseMap(models.unicycle()), start, 'path'))

    def arrived() -> bool:
        with lock:
            return bool(odometry) and odometry[-1][1] > length - 0.3
    assert wait_until(arrived, length / SPEED + 30.0), odometry[-1:]
    with lock:
        track = np.array(odometry)
    gaps = np.array([np.hypot(*(discs.at(s) - xy).T) for s, *xy in track]).reshape(len(track), -1)
    closest = gaps.min(axis=0, initial=np.inf) - discs.radius - ROBOT_RADIUS
    assert planner.errors == 0 and sim.errors == 0
    return closest, track[-1, 0] - start, planner, sim


def test_discs_crossing_the_route_are_passed_without_collision_and_the_robot_arrives(graph):
    length = 2.0 + 2.0 * CROSSINGS
    closest, took, planner, sim = drive(graph, lambda start: Crossings(11, start), length)
    print(f'\n{CROSSINGS} discs crossing at {DISC_SPEED} m/s: closest approach per disc '
          f'{np.round(closest, 3).tolist()} m; arrived {took - length / SPEED:+.1f} s after '
          f'the reference; {planner.planner.stats.fallbacks} fallbacks, {sim.collisions} '
          'collisions counted')
    assert closest.min() >= 0.0 and sim.collisions == 0
    assert closest.max() < 1.0  # each crossing met the robot: the test tests something


def test_a_disc_centred_on_the_route_is_got_past_in_at_most_half_again_the_time(graph):
    length = 6.0
    _, free, _, _ = drive(graph, lambda start: Standing([]), length)
    closest, took, planner, sim = drive(graph, lambda start: Standing([(3.0, 0.0, 0.3)]),
                                        length)
    print(f'\na disc centred on the route: arrived after {took:.1f} s ({free:.1f} s without '
          f'it), closest approach {closest[0]:.3f} m, {sim.collisions} collisions counted')
    assert took <= 1.5 * free and closest[0] >= 0.0 and sim.collisions == 0
