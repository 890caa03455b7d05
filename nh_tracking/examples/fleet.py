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


"""The fleet figure: K robots, each a namespaced planner + simulator in separate processes.

How many robots one machine plans for: K pairs of the installed executables (``planner``,
``sim``), each in its own namespace ``/robot_<i>``, talk over DDS on a domain of their own (the
distributed engine is DDS; nothing home-made), every planner replanning at 10 Hz with a deadline
of one period. For each K: deadline misses and late plans (from the planners' diagnostics), the
CPU each process used (from /proc), and the tracking error — the figure that says how a fleet
spreads over machines. Grows K until a robot misses a deadline.
"""
from __future__ import annotations

from collections.abc import Callable
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry, Path as PathMsg
import numpy as np

from nh_tracking.core.metrics import cross_track_error
from nh_tracking.ros import conversions as cv
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.graph import InProcessGraph, wait_until
from nh_tracking.ros.planner_interface import LATCHED

RADIUS, SPEED = 2.0, 0.5  # every robot tracks a circle at this speed
PERIOD = 0.1  # replanning period, and each solve's deadline
START_MARGIN = 5.0  # [s] from publishing the references to their start
SETTLE = 5.0  # [s] of tracking before the measured window


class Robot:
    """One planner + simulator pair in /robot_<i>, and what the measuring node hears of it."""

    def __init__(self, index: int, env: dict[str, str], node: Any) -> None:
        self.namespace = f'/robot_{index}'
        remap = ['--ros-args', '-r', f'__ns:={self.namespace}']
        start = f'initial_state:=[{RADIUS + 0.2}, 0.0, {math.pi / 2}, 0.0, 0.0]'
        bin_dir = Path(sys.executable).parent
        self.processes = [
            subprocess.Popen([str(bin_dir / 'sim'), *remap, '-p', start], env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL),
            subprocess.Popen([str(bin_dir / 'planner'), *remap, '-p',
                              f'replan_period:={PERIOD}', '-p', f'max_solve_time:={PERIOD}'],
                             env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
        self.odom: list[tuple[float, float, float]] = []
        self.health: dict[str, str] = {}
        node.create_subscription(Odometry, f'{self.namespace}/odom', self._on_odom, 10)
        self.reference = node.create_publisher(PathMsg, f'{self.namespace}/reference_path',
                                               LATCHED)

    def _on_odom(self, msg: Odometry) -> None:
        p = msg.pose.pose.position
        self.odom.append((cv.stamp_ns(msg.header.stamp) * 1e-9, p.x, p.y))

    def cpu_seconds(self) -> float:
        """User + system CPU time of the pair so far."""
        total = 0.0
        for proc in self.processes:
            fields = Path(f'/proc/{proc.pid}/stat').read_text().rsplit(')', 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
        return total

    def counts(self) -> dict[str, int]:
        keys = ('plans', 'deadline_misses', 'shifted', 'fallbacks')
        return {k: int(self.health.get(k, 0)) for k in keys}

    def stop(self) -> None:
        for proc in self.processes:
            proc.send_signal(signal.SIGINT)
        for proc in self.processes:
            try:
                proc.wait(20.0)
            except subprocess.TimeoutExpired:
                proc.kill()


def circle(start_ns: int, duration: float, dt: float = 0.1) -> tuple[PathMsg, np.ndarray]:
    t = np.arange(0.0, duration, dt)
    angle = SPEED / RADIUS * t
    poses = np.stack([RADIUS * np.cos(angle), RADIUS * np.sin(angle), 0 * t,
                      angle + math.pi / 2], axis=1)
    return msgs.path_msg('odom', [start_ns + int(round(s * 1e9)) for s in t], poses), poses[:, :2]


def run_fleet(size: int, domain: int, duration: float, log: Callable[[str], None]) -> dict:
    """K = ``size`` pairs for ``duration`` seconds of tracking; their misses and CPU."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    graph = InProcessGraph(domain_id=domain)
    node = graph.plain_node('fleet_monitor')
    robots = [Robot(i, env, node) for i in range(size)]
    lock = threading.Lock()

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            for robot in robots:
                if status.hardware_id.startswith(robot.namespace + '/'):
                    with lock:
                        robot.health = {kv.key: kv.value for kv in status.values}

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 100)
    try:
        if not wait_until(lambda: all(r.odom and r.health for r in robots), 120.0):
            raise RuntimeError(f'{size} robots did not all come up within 120 s')
        # one reference for all, as long as the run, starting a margin after now (the wall
        # clock all processes share), so that no robot is behind its reference before its
        # planner has it: with a 6000-pose path built per robot, the K = 8 planners got theirs
        # 7-24 s after publishing began, and chased it at 5 m/s, one to 92 m off and back
        start_ns = node.get_clock().now().nanoseconds + int(START_MARGIN * 1e9)
        reference, path = circle(start_ns, START_MARGIN + SETTLE + duration + 30.0)
        for robot in robots:
            robot.reference.publish(reference)
        if not wait_until(lambda: all(r.counts()['plans'] > 0 for r in robots), 60.0):
            raise RuntimeError(f'{size} planners did not all plan within 60 s')
        first_plans = time.time_ns()  # the diagnostics lag: this bounds the first plans' time
        time.sleep(max(0.0, (start_ns - time.time_ns()) * 1e-9) + SETTLE)
        before = [(r.counts(), r.cpu_seconds()) for r in robots]
        started = time.monotonic()
        time.sleep(duration)
        wall = time.monotonic() - started
        time.sleep(1.5)  # one more diagnostics message after the window
        rows = []
        for robot, (counts, cpu) in zip(robots, before):
            now = robot.counts()
            track = np.array(robot.odom[-50:])
            rows.append({
                **{k: now[k] - counts[k] for k in now},
                'cpu_percent': 100.0 * (robot.cpu_seconds() - cpu) / wall,
                'cross_track_error': float(cross_track_error(track[:, 1:], path).max()),
                'solve_p99_ms': float(robot.health.get('solve_time_p99_ms', 'nan'))})
    finally:
        for robot in robots:
            robot.stop()
        graph.close()
    misses = sum(r['deadline_misses'] + r['shifted'] + r['fallbacks'] for r in rows)
    result = {'robots': size, 'misses': misses,
              'planning_before_reference_start_s': (start_ns - first_plans) * 1e-9,
              'plans': sum(r['plans'] for r in rows),
              'cpu_percent_per_robot': float(np.mean([r['cpu_percent'] for r in rows])),
              'worst_cross_track_error': max(r['cross_track_error'] for r in rows),
              'worst_solve_p99_ms': max(r['solve_p99_ms'] for r in rows), 'per_robot': rows}
    log(f"  K = {size}: {result['plans']} plans, {misses} late or failed; CPU per robot "
        f"{result['cpu_percent_per_robot']:.0f} % of a core; worst p99 solve "
        f"{result['worst_solve_p99_ms']:.1f} ms; worst cross-track error "
        f"{result['worst_cross_track_error']:.3f} m; every planner had its reference "
        f"{result['planning_before_reference_start_s']:.1f} s before it started")
    return result


def fleet(log: Callable[[str], None], sizes: tuple[int, ...] = (1, 2, 4, 8, 12, 16),
          duration: float = 20.0) -> dict:
    """Grow the fleet until a robot misses a deadline; the largest K that never did."""
    out: dict[str, Any] = {'cores': os.cpu_count(), 'replan_hz': 1.0 / PERIOD, 'sizes': []}
    for size in sizes:
        row = run_fleet(size, 120 + size, duration, log)
        out['sizes'].append(row)
        if row['misses']:
            break
    clean = [r['robots'] for r in out['sizes'] if not r['misses']]
    out['largest_without_misses'] = max(clean, default=0)
    log(f"  largest fleet without a miss on {out['cores']} cores: "
        f"{out['largest_without_misses']} robots")
    return out
