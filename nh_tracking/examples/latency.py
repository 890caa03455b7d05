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

"""ROS latency for the benchmark: odometry receipt to control_sequence publish, in process."""
from __future__ import annotations

from collections.abc import Callable
import time
from typing import Any

from nav_msgs.msg import Odometry
import numpy as np

from nh_tracking.examples.demo import ClosedLoop, sleigh_reference
from nh_tracking.metrics import percentiles_ms
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.graph import InProcessGraph, wait_until
from nh_tracking.ros.runner import responsive_threads


REAL_TIME = {'iterations': 1}  # the planner's fastest mode: one Gauss-Newton step a replan


def ros_latency(log: Callable[[str], None], duration: float = 6.0, rate: float = 100.0) -> dict:
    """Measure the latency from odometry receipt to the control sequence's publication.

    The planner replans on every odometry message (``replan_on_odom``, in its fastest mode:
    compiled, one real-time iteration per replan) of a robot driving the reference, replayed
    at ``rate`` Hz on the wall clock; the figures say how much of the latency is not the solve.

    The odometry is replayed rather than simulated in the same process, so the figure is the
    planner's own pipeline, not its competition for the interpreter with a simulator.
    """
    reference = sleigh_reference(duration + 30.0)
    responsive_threads()
    with InProcessGraph() as graph:
        loop = ClosedLoop(graph, namespace='/bench', planner_overrides={
            'use_sim_time': False, 'replan_on_odom': True, 'replan_period': 60.0,
            **REAL_TIME})
        planner = loop.planner
        replay = graph.plain_node('odometry_replay', '/bench')
        pub = replay.create_publisher(Odometry, 'odom', 10)
        t0 = time.monotonic()  # the reference starts now on the wall clock, and so does the robot
        loop.send_reference(reference, 'path', start=planner.get_clock().now().nanoseconds * 1e-9)

        def publish() -> None:
            q, v = reference.at(time.monotonic() - t0)
            pose_map = planner.pose_map
            pub.publish(cv.odometry_msg('odom', 'base_link', planner.get_clock().now().nanoseconds,
                                        pose_map.pose(q), pose_map.body_twist(q, v)))

        replay.create_timer(1.0 / rate, publish)
        wait_until(lambda: len(planner.live.latencies) > 50, 20.0)
        planner.live.latencies.clear()
        time.sleep(duration)
        samples = np.array(list(planner.live.latencies))
    latency, planning, solve = samples[:, 0], samples[:, 1], samples[:, 2]
    result: dict[str, Any] = {
        'plans': int(len(samples)), 'odometry_rate_hz': rate,
        'latency_ms': percentiles_ms(latency), 'planner_ms': percentiles_ms(planning),
        'solve_ms': percentiles_ms(solve), 'overhead_ms': percentiles_ms(latency - planning),
        'not_in_nlp_solver_ms': percentiles_ms(latency - solve)}
    log(f"  {len(samples)} plans: latency p50 {result['latency_ms']['p50']:.2f} ms, p99 "
        f"{result['latency_ms']['p99']:.2f} ms; numerical planner p50 "
        f"{result['planner_ms']['p50']:.2f} ms (NLP solver {result['solve_ms']['p50']:.2f} ms);"
        f" ROS layer p50 {result['overhead_ms']['p50']:.2f} ms")
    return result
