"""The planner node: reference + odometry in, optimal tracking plans out.

A worker thread owns the solver, so executor callbacks only copy messages in and never wait
on a solve; the latest odometry wins. Every callback is guarded: bad input is rejected with
one log line and a diagnostic, and the last good plan stays in force.
"""
from __future__ import annotations

import sys
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry, Path
from nav_msgs.srv import GetPlan
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory
from visualization_msgs.msg import MarkerArray

from nh_tracking import models
from nh_tracking.poses import PoseMap
from nh_tracking.problem import Solution
from nh_tracking.receding_horizon import PlannerSettings, PlanOutcome, RecedingHorizonPlanner
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.parameters import declare, declare_model
from nh_tracking.ros.safety import SafeNode, guarded
from nh_tracking.solvers import METHODS

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
SWITCH_INTERVAL = 5e-4  # s
SERVICE_QUEUE = 100  # requests
SETTINGS = ("horizon", "steps", "epsilon", "omega", "terminal", "method", "max_solve_time",
            "wrap_angles", "compiled")


@dataclass
class _Odometry:
    ns: int
    q: np.ndarray
    v: np.ndarray
    received: float  # time.perf_counter() at receipt, for latency figures


class PlannerNode(SafeNode):
    """``nh_tracking_planner``: see DESIGN §3 for topics, services and parameters."""

    def __init__(self, **kwargs) -> None:
        super().__init__("nh_tracking_planner", **kwargs)
        self.model, model_params = declare_model(self)
        d = PlannerSettings()
        declare(self, "horizon", d.horizon, "planning horizon [s]", (0.05, 600.0))
        declare(self, "steps", d.steps, "intervals on the horizon", (2, 2000))
        declare(self, "epsilon", d.epsilon, "control weight eps", (1e-9, 1e9))
        declare(self, "omega", d.omega, "terminal cost weight (terminal=cost)", (1e-9, 1e9))
        declare(self, "terminal", d.terminal, "terminal condition: cost | equality")
        declare(self, "method", d.method, f"solver: one of {list(METHODS)}")
        declare(self, "max_solve_time", d.max_solve_time,
                "deadline of one solve [s]; a later solve keeps the previous plan", (1e-3, 60.0))
        declare(self, "wrap_angles", d.wrap_angles, "compare angles modulo 2 pi")
        declare(self, "compiled", d.compiled, "solve with the NLP compiled to C (the first "
                "start per machine and structure compiles for seconds; then cached)")
        self.replan_period = declare(self, "replan_period", 0.1, "time between replans [s]",
                                     (1e-3, 60.0))
        self.cmd_rate = declare(self, "cmd_rate", 20.0, "cmd_vel publishing rate [Hz]",
                                (0.1, 1000.0))
        self.replan_on_odom = declare(self, "replan_on_odom", False,
                                      "also replan on every odometry message (latest wins)")
        self.odom_timeout = declare(self, "odom_timeout", 0.5,
                                    "odometry older than this is stale [s]", (1e-3, 3600.0))
        self.frame = declare(self, "frame_id", "odom", "fixed frame of references and odometry",
                             read_only=True)
        stamped = declare(self, "cmd_vel_stamped", False, "publish TwistStamped on cmd_vel",
                          read_only=True)
        self.system = models.create(self.model, **model_params)
        self.pose_map = PoseMap(self.system)
        self.planner = RecedingHorizonPlanner(self.system, self._settings_from_parameters())
        self.planner.prepare()

        self._lock = threading.Lock()  # guards the fields below shared with the worker
        self._solve_lock = threading.Lock()  # one solve at a time: worker, services, params
        self._odom: _Odometry | None = None
        self._outcome: PlanOutcome | None = None
        self._plan_traj = None
        self._stale = False
        # (odometry receipt -> control_sequence published, of which in the numerical planner,
        # of which in the NLP solver) [s], for the recent plans
        self.latencies: deque[tuple[float, float, float]] = deque(maxlen=2000)
        self._epoch_ns = self.get_clock().now().nanoseconds

        self.pub_path = self.create_publisher(Path, "planned_path", LATCHED)
        self.pub_controls = self.create_publisher(JointTrajectory, "control_sequence", LATCHED)
        self.pub_cmd = self.create_publisher(TwistStamped if stamped else Twist, "cmd_vel", 10)
        self.pub_markers = self.create_publisher(MarkerArray, "planned_markers", LATCHED)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Path, "reference_path", self.on_reference_path, 10)
        self.create_subscription(MultiDOFJointTrajectory, "reference_trajectory",
                                 self.on_reference_trajectory, 10)
        self.create_subscription(Odometry, "odom", self.on_odom, 10)
        services = MutuallyExclusiveCallbackGroup()
        # a burst of requests is queued, not dropped (the default keeps only the last 10)
        requests = QoSProfile(depth=SERVICE_QUEUE, reliability=ReliabilityPolicy.RELIABLE)
        self.create_service(GetPlan, "plan", self.on_plan, callback_group=services,
                            qos_profile=requests)
        self.create_service(Trigger, "replan", self.on_replan, callback_group=services,
                            qos_profile=requests)
        self._replan_timer = self.create_timer(self.replan_period, self._wake_worker)
        self._cmd_timer = self.create_timer(1.0 / self.cmd_rate, self.publish_cmd_vel)
        self.create_timer(1.0, self.publish_diagnostics)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        # The solver thread must get the interpreter promptly when odometry arrives: CPython's
        # default switch interval (5 ms) alone would add up to 5 ms to every replan's latency.
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL))
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._work, name="nh_tracking_solver",
                                        daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"planning for {self.model} {model_params} with {self.planner.settings}")

    # time -------------------------------------------------------------------------------------
    def _seconds(self, ns: int) -> float:
        return (ns - self._epoch_ns) * 1e-9

    def _ns(self, seconds: float) -> int:
        return self._epoch_ns + int(round(seconds * 1e9))

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    # inputs -----------------------------------------------------------------------------------
    def on_problem(self) -> None:
        self.publish_diagnostics()

    @guarded("reference_path")
    def on_reference_path(self, msg: Path) -> None:
        stamps, poses = cv.path_to_arrays(msg, self.frame, self._now_ns())
        self._set_reference(stamps, poses, None)

    @guarded("reference_trajectory")
    def on_reference_trajectory(self, msg: MultiDOFJointTrajectory) -> None:
        stamps, poses, twists = cv.multidof_to_arrays(msg, self.frame, self._now_ns())
        self._set_reference(stamps, poses, twists)

    def _set_reference(self, stamps: np.ndarray, poses: np.ndarray, twists) -> None:
        with self._lock:
            hidden = None if self._odom is None else self._odom.q
        times = np.array([self._seconds(int(ns)) for ns in stamps])
        reference = self.pose_map.reference(times, poses, twists, hidden)
        with self._solve_lock:
            self.planner.set_reference(reference)
        self.get_logger().info(f"new reference: {len(times)} points over "
                               f"{times[-1] - times[0]:.2f} s")
        self._wake_worker()

    @guarded("odom")
    def on_odom(self, msg: Odometry) -> None:
        received = time.perf_counter()
        ns, pose, twist = cv.odom_to_arrays(msg, self.frame)
        with self._lock:
            prev = self._odom
        q_prev = None if prev is None else prev.q
        v_prev = None if prev is None else prev.v
        dt = 0.0 if prev is None else (ns - prev.ns) * 1e-9
        q = self.pose_map.configuration(pose, q_prev)
        v = self.pose_map.velocity(q, twist)
        q = self.pose_map.dead_reckon(pose, v, q_prev, v_prev, dt)
        with self._lock:
            self._odom = _Odometry(ns, q, v, received)
        if self.replan_on_odom:
            self._wake_worker()

    # planning ---------------------------------------------------------------------------------
    def _wake_worker(self) -> None:
        self._wake.set()

    def _work(self) -> None:
        while not self._stop.is_set():
            if self._wake.wait(0.2):
                self._wake.clear()
                if not self._stop.is_set():
                    self._replan()

    @guarded("replanning")
    def _replan(self) -> tuple[bool, str]:
        with self._lock:
            odom = self._odom
        if self.planner.reference is None:
            return False, "no reference yet"
        if odom is None:
            return False, "no odometry yet"
        age = (self._now_ns() - odom.ns) * 1e-9
        if age > self.odom_timeout:
            with self._lock:
                newly_stale, self._stale = not self._stale, True
            if newly_stale:
                self.get_logger().warn(f"odometry is {age:.2f} s old: stopped commanding")
            return False, f"odometry is stale ({age:.2f} s old); not planning"
        with self._solve_lock:
            outcome = self.planner.plan(self._seconds(odom.ns), odom.q, odom.v)
        plan = outcome.plan
        start_ns = self._ns(plan.t[0])
        # the control sequence first: it is what the robot waits for
        self.pub_controls.publish(cv.control_sequence_msg(
            self.frame, start_ns, plan.t[:-1] - plan.t[0], self.system.control_names, plan.u))
        self.latencies.append((time.perf_counter() - odom.received,
                               self.planner.stats.plan_durations[-1], outcome.solve_time))
        trajectory = plan.trajectory()
        with self._lock:
            if self._stale:
                self.get_logger().info("odometry is fresh again: planning resumed")
            self._stale = False
            self._outcome = outcome
            self._plan_traj = trajectory
        self._publish_display(outcome)
        return True, (f"{outcome.status}: {outcome.message} "
                      f"({outcome.solve_time * 1e3:.1f} ms)")

    def _publish_display(self, outcome: PlanOutcome) -> None:
        """planned_path and planned_markers (markers only when someone listens)."""
        plan = outcome.plan
        stamps = [self._ns(t) for t in plan.t]
        poses = np.array([self.pose_map.pose(q) for q in plan.q])
        self.pub_path.publish(cv.path_msg(self.frame, stamps, poses))
        if self.pub_markers.get_subscription_count() > 0:
            reference = np.array([self.pose_map.pose(q) for q in outcome.reference])
            self.pub_markers.publish(cv.plan_markers(self.frame, stamps[0], poses[:, :3],
                                                     reference[:, :3]))

    @guarded("cmd_vel")
    def publish_cmd_vel(self) -> None:
        """The plan's velocity now, as a body twist; zero when odometry is stale."""
        with self._lock:
            traj, stale = self._plan_traj, self._stale
        if traj is None:
            return
        now = self._now_ns()
        t = self._seconds(now)
        twist = np.zeros(4)
        if not stale and traj.t[0] <= t <= traj.t[-1]:
            q, v = traj.sample(t)
            twist = self.pose_map.body_twist(q[0], v[0])
        if self.pub_cmd.msg_type is TwistStamped:
            self.pub_cmd.publish(cv.twist_stamped_msg(self.frame, now, twist))
        else:
            self.pub_cmd.publish(cv.twist_msg(twist))

    # services ---------------------------------------------------------------------------------
    @guarded("plan service")
    def on_plan(self, request: GetPlan.Request, response: GetPlan.Response) -> GetPlan.Response:
        """A plan from ``start`` (at rest), or from the latest odometry when start's frame is
        empty, tracking the active reference; an empty path when there is none to give.
        Solved in the callback (bounded by max_solve_time), not queued behind the worker."""
        response.plan = Path()
        response.plan.header.frame_id = self.frame
        try:
            solution = self._preview(request.start)
        except cv.InputRejected as exc:
            self.reject("plan request", str(exc))
            return response
        if solution is None:
            return response
        stamps = [self._ns(t) for t in solution.t]
        response.plan = cv.path_msg(self.frame, stamps,
                                    np.array([self.pose_map.pose(q) for q in solution.q]))
        return response

    def _preview(self, start) -> Solution | None:
        with self._lock:
            odom = self._odom
        if self.planner.reference is None:
            self.get_logger().warn("plan request: no reference to track yet")
            return None
        if not start.header.frame_id:
            if odom is None:
                self.get_logger().warn("plan request: empty start and no odometry yet")
                return None
            t, q, v = self._seconds(odom.ns), odom.q, odom.v
        else:
            cv.check_frame(start.header.frame_id, self.frame, "plan start")
            pose = cv.pose_array(start.pose, "plan start")
            q = self.pose_map.configuration(pose, None if odom is None else odom.q)
            t, v = self._seconds(self._now_ns()), np.zeros(self.system.k)
        with self._solve_lock:
            solution = self.planner.preview(t, q, v)
        if not solution.success:
            self.get_logger().warn(f"plan request: solver failed ({solution.message})")
            return None
        return solution

    @guarded("replan service")
    def on_replan(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        result = self._replan()
        response.success, response.message = result if result else (False, self.take_problem())
        return response

    # parameters -------------------------------------------------------------------------------
    def _settings_from_parameters(self, overrides: dict | None = None) -> PlannerSettings:
        values = {name: self.get_parameter(name).value for name in SETTINGS}
        values.update(overrides or {})
        return PlannerSettings(**values)

    def _validate_parameters(self, params) -> SetParametersResult:
        changes = {p.name: p.value for p in params}
        try:
            self._settings_from_parameters({k: v for k, v in changes.items() if k in SETTINGS})
            physical = {k: v for k, v in changes.items() if k in self.system.parameters}
            if physical:
                models.create(self.model, **{**self.system.parameters, **physical})
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    @guarded("parameter change")
    def _apply_parameters(self, params) -> None:
        names = {p.name for p in params}
        if "replan_period" in names:
            self.replan_period = self.get_parameter("replan_period").value
            self._replan_timer.timer_period_ns = int(self.replan_period * 1e9)
        if "cmd_rate" in names:
            self.cmd_rate = self.get_parameter("cmd_rate").value
            self._cmd_timer.timer_period_ns = int(1e9 / self.cmd_rate)
        if "odom_timeout" in names:
            self.odom_timeout = self.get_parameter("odom_timeout").value
        if "replan_on_odom" in names:
            self.replan_on_odom = self.get_parameter("replan_on_odom").value
        physical = {n: self.get_parameter(n).value for n in self.system.parameters}
        with self._solve_lock:
            if names & set(self.system.parameters):  # the model changed: start afresh
                reference = self.planner.reference
                self.system = models.create(self.model, **physical)
                self.pose_map = PoseMap(self.system)
                self.planner = RecedingHorizonPlanner(self.system, self.planner.settings)
                if reference is not None:
                    self.planner.set_reference(reference)
            if names & set(SETTINGS):  # keeps the warm start
                self.planner.update(**{n: self.get_parameter(n).value for n in SETTINGS})
            self.planner.prepare()
        self.get_logger().info(f"parameters changed: {sorted(names)}")

    # diagnostics ------------------------------------------------------------------------------
    @guarded("diagnostics")
    def publish_diagnostics(self) -> None:
        with self._lock:
            outcome, stale = self._outcome, self._stale
        problem = self.take_problem()
        st = self.planner.stats
        level, message = DiagnosticStatus.OK, "planning"
        if self.planner.reference is None or self._odom is None:
            level, message = DiagnosticStatus.WARN, "waiting for reference and odometry"
        elif stale:
            level, message = DiagnosticStatus.STALE, "odometry is stale: not commanding"
        elif outcome is not None and outcome.status != "optimal":
            level, message = DiagnosticStatus.WARN, f"{outcome.status}: {outcome.message}"
        if problem and level == DiagnosticStatus.OK:
            level, message = DiagnosticStatus.WARN, problem
        times = np.array(st.solve_times[-200:]) if st.solve_times else np.zeros(1)
        values = {
            "status": outcome.status if outcome else "none", "plans": st.plans,
            "optimal": st.optimal, "shifted": st.shifted, "fallbacks": st.fallbacks,
            "deadline_misses": st.deadline_misses, "rejected_inputs": self.rejected_inputs,
            "errors": self.errors, "last_problem": problem,
            "solve_time_last_ms": f"{(outcome.solve_time if outcome else 0.0) * 1e3:.2f}",
            "solve_time_p50_ms": f"{np.percentile(times, 50) * 1e3:.2f}",
            "solve_time_p99_ms": f"{np.percentile(times, 99) * 1e3:.2f}",
        }
        array = DiagnosticArray(status=[cv.diagnostic_status(
            f"{self.get_name()}: planning", self.get_fully_qualified_name(), level, message,
            values)])
        array.header.stamp = cv.time_msg(self._now_ns())
        self.pub_diag.publish(array)

    def destroy_node(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._worker.is_alive() and threading.current_thread() is not self._worker:
            self._worker.join(timeout=10.0)
        super().destroy_node()
