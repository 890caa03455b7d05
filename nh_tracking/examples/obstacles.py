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

"""``nh-tracking demo --scenario obstacles``: a line through two obstacles, torques limited.

A differential-drive robot (the dynamic unicycle) tracks a straight Path at 0.5 m/s with two
discs lying on it, its accelerations limited to |u| <= 0.15; the obstacles reach the planner as
markers on ``obstacles`` or as a Nav2-style OccupancyGrid on ``costmap``.
"""
from __future__ import annotations

from collections.abc import Callable
from functools import partial
import json
from pathlib import Path
import threading
import time

from geometry_msgs.msg import Pose
from nav_msgs.msg import OccupancyGrid, Odometry
from nav_msgs.msg import Path as PathMsg
import numpy as np
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from nh_tracking import models
from nh_tracking.core.metrics import cross_track_error
from nh_tracking.core.poses import PoseMap
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.ros import conversions as cv
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.graph import InProcessGraph, parameters, wait_until
from nh_tracking.ros.markers import obstacle_markers
from nh_tracking.ros.planner_node import LATCHED, PlannerNode
from nh_tracking.ros.simulator_node import SimulatorNode

OBSTACLES = np.array([(3.0, 0.05, 0.3), (6.0, -0.05, 0.3)])  # x, y, r [m], on the line
ROBOT_RADIUS = 0.2
INFLATION = 0.05  # [m] the planner keeps this much more: plans hold clearance at knots and
# midpoints only, and a path can cut a little inside between them (Nav2 inflates likewise)
U_LIMIT = 0.15  # |linear and angular acceleration|: active while swerving
SPEED = 0.5
START = 1.0  # simulated s when the robot and the reference set off
HORIZON = 5.0  # [s]: long enough to see a way around an obstacle, not just to brake
LIMITS = {'u_min': [-U_LIMIT], 'u_max': [U_LIMIT]}


def line_reference(duration: float) -> Trajectory:
    t = np.linspace(0.0, duration, int(round(duration / 0.1)) + 1)
    q = np.c_[SPEED * t, 0 * t, 0 * t]
    return Trajectory(t=t, q=q, v=np.c_[np.full_like(t, SPEED), 0 * t],
                      u=np.zeros((len(t) - 1, 2)))


def costmap_msg(frame: str, discs: np.ndarray, resolution: float = 0.05) -> OccupancyGrid:
    """Return a 12 m x 3 m grid from (-1, -1.5): lethal (100) inside the discs, else free."""
    grid = OccupancyGrid()
    grid.header.frame_id = frame
    width, height = int(12 / resolution), int(3 / resolution)
    grid.info.resolution, grid.info.width, grid.info.height = resolution, width, height
    grid.info.origin = Pose()
    grid.info.origin.position.x, grid.info.origin.position.y = -1.0, -1.5
    grid.info.origin.orientation.w = 1.0
    x = -1.0 + (np.arange(width) + 0.5) * resolution
    y = -1.5 + (np.arange(height) + 0.5) * resolution
    xx, yy = np.meshgrid(x, y)
    inside = np.zeros_like(xx, dtype=bool)
    for cx, cy, r in discs:
        inside |= np.hypot(xx - cx, yy - cy) <= r
    grid.data = np.where(inside, 100, 0).astype(np.int8).ravel().tolist()
    return grid


def _subscribed(publisher) -> bool:
    return publisher.get_subscription_count() > 0


