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

"""The simulator node: integrates the model's real controlled dynamics, publishes the state.

Odometry, the coordinates a pose does not show as ``joint_states`` (with their rates), and the
odometry pose on ``/tf`` (``frame_id`` -> ``child_frame_id``), all at the same stamps.

It applies ``control_sequence`` by its timing (each effort held over its interval, the step
split at interval boundaries), zero control after ``control_timeout`` without a new sequence
or past its end, or — in ``velocity`` mode — follows ``cmd_vel``. It can own the clock
(``publish_clock``) to run faster than real time.
"""
from __future__ import annotations

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
import numpy as np
from rclpy.clock import Clock, ClockType, ROSClock
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectory

from nh_tracking import models
from nh_tracking.core.joints import joint_mapping
from nh_tracking.core.poses import carried, PoseMap
from nh_tracking.core.simulate import drive, LeftDomain, simulate
from nh_tracking.navigation.costmap import CellsByX, gap, NO_CELLS_BY_X
from nh_tracking.problem.limits import bounds_from_lists
from nh_tracking.ros import conversions as cv
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.guarded import guarded, ProblemLog
from nh_tracking.ros.obstacle_listener import ObstacleListener
from nh_tracking.ros.parameters import declare, declare_all, declare_model, plain
from nh_tracking.ros.planner_interface import COSTMAP_THRESHOLD, JOINT_NAMES
from nh_tracking.ros.twin_watch import TwinVerdict, TwinWatch

Piece = tuple[int, int, np.ndarray | None]  # (from, to) in ns and the effort held (None: v)
CLOCK_JUMP = 1.0  # [s] a step's clock time this far (and 5 steps) from what passed: a jump

PARAMETERS = (
    plain('rate', 50.0, 'integration and odometry rate', 'Hz', (1.0, 2000.0), read_only=True),
    plain('control_timeout', 0.5, 'zero control after this long without commands', 's',
          (1e-3, 3600.0)),
    plain('mode', 'effort', 'effort: follow control_sequence; velocity: follow cmd_vel',
          read_only=True, choices=('effort', 'velocity')),
    plain('frame_id', 'odom', 'odometry frame', read_only=True),
    plain('child_frame_id', 'base_link', 'body frame', read_only=True),
    plain('publish_clock', False, 'own the clock: publish /clock (sim time)', read_only=True),
    plain('time_scale', 1.0, 'simulated seconds per wall second when publishing /clock', '',
          (1e-3, 1000.0), read_only=True),
    plain('start_time', 0.0, 'initial /clock time', 's', (0.0, 1e9), read_only=True),
    plain('cmd_vel_stamped', False, 'cmd_vel is TwistStamped', read_only=True),
    plain('u_min', (), 'lower bounds applied to the controls received: one per control, or '
          'one for all; empty: none', read_only=True),
    plain('u_max', (), 'upper bounds applied to the controls received (as u_min)',
          read_only=True),
    plain('robot_radius', 0.0, "the robot's radius: closer to an obstacle is a collision "
          '(a diagnostic)', 'm', (0.0, 100.0), read_only=True),
    COSTMAP_THRESHOLD,
    JOINT_NAMES,
    plain('publish_tf', True, 'broadcast frame_id -> child_frame_id on /tf', read_only=True),
)


