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

"""``nh-tracking demo --scenario crossing``: discs crossing a differential-drive robot's way.

A tracker publishes each disc on ``obstacles`` ten times a second, stamped, where it is; the
planner estimates the velocities of the moving ones and keeps clear of where they will be. The
closest approaches are measured against the discs' true motion (not the planner's estimate),
at every odometry message.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import json
from pathlib import Path
import threading

from nav_msgs.msg import Odometry, Path as PathMsg
import numpy as np
from rclpy.node import Node
from visualization_msgs.msg import Marker, MarkerArray

from nh_tracking import models
from nh_tracking.core.poses import PoseMap
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.ros import conversions as cv
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.graph import InProcessGraph, parameters, wait_until
from nh_tracking.ros.planner_node import LATCHED, PlannerNode
from nh_tracking.ros.simulator_node import SimulatorNode

ROBOT_RADIUS, INFLATION = 0.2, 0.05  # [m]: the planner keeps the inflation more
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

    def __init__(self, discs: list[tuple[float, float, float]]) -> None:
        self.discs = np.array(discs, dtype=float).reshape(-1, 3)
        self.radius = self.discs[:, 2]

    def at(self, t: float) -> np.ndarray:
        return self.discs[:, :2]


Discs = Crossings | Standing


def random_scene(rng: np.random.Generator) -> Standing:
    """Return 3-6 discs (radius 0.1-0.3 m) within 0.5 m of a 6 m route along +x."""
    count = rng.integers(3, 7)
    return Standing(np.c_[rng.uniform(1.0, 5.0, count), rng.uniform(-0.5, 0.5, count),
                          rng.uniform(0.1, 0.3, count)].tolist())


def markers(discs: Discs, stamp_ns: int) -> MarkerArray:
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


@dataclass
class Drive:
    """What one drive past discs came to."""

    track: np.ndarray  # (T, 3): t [s, absolute], x, y
    start: float  # when the reference started [s, absolute]
    discs: Discs
    arrived: bool
    planner: PlannerNode
    sim: SimulatorNode
    probe: Node

    @property
    def closest(self) -> np.ndarray:
        """Closest approach to each disc's edge, beyond the robot's radius [m]."""
        gaps = np.array([np.hypot(*(self.discs.at(t) - xy).T) for t, *xy in self.track])
        gaps = gaps.reshape(len(self.track), -1)
        return gaps.min(axis=0, initial=np.inf) - self.discs.radius - ROBOT_RADIUS

    @property
    def took(self) -> float:
        return float(self.track[-1, 0] - self.start)


def drive(graph: InProcessGraph, discs_at_start: Callable[[float], Discs], length: float,
          namespace: str = '', patience: float = 30.0) -> Drive:
    """Follow a line of ``length`` m at SPEED past discs, until within 0.3 m of its end.

    ``discs_at_start(start)``: the discs, given the reference's start (absolute s); sent ten
    times a second. Bounded: the reference's duration and ``patience`` seconds.
    """
    ns = namespace
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
    reference_pub = probe.create_publisher(PathMsg, 'reference_path', LATCHED)
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
    done = wait_until(arrived, length / SPEED + patience)
    with lock:
        track = np.array(odometry)
    return Drive(track, start, discs, done, planner, sim, probe)


def obstacle_scenes(log: Callable[[str], None] = print, scenes: int = 10, seed: int = 0
                    ) -> dict:
    """Drive the closed-loop scenes with discs through the nodes, at default settings.

    A 6 m route without discs and with one centred on it (times to the end); ``scenes`` seeded
    scenes of :func:`random_scene` (how many arrive, in what time); CROSSINGS discs crossing a
    longer route (closest approaches, delay at the end). Collisions as the simulator counts them.
    """
    def summary(run: Drive) -> dict:
        return {'arrived': run.arrived, 'took_s': run.took, 'collisions': run.sim.collisions,
                'closest_m': float(run.closest.min(initial=np.inf))}

    out: dict = {}
    with InProcessGraph() as graph:
        def run_scene(name: str, discs: Callable[[float], Discs], length: float,
                      patience: float = 30.0) -> dict:
            run = drive(graph, discs, length, f'/{name}', patience)
            graph.remove(run.planner, run.sim, run.probe)
            return summary(run)

        out['free'] = run_scene('free', lambda start: Standing([]), 6.0)
        out['centred'] = run_scene('centred', lambda start: Standing([(3.0, 0.0, 0.3)]), 6.0)
        log(f"  a disc centred on a 6 m route: {out['centred']['took_s']:.1f} s to the end "
            f"({out['free']['took_s']:.1f} s without it), "
            f"{out['centred']['collisions']} collisions")
        rng = np.random.default_rng(seed)
        out['scenes'] = [run_scene(f'scene{i}', lambda start: random_scene(rng), 6.0, 10.0)
                         for i in range(scenes)]
        took = [scene['took_s'] for scene in out['scenes'] if scene['arrived']]
        log(f'  {scenes} scenes of 3-6 discs: {len(took)} arrived (median '
            f'{np.median(took) if took else np.nan:.1f} s), '
            f"{sum(scene['collisions'] for scene in out['scenes'])} collisions")
        length = 2.0 + 2.0 * CROSSINGS
        out['crossing'] = run_scene('crossing', lambda start: Crossings(11, start), length)
        out['crossing']['late_s'] = out['crossing']['took_s'] - length / SPEED
        log(f'  {CROSSINGS} discs crossing at {DISC_SPEED} m/s: arrived '
            f"{out['crossing']['late_s']:+.1f} s after the reference, closest "
            f"{out['crossing']['closest_m']:.3f} m, {out['crossing']['collisions']} collisions")
    return out


def run_crossing_demo(out: Path, log: Callable[[str], None] = print, seed: int = 11) -> dict:
    """Write crossing.png (paths, and the gap to each disc over time) and crossing.json."""
    from nh_tracking.examples.plotting import plot_crossing

    out.mkdir(parents=True, exist_ok=True)
    length = 2.0 + 2.0 * CROSSINGS
    with InProcessGraph() as graph:
        run = drive(graph, lambda start: Crossings(seed, start), length)
        collisions, fallbacks = run.sim.collisions, run.planner.planner.stats.fallbacks
        errors = run.planner.problems.errors + run.sim.problems.errors
    closest = run.closest
    summary = {'crossings': CROSSINGS, 'disc_speed': DISC_SPEED, 'robot_speed': SPEED,
               'arrived': run.arrived, 'late_s': run.took - length / SPEED,
               'closest_approach_per_disc': closest.tolist(), 'collisions': collisions,
               'fallbacks': fallbacks, 'errors': errors}
    figure = plot_crossing(run.track, run.discs, ROBOT_RADIUS, out / 'crossing.png')
    (out / 'crossing.json').write_text(json.dumps(summary, indent=2))
    log(f'{CROSSINGS} discs crossing at {DISC_SPEED} m/s: closest approach '
        f'{closest.min():.3f} m, {collisions} collisions, arrived '
        f"{summary['late_s']:+.1f} s after the reference")
    log(f"wrote {figure} and {out / 'crossing.json'}")
    return summary
