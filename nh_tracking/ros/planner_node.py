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

"""The planner node: reference + odometry in, optimal tracking plans out, as a lifecycle node.

Numerics live in a ROS-free :class:`~nh_tracking.session.tracking_session.TrackingSession`;
callbacks only convert messages. Services and odometry run on threads of their own
(``replan_on_odom``: plans on receipt). Lifecycle as in Nav2; ``autostart`` (default true) goes to
active at start-up.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
import gc
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav2_msgs.msg import SpeedLimit as SpeedLimitMsg
from nav_msgs.msg import Odometry, Path
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.timer import Timer
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import MultiDOFJointTrajectory

from nh_tracking.core.joints import JointsRejected
from nh_tracking.planning.command_guard import SpeedLimit
from nh_tracking.planning.receding_horizon import PlannerSettings
from nh_tracking.ros import conversions as cv, messages as msgs
from nh_tracking.ros.clock_watch import ClockWatchdog, other_clocks, warn_of_other_clocks
from nh_tracking.ros.follow_path import FollowPathServer
from nh_tracking.ros.guarded import guarded, ProblemLog
from nh_tracking.ros.lifecycle import answer_every_transition
from nh_tracking.ros.obstacle_listener import (CostmapDiscs, DISC_SIZE, NO_COSTMAP,
                                               ObstacleListener)
from nh_tracking.ros.odometry_receiver import OdometryReceiver
from nh_tracking.ros.path_input import take_path, take_trajectory
from nh_tracking.ros.plan_outputs import PlanOutputs
from nh_tracking.ros.planner_interface import LATCHED, PARAMETERS, subscribe_latched
from nh_tracking.ros.planner_parameters import ParameterHandler
from nh_tracking.ros.planner_services import PlannerServices
from nh_tracking.ros.reference_receiver import ReferenceReceiver
from nh_tracking.ros.runner import autostart
from nh_tracking.ros.twin_watch import TwinVerdict, TwinWatch
from nh_tracking.session.health import HealthLevel, session_health
from nh_tracking.session.interface import ClockSkew
from nh_tracking.session.tracking_session import TrackingSession
from nh_tracking.solvers.obstacles import MAX_OBSTACLES

__all__ = ['LATCHED', 'PARAMETERS', 'PlannerNode']  # (the first two re-exported)

AT_REST = 0.01  # [m/s, rad/s] slower than this, a robot being stopped is at rest


def _nothing() -> None:
    """Do nothing (a process hook not asked for)."""


def _collect() -> None:
    """Collect the garbage a cleanup dropped (the session's models and NLPs: cyclic)."""
    gc.collect()


class PlannerNode(LifecycleNode):
    """``nh_tracking_planner``: topics, services and parameters in docs/ros.md.

    It holds its parts, each with one job: :attr:`problems` (what went wrong, for every
    callback), :attr:`parameter_handler`, and, while configured, the session, its
    :attr:`outputs`, the :attr:`obstacle_listener`, the :attr:`clock_watchdog` and the
    companions (services, ``follow_path``, odometry and reference threads).

    ``on_commanding()`` is called each time the node starts commanding (activate), and
    ``on_released()`` once a cleanup has dropped its session. By default the first does nothing
    and the second collects the dropped session (cyclic garbage) with ``gc.collect()``: a node
    made in any process changes no interpreter setting. The ``planner`` executable passes
    :func:`~nh_tracking.ros.runner.settle_heap`: it freezes the process's heap as the node starts
    commanding (no full collection walks the planner while it commands), and unfreezes and
    collects as a cleanup drops the session.
    """

    def __init__(self, *, on_commanding: Callable[[], None] = _nothing,
                 on_released: Callable[[], None] = _collect, **kwargs) -> None:
        super().__init__('nh_tracking_planner', **kwargs)
        self.session: TrackingSession | None = None
        self.problems = ProblemLog(self, on_problem=self.publish_diagnostics)
        answer_every_transition(self, self.problems.reject)
        self._on_commanding, self._on_released = on_commanding, on_released
        self.command_timers: list[Timer] = []  # replan, cmd_vel, display (while active)
        self.parameter_handler = ParameterHandler(self, self.problems, lambda: self.session,
                                                  lambda: self.command_timers)
        self.frame = self.params['frame_id']
        self._outputs: PlanOutputs | None = None
        self.obstacle_listener: ObstacleListener[CostmapDiscs] | None = None
        self.clock_watchdog: ClockWatchdog | None = None
        self._entities: list = []
        self._service_host: PlannerServices | None = None
        self._follow_path: FollowPathServer | None = None
        self._odometry: OdometryReceiver | None = None
        self._references: ReferenceReceiver | None = None
        self._obstacles_lock = threading.Lock()
        self._discs_centre = np.zeros(2)  # where the costmap discs in force were chosen
        self._planned_ns = 0  # system time the last plan made on receipt of odometry ended
        self._configure_error = ''  # why the last configure failed
        self.twins = TwinWatch(self)
        if self.params['autostart']:
            autostart(self, lambda: self._configure_error)

    @property
    def params(self) -> dict:
        """Return the parameters in force (the parameter handler's)."""
        return self.parameter_handler.params

    @property
    def live(self) -> TrackingSession:
        """Return the session; callbacks run only while the node is configured."""
        if self.session is None:
            raise RuntimeError('the planner is not configured')
        return self.session

    @property
    def outputs(self) -> PlanOutputs:
        """Return the plan outputs; they exist while the node is configured."""
        if self._outputs is None:
            raise RuntimeError('the planner is not configured')
        return self._outputs

    @property
    def planner(self):
        return self.live.planner

    @property
    def pose_map(self):
        return self.live.pose_map

    def now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _log(self, level: str, text: str) -> None:
        """Log ``text``; one call site per severity (rclpy ties a call site to a severity)."""
        if level == 'error':  # counted, and reported as a diagnostic
            self.problems.fail('planning', RuntimeError(text))
        elif level == 'warn':
            self.get_logger().warn(text)
        else:
            self.get_logger().info(text)

    # lifecycle --------------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        handler, params = self.parameter_handler, self.params
        self.get_logger().info(f'configuring: building the solver for {handler.model}')
        try:
            session = TrackingSession(handler.model, handler.physical,
                                      PlannerSettings(**handler.settings_values()), self.now_ns,
                                      params['odom_timeout'], self._log, params['joint_names'])
            session.planner.prepare()  # blocking: the first plan must not be late
            if params['adapt']:
                session.adapt(params['adapt'])
        except Exception as exc:  # noqa: BLE001 - a user's model may raise anything
            self._configure_error = f'{type(exc).__name__}: {exc}'
            self.problems.fail('configure', exc)
            return TransitionCallbackReturn.FAILURE
        handler.tune(session)
        session.on_stale = self._on_stale
        self.session = session
        self._outputs = PlanOutputs(self, session, self.problems, self.twins, self.frame,
                                    params['cmd_vel_stamped'])
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.clock_watchdog = ClockWatchdog(self, self.problems, self._on_clock_stopped)
        self._entities = [self.pub_diag,  # diagnostics even if the clock stands
                          self.create_timer(1.0, self.publish_diagnostics,
                                            clock=Clock(clock_type=ClockType.STEADY_TIME))]
        self._references = ReferenceReceiver(self, self.on_reference_path,
                                             self.on_reference_trajectory)
        self._entities += subscribe_latched(self, SpeedLimitMsg, 'speed_limit',
                                            self.on_speed_limit)
        self._discs_centre = np.zeros(2)
        self._service_host = PlannerServices(self)
        self._follow_path = FollowPathServer.serve(self)
        session.start(self._outputs.publish_plan)
        # last: their callbacks start at once, on their own threads, and need all of the above
        self.obstacle_listener = ObstacleListener(
            self, self.problems, self.frame, params['costmap_threshold'], CostmapDiscs.of,
            NO_COSTMAP, self.obstacles_changed)
        self._odometry = OdometryReceiver(self, 'odom', self.on_odom, self.on_joint_states
                                          if session.pose_map.hidden else None)
        self.get_logger().info(f'planning for {handler.model} {handler.physical} with '
                               f'{session.planner.settings}')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        outputs = self.outputs
        self.command_timers = [
            self.create_timer(self.params['replan_period'], self.live.wake),
            self.create_timer(1.0 / self.params['cmd_rate'], outputs.publish_cmd_vel),
            self.create_timer(1.0 / self.params['display_rate'], outputs.publish_display)]
        self.live.active = True
        self.live.wake()
        self._on_commanding()
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Bring the robot to rest and drop the path in force, then stop commanding."""
        self.outputs.publish_stop()
        try:
            self._bring_to_rest()
        except ValueError as exc:  # (a stop the reference checks refuse: faster than allowed)
            self.problems.fail('stopping on deactivation', exc)
        self.live.active = False
        for timer in self.command_timers:
            self.destroy_timer(timer)
        self.command_timers = []
        self.outputs.publish_stop()  # the robot stops: nothing commands it any more
        return super().on_deactivate(state)

    def _bring_to_rest(self, timeout: float = 3.0) -> None:
        """Replan to rest until the robot is (or ``timeout`` [s] has passed).

        A robot driven by effort keeps its speed without controls: one plan would not do, as
        the simulator (like a driver) drops a sequence not renewed within its timeout.
        """
        session = self.live
        session.following.halt()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            session.replan()
            state = session.state
            if state is None or np.abs(session.pose_map.body_twist(state.q, state.v)).max() \
                    < AT_REST:
                return
            time.sleep(self.params['replan_period'])

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.session is not None and self.session.active:
            self.on_deactivate(state)
        return self.on_cleanup(state)

    def _release(self) -> None:
        """Close what configure made, in an order that lets no callback find it half gone."""
        if self.obstacle_listener is not None:
            self.obstacle_listener.close()
            self.obstacle_listener = None
        for receiver in (self._odometry, self._references):
            if receiver is not None:
                receiver.close()
        self._odometry = self._references = None
        if self._service_host is not None:
            self._service_host.close()
            self._service_host = None
        if self._follow_path is not None:
            self._follow_path.close()
            self._follow_path = None
        if self.session is not None:
            self.live.stop()
            self.session = None
            self._on_released()  # its models and NLPs go with it
        for part in (self._outputs, self.clock_watchdog):
            if part is not None:
                part.close()
        self._outputs, self.clock_watchdog = None, None
        for entity in self._entities:
            if hasattr(entity, 'timer_period_ns'):
                self.destroy_timer(entity)
            elif hasattr(entity, 'publish'):
                self.destroy_publisher(entity)
            else:
                self.destroy_subscription(entity)
        self._entities = []

    @guarded('reference_path')
    def on_reference_path(self, msg: Path | bytes) -> None:
        take_path(self, msg)

    @guarded('reference_trajectory')
    def on_reference_trajectory(self, msg: MultiDOFJointTrajectory) -> None:
        take_trajectory(self, msg)

    @guarded('odom')
    def on_odom(self, msg: Odometry | bytes, info: dict) -> None:
        """Take the state; replan_on_odom: plan here, unless it waited (odometry_receiver)."""
        received = time.perf_counter()
        stamp, pose, twist = cv.odom_to_arrays(msg, self.frame)
        try:
            self.live.set_odometry(stamp, pose, twist, received)
        except ClockSkew as exc:
            raise cv.InputRejected(f'{exc}{other_clocks(self)}') from None
        obstacles = self.obstacle_listener
        if obstacles is not None and len(obstacles.costmap.cells) \
                and np.hypot(*(pose[:2] - self._discs_centre)) > DISC_SIZE:
            self.obstacles_changed(obstacles)  # re-choose the costmap discs near the robot
        arrived = info.get('received_timestamp') or 0  # 0: not known (rmw_cyclonedds)
        if self.params['replan_on_odom'] and 0 < arrived < self._planned_ns:
            self.live.wake()  # it waited behind the last plan: plan for the latest, there
        elif self.params['replan_on_odom']:
            self.live.replan()
            self._planned_ns = time.time_ns()  # the clock of DDS's reception stamps

    @guarded('joint_states')
    def on_joint_states(self, msg: JointState) -> None:
        stamp, names, positions, velocities = cv.joint_state_arrays(msg)
        try:
            self.live.set_joints(stamp, names, positions, velocities)
        except ClockSkew as exc:
            raise cv.InputRejected(f'{exc}{other_clocks(self)}') from None
        except JointsRejected as exc:
            raise cv.InputRejected(str(exc)) from None

    @guarded('speed_limit')
    def on_speed_limit(self, msg: SpeedLimitMsg) -> None:
        """Take Nav2's speed limit (a speed zone): commands are capped from the next one on."""
        try:
            limit = SpeedLimit(float(msg.speed_limit), bool(msg.percentage))
        except ValueError as exc:
            raise cv.InputRejected(str(exc)) from None
        if self.live.commands.set_speed_limit(limit):
            self.get_logger().info(f'speed limit in force: {limit}')

    def obstacles_changed(self, obstacles: ObstacleListener[CostmapDiscs]) -> None:
        """Choose the discs in force, one call at a time (executor and odometry threads).

        The plans keep clear of the markers' discs and the nearest costmap discs; every command
        of the markers' discs and every occupied cell.
        """
        with self._obstacles_lock:
            state, session = self.live.state, self.live
            centre = np.zeros(2) if state is None else session.pose_map.pose(state.q)[:2]
            self._discs_centre = centre
            markers, stamps = obstacles.markers.sightings()
            costmap = obstacles.costmap.near(centre, self.params['costmap_reach'],
                                             MAX_OBSTACLES)
            session.set_obstacles(np.vstack([markers, costmap]), np.concatenate(
                [stamps, np.zeros(len(costmap), dtype=np.int64)]))
            seen = np.where(stamps == 0, -np.inf,
                            session.seconds(stamps))  # type: ignore[arg-type]
            session.commands.set_obstacles(markers, seen, obstacles.costmap.cells)

    def _on_clock_stopped(self) -> None:
        """Make the robot safe while the clock stands: a zero command at every look."""
        session, outputs = self.session, self._outputs
        if session is not None and outputs is not None and session.active:
            outputs.publish_stop()

    # diagnostics ------------------------------------------------------------------------------
    def _on_stale(self) -> None:
        warn_of_other_clocks(self)
        self.publish_diagnostics()

    @guarded('diagnostics')
    def publish_diagnostics(self) -> None:
        session = self.session
        if session is None:
            return
        health = session_health(session, self.problems.recent(), {
            'rejected_inputs': self.problems.rejected_inputs, 'errors': self.problems.errors})
        watchdog = self.clock_watchdog
        if watchdog is not None and (clock := watchdog.problem()):
            health = replace(health, level=HealthLevel.STALE, message=clock)
        level = {HealthLevel.OK: DiagnosticStatus.OK, HealthLevel.WARN: DiagnosticStatus.WARN,
                 HealthLevel.STALE: DiagnosticStatus.STALE}[health.level]
        message, values = health.message, health.values
        obstacles = self.obstacle_listener  # (a cleanup may drop it)
        if obstacles is not None and (receiver := obstacles.receiver) is not None:
            values = {**values, **receiver.values()}
            if level == DiagnosticStatus.OK and (lagging := receiver.problems()):
                level, message = DiagnosticStatus.WARN, '; '.join(lagging)
        if self.twins.check() is not TwinVerdict.ALONE:
            level, message = DiagnosticStatus.ERROR, self.twins.describe()
        array = DiagnosticArray(status=[msgs.diagnostic_status(
            f'{self.get_name()}: planning', self.get_fully_qualified_name(), level,
            message, values)])
        array.header.stamp = msgs.time_msg(self.now_ns())
        self.pub_diag.publish(array)

    def destroy_node(self) -> None:
        """Free everything; a robot still commanded gets a zero ``cmd_vel`` first."""
        if self.session is not None and self.live.active:
            self.live.active = False
            if self.context.ok():  # (an external shutdown may have taken it down)
                self.outputs.publish_stop()
        self._release()
        super().destroy_node()
