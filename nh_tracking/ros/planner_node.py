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

from dataclasses import replace
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist, TwistStamped
from nav2_msgs.msg import SpeedLimit as SpeedLimitMsg
from nav_msgs.msg import Odometry, Path
import numpy as np
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory
from visualization_msgs.msg import MarkerArray

from nh_tracking.core.joints import JointsRejected
from nh_tracking.planning.command_guard import SpeedLimit
from nh_tracking.planning.receding_horizon import PlannerSettings
from nh_tracking.ros import conversions as cv, messages as msgs
from nh_tracking.ros.clock_watch import ClockWatchdog
from nh_tracking.ros.follow_path import FollowPathServer
from nh_tracking.ros.guarded import guarded
from nh_tracking.ros.lifecycle import answer_every_transition
from nh_tracking.ros.obstacle_listener import DISC_SIZE, ObstacleListener
from nh_tracking.ros.odometry_receiver import OdometryReceiver
from nh_tracking.ros.parameters import declare_all, declare_model
from nh_tracking.ros.path_input import take_path, take_trajectory
from nh_tracking.ros.plan_outputs import PlanOutputs
from nh_tracking.ros.planner_interface import LATCHED, PARAMETERS, subscribe_latched
from nh_tracking.ros.planner_parameters import RuntimeParameters
from nh_tracking.ros.planner_services import PlannerServices
from nh_tracking.ros.reference_receiver import ReferenceReceiver
from nh_tracking.ros.runner import autostart, settle_heap
from nh_tracking.ros.twin_watch import TwinVerdict, TwinWatch
from nh_tracking.session.health import HealthLevel, session_health
from nh_tracking.session.interface import ClockSkew
from nh_tracking.session.tracking_session import TrackingSession
from nh_tracking.solvers.obstacles import MAX_OBSTACLES


AT_REST = 0.01  # [m/s, rad/s] slower than this, a robot being stopped is at rest


