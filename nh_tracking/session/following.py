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

"""The path in force as a goal: routes timed from the robot's motion, arrival and progress.

A route re-sent unchanged (Nav2 re-sends its path at its replanning rate) changes nothing; a
new one is timed from where the robot is and how fast it goes, so re-sending never slows it.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import threading
from typing import Protocol

import numpy as np

from nh_tracking.core.poses import PoseMap
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.navigation.goal_checking import GoalSettings, GoalState, GoalStatus, GoalTracker
from nh_tracking.navigation.reference_checks import (bound_ratios, check_implied_motion,
                                                     check_velocity_bounds, ReferenceRejected,
                                                     thin)
from nh_tracking.navigation.route import RouteSettings, time_route, time_shape, TimedRoute
from nh_tracking.navigation.route_shape import RouteHeadings, RouteShape, shape_route
from nh_tracking.planning.receding_horizon import RecedingHorizonPlanner
from nh_tracking.session.commanding import Commands
from nh_tracking.session.interface import StateEstimate

SAME_ROUTE = 1e-3  # [m, rad] a route whose poses all lie this close to those in force is it
PAST, FUTURE = 1.0, 60.0  # [s] a timed reference starting further off is taken with a warning
BOUND_MARGIN = 0.98  # a route slowed into the velocity bounds keeps 2 % from them


@dataclass(frozen=True)
class TimedPoses:
    """A reference to track: times [s] on the session's axis, poses (N, 4), body twists."""

    times: np.ndarray
    poses: np.ndarray
    twists: np.ndarray
    route: TimedRoute


class Session(Protocol):
    """What :class:`Following` takes from its tracking session."""

    planner: RecedingHorizonPlanner
    log: Callable[[str, str], None]
    commands: Commands

    @property
    def pose_map(self) -> PoseMap: ...

    @property
    def state(self) -> StateEstimate | None: ...

    def now(self) -> float: ...

    def track(self, times: np.ndarray, poses: np.ndarray,
              twists: np.ndarray | None) -> Trajectory: ...


class Following:
    """References in (timed ones, routes, a stop), the path in force judged; thread-safe."""

    def __init__(self, session: Session) -> None:
        self.session = session
        self.route_settings = RouteSettings()
        self.goal_settings = GoalSettings()
        self.halted = False  # cancelled: brought to rest, until a new path
        self.generation = 0  # counts the paths taken (and dropped): whose is in force
        self._lock = threading.Lock()
        self._route: tuple[np.ndarray, RouteSettings] | None = None  # poses as sent, settings
        self._tracker: GoalTracker | None = None

    def set_reference(self, stamps: np.ndarray, poses: np.ndarray, twists: np.ndarray | None,
                      check_progress: bool = False) -> Trajectory:
        """Track poses at ``stamps`` [s], thinned to 4 a plan step; else ReferenceRejected.

        One that has ended already is refused; one that starts far off, taken with a warning.
        """
        session = self.session
        warning = timing_problem(stamps, session.now())
        reference = session.track(stamps, poses, twists)
        if warning:
            session.log('warn', warning)
        self._follow(poses[:, :2], poses[-1], check_progress)
        return reference

    def set_route(self, poses: np.ndarray, check_progress: bool = True) -> TimedPoses | None:
        """Track an untimed route from the robot's place and speed; None: it is the one in force.

        ReferenceRejected when untimed routes are refused (``reference_speed`` 0).
        """
        if self.route_settings.reference_speed == 0:
            raise ReferenceRejected('its poses all carry one stamp (an untimed route) and '
                                    'reference_speed is 0: stamp each pose with its time, or '
                                    'set reference_speed')
        if self._same_route(poses):
            return None
        session = self.session
        state, pose_map = session.state, session.pose_map
        if state is None:
            start, speed = poses[0, :2], 0.0
        else:
            start, speed = pose_map.pose(state.q)[:2], self._start_speed(state)
        shape = shape_route(poses, start, RouteHeadings(self.route_settings.route_headings))
        route = within_bounds(shape, speed, self.route_settings, pose_map,
                              session.planner.limits['velocity_bounds'])
        timed = TimedPoses(session.now() + route.times, route.poses, route.twists, route)
        session.track(timed.times, timed.poses, timed.twists)
        self._follow(timed.poses[:, :2], timed.poses[-1], check_progress, poses)
        return timed

    def halt(self) -> None:
        """Drop the path in force: brought to rest, straight ahead.

        Dropped first: a stop the reference checks refuse (a robot faster than bounds just
        lowered) leaves the robot held where it is, never on the old path.
        """
        with self._lock:
            self._tracker, self._route, self.halted = None, None, True
            self.generation += 1
        session = self.session
        state = session.state
        if state is None:
            return
        pose, speed = session.pose_map.pose(state.q), self._start_speed(state)
        distance = speed * abs(speed) / (2 * self.route_settings.max_accel)
        ahead = pose + distance * np.array([np.cos(pose[3]), np.sin(pose[3]), 0.0, 0.0])
        stop = time_route(np.vstack([pose, ahead]), pose[:2], speed, RouteSettings(
            max(abs(speed), 1e-3), self.route_settings.max_accel,
            self.route_settings.max_lateral_accel, 'poses'))
        try:
            session.track(session.now() + stop.times, stop.poses, stop.twists)
        except ReferenceRejected as exc:
            session.log('warn', f'held where it is: the stop asked for too much ({exc})')
            session.track(session.now() + np.array([0.0, 1.0]), np.vstack([pose, pose]),
                          np.zeros((2, 4)))

    def _start_speed(self, state: StateEstimate) -> float:
        """Return the robot's forward speed, within what its velocity bounds allow (the guard's).

        A robot faster than that (pushed, or the bounds lowered) is slowed into them by the
        command guard; a route starting faster would ask for more than the bounds allow.
        """
        session = self.session
        matrix = session.pose_map.twist_matrix(state.q)
        top = session.commands.guard(session.planner).max_speed(matrix)
        return float(np.clip((matrix @ state.v)[0], -top, top))

    def _same_route(self, poses: np.ndarray) -> bool:
        """Whether ``poses`` is the route in force, re-sent (same poses, same settings).

        Once arrived it is a new request (a patrol loop sent again is driven again).
        """
        with self._lock:
            route, tracker = self._route, self._tracker
        if route is None or route[1] != self.route_settings or route[0].shape != poses.shape \
                or tracker is None or tracker.status.state is GoalState.ARRIVED:
            return False
        gap = np.abs(route[0] - poses)
        gap[:, 3] = np.abs(np.remainder(gap[:, 3] + np.pi, 2 * np.pi) - np.pi)
        return bool(gap.max() <= SAME_ROUTE)

    def _follow(self, positions: np.ndarray, goal: np.ndarray, check_progress: bool,
                route: np.ndarray | None = None) -> None:
        """Judge arrival at ``goal`` along ``positions``; ``route``: the route's poses as sent."""
        tracker = GoalTracker(positions, goal, self.goal_settings,
                              self.session.pose_map.has_yaw, check_progress)
        with self._lock:
            going = self._tracker
            if going is not None and going.watch is not None and tracker.watch is not None \
                    and going.status.state is not GoalState.ARRIVED:
                tracker.watch = going.watch  # a path updated on the way: progress judged on
            self._tracker, self.halted = tracker, False
            self.generation += 1
            self._route = None if route is None else (route, self.route_settings)

    def configure(self, route: RouteSettings, goal: GoalSettings) -> None:
        """Take new settings: the goal in force is judged by them, a route in force re-timed."""
        changed, self.route_settings, self.goal_settings = (
            route != self.route_settings), route, goal
        with self._lock:
            tracker, sent = self._tracker, self._route
        if tracker is not None:
            tracker.judge_by(goal)
        if changed and sent is not None and tracker is not None and \
                tracker.status.state is not GoalState.ARRIVED:
            try:
                self.set_route(sent[0], tracker.watch is not None)
            except ReferenceRejected as exc:
                self.session.log('warn', f'the route in force keeps its timing: {exc}')

    def update(self, pose: np.ndarray, twist: np.ndarray, now: float) -> None:
        """Judge the robot at ``pose`` moving with body ``twist`` at ``now`` [s]."""
        with self._lock:
            tracker = self._tracker
        if tracker is not None:
            tracker.update(pose, twist, now)

    @property
    def status(self) -> GoalStatus:
        with self._lock:
            tracker = self._tracker
        return GoalStatus(GoalState.NONE) if tracker is None else tracker.status


