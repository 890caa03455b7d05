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

"""``nh-tracking demo --scenario nav2``: driven as Nav2 drives a controller.

A differential-drive robot (config/diff_drive.yaml's settings) gets a ``follow_path`` goal
whose path is what a Nav2 planner publishes — a pose every 5 cm, every stamp and orientation
unset, a sharp 90-degree turn — past a block in a costmap inflated as Nav2's inflation layer
does it. Planner and simulator in one process, on the wall clock.
"""
from __future__ import annotations

from collections.abc import Callable
import json
from pathlib import Path
import time

from nav_msgs.msg import OccupancyGrid, Odometry
import numpy as np
from rclpy.action import ActionClient

from nh_tracking.core.metrics import cross_track_error
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.graph import InProcessGraph, parameters, wait_until
from nh_tracking.ros.obstacle_messages import LETHAL
from nh_tracking.ros.planner_node import LATCHED, PlannerNode
from nh_tracking.ros.runner import responsive_threads
from nh_tracking.ros.simulator_node import SimulatorNode

ROBOT_RADIUS = 0.2
SETTINGS = {'model': 'unicycle', 'epsilon': 0.05, 'robot_radius': ROBOT_RADIUS,  # diff_drive.yaml
            'v_min': [-0.7, -3.0], 'v_max': [0.7, 3.0]}
BLOCK = (2.35, 0.5, 2.65, 0.8)  # x0, y0, x1, y1 [m]: 0.35 m beside the second leg
INSCRIBED, INFLATED = 99, 98  # Nav2's published costs next to lethal (100)


def polyline(*corners: tuple[float, float], spacing: float = 0.05) -> np.ndarray:
    """Poses (N, 4) every ``spacing`` along straight legs between ``corners``, heading unset."""
    ends = np.asarray(corners, dtype=float)
    points = [ends[0]]
    for a, b in zip(ends, ends[1:]):
        count = max(1, int(np.ceil(np.hypot(*(b - a)) / spacing)))
        points += [a + (b - a) * f for f in np.arange(1, count + 1) / count]
    xy = np.array(points)
    return np.c_[xy, np.zeros((len(xy), 2))]


def nav2_costmap(blocks: list[tuple[float, float, float, float]], robot_radius: float,
                 inflation: float = 0.55, scaling: float = 3.0, resolution: float = 0.05,
                 origin: tuple[float, float] = (-1.0, -2.0), size: tuple[int, int] = (140, 80)
                 ) -> OccupancyGrid:
    """Return a costmap as Nav2 publishes one around rectangles (x0, y0, x1, y1).

    Lethal (100) inside, inscribed (99) within the robot's radius, then 98..1 falling as
    exp(-scaling (d - radius)) out to ``inflation``: what its inflation layer grades.
    """
    grid = OccupancyGrid()
    grid.header.frame_id = 'odom'
    grid.info.resolution, (grid.info.width, grid.info.height) = resolution, size
    grid.info.origin.position.x, grid.info.origin.position.y = origin
    grid.info.origin.orientation.w = 1.0
    x = origin[0] + (np.arange(size[0]) + 0.5) * resolution
    y = origin[1] + (np.arange(size[1]) + 0.5) * resolution
    xx, yy = np.meshgrid(x, y)
    distance = np.full(xx.shape, np.inf)
    for x0, y0, x1, y1 in blocks:
        dx = np.maximum(np.maximum(x0 - xx, xx - x1), 0)
        dy = np.maximum(np.maximum(y0 - yy, yy - y1), 0)
        distance = np.minimum(distance, np.hypot(dx, dy))
    graded = 1 + 97 * np.exp(-scaling * (distance - robot_radius))
    cost = np.where(distance <= inflation, np.minimum(graded, INFLATED), 0)
    cost = np.where(distance <= robot_radius, INSCRIBED, cost)
    cost = np.where(distance == 0, LETHAL, cost)
    grid.data = [int(c) for c in cost.ravel()]
    return grid


def route_msg(poses: np.ndarray, stamp_ns: int = 0):
    """Return a Path as Nav2's planners publish it: every pose with the header's stamp."""
    msg = msgs.path_msg('odom', [stamp_ns] * len(poses), poses)
    msg.header.stamp = msgs.time_msg(stamp_ns)
    return msg


def run_nav2_demo(out: Path, log: Callable[[str], None] = print) -> dict:
    """Send the goal, follow it to its result; write nav2.png and nav2.json."""
    from nav2_msgs.action import FollowPath

    from nh_tracking.examples.plotting import plot_route

    out.mkdir(parents=True, exist_ok=True)
    route = polyline((0, 0), (2, 0), (2, 2))
    responsive_threads()
    with InProcessGraph() as graph:
        graph.add(SimulatorNode, parameter_overrides=parameters(
            model='unicycle', robot_radius=ROBOT_RADIUS))
        planner = graph.add(PlannerNode, parameter_overrides=parameters(**SETTINGS))
        node = graph.plain_node('nav2_demo')
        odometry: list[tuple[float, float, float, float]] = []

        def on_odom(m: Odometry) -> None:
            odometry.append((time.monotonic(), m.pose.pose.position.x, m.pose.pose.position.y,
                             m.twist.twist.linear.x))
        node.create_subscription(Odometry, 'odom', on_odom, 100)
        costmap = nav2_costmap([BLOCK], ROBOT_RADIUS)
        node.create_publisher(OccupancyGrid, 'costmap', LATCHED).publish(costmap)
        client = ActionClient(node, FollowPath, 'follow_path')
        assert client.wait_for_server(30.0), 'no follow_path action'
        feedback: list[tuple[float, float]] = []
        start = time.monotonic()
        sent = graph.call(
            client.send_goal_async, FollowPath.Goal(path=route_msg(route)),
            feedback_callback=lambda f: feedback.append(
                (time.monotonic() - start, f.feedback.distance_to_goal)))
        assert wait_until(sent.done, 30.0) and sent.result().accepted
        result = graph.call(sent.result().get_result_async)
        while not wait_until(result.done, 1.0) and time.monotonic() - start < 60.0:
            if feedback:
                log(f't = {feedback[-1][0]:5.1f} s | distance to goal {feedback[-1][1]:.2f} m')
        wait_until(lambda: False, 2.0)  # the robot coming to rest after "arrived"
        code = result.result().result.error_code if result.done() else -1
        arrived = feedback[-1][0] if feedback else float('nan')
        stats = planner.planner.stats
    track = np.array(odometry)
    track[:, 0] -= start
    moving = track[track[:, 0] > 2.0]
    error = cross_track_error(moving[:, 1:3], route[:, :2])
    summary = {'error_code': int(code), 'arrived_after_s': arrived,
               'max_cross_track_error_after_2s': float(error.max()),
               'final_distance_to_goal': float(np.hypot(*(track[-1, 1:3] - route[-1, :2]))),
               'max_speed': float(track[:, 3].max()), 'plans': stats.plans,
               'fallbacks': stats.fallbacks}
    figure = plot_route(route, track, np.array(feedback), BLOCK, ROBOT_RADIUS,
                        out / 'nav2.png')
    (out / 'nav2.json').write_text(json.dumps(summary, indent=2))
    log(f'result {code} (0: arrived) after {arrived:.1f} s; cross-track after 2 s at most '
        f"{summary['max_cross_track_error_after_2s']:.3f} m; at rest "
        f"{summary['final_distance_to_goal']:.3f} m from the goal")
    log(f"wrote {figure} and {out / 'nav2.json'}")
    return summary
