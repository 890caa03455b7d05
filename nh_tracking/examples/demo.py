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

"""``nh-tracking demo``: planner and simulator closing the loop on the paper's sleigh.

Both run in one process; the simulated robot is 10 % heavier in inertia than the planner's model.
"""
from __future__ import annotations

from collections.abc import Callable
import json
from pathlib import Path
import threading
import time

from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
import numpy as np
from trajectory_msgs.msg import MultiDOFJointTrajectory

from nh_tracking import models
from nh_tracking.core.metrics import cross_track_error, percentiles_ms
from nh_tracking.core.poses import PoseMap
from nh_tracking.core.simulate import simulate
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.examples.experiments import SLEIGH_REFERENCE_START, SLEIGH_START
from nh_tracking.ros import conversions as cv
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.graph import InProcessGraph, parameters, wait_until
from nh_tracking.ros.planner_node import LATCHED, PlannerNode
from nh_tracking.ros.runner import responsive_threads
from nh_tracking.ros.simulator_node import SimulatorNode

START = 1.0  # s on the simulated clock when the robot starts and the reference begins
INERTIA_MISMATCH = 1.10


def sleigh_reference(duration: float) -> Trajectory:
    """Return the uncontrolled sleigh from (0, 1/2, 0; 1/3, 1), sampled every 0.1 s."""
    t = np.linspace(0.0, duration, int(round(duration / 0.1)) + 1)
    return simulate(models.chaplygin_sleigh(), *SLEIGH_REFERENCE_START, t)


class ClosedLoop:
    """A planner and a simulator (10 % heavier than the planner's model) in one graph.

    The simulator, which owns the clock, starts only in :meth:`start`, once the planner is
    built and has the reference: the robot and the reference set off together at START.
    """

    def __init__(self, graph: InProcessGraph, namespace: str = '/demo',
                 planner_overrides: dict | None = None, robot: dict | None = None) -> None:
        """``robot``: the simulated robot's physical parameters (default: J 10 % above)."""
        model = models.chaplygin_sleigh()
        self.graph = graph
        self.pose_map = PoseMap(model)
        self.namespace = namespace
        self.robot = robot or {'J': model.parameters['J'] * INERTIA_MISMATCH}
        self.planner = graph.add(PlannerNode, namespace=namespace, parameter_overrides=parameters(
            **{'use_sim_time': True, **(planner_overrides or {})}))
        self.sim: SimulatorNode | None = None
        self.feeder = graph.plain_node('reference_feeder', namespace)
        self._lock = threading.Lock()
        self.odometry: list[tuple[float, np.ndarray]] = []
        self.feeder.create_subscription(Odometry, 'odom', self._on_odom, 100)
        # latched, as a reference should be: a restarted planner picks it up again
        self.publishers = {'path': self.feeder.create_publisher(PathMsg, 'reference_path',
                                                                LATCHED),
                           'trajectory': self.feeder.create_publisher(
                               MultiDOFJointTrajectory, 'reference_trajectory', LATCHED)}

    def _on_odom(self, msg: Odometry) -> None:
        stamp, pose, _ = cv.odom_to_arrays(msg, 'odom')
        with self._lock:
            self.odometry.append((stamp * 1e-9, pose))

    def send_reference(self, reference: Trajectory, kind: str, timeout: float = 10.0,
                       start: float = START) -> None:
        """Send the reference to begin at ``start`` s on the planner's clock."""
        pub = self.publishers[kind]
        if not wait_until(lambda: pub.get_subscription_count() > 0, timeout):
            raise RuntimeError(f'planner did not subscribe to {pub.topic_name} in {timeout} s')
        received = self.planner.planner.reference
        pub.publish(msgs.reference_message(reference, self.pose_map, start, kind))
        if not wait_until(lambda: self.planner.planner.reference is not received, timeout):
            raise RuntimeError(f'planner did not take the reference in {timeout} s')

    def start(self, reference: Trajectory, kind: str, time_scale: float = 4.0,
              start_state: tuple = SLEIGH_START) -> None:
        """Send the reference, then start the simulated robot (and its clock)."""
        self.send_reference(reference, kind)
        self.sim = self.graph.add(SimulatorNode, namespace=self.namespace,
                                  parameter_overrides=parameters(
                                      **self.robot, publish_clock=True, rate=50.0,
                                      initial_state=np.concatenate(start_state).tolist(),
                                      time_scale=time_scale, start_time=START))

    def sim_time(self) -> float:
        with self._lock:
            return self.odometry[-1][0] if self.odometry else 0.0

    def track(self) -> tuple[np.ndarray, np.ndarray]:
        """Return (times, positions (M, 2)) of the robot so far."""
        with self._lock:
            rows = list(self.odometry)
        return np.array([t for t, _ in rows]), np.array([p[:2] for _, p in rows])


def run_demo(out: Path, duration: float = 15.0, reference_kind: str = 'path',
             time_scale: float = 4.0, log: Callable[[str], None] = print) -> dict:
    """Close the loop for ``duration`` simulated seconds; write demo.png and demo.json."""
    from nh_tracking.examples.plotting import plot_closed_loop

    out.mkdir(parents=True, exist_ok=True)
    reference = sleigh_reference(duration + 10.0)
    path_xy = reference.q[:, :2]
    responsive_threads()
    with InProcessGraph() as graph:
        loop = ClosedLoop(graph)
        loop.start(reference, reference_kind, time_scale)
        next_report = START + 1.0
        wall_limit = time.monotonic() + 30.0 + 5.0 * duration / time_scale
        while loop.sim_time() < START + duration and time.monotonic() < wall_limit:
            time.sleep(0.05)
            if loop.sim_time() >= next_report:
                t, xy = loop.track()
                stats = loop.planner.planner.stats
                log(f't = {t[-1] - START:5.1f} s | cross-track '
                    f'{cross_track_error(xy[-1:], path_xy)[0]:.3f} m | plans {stats.plans} '
                    f'(fallbacks {stats.fallbacks}) | solve p50 '
                    f"{percentiles_ms(stats.solve_times)['p50']:.1f} ms")
                next_report += 1.0
        t, xy = loop.track()
        stats = loop.planner.planner.stats
        solve_t = np.array(stats.plan_times) - START  # the planner's clock is the sim's
        solve_s = np.array(stats.solve_times)
    t = t - START
    error = cross_track_error(xy, path_xy)
    summary = {
        'duration': float(t[-1]), 'reference': reference_kind,
        'inertia_mismatch': INERTIA_MISMATCH,
        'final_cross_track_error': float(error[-1]),
        'max_cross_track_error_after_12s': float(error[t >= 12.0].max()) if (t >= 12).any()
        else float('nan'),
        'solve_time_ms': percentiles_ms(solve_s), 'plans': stats.plans,
        'fallbacks': stats.fallbacks, 'shifted': stats.shifted,
        'deadline_misses': stats.deadline_misses,
    }
    figure = plot_closed_loop(reference, t, xy, error, solve_t, solve_s, out / 'demo.png')
    (out / 'demo.json').write_text(json.dumps(summary, indent=2))
    log(f"final cross-track error {summary['final_cross_track_error']:.4f} m; solve time "
        f"p50 {summary['solve_time_ms']['p50']:.1f} ms, p99 {summary['solve_time_ms']['p99']:.1f}"
        f' ms; {stats.fallbacks} fallbacks, {stats.deadline_misses} deadline misses')
    log(f"wrote {figure} and {out / 'demo.json'}")
    return summary
