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

"""A tracking session: reference and odometry in, plans out, on one time base — without ROS.

Integer nanoseconds in, seconds from an epoch inside (wall-clock stamps keep their resolution);
a solver thread so callbacks never wait, and a builder thread: a rebuild never stops the plan
in force, the new solver is swapped in between two replans.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
import dataclasses
from dataclasses import dataclass
import threading
import time

import numpy as np
from numpy.typing import ArrayLike

from nh_tracking import models
from nh_tracking.core.poses import carried, PoseMap, reexpressed
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.estimation.adaptation import BackgroundEstimates, SentControls
from nh_tracking.planning.receding_horizon import (PlannerSettings, PlanOutcome, PlanStatus,
                                                   RecedingHorizonPlanner)
from nh_tracking.problem.limits import moved, obstacle_discs
from nh_tracking.problem.tracking_problem import Solution
from nh_tracking.session.commanding import Commands, predicted
from nh_tracking.session.following import checked_reference, Following
from nh_tracking.session.interface import Clock, PlanResult, Staleness, StateEstimate
from nh_tracking.session.robot_state import LEAD, RobotState
from nh_tracking.solvers.compiled import cancel_builds


@dataclass(frozen=True)
class _Build:
    physical: dict
    settings: PlannerSettings


class TrackingSession:
    """One robot's tracking: model, planner, reference, odometry, and the solver thread."""

    def __init__(self, model: str, physical: Mapping[str, float], settings: PlannerSettings,
                 clock: Clock, odom_timeout: float = 0.5,
                 log: Callable[[str, str], None] = lambda level, text: None,
                 joint_names: Sequence[str] = ()) -> None:
        """``joint_names``: ``coordinate:joint`` entries for joints not named as coordinates."""
        self.model = model
        self.clock = clock
        self.reference_bounds = (0.0, 0.0)  # (max speed [m/s], max accel [m/s^2]); 0: unchecked
        self.on_stale: Callable[[], None] = lambda: None  # said at once, on the thread that saw it
        self.log = log
        self.epoch_ns = clock()
        system = models.create_parametrised(model, **physical)
        self.robot = RobotState(PoseMap(system), clock, joint_names, odom_timeout, log)
        self.following = Following(self)  # references in; the path in force as a goal
        self.commands = Commands()  # every command through the guard
        self.planner = RecedingHorizonPlanner(system, settings)
        self.active = False  # plans are made only while active (the lifecycle's "active")
        self.staleness = Staleness()
        self.outcome: PlanOutcome | None = None
        self._commanded: tuple[PlanOutcome, Trajectory] | None = None  # and its interpolant
        # (odometry receipt -> plan published, of which the numerical planner, of which the
        # NLP solver) [s], for the recent plans
        self.latencies: deque[tuple[float, float, float]] = deque(maxlen=2000)
        self._obstacles = (np.zeros((0, 5)), np.zeros(0))  # discs, when seen (planner clock)
        self._lock = threading.Lock()  # the fields above shared between threads
        self._solve_lock = threading.Lock()  # one solve at a time; swaps happen between them
        self._pending: _Build | None = None
        self._wake, self._rebuild, self._stop = (threading.Event() for _ in range(3))
        self._threads: list[threading.Thread] = []
        self._on_plan: Callable[[PlanResult], None] = lambda result: None
        self.adaptation: BackgroundEstimates | None = None  # online estimates, when adapting
        self.sent_controls = SentControls()  # what the robot was sent, for the estimates

    @property
    def system(self) -> NonholonomicSystem:
        """Return the model the planner in force uses."""
        return self.planner.system

    # time -------------------------------------------------------------------------------------
    def seconds(self, ns: int) -> float:
        """Seconds since the session's epoch (the planner's time axis)."""
        return (ns - self.epoch_ns) * 1e-9

    def ns(self, seconds: float) -> int:
        return self.epoch_ns + int(round(seconds * 1e9))

    def now(self) -> float:
        return self.seconds(self.clock())

    # threads ----------------------------------------------------------------------------------
    def start(self, on_plan: Callable[[PlanResult], None]) -> None:
        """Start the threads; each plan goes to ``on_plan`` at once (displays read outcome)."""
        self._on_plan = on_plan
        self._stop.clear()
        self._threads = [threading.Thread(target=self._loop, args=(self._wake, self.replan),
                                          name='nh_tracking_solver', daemon=True),
                         threading.Thread(target=self._loop, args=(self._rebuild, self._build),
                                          name='nh_tracking_builder', daemon=True)]
        for thread in self._threads:
            thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        if self.adaptation is not None:
            self.adaptation.close()
        self._stop.set()
        self._wake.set()
        self._rebuild.set()
        for thread in self._threads:
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join(timeout)
        self._threads = []

    def wake(self) -> None:
        """Ask the solver thread for a new plan (latest request wins)."""
        self._wake.set()

    def _loop(self, event: threading.Event, work: Callable[[], object]) -> None:
        while not self._stop.is_set():
            if event.wait(0.2):
                event.clear()
                if not self._stop.is_set():
                    try:
                        work()
                    except Exception as exc:  # noqa: BLE001 - the thread must survive
                        self.log('error', f'{threading.current_thread().name}: '
                                          f'{type(exc).__name__}: {exc}')

    # inputs -----------------------------------------------------------------------------------
    def track(self, times: np.ndarray, poses: np.ndarray,
              twists: np.ndarray | None) -> Trajectory:
        """Track poses at ``times`` [s], thinned; ReferenceRejected if the robot may not."""
        state = self.state
        hidden = None if state is None else state.q
        reference = checked_reference(times, poses, twists, hidden, self.pose_map,
                                      self.planner, self.reference_bounds)
        with self._solve_lock:
            self.planner.set_reference(reference)
        return reference

    def set_joints(self, ns: int, names: Sequence[str], positions: Sequence[float] | np.ndarray,
                   velocities: Sequence[float] | np.ndarray) -> bool:
        """Take joint states (:meth:`RobotState.set_joints`)."""
        return self.robot.set_joints(ns, names, positions, velocities)

    def set_odometry(self, ns: int, pose: np.ndarray, twist: np.ndarray,
                     received: float) -> None:
        """Take the latest pose and body twist (:meth:`RobotState.set_odometry`)."""
        state = self.robot.set_odometry(ns, pose, twist, received)
        self.following.update(pose, twist, self.seconds(state.ns))
        if self.adaptation is not None:
            if not self.active:  # commands stop: what was sent before is not in force after
                self.sent_controls.clear()
            self.adaptation.sample(self.seconds(state.ns), state.q, self.sent_controls.readings)

    def adapt(self, names: Sequence[str]) -> None:
        """Estimate the physical parameters ``names`` online; a moved estimate is put in use."""
        self.adaptation = BackgroundEstimates(self.model, names, self.system.parameters,
                                              self._adapted)

    def _adapted(self) -> None:
        """Put the estimates in use, over a build still to come (a user's change)."""
        with self._lock:
            build = self._pending
        if build is None:
            self.reconfigure(self.system.parameters, self.planner.settings)
        else:
            self.reconfigure(build.physical, build.settings)

    def _send(self, result: PlanResult) -> None:
        """Hand a plan to ``on_plan`` (the commands); remember its controls when adapting.

        The estimates read a plan as in force from its start (the state it was planned from),
        or from one odometry interval after it was sent (``SentControls``).
        """
        self._on_plan(result)
        if self.adaptation is not None and result.outcome is not None:
            plan = result.outcome.plan
            self.sent_controls.sent(self.now(), plan.t, plan.u)

    @property
    def state(self) -> StateEstimate | None:
        return self.robot.latest

    @property
    def pose_map(self) -> PoseMap:
        return self.robot.pose_map

    @property
    def obstacles(self) -> np.ndarray:
        """Return the discs (x, y, r, vx, vy) the plans keep clear of, where they were seen."""
        with self._lock:
            return self._obstacles[0]

    def obstacles_at(self, t: float) -> np.ndarray:
        """Return the discs (x, y, r, vx, vy) where they will be at t (planner clock)."""
        with self._lock:
            discs, seen = self._obstacles
        return moved(discs, t - seen)

    def set_obstacles(self, discs: np.ndarray, seen_ns: ArrayLike | None = None) -> None:
        """Keep clear of ``discs`` (x, y, r) or (x, y, r, vx, vy) from the next plan on.

        ``seen_ns``: when they were where they are said to be, one stamp for all or one each
        (0: no stamp, at rest); None: now.
        """
        discs = obstacle_discs(discs)
        stamps = np.broadcast_to(np.asarray(self.clock() if seen_ns is None else seen_ns,
                                            dtype=np.int64), (len(discs),))
        seen = np.where(stamps == 0, -np.inf, self.seconds(stamps))  # type: ignore[arg-type]
        with self._lock:
            self._obstacles = (discs, seen)

    # reconfiguration --------------------------------------------------------------------------
    def reconfigure(self, physical: Mapping[str, float], settings: PlannerSettings) -> None:
        """Rebuild with new parameters on the builder thread (the latest request wins)."""
        adapted = self.adaptation.values if self.adaptation is not None else {}
        with self._lock:  # the estimates in use, not the values typed, of what is adapted
            self._pending = _Build({**physical, **adapted}, settings)
        self._rebuild.set()

    @property
    def reconfiguring(self) -> bool:
        with self._lock:
            return self._pending is not None

    def _build(self) -> None:
        with self._lock:
            build = self._pending
        if build is None:
            return
        current = self.planner
        system = models.with_parameters(current.system, self.model, build.physical)
        same_model, same_family = system is current.system, system.family is current.system.family
        if current.settings.compiled and not build.settings.compiled:
            cancel_builds()  # the C code it was building is not wanted any more
        planner = RecedingHorizonPlanner(system, build.settings)
        started = time.perf_counter()
        planner.prepare()  # the slow part: NLP construction, C compilation
        with self._solve_lock:
            old = self.planner
            planner.reference, planner.stats = old.reference, old.stats
            if same_model:  # the warm start survives a settings change
                planner.previous = old.previous
            else:  # velocities were in the old basis, which may scale with the values
                self.robot.set_pose_map(PoseMap(system))
                if old.reference is not None:
                    planner.set_reference(reexpressed(old.reference, old.system, system))
                if same_family and old.previous is not None:  # and new values
                    planner.previous = dataclasses.replace(old.previous, v=carried(
                        old.system, system, old.previous.q, old.previous.v),
                        minimum_check=None, attempts=list(old.previous.attempts))
            self.planner = planner
        with self._lock:
            self._pending = None if self._pending is build else self._pending
        took = time.perf_counter() - started
        if (same_family and not same_model and build.settings == current.settings
                and build.settings.method == 'variational'):  # the others hold the numbers
            self.log('info', f'new model values in use after {took:.3f} s, nothing rebuilt: '
                             f'{_changes(current.system, system)}')
        else:
            self.log('info', f'rebuilt in {took:.2f} s: {build.settings}')

    # planning ---------------------------------------------------------------------------------
    def replan(self) -> PlanResult:
        """Plan from the latest state, to ``on_plan`` too; under one lock (threads take turns)."""
        with self._solve_lock:
            state = self.state
            reason = self._why_not(state)
            if reason or state is None:
                return self._brake_if_stale(state, reason)
            planner = self.planner
            with self._lock:
                planner.obstacles, planner.obstacles_time = self._obstacles
            outcome = self.commands.controls(planner, self.pose_map,
                                             planner.plan(self.seconds(state.ns), state.q,
                                                          state.v))
            result = PlanResult(outcome, state, f'{outcome.status}: {outcome.message} '
                                                f'({outcome.solve_time * 1e3:.1f} ms)')
            self._send(result)  # the commands first: the robot waits for them
            self.latencies.append((time.perf_counter() - state.received,
                                   planner.stats.plan_durations[-1], outcome.solve_time))
            with self._lock:
                if self.staleness.mark(False):
                    self.log('info', 'odometry is fresh again: planning resumed')
                self.outcome = outcome
        return result

    def _brake_if_stale(self, state: StateEstimate | None, reason: str) -> PlanResult:
        """While the state is stale, brake to rest from it (planned once); else plan nothing.

        The braking plan is sent again at every replan: a driver drops a control sequence not
        renewed within its timeout, and an effort-driven robot given none coasts on.
        """
        with self._lock:
            outcome = self.outcome
        if state is None or not self.active or not self.staleness.now or outcome is None:
            return PlanResult(None, state, reason)
        if outcome.status in (PlanStatus.BRAKE, PlanStatus.STOP):
            if outcome.status is PlanStatus.BRAKE:
                self._send(PlanResult(outcome, state, reason))
            return PlanResult(None, state, reason)
        # braking from the state the plan in force predicts when it reaches the robot (a
        # command period from now): a sequence received after its start misses its first pull
        t = self.now() + self.commands.command_period
        q, v = predicted(outcome.plan, t, state.q, state.v)
        braking = self.commands.controls(self.planner, self.pose_map, self.planner.brake(
            t, q, v, reason, self.commands.settings.max_decel))
        result = PlanResult(braking, state, braking.message)
        self._send(result)
        with self._lock:
            self.outcome = braking
        return result

    def _why_not(self, state: StateEstimate | None) -> str:
        """Why no plan can be made now ('' if one can)."""
        if not self.active:
            return 'not active'
        if self.planner.reference is None:
            return 'no reference yet'
        if state is None:
            return 'no odometry yet'
        age = self.check_stale(state)
        if age is not None:
            return f'odometry is stale ({age:.2f} s old); not planning'
        return ''

    def check_stale(self, state: StateEstimate | None) -> float | None:
        """Return the state's age [s] if it is stale (and mark the session so), else None."""
        if state is None:
            return None
        age = (self.clock() - state.ns) * 1e-9
        if age <= self.robot.odom_timeout:
            return None
        if self.staleness.mark(True):
            self.log('warn', f'odometry is {age:.2f} s old: braking to rest, no plans')
            self.on_stale()
        return age

    def preview(self, pose: np.ndarray | None) -> tuple[Solution | None, str]:
        """Return a plan from ``pose`` at rest (None: the latest state), or (None, why not)."""
        state = self.state
        if self.planner.reference is None:
            return None, 'no reference to track yet'
        if pose is None:
            if state is None:
                return None, 'empty start and no odometry yet'
            t, q, v = self.seconds(state.ns), state.q, state.v
        else:
            q = self.pose_map.configuration(pose, None if state is None else state.q)
            t, v = self.seconds(self.clock()), np.zeros(self.system.k)
        with self._solve_lock:
            with self._lock:
                self.planner.obstacles, self.planner.obstacles_time = self._obstacles
            solution = self.planner.preview(t, q, v)
        if not solution.success:
            return None, f'solver failed ({solution.message})'
        return solution, ''

    def command(self, now_ns: int) -> np.ndarray | None:
        """Return the plan's body twist now; None before a plan.

        Stale, halted, inactive or outside the plan: slowing to rest at ``max_decel``.
        """
        stale = self.active and self.check_stale(self.state) is not None
        with self._lock:
            outcome, stale, commanded = self.outcome, stale or self.staleness.now, self._commanded
        if outcome is None:
            return None
        if commanded is None or commanded[0] is not outcome:
            # here, not on the solver thread: when replanning outpaces commanding, most are not
            commanded = (outcome, outcome.plan.trajectory())
            with self._lock:
                self._commanded = commanded
        trajectory = commanded[1]
        t = self.seconds(now_ns)
        if trajectory.t[0] - LEAD <= t < trajectory.t[0]:
            t = trajectory.t[0]  # planned from odometry stamped a little ahead of this clock
        state = self.state
        if state is None:
            self.commands.stopped(t)
            return np.zeros(4)
        age = t - self.seconds(state.ns)
        if stale or not self.active or self.following.halted or \
                not trajectory.t[0] <= t <= trajectory.t[-1]:
            return self.commands.halt(self.planner, self.pose_map, t, state.q, state.v, age)
        q, v = trajectory.sample(t)
        return self.commands.twist(self.planner, self.pose_map, t, q[0], v[0], state.q, state.v,
                                   age)


def _changes(old: NonholonomicSystem, new: NonholonomicSystem) -> str:
    return ', '.join(f'{k} {old.parameters[k]:g} -> {x:g}' for k, x in new.parameters.items()
                     if old.parameters.get(k) != x)
