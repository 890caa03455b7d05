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

"""Discs crossing the route through ROS: markers re-sent as they move, planner and simulator.

A tracker publishes each disc on ``obstacles`` ten times a second, stamped, where it is; the
planner estimates their velocities and keeps clear of where they will be. Collisions are
counted against the discs' true motion (not the planner's estimate), at every odometry message.
"""
import threading

import numpy as np
import pytest
from visualization_msgs.msg import Marker, MarkerArray

pytestmark = pytest.mark.timeout(240)
ROBOT_RADIUS, INFLATION = 0.2, 0.05
SPEED, DISC_SPEED, DISC_RADIUS = 0.8, 0.3, 0.25
CROSSINGS = 10


class Crossings:
    """Discs crossing a line along +x at DISC_SPEED, each timed to meet the reference there."""

    def __init__(self, seed: int, start: float) -> None:
        rng = np.random.default_rng(seed)
        self.x = 2.0 + 2.0 * np.arange(CROSSINGS)
        self.meet = start + self.x / SPEED + rng.uniform(-0.5, 0.5, CROSSINGS)  # absolute s
        self.side = rng.choice([-1.0, 1.0], CROSSINGS)  # +1: from y < 0 towards y > 0

    def at(self, t: float) -> np.ndarray:
        """Return the discs' centres (CROSSINGS, 2) at time t."""
        return np.c_[self.x, self.side * DISC_SPEED * (t - self.meet)]

    def markers(self, stamp_ns: int) -> MarkerArray:
        centres = self.at(stamp_ns * 1e-9)
        markers = []
        for i, (x, y) in enumerate(centres):
            marker = Marker(ns='crossing', id=i, type=Marker.CYLINDER, action=Marker.ADD)
            marker.header.frame_id = 'odom'
            marker.header.stamp.sec, marker.header.stamp.nanosec = divmod(stamp_ns, 10**9)
            marker.pose.position.x, marker.pose.position.y = float(x), float(y)
            marker.pose.orientation.w = 1.0
            marker.scale.x = marker.scale.y = 2 * DISC_RADIUS
            marker.scale.z = 0.5
            markers.append(marker)
        return MarkerArray(markers=markers)


def test_discs_crossing_the_route_are_passed_without_collision_and_the_robot_arrives(graph):
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
    markers = probe.create_publisher(MarkerArray, 'obstacles', 10)
    reference_pub = probe.create_publisher(Path, 'reference_path', LATCHED)
    assert wait_until(lambda: markers.get_subscription_count() >= 2, 20.0)  # planner and sim
    start = probe.get_clock().now().nanoseconds * 1e-9 + 1.0
    crossings = Crossings(seed=11, start=start)
    probe.create_timer(0.1, lambda: markers.publish(
        crossings.markers(probe.get_clock().now().nanoseconds)))
    length = crossings.x[-1] + 2.0
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
    gaps = np.array([np.hypot(*(crossings.at(s) - xy).T) for s, *xy in track])
    closest = gaps.min(axis=0) - DISC_RADIUS - ROBOT_RADIUS
    late = track[-1, 0] - (start + length / SPEED)
    print(f'\n{CROSSINGS} discs crossing at {DISC_SPEED} m/s: closest approach per disc '
          f'{np.round(closest, 3).tolist()} m; arrived {late:+.1f} s after the reference; '
          f'{planner.planner.stats.fallbacks} fallbacks, {sim.collisions} collisions counted')
    assert closest.min() >= 0.0 and sim.collisions == 0
    assert planner.errors == 0 and sim.errors == 0
    assert closest.max() < 1.0  # each crossing met the robot: the test tests something