def timing_problem(times: np.ndarray, now: float) -> str:
    """Return a warning for a timed reference starting far from ``now`` [s] ('' if none).

    ReferenceRejected if it has ended already: its header stamps were misread, most likely.
    """
    if times[-1] < now:
        raise ReferenceRejected(
            f'it ended {now - times[-1]:.3g} s ago (its last pose is stamped before now); '
            'a header stamp of 0 has the pose stamps read as times from receipt')
    offset = times[0] - now
    if -PAST <= offset <= FUTURE:
        return ''
    return (f'the reference starts {abs(offset):.3g} s {"before" if offset < 0 else "after"} '
            'now: taken as stamped')


def within_bounds(shape: RouteShape, start_speed: float, settings: RouteSettings,
                  pose_map: PoseMap, bounds: tuple | None) -> TimedRoute:
    """Return ``shape`` timed, slower where it would ask for more than the velocity ``bounds``.

    A model's velocities at a point scale with the speed there, so each point's speed (and its
    neighbours', whose times its rates are taken over) is capped by the ratio it asked for, up
    to five times.
    """
    route = time_shape(shape, start_speed, settings)
    if bounds is None or shape.at_goal:
        return route
    caps = np.full(len(shape.positions), np.inf)
    for _ in range(5):
        reference = pose_map.reference(route.times, route.poses, route.twists)
        ratio = bound_ratios(reference.v, bounds)[:len(caps)]
        if ratio.max() <= 1.0 or not np.isfinite(ratio).all():
            break
        with np.errstate(divide='ignore', invalid='ignore'):
            wanted = np.where(ratio > 1.0, np.abs(route.speeds[:len(caps)]) / ratio
                              * BOUND_MARGIN, np.inf)
        # a point's rates are differences with its neighbours': they are slowed alike
        wanted = np.minimum.reduce([np.roll(wanted, k) for k in (-1, 0, 1)])
        caps = np.minimum(caps, wanted)
        route = time_shape(shape, start_speed, settings, caps)
    return route


def checked_reference(times: np.ndarray, poses: np.ndarray, twists: np.ndarray | None,
                      hidden: np.ndarray | None, pose_map: PoseMap,
                      planner: RecedingHorizonPlanner,
                      reference_bounds: tuple[float, float]) -> Trajectory:
    """Return the reference of poses at ``times`` [s], thinned to 4 a plan step.

    ReferenceRejected where it asks for more than ``reference_bounds`` (speed, acceleration)
    or the planner's velocity bounds.
    """
    keep = thin(times, planner.settings.horizon / planner.settings.steps / 4)
    times, poses = times[keep], np.asarray(poses)[keep]
    twists = None if twists is None else np.asarray(twists)[keep]
    check_implied_motion(times, poses[:, :2], *reference_bounds)
    reference = pose_map.reference(times, poses, twists, hidden)
    check_velocity_bounds(reference.v, planner.limits['velocity_bounds'],
                          pose_map.system.velocity_names)
    return reference