class ObstacleLoop:
    """Planner and simulator (sim time) with the limits; a probe sends the obstacles."""

    def __init__(self, graph: InProcessGraph, namespace: str, time_scale: float = 2.0) -> None:
        self.graph, self.namespace, self.time_scale = graph, namespace, time_scale
        self.pose_map = PoseMap(models.unicycle())
        self.planner = graph.add(PlannerNode, namespace=namespace, parameter_overrides=parameters(
            model='unicycle', use_sim_time=True, horizon=HORIZON, steps=int(HORIZON * 10),
            robot_radius=ROBOT_RADIUS + INFLATION, **LIMITS))
        self.sim: SimulatorNode | None = None
        self.probe = graph.plain_node('obstacle_probe', namespace)
        self._lock = threading.Lock()
        self.odometry: list[tuple[float, np.ndarray]] = []
        self.efforts: list[tuple[float, np.ndarray]] = []
        self.probe.create_subscription(Odometry, 'odom', self._on_odom, 100)
        self.probe.create_subscription(JointTrajectory, 'control_sequence', self._on_controls,
                                       10)
        self.reference_pub = self.probe.create_publisher(PathMsg, 'reference_path', LATCHED)
        self.marker_pub = self.probe.create_publisher(MarkerArray, 'obstacles', 10)
        self.costmap_pub = self.probe.create_publisher(OccupancyGrid, 'costmap', 10)

    def _on_odom(self, msg: Odometry) -> None:
        stamp, pose, _ = cv.odom_to_arrays(msg, 'odom')
        with self._lock:
            self.odometry.append((stamp * 1e-9, pose))

    def _on_controls(self, msg: JointTrajectory) -> None:
        start, _, efforts = cv.controls_to_arrays(msg, ('linear_acceleration',
                                                        'angular_acceleration'))
        with self._lock:
            self.efforts.append((start * 1e-9, efforts[0]))

    def start(self, reference: Trajectory, kind: str) -> None:
        """Send the obstacles (``markers`` or ``costmap``) and the reference; start the robot."""
        pub = self.marker_pub if kind == 'markers' else self.costmap_pub
        for p in (pub, self.reference_pub):
            if not wait_until(partial(_subscribed, p), 10.0):
                raise RuntimeError(f'the planner did not subscribe to {p.topic_name}')
        message = (MarkerArray(markers=obstacle_markers('odom', 0, OBSTACLES))
                   if kind == 'markers' else costmap_msg('odom', OBSTACLES))
        pub.publish(message)
        if not wait_until(lambda: len(self.planner.live.obstacles) > 0, 10.0):
            raise RuntimeError('the planner did not take the obstacles')
        self.reference_pub.publish(msgs.reference_message(reference, self.pose_map, START, 'path'))
        if not wait_until(lambda: self.planner.planner.reference is not None, 10.0):
            raise RuntimeError('the planner did not take the reference')
        self.sim = self.graph.add(SimulatorNode, namespace=self.namespace,
                                  parameter_overrides=parameters(
                                      model='unicycle', publish_clock=True, rate=50.0,
                                      initial_state=[0.0, 0.0, 0.0, SPEED, 0.0],
                                      time_scale=self.time_scale, start_time=START,
                                      robot_radius=ROBOT_RADIUS, **LIMITS))
        pub.publish(message)  # the simulator listens too: it counts collisions

    def sim_time(self) -> float:
        with self._lock:
            return self.odometry[-1][0] if self.odometry else 0.0

    def record(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return (odometry times, positions (M, 2), control times, efforts (K, 2)) so far."""
        with self._lock:
            odom, efforts = list(self.odometry), list(self.efforts)
        return (np.array([t for t, _ in odom]), np.array([p[:2] for _, p in odom]),
                np.array([t for t, _ in efforts]), np.array([e for _, e in efforts]))


def run(graph: InProcessGraph, kind: str, duration: float, namespace: str = '/obstacles',
        time_scale: float = 2.0) -> tuple[ObstacleLoop, Trajectory]:
    """Close the loop for ``duration`` simulated seconds (bounded wall time)."""
    reference = line_reference(duration + 10.0)
    loop = ObstacleLoop(graph, namespace, time_scale)
    loop.start(reference, kind)
    wait_until(lambda: loop.sim_time() >= START + duration, 30.0 + 5.0 * duration / time_scale)
    return loop, reference


def run_obstacle_demo(out: Path, duration: float = 20.0, kind: str = 'markers',
                      log: Callable[[str], None] = print) -> dict:
    """Write obstacles.png (obstacles, reference, driven path, saturation) and obstacles.json."""
    from nh_tracking.examples.plotting import plot_obstacles

    out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    with InProcessGraph() as graph:
        loop, reference = run(graph, kind, duration)
        t, xy, tu, u = loop.record()
        assert loop.sim is not None
        collisions = loop.sim.collisions
        stats = loop.planner.planner.stats
    error = cross_track_error(xy, reference.q[:, :2])
    settled = t >= t[-1] - 3.0  # the last 3 s, well past the obstacles
    summary = {
        'obstacles_via': kind, 'duration': float(t[-1] - START), 'collisions': collisions,
        'max_abs_effort': float(np.abs(u).max()), 'effort_limit': U_LIMIT,
        'saturated_fraction': float(np.mean(np.abs(u) >= U_LIMIT - 1e-6)),
        'cross_track_error_last_3s': float(error[settled].max()),
        'closest_approach': float(min(np.hypot(*(xy - c[:2]).T).min() - c[2]
                                      for c in OBSTACLES)),
        'plans': stats.plans, 'fallbacks': stats.fallbacks,
        'wall_time_s': time.monotonic() - started,
    }
    figure = plot_obstacles(reference, OBSTACLES, ROBOT_RADIUS, xy, tu - START, u, U_LIMIT,
                            out / 'obstacles.png')
    (out / 'obstacles.json').write_text(json.dumps(summary, indent=2))
    log(f"{collisions} collisions, closest approach {summary['closest_approach']:.3f} m "
        f"(robot radius {ROBOT_RADIUS} m), max |u| {summary['max_abs_effort']:.3f} "
        f'(limit {U_LIMIT}), cross-track error over the last 3 s '
        f"{summary['cross_track_error_last_3s']:.4f} m")
    log(f"wrote {figure} and {out / 'obstacles.json'}")
    return summary