class SimulatorNode(Node):
    """``nh_tracking_sim``: topics and parameters in docs/ros.md.

    It holds :attr:`problems` (what went wrong, for every callback) and the
    :attr:`obstacle_listener` (markers and costmap cells, for the clearance check).
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('nh_tracking_sim', **kwargs)
        self.problems = ProblemLog(self)
        model, params = declare_model(self)
        self.model = model
        self.system = models.create_parametrised(model, **params)
        self.pose_map = PoseMap(self.system)
        n, k = self.system.n, self.system.k
        initial = declare(self, plain('initial_state', (0.0,) * (n + k),
                                      f'initial q then v ({n} + {k} numbers)'))
        initial = np.asarray(initial, dtype=float)
        if initial.size != n + k or not np.all(np.isfinite(initial)):
            raise ValueError(f'parameter initial_state needs {n + k} finite numbers '
                             f'(q then v of {model}), got {initial.tolist()}')
        p = declare_all(self, PARAMETERS)
        self.rate, self.control_timeout, self.mode = p['rate'], p['control_timeout'], p['mode']
        self.frame, self.child_frame = p['frame_id'], p['child_frame_id']
        self.publish_clock, scale, start = p['publish_clock'], p['time_scale'], p['start_time']
        stamped = p['cmd_vel_stamped']
        bounds = bounds_from_lists(tuple(p['u_min']), tuple(p['u_max']), self.system.r, 'u')
        self.saturation = None if bounds is None else np.vstack(
            [np.broadcast_to(b, self.system.r) for b in bounds])
        self.robot_radius = p['robot_radius']
        self.collisions = 0  # steps ended closer than robot_radius to an obstacle

        self._lock = threading.Lock()
        self._q, self._v = initial[:n].copy(), initial[n:].copy()
        self._controls: tuple[int, np.ndarray, np.ndarray] | None = None
        self._command: np.ndarray | None = None
        self._command_ns = 0
        self._step_ns = int(round(1e9 / self.rate))
        self._sim_ns = int(round(start * 1e9)) if self.publish_clock else self._clock_ns()
        self._last_ns = self._sim_ns
        self._last_steady_ns = time.monotonic_ns()

        joints = joint_mapping(p['joint_names'], self.pose_map)
        by_coordinate = {c: joint for joint, c in joints.items()}
        self.joint_names = [by_coordinate[h] for h in self.pose_map.hidden]
        self.pub_odom = self.create_publisher(Odometry, 'odom', 10)
        self.pub_joints = (self.create_publisher(JointState, 'joint_states', 10)
                           if joints else None)
        self.pub_tf = self.create_publisher(TFMessage, '/tf', 100) if p['publish_tf'] else None
        self.pub_clock = (self.create_publisher(ClockMsg, '/clock', 10)
                          if self.publish_clock else None)
        # volatile: matches latched (the planner's) and ordinary publishers alike
        self.create_subscription(JointTrajectory, 'control_sequence', self.on_controls, 10)
        self.create_subscription(TwistStamped if stamped else Twist, 'cmd_vel',
                                 self.on_cmd_vel, 10)
        self.create_subscription(PoseWithCovarianceStamped, 'initialpose', self.on_initialpose,
                                 10)
        self.obstacle_listener: ObstacleListener[CellsByX] = ObstacleListener(
            self, self.problems, self.frame, p['costmap_threshold'], CellsByX, NO_CELLS_BY_X)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.twins = TwinWatch(self, 'simulate the robot (odometry, /tf, /clock)')
        self.create_timer(1.0, self._report_twin, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.add_post_set_parameters_callback(self._apply_parameters)
        if self.publish_clock:
            self.create_timer(1.0 / (self.rate * scale), self.step,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
        else:
            self.create_timer(1.0 / self.rate, self.step)
        self.get_logger().info(f'simulating {model} {params} from {initial.tolist()}, '
                               f'{self.mode} mode at {self.rate:g} Hz')

    @guarded('parameter change')
    def _apply_parameters(self, params) -> None:
        for p in params:
            if p.name == 'control_timeout':
                self.control_timeout = p.value
        physical = {p.name: float(p.value) for p in params if p.name in self.system.parameters}
        if physical:
            self._change_model(physical)

    def _change_model(self, physical: dict[str, float]) -> None:
        """Change the robot's physical parameters now (a payload, a correction), qdot carried."""
        old = self.system
        system = models.with_parameters(old, self.model, physical)
        with self._lock:
            self._v = carried(old, system, self._q, self._v)[0]
            self.system, self.pose_map = system, PoseMap(system)
        self.get_logger().info(f'simulating {self.model} {system.parameters} from now on')

    def _clock_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _now_ns(self) -> int:
        return self._sim_ns if self.publish_clock else self._clock_ns()

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) now (a copy)."""
        with self._lock:
            return self._q.copy(), self._v.copy()

    @guarded('control_sequence')
    def on_controls(self, msg: JointTrajectory) -> None:
        start, offsets, efforts = cv.controls_to_arrays(msg, self.system.control_names)
        if self.saturation is not None:  # the actuators' limits
            efforts = np.clip(efforts, *self.saturation)
        with self._lock:
            self._controls = (start, offsets, efforts)
            self._command_ns = self._now_ns()

    @guarded('cmd_vel')
    def on_cmd_vel(self, msg) -> None:
        twist = cv.twist_array(msg.twist if isinstance(msg, TwistStamped) else msg, 'cmd_vel')
        with self._lock:
            self._command = twist
            self._command_ns = self._now_ns()

    @guarded('initialpose')
    def on_initialpose(self, msg: PoseWithCovarianceStamped) -> None:
        cv.check_frame(msg.header.frame_id, self.frame, 'initial pose')
        pose = cv.pose_array(msg.pose.pose, 'initial pose')
        with self._lock:
            self._q = self.pose_map.configuration(pose, self._q)
            self._v = np.zeros(self.system.k)
            self._controls, self._command = None, None
        self.get_logger().info(f'reset to pose {np.round(pose, 3).tolist()} at rest')

    def _pieces(self, t0: int, t1: int) -> list[Piece]:
        """[(from, to, u)] covering [t0, t1]: the control sequence held per interval.

        Zero outside it and from the instant the control timeout expires (a cut in the step).
        """
        zero = np.zeros(self.system.r)
        expiry = self._command_ns + int(round(self.control_timeout * 1e9))
        if self._controls is None or t0 >= expiry:
            return [(t0, t1, zero)]
        start, offsets, efforts = self._controls
        h = offsets[-1] - offsets[-2] if len(offsets) > 1 else self.control_timeout
        edges = [start + int(round(o * 1e9)) for o in offsets] + [
            start + int(round((offsets[-1] + h) * 1e9))]
        cuts = sorted({t0, t1, *[e for e in edges + [expiry] if t0 < e < t1]})
        pieces = []
        for a, b in zip(cuts[:-1], cuts[1:]):
            i = int(np.searchsorted(edges, a, side='right')) - 1
            active = a < expiry and 0 <= i < len(efforts)
            pieces.append((a, b, efforts[i] if active else zero))
        return pieces

    def _jumped(self, t0: int, t1: int) -> bool:
        """Whether the clock jumped between steps (logged): its time is not motion.

        On the system clock: it moved more than :data:`CLOCK_JUMP` (and five steps) away from
        the steady clock (a pause of this process is time that passed, and is integrated); on
        ``/clock``: it moved on more than that in one step, or back.
        """
        steady = time.monotonic_ns()
        passed, self._last_steady_ns = (steady - self._last_steady_ns) * 1e-9, steady
        gap, limit = (t1 - t0) * 1e-9, max(CLOCK_JUMP, 5.0 * self._step_ns * 1e-9)
        clock = self.get_clock()
        on_topic = isinstance(clock, ROSClock) and clock.ros_time_is_active
        jumped = gap < 0.0 or (gap > limit if on_topic else abs(gap - passed) > limit)
        if jumped:
            self.get_logger().warn(f'the clock jumped {gap:+.3f} s in a step ({passed:.3f} s '
                                   'passed): not integrated, the robot held where it was')
        return jumped

    @guarded('simulation step')
    def step(self) -> None:
        t0 = self._sim_ns if self.publish_clock else self._last_ns
        t1 = t0 + self._step_ns if self.publish_clock else self._clock_ns()
        self._last_ns = t1
        if t1 == t0 or (not self.publish_clock and (t0 == 0 or self._jumped(t0, t1))):
            return  # (t0 = 0: on /clock, before its first message)
        if self.twins.yields:  # the twin started first simulates the robot: this one waits
            self._sim_ns = t1
            return
        # One step under the lock: a parameter change or a reset is applied between steps,
        # never lost to a step that began before it.
        with self._lock:
            q, v = self._q, self._v
            if self.mode == 'velocity':  # the command driven until it expires, then at rest
                expiry = self._command_ns + int(round(self.control_timeout * 1e9))
                v = np.zeros(self.system.k)
                if self._command is not None and t0 < expiry:
                    driven = self.pose_map.velocity(q, self._command)
                    q = self._integrate(q, driven, [(t0, min(t1, expiry), None)])[0]
                    v = driven if t1 <= expiry else v
            else:
                q, v = self._integrate(q, v, self._pieces(t0, t1))
            self._q, self._v = q, v
        if self.pub_clock is not None:
            self._sim_ns = t1
            self.pub_clock.publish(ClockMsg(clock=msgs.time_msg(t1)))
        self._publish_state(q, v, t1)

    def _report_twin(self) -> None:
        """Publish an ERROR diagnostic, each second while another node has this one's name."""
        if self.twins.check() is TwinVerdict.ALONE:
            return
        array = DiagnosticArray(status=[msgs.diagnostic_status(
            f'{self.get_name()}: simulating', self.get_fully_qualified_name(),
            DiagnosticStatus.ERROR, self.twins.describe(), {})])
        array.header.stamp = msgs.time_msg(self._now_ns())
        self.pub_diag.publish(array)

    def _integrate(self, q: np.ndarray, v: np.ndarray, pieces: list[Piece]
                   ) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) after the pieces: efforts held, or (u None) the velocity v driven."""
        for a, b, u in pieces:
            # The dynamics are autonomous: integrate each piece from 0 over its length in
            # integer nanoseconds. Wall-clock stamps (~1.8e18 ns) times 1e-9 would collapse
            # pieces a few ns long to nothing.
            if u is None:
                q = drive(self.system, q, v, (b - a) * 1e-9)
                continue
            try:
                traj = simulate(self.system, q, v, [0.0, (b - a) * 1e-9], u[None, :],
                                rtol=1e-9, atol=1e-11)
            except LeftDomain as exc:  # as at a mechanical stop: the robot halts short of it
                self.problems.fail('simulation step', LeftDomain(f'{exc}; stopped short of it'))
                return q, np.zeros(self.system.k)
            q, v = traj.q[-1], traj.v[-1]
        return q, v

    def _publish_state(self, q: np.ndarray, v: np.ndarray, stamp: int) -> None:
        """Odometry, joint states and /tf of (q, v) at ``stamp``."""
        pose = self.pose_map.pose(q)
        self.pub_odom.publish(msgs.odometry_msg(self.frame, self.child_frame, stamp, pose,
                                                self.pose_map.body_twist(q, v)))
        if self.pub_joints is not None:
            self.pub_joints.publish(msgs.joint_state_msg(
                stamp, self.joint_names, q[self.pose_map.hidden],
                self.pose_map.hidden_rates(q, v)))
        if self.pub_tf is not None:
            self.pub_tf.publish(msgs.tf_msg(self.frame, self.child_frame, stamp, pose))
        self._check_clearance(pose, stamp)

    def destroy_node(self) -> None:
        self.obstacle_listener.close()
        super().destroy_node()

    def _check_clearance(self, pose: np.ndarray, stamp: int) -> None:
        """Count a step that ends closer than robot_radius to an obstacle, and report it."""
        obstacles = self.obstacle_listener
        cells = obstacles.costmap  # sorted: the check looks only at the cells near the robot
        discs = obstacles.markers.discs(stamp)
        near = cells.near(pose, self.robot_radius)  # (a cell farther away is no collision)
        clearance = gap(pose, discs, near, cells.cell_size) - self.robot_radius
        if clearance >= 0:
            return
        self.collisions += 1
        text = f'collision: {-clearance:.3f} m inside an obstacle at ({pose[0]:.2f}, ' \
               f'{pose[1]:.2f})'
        if self.collisions == 1 or self.collisions % 50 == 0:
            self.get_logger().warn(f'{text} ({self.collisions} steps so far)')
        array = DiagnosticArray(status=[msgs.diagnostic_status(
            f'{self.get_name()}: clearance', self.get_fully_qualified_name(),
            DiagnosticStatus.WARN, text, {'collisions': self.collisions})])
        array.header.stamp = msgs.time_msg(stamp)
        self.pub_diag.publish(array)