class PlannerNode(RuntimeParameters, PlanOutputs, ObstacleListener, ClockWatchdog,
                  LifecycleNode):
    """``nh_tracking_planner``: topics, services and parameters in docs/ros.md."""

    def __init__(self, **kwargs) -> None:
        super().__init__('nh_tracking_planner', **kwargs)
        answer_every_transition(self, self.reject)
        self.model, self.physical = declare_model(self)
        self.params = declare_all(self, PARAMETERS)
        self.frame = self.params['frame_id']
        self.costmap_threshold = self.params['costmap_threshold']
        PlannerSettings(**self._settings_values())  # consistent at start-up, or ValueError
        self.session: TrackingSession | None = None
        self._command_timers: list = []
        self._entities: list = []
        self._service_host: PlannerServices | None = None
        self._follow_path: FollowPathServer | None = None
        self._odometry: OdometryReceiver | None = None
        self._references: ReferenceReceiver | None = None
        self._obstacles_lock = threading.Lock()
        self._planned_ns = 0  # system time the last plan made on receipt of odometry ended
        self._configure_error = ''  # why the last configure failed
        self.twins = TwinWatch(self)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        if self.params['autostart']:
            autostart(self, lambda: self._configure_error)

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
            self.fail('planning', RuntimeError(text))
        elif level == 'warn':
            self.get_logger().warn(text)
        else:
            self.get_logger().info(text)

    # lifecycle --------------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.get_logger().info(f'configuring: building the solver for {self.model}')
        try:
            session = TrackingSession(self.model, self.physical,
                                      PlannerSettings(**self._settings_values()), self.now_ns,
                                      self.params['odom_timeout'], self._log,
                                      self.params['joint_names'])
            session.planner.prepare()  # blocking: the first plan must not be late
            if self.params['adapt']:
                session.adapt(self.params['adapt'])
        except Exception as exc:  # noqa: BLE001 - a user's model may raise anything
            self._configure_error = f'{type(exc).__name__}: {exc}'
            self.fail('configure', exc)
            return TransitionCallbackReturn.FAILURE
        self._tune(session)
        session.on_stale = self._on_stale
        self.session = session
        cmd_type = TwistStamped if self.params['cmd_vel_stamped'] else Twist
        self.pub_path = self.create_lifecycle_publisher(Path, 'planned_path', LATCHED)
        self.pub_controls = self.create_lifecycle_publisher(JointTrajectory, 'control_sequence',
                                                            LATCHED)
        self.pub_cmd = self.create_lifecycle_publisher(cmd_type, 'cmd_vel', 10)
        self.pub_markers = self.create_lifecycle_publisher(MarkerArray, 'planned_markers',
                                                           LATCHED)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._entities = [self.pub_path, self.pub_controls, self.pub_cmd, self.pub_markers,
                          self.pub_diag, self.watch_clock()]  # diagnostics even if it stands
        self._entities.append(self.create_timer(1.0, self.publish_diagnostics,
                                                clock=self.steady_clock))
        self._references = ReferenceReceiver(self, self.on_reference_path,
                                             self.on_reference_trajectory)
        self._entities += subscribe_latched(self, SpeedLimitMsg, 'speed_limit',
                                            self.on_speed_limit)
        self._discs_centre, self._displayed = np.zeros(2), None
        self._service_host = PlannerServices(self)
        self._follow_path = FollowPathServer.serve(self)
        session.start(self._publish_plan)
        # last: their callbacks start at once, on their own threads, and need all of the above
        self.listen_for_obstacles()
        self._odometry = OdometryReceiver(self, 'odom', self.on_odom, self.on_joint_states
                                          if session.pose_map.hidden else None)
        self.get_logger().info(f'planning for {self.model} {self.physical} with '
                               f'{session.planner.settings}')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._command_timers = [
            self.create_timer(self.params['replan_period'], self.live.wake),
            self.create_timer(1.0 / self.params['cmd_rate'], self.publish_cmd_vel),
            self.create_timer(1.0 / self.params['display_rate'], self.publish_display)]
        self.live.active = True
        self.live.wake()
        settle_heap()  # no full collection walks the planner while it commands
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Bring the robot to rest and drop the path in force, then stop commanding."""
        self._publish_stop()
        try:
            self._bring_to_rest()
        except ValueError as exc:  # (a stop the reference checks refuse: faster than allowed)
            self.fail('stopping on deactivation', exc)
        self.live.active = False
        for timer in self._command_timers:
            self.destroy_timer(timer)
        self._command_timers = []
        self._publish_stop()  # the robot stops: nothing commands it any more
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
        self.stop_listening_for_obstacles()
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
            settle_heap(release=True)  # its models and NLPs go with it
        for entity in self._entities:
            if hasattr(entity, 'timer_period_ns'):
                self.destroy_timer(entity)
            elif hasattr(entity, 'publish'):
                self.destroy_lifecycle_publisher(entity)
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
            raise cv.InputRejected(f'{exc}{self.other_clocks()}') from None
        if len(self.costmap_cells) and np.hypot(*(pose[:2] - self._discs_centre)) > DISC_SIZE:
            self.obstacles_changed()  # re-choose the costmap discs near the robot
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
            raise cv.InputRejected(f'{exc}{self.other_clocks()}') from None
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

    def obstacles_changed(self) -> None:
        """Choose the discs in force, one call at a time (executor and odometry threads).

        The plans keep clear of the markers' discs and the nearest costmap discs; every command
        of the markers' discs and every occupied cell.
        """
        with self._obstacles_lock:
            state, session = self.live.state, self.live
            centre = np.zeros(2) if state is None else session.pose_map.pose(state.q)[:2]
            self._discs_centre = centre
            markers, stamps = self.marker_obstacles.sightings()
            costmap = self.costmap_discs_near(centre, self.params['costmap_reach'],
                                              MAX_OBSTACLES)
            session.set_obstacles(np.vstack([markers, costmap]), np.concatenate(
                [stamps, np.zeros(len(costmap), dtype=np.int64)]))
            seen = np.where(stamps == 0, -np.inf,
                            session.seconds(stamps))  # type: ignore[arg-type]
            session.commands.set_obstacles(markers, seen, self.costmap_cells)

    # diagnostics ------------------------------------------------------------------------------
    def on_problem(self) -> None:
        self.publish_diagnostics()

    def _on_stale(self) -> None:
        self.warn_of_other_clocks()
        self.publish_diagnostics()

    @guarded('diagnostics')
    def publish_diagnostics(self) -> None:
        session = self.session
        if session is None:
            return
        health = session_health(session, self.recent_problem(), {
            'rejected_inputs': self.rejected_inputs, 'errors': self.errors})
        if clock := self.clock_problem():
            health = replace(health, level=HealthLevel.STALE, message=clock)
        level = {HealthLevel.OK: DiagnosticStatus.OK, HealthLevel.WARN: DiagnosticStatus.WARN,
                 HealthLevel.STALE: DiagnosticStatus.STALE}[health.level]
        message, values = health.message, health.values
        if (receiver := self.obstacle_receiver) is not None:  # (a cleanup may drop it)
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
                self._publish_stop()
        self._release()
        super().destroy_node()
