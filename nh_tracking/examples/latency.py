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

"""ROS latency for the benchmark: odometry receipt to control_sequence publish.

Deployed (the planner executable in a process of its own, as users run it) and in one process
with the odometry's source (where the figure can be split into solver, planner and ROS layer).
"""
from __future__ import annotations

from collections.abc import Callable
import os
from pathlib import Path
import signal
import subprocess
import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry, Path as PathMsg
import numpy as np

from nh_tracking import models
from nh_tracking.core.metrics import percentiles_ms
from nh_tracking.core.poses import PoseMap
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.examples.demo import ClosedLoop, sleigh_reference
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.graph import InProcessGraph, wait_until
from nh_tracking.ros.planner_interface import LATCHED
from nh_tracking.ros.runner import responsive_threads


REAL_TIME = {'iterations': 1}  # the planner's fastest mode: one Gauss-Newton step a replan
DOMAIN = 139  # the deployed measurement's own DDS domain


def _replay(node: Any, reference: Trajectory, pose_map: PoseMap, rate: float) -> None:
    """Publish on ``odom`` the odometry of a robot on ``reference``, started now (wall clock)."""
    pub = node.create_publisher(Odometry, 'odom', 10)
    t0 = time.monotonic()

    def publish() -> None:
        q, v = reference.at(time.monotonic() - t0)
        pub.publish(msgs.odometry_msg('odom', 'base_link', node.get_clock().now().nanoseconds,
                                      pose_map.pose(q), pose_map.body_twist(q, v)))

    node.create_timer(1.0 / rate, publish)


def deployed_latency(log: Callable[[str], None], duration: float = 8.0, rate: float = 100.0
                     ) -> dict:
    """Measure the same figure from the ``planner`` executable, read from its /diagnostics.

    Odometry replayed at ``rate`` Hz from this process; each diagnostics message gives the
    percentiles over the planner's last 200 plans; the figures are their medians (p99: worst).
    """
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    health: list[dict[str, str]] = []
    graph = InProcessGraph(domain_id=DOMAIN)
    planner = subprocess.Popen(
        [str(Path(sys.executable).parent / 'planner'), '--ros-args', '-r', '__ns:=/latency',
         '-p', 'replan_on_odom:=true', '-p', 'replan_period:=60.0',
         '-p', f"iterations:={REAL_TIME['iterations']}"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        node = graph.plain_node('odometry_replay', '/latency')

        def on_diagnostics(msg: DiagnosticArray) -> None:
            health.extend({kv.key: kv.value for kv in s.values} for s in msg.status
                          if s.hardware_id.startswith('/latency/'))

        node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
        reference_pub = node.create_publisher(PathMsg, 'reference_path', LATCHED)
        if not wait_until(lambda: bool(health) or planner.poll() is not None, 60.0) or (
                planner.poll() is not None):
            raise RuntimeError(f'the planner did not come up within 60 s (exit {planner.poll()})')
        reference, pose_map = sleigh_reference(duration + 30.0), PoseMap(models.create(
            'chaplygin_sleigh'))
        start = node.get_clock().now().nanoseconds * 1e-9
        reference_pub.publish(msgs.reference_message(reference, pose_map, start, 'path'))
        _replay(node, reference, pose_map, rate)
        time.sleep(3.0)  # the planner's recent plans all made on this odometry
        del health[:]
        time.sleep(duration)
        window = [h for h in health if int(h.get('plans', 0)) > 0]
    finally:
        planner.send_signal(signal.SIGINT)
        try:
            planner.wait(20.0)
        except subprocess.TimeoutExpired:
            planner.kill()
        graph.close()
    if not window:
        raise RuntimeError('the planner made no plans on the replayed odometry')

    def figures(name: str) -> dict[str, float]:
        return {'p50': float(np.median([float(h[f'{name}_p50_ms']) for h in window])),
                'p99': max(float(h[f'{name}_p99_ms']) for h in window)}

    result: dict[str, Any] = {'odometry_rate_hz': rate, 'reports': len(window),
                              'latency_ms': figures('latency'), 'solve_ms': figures('solve_time')}
    log(f"  deployed (planner process): latency p50 {result['latency_ms']['p50']:.2f} ms, p99 "
        f"{result['latency_ms']['p99']:.2f} ms (solve p50 {result['solve_ms']['p50']:.2f} ms)")
    return result


def ros_latency(log: Callable[[str], None], duration: float = 6.0, rate: float = 100.0) -> dict:
    """Measure the latency from odometry receipt to the control sequence's publication.

    The planner replans on every odometry message (``replan_on_odom``, in its fastest mode: one
    real-time iteration per replan) of a robot driving the reference, replayed at ``rate`` Hz
    on the wall clock by a node in the same process (whose executor shares the interpreter);
    the figures say how much of the latency is not the solve.
    """
    reference = sleigh_reference(duration + 30.0)
    responsive_threads()
    with InProcessGraph() as graph:
        loop = ClosedLoop(graph, namespace='/bench', planner_overrides={
            'use_sim_time': False, 'replan_on_odom': True, 'replan_period': 60.0,
            **REAL_TIME})
        planner = loop.planner
        # the reference starts now on the wall clock, and so does the robot
        loop.send_reference(reference, 'path', start=planner.get_clock().now().nanoseconds * 1e-9)
        _replay(graph.plain_node('odometry_replay', '/bench'), reference, planner.pose_map, rate)
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
