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

"""The ROS layer, end to end: real nodes, the real solver, one Context per test, no launch."""
from functools import partial
import math
import uuid

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import OccupancyGrid, Odometry, Path
from nav_msgs.srv import GetPlan
import numpy as np
import pytest
from rcl_interfaces.msg import Log
from rclpy.clock import JumpThreshold
from rclpy.duration import Duration
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint, MultiDOFJointTrajectory
from visualization_msgs.msg import Marker, MarkerArray

from faults import Faulty
from nh_tracking import models
from nh_tracking.core.metrics import cross_track_error
from nh_tracking.examples.demo import ClosedLoop, sleigh_reference, START
from nh_tracking.examples.experiments import SLEIGH_REFERENCE_START
from nh_tracking.examples.obstacles import costmap_msg
from nh_tracking.ros import conversions as cv
from nh_tracking.ros import messages as msgs
from nh_tracking.ros import PlannerNode, SimulatorNode
from nh_tracking.ros.graph import parameters, wait_until
from nh_tracking.ros.runner import settle_heap
from processes import busy_cores

pytestmark = pytest.mark.timeout(180)


def unique_namespace() -> str:
    return f'/t{uuid.uuid4().hex[:8]}'


@pytest.mark.ros
@pytest.mark.parametrize('kind', ['path', 'trajectory'])
def test_closed_loop_tracks_through_ros_with_inertia_mismatch(graph, kind):
    """Robot 10 % heavier than the planner thinks; cross-track error < 0.05 m after 12 s."""
    loop = ClosedLoop(graph, namespace=unique_namespace())
    reference = sleigh_reference(30.0)
    loop.start(reference, kind, time_scale=5.0)
    assert wait_until(lambda: loop.sim_time() >= START + 14.0, timeout=90.0)
    t, xy = loop.track()
    error = cross_track_error(xy[t - START >= 12.0], reference.q[:, :2])
    assert error.size > 50 and error.max() < 0.05
    stats = loop.planner.planner.stats
    assert stats.plans > 80 and stats.fallbacks == 0


@pytest.mark.ros
@pytest.mark.slow
def test_a_second_clock_on_the_domain_is_named_and_the_loaded_loop_gets_back_on_track(graph):
    """Another world's /clock on this domain, both cores busy: it says why its clock jumps.

    The planner's clock reads now one world's time, now the other's (here
    LEAD s ahead, ticking just after this one's, for 5 s of this world's time from when the echo
    first hears it, and on, up to 45 s, until the planner has read it once: a planner starved
    by the load keeps only the newest of the clock messages it missed, so when it first reads
    the other time is up to the load, and the scenario runs until it has): odometry looks stale
    at times and plans aim at the reference LEAD s on.
    Given no command, the effort-driven sleigh would coast off its curve (4-15 m); it brakes
    while its state is stale and drives on when it is fresh, cutting across to catch up, never
    further off than the reference runs in LEAD s, and is back on the curve once the other clock
    is gone.
    """
    lead = 10
    loop = ClosedLoop(graph, namespace=unique_namespace())
    logs = []
    loop.feeder.create_subscription(Log, '/rosout', logs.append, 100)
    other_clock = loop.feeder.create_publisher(ClockMsg, '/clock', 10)
    heard = []  # this world's time when the echo first heard it: discovery may take a while
    ended = []  # ... and when it stopped
    jumps = []

    def echo(msg: ClockMsg) -> None:
        now = msg.clock.sec + msg.clock.nanosec * 1e-9
        if ended or (heard and now > heard[-1] + lead / 2):  # (or its own echo, heard back)
            return
        heard.append(now)
        if now >= heard[0] + 5.0 and (jumps or now >= heard[0] + 45.0):
            ended.append(now)
            return
        msg.clock.sec += lead
        other_clock.publish(msg)

    loop.feeder.create_subscription(ClockMsg, '/clock', echo, 10)
    jump_handle = loop.planner.get_clock().create_jump_callback(  # noqa: F841 (kept alive)
        JumpThreshold(min_forward=Duration(seconds=lead / 2), min_backward=None,
                      on_clock_change=False), post_callback=jumps.append)
    assert wait_until(lambda: other_clock.get_subscription_count() >= 2, 10.0)
    reference = sleigh_reference(60.0)
    with busy_cores(2):
        loop.start(reference, 'trajectory', time_scale=5.0)
        assert wait_until(lambda: ended and loop.sim_time() >= ended[0] + 15.0, timeout=150.0)
    assert jumps  # the planner did read the other world's time
    t, xy = loop.track()
    error = cross_track_error(xy[t >= START], reference.q[:, :2])
    late = cross_track_error(xy[t >= ended[0] + 11.0], reference.q[:, :2])
    print(f'\ncross-track: start {error[0]:.3f} m, worst {error.max():.3f} m, '
          f'from {ended[0] + 11.0:.0f} s {late.max():.4f} m; {len(jumps)} jumps ahead; the other '
          f'clock for {ended[0] - heard[0]:.1f} s')
    speed = np.linalg.norm(np.diff(reference.q[:, :2], axis=0), axis=1) / np.diff(reference.t)
    misled = error[0] + lead * speed.max()
    assert error.size > 800 and error.max() < misled, (error[0], error.max(), misled)
    assert late.size > 150 and late.max() < 0.1
    named = [entry for entry in logs if '2 nodes publish /clock' in entry.msg]
    assert named and all(entry.level == Log.WARN for entry in named), [e.msg for e in logs]


class WallClockPair:
    """Planner + simulator on the wall clock, the robot starting on the reference.

    The planner freezes the heap as it starts commanding, as the ``planner`` executable does.
    """

    def __init__(self, graph, namespace=None, offset=(0.0, 0.0), planner_params=None):
        self.ns = namespace or unique_namespace()
        q0, v0 = SLEIGH_REFERENCE_START
        start = [q0[0] + offset[0], q0[1] + offset[1], q0[2], *v0]
        self.sim = graph.add(SimulatorNode, namespace=self.ns,
                             parameter_overrides=parameters(initial_state=start, rate=50.0))
        self.planner = graph.add(  # with the planner executable's process hooks, as deployed
            PlannerNode, namespace=self.ns, on_commanding=settle_heap,
            on_released=partial(settle_heap, release=True),
            parameter_overrides=parameters(**(planner_params or {})))
        self.node = graph.plain_node('probe', self.ns)
        self.reference = sleigh_reference(60.0)
        self.offset = np.array(offset)
        self.published = {'path': [], 'control_sequence': [], 'cmd_vel': []}
        self.node.create_subscription(Path, 'planned_path',
                                      lambda m: self.published['path'].append(m), 10)
        self.node.create_subscription(JointTrajectory, 'control_sequence',
                                      lambda m: self.published['control_sequence'].append(m), 10)
        self.node.create_subscription(Twist, 'cmd_vel',
                                      lambda m: self.published['cmd_vel'].append(m), 10)
        self.odom = []
        self.node.create_subscription(Odometry, 'odom', lambda m: self.odom.append(m), 10)

    def publisher(self, msg_type, topic):
        """Return a publisher matched to every subscriber of ``topic``.

        The probe listens to odom and control_sequence itself, so one match alone would not
        mean the node under test.
        """
        pub = self.node.create_publisher(msg_type, topic, 10)
        expected = 2 if topic in ('odom', 'control_sequence') else 1
        assert wait_until(lambda: pub.get_subscription_count() >= expected, 10.0)
        return pub

    def send_reference(self):
        """Send the reference with a zero stamp: it starts when received."""
        msg = msgs.reference_message(self.reference, self.planner.pose_map, 0.0, 'path')
        msg.header.stamp = msgs.time_msg(0)
        for ps in msg.poses:
            ps.pose.position.x += float(self.offset[0])
            ps.pose.position.y += float(self.offset[1])
        self.publisher(Path, 'reference_path').publish(msg)
        assert wait_until(lambda: self.planner.planner.reference is not None, 10.0)
        assert wait_until(lambda: self.planner.planner.stats.optimal >= 3, 20.0)

    def call(self, srv_type, name, request, timeout=20.0):
        client = self.node.create_client(srv_type, f'{self.ns}/{name}')
        assert client.wait_for_service(timeout_sec=10.0)
        future = client.call_async(request)
        assert wait_until(future.done, timeout)
        return future.result()


def _finite_outputs(pair) -> bool:
    paths = all(math.isfinite(p.pose.position.x) and math.isfinite(p.pose.position.y)
                for m in pair.published['path'] for p in m.poses)
    efforts = all(math.isfinite(e) for m in pair.published['control_sequence']
                  for pt in m.points for e in pt.effort)
    twists = all(math.isfinite(m.linear.x) and math.isfinite(m.angular.z)
                 for m in pair.published['cmd_vel'])
    return paths and efforts and twists


@pytest.mark.ros
@pytest.mark.slow
def test_services_answer_before_and_after_a_reference(graph):
    pair = WallClockPair(graph)
    early = pair.call(Trigger, 'replan', Trigger.Request())
    assert not early.success and 'no reference' in early.message
    empty = pair.call(GetPlan, 'plan', GetPlan.Request())
    assert len(empty.plan.poses) == 0
    pair.send_reference()
    done = pair.call(Trigger, 'replan', Trigger.Request())
    assert done.success and done.message.startswith('optimal')
    from_odom = pair.call(GetPlan, 'plan', GetPlan.Request())
    assert len(from_odom.plan.poses) == 31
    xy = np.array([[p.pose.position.x, p.pose.position.y] for p in from_odom.plan.poses])
    assert np.all(np.isfinite(xy)) and cross_track_error(xy, pair.reference.q[:, :2]).max() < 0.1
    request = GetPlan.Request()
    request.start = PoseStamped()
    request.start.header.frame_id = 'odom'
    request.start.pose = msgs.pose_msg(np.array([1.0, 1.5, 0.0, 0.5]))
    from_start = pair.call(GetPlan, 'plan', request)
    first = from_start.plan.poses[0].pose.position
    assert (first.x, first.y) == pytest.approx((1.0, 1.5), abs=1e-9)
    assert all(np.isfinite([p.pose.position.x for p in from_start.plan.poses]))


def _bad_messages(pair):
    good = msgs.reference_message(pair.reference, pair.planner.pose_map, 0.0, 'path')
    good.header.stamp = msgs.time_msg(0)

    def path(edit):
        """Return a fresh copy of the first 20 poses (no shared sub-messages), then ``edit``."""
        msg = Path(header=Header(frame_id='odom', stamp=msgs.time_msg(0)), poses=[
            PoseStamped(header=Header(frame_id=p.header.frame_id, stamp=p.header.stamp),
                        pose=msgs.pose_msg(cv.pose_array(p.pose, 'pose')))
            for p in good.poses[:20]])
        edit(msg)
        return msg

    def nan_pose(m):
        m.poses[5].pose.position.x = float('nan')

    def repeat_stamp(m):
        m.poses[7].header.stamp = m.poses[6].header.stamp

    def other_frame(m):
        m.header.frame_id = 'map'

    def long_quaternion(m):
        m.poses[3].pose.orientation.w = 2.0

    trajectory = msgs.reference_message(pair.reference, pair.planner.pose_map, 0.0, 'trajectory')
    mismatched = MultiDOFJointTrajectory(header=trajectory.header,
                                         joint_names=trajectory.joint_names,
                                         points=list(trajectory.points[:10]))
    mismatched.points[4].transforms = list(mismatched.points[4].transforms) * 2
    infinite = MultiDOFJointTrajectory(header=trajectory.header,
                                       joint_names=trajectory.joint_names,
                                       points=list(trajectory.points[10:20]))
    infinite.points[2].velocities[0].linear.x = float('inf')
    odom = Odometry()
    odom.header.frame_id = 'odom'
    odom.pose.pose.position.y = float('nan')
    odom.pose.pose.orientation.w = 1.0
    wrong_frame_odom = Odometry()
    wrong_frame_odom.header.frame_id = 'map'
    wrong_frame_odom.pose.pose.orientation.w = 1.0
    disc = Marker(type=Marker.CYLINDER, action=Marker.ADD)
    disc.header.frame_id = 'odom'
    disc.scale.x = -0.4
    grid = costmap_msg('odom', np.zeros((0, 3)))
    grid.data = grid.data[:-1]
    return [
        (Path, 'reference_path', Path(header=Header(frame_id='odom')), 'path is empty'),
        (Path, 'reference_path', path(nan_pose), 'NaN'),
        (Path, 'reference_path', path(repeat_stamp), 'not strictly increasing'),
        (Path, 'reference_path', path(other_frame), "frame 'map'"),
        (Path, 'reference_path', path(long_quaternion), 'not unit'),
        (MultiDOFJointTrajectory, 'reference_trajectory', mismatched, '2 transforms'),
        (MultiDOFJointTrajectory, 'reference_trajectory', infinite, 'NaN or Inf'),
        (Odometry, 'odom', odom, 'NaN'),
        (Odometry, 'odom', wrong_frame_odom, "frame 'map'"),
        (MarkerArray, 'obstacles', MarkerArray(markers=[disc]), 'diameter scale.x >= 0'),
        (OccupancyGrid, 'costmap', grid, 'width x height = len(data)'),
    ]


@pytest.mark.ros
@pytest.mark.slow
def test_malformed_input_is_rejected_and_the_last_good_plan_stays(graph):
    pair = WallClockPair(graph)
    logs, diagnostics = [], []
    pair.node.create_subscription(Log, '/rosout', logs.append, 100)
    pair.node.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, 100)
    pair.send_reference()
    reference = pair.planner.planner.reference
    for msg_type, topic, msg, reason in _bad_messages(pair):
        before = pair.planner.problems.rejected_inputs
        plans = pair.planner.planner.stats.plans
        pair.publisher(msg_type, topic).publish(msg)
        assert wait_until(lambda: pair.planner.problems.rejected_inputs == before + 1,
                          10.0), reason
        assert wait_until(lambda: any(
            reason in entry.msg and entry.level == Log.WARN and pair.ns[1:] in entry.name
            for entry in logs), 10.0), (reason, [(e.level, e.name, e.msg) for e in logs[-5:]])
        assert wait_until(lambda: any(
            s.level == DiagnosticStatus.WARN and reason in s.message
            for d in diagnostics for s in d.status), 10.0), reason
        assert pair.planner.planner.reference is reference  # last good reference in force
        assert wait_until(lambda: pair.planner.planner.stats.plans > plans + 2, 10.0)
    assert pair.planner.problems.rejected_inputs == len(_bad_messages(pair))
    assert pair.planner.problems.errors == 0 and _finite_outputs(pair)
    # the simulator rejects a control sequence for joints it does not have, and keeps going
    bad = JointTrajectory(joint_names=['left', 'right'],
                          points=[JointTrajectoryPoint(effort=[1.0, 2.0])])
    count, rejected = len(pair.odom), pair.sim.problems.rejected_inputs  # (it refused the bad
    pair.publisher(JointTrajectory, 'control_sequence').publish(bad)  # obstacles too)
    assert wait_until(lambda: pair.sim.problems.rejected_inputs == rejected + 1, 10.0)
    assert wait_until(lambda: len(pair.odom) > count + 10, 10.0)


@pytest.mark.ros
@pytest.mark.slow
def test_parameter_changes_take_effect_and_bad_ones_are_refused(graph):
    pair = WallClockPair(graph)
    pair.send_reference()
    planner = pair.planner
    result = planner.set_parameters([Parameter('horizon', value=2.0)])[0]
    assert result.successful
    pair.published['control_sequence'].clear()

    def last_offset():
        msgs = pair.published['control_sequence']
        return cv.duration_seconds(msgs[-1].points[-1].time_from_start) if msgs else None

    assert wait_until(lambda: last_offset() == pytest.approx(2.0 - 2.0 / 30), 10.0)
    assert planner.planner.previous is not None  # warm start kept across the change
    for name, value in [('horizon', -1.0), ('steps', 1), ('max_solve_time', 0.0),
                        ('method', 'magic'), ('terminal', 'free'), ('model', 'unicycle'),
                        ('J', -4.0)]:
        outcome = planner.set_parameters([Parameter(name, value=value)])[0]
        assert not outcome.successful, name
        assert outcome.reason, name
    assert planner.get_parameter('horizon').value == 2.0
    assert planner.set_parameters([Parameter('J', value=4.4)])[0].successful
    # rebuilt in the background, then swapped in
    assert wait_until(lambda: planner.planner.system.parameters['J'] == 4.4, 20.0)
    assert wait_until(lambda: planner.planner.stats.optimal >= 3, 10.0)


@pytest.mark.ros
@pytest.mark.slow
def test_two_pairs_in_namespaces_do_not_cross_talk(graph):
    a = WallClockPair(graph, offset=(0.0, 0.0))
    b = WallClockPair(graph, offset=(0.0, 10.0))
    a.send_reference()
    b.send_reference()

    def recent_error(pair: WallClockPair) -> float:
        """Worst cross-track error over the last second of odometry (50 messages at 50 Hz)."""
        if len(pair.odom) < 50:
            return math.inf
        xy = np.array([[m.pose.pose.position.x, m.pose.pose.position.y] for m in pair.odom[-50:]])
        return float(cross_track_error(xy, pair.reference.q[:, :2] + pair.offset).max())

    # each robot converges onto its own reference (how soon depends on the machine's load: the
    # two planners start while the first one is already planning)
    count_a, count_b = len(a.odom), len(b.odom)
    assert wait_until(lambda: len(a.odom) > count_a + 100 and len(b.odom) > count_b + 100
                      and max(recent_error(a), recent_error(b)) < 0.2, 30.0, period=0.1), \
        (recent_error(a), recent_error(b))
    for pair in (a, b):
        assert pair.planner.planner.reference.q[0, 1] == pytest.approx(0.5 + pair.offset[1])
    # the same reference shape 10 m apart, started together: the robots stay 10 m apart (a
    # robot driven by the other's planner would close that gap)
    gap = [m.pose.pose.position for m in (a.odom[-1], b.odom[-1])]
    assert math.hypot(gap[1].x - gap[0].x, gap[1].y - gap[0].y) == pytest.approx(10.0, abs=0.5)


def _unicycle_sim(graph, **overrides):
    ns = unique_namespace()
    sim = graph.add(SimulatorNode, namespace=ns, parameter_overrides=parameters(
        model='unicycle', initial_state=[0.0, 0.0, 0.0, 0.0, 0.0], rate=100.0, **overrides))
    probe = graph.plain_node('probe', ns)
    return sim, probe


@pytest.mark.ros
def test_simulator_holds_controls_until_the_timeout_then_coasts(graph):
    """U = (1, 0) for 10 s is sent once.

    It applies from its stamp until control_timeout (0.3 s) after receipt, then the unicycle coasts
    (no drift terms in its dynamics).
    """
    sim, probe = _unicycle_sim(graph, control_timeout=0.3)
    pub = probe.create_publisher(JointTrajectory, 'control_sequence', 10)
    assert wait_until(lambda: pub.get_subscription_count() > 0, 10.0)
    now = sim.get_clock().now().nanoseconds
    pub.publish(msgs.control_sequence_msg('odom', now, np.arange(0.0, 10.0, 0.1),
                                          sim.system.control_names, np.tile([1.0, 0.0], (100, 1))))
    assert wait_until(lambda: sim.state[1][0] > 0.05, 5.0)
    wait_until(lambda: False, 1.0)
    speed = sim.state[1][0]
    # applied from the first step after receipt (not retroactively; one 10 ms step of slack)
    # and never past receipt + timeout
    latest = (sim._command_ns - now) * 1e-9 + 0.3
    assert 0.29 <= speed <= latest + 1e-9
    wait_until(lambda: False, 0.5)
    assert sim.state[1][0] == pytest.approx(speed, abs=1e-9)


@pytest.mark.ros
def test_simulator_physical_parameters_change_at_run_time_and_the_motion_goes_on(graph):
    """A sleigh's J and m set while it slides: new numbers in its dynamics, qdot kept.

    Its basis scales with m and J, so the quasi-velocities change with them; qdot must not.
    With its blade at the centre of mass (a = 0) it slides at a constant speed and turn rate,
    so however many steps the simulator takes while the parameters are set, qdot is comparable.
    """
    ns = unique_namespace()
    sim = graph.add(SimulatorNode, namespace=ns, parameter_overrides=parameters(
        model='chaplygin_sleigh', a=0.0, initial_state=[0.0, 0.0, 0.0, 0.3, 1.0], rate=100.0))
    family = sim.system.family
    assert wait_until(lambda: sim.state[0][0] > 0.05, 5.0)
    (q, v), old = sim.state, sim.system
    assert sim.set_parameters([Parameter('J', value=5.2), Parameter('m', value=0.8)])[0] \
        .successful
    (q_now, v_now), new = sim.state, sim.system
    assert sim.system.family is family and sim.system.parameters['J'] == 5.2
    # steps apart: speed and turn rate nearly the same, the quasi-velocities 10 % and more apart
    motion = lambda qdot: np.array([np.hypot(qdot[0], qdot[1]), qdot[2]])  # noqa: E731
    assert motion(new.rho(q_now) @ v_now) == pytest.approx(motion(old.rho(q) @ v), abs=5e-3)
    assert np.abs(v_now - v).max() > 0.08
    built = models.chaplygin_sleigh(m=0.8, J=5.2, a=0.0)
    q, v = sim.state
    assert np.allclose(np.concatenate(sim.system.dynamics(q, v)),
                       np.concatenate(built.dynamics(q, v)), atol=1e-12)
    assert sim.set_parameters([Parameter('a', value=0.3)])[0].successful
    assert sim.system.parameters == {'m': 0.8, 'J': 5.2, 'a': 0.3}
    assert wait_until(lambda: sim.state[0][0] > q[0] + 0.05, 5.0)  # and it steps on


@pytest.mark.ros
def test_simulator_velocity_mode_follows_cmd_vel_and_initialpose_resets(graph):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    sim, probe = _unicycle_sim(graph, mode='velocity', control_timeout=5.0)
    odoms = []
    probe.create_subscription(Odometry, 'odom', odoms.append, 100)
    pub = probe.create_publisher(Twist, 'cmd_vel', 10)
    assert wait_until(lambda: pub.get_subscription_count() > 0, 10.0)
    pub.publish(msgs.twist_msg(np.array([0.5, 0.3, 0.0, 0.4])))  # lateral slip is projected out
    assert wait_until(lambda: sim.state[0][0] > 0.2, 10.0)
    q, v = sim.state
    assert v == pytest.approx([0.5, 0.4], abs=1e-6)
    assert wait_until(lambda: odoms and odoms[-1].twist.twist.linear.x == pytest.approx(0.5), 5.0)
    assert abs(odoms[-1].twist.twist.linear.y) < 1e-9
    reset = PoseWithCovarianceStamped()
    reset.header.frame_id = 'odom'
    reset.pose.pose = msgs.pose_msg(np.array([3.0, -2.0, 0.0, 1.0]))
    pose_pub = probe.create_publisher(PoseWithCovarianceStamped, 'initialpose', 10)
    assert wait_until(lambda: pose_pub.get_subscription_count() > 0, 10.0)
    pub.publish(msgs.twist_msg(np.zeros(4)))
    assert wait_until(lambda: abs(sim.state[1][0]) < 1e-9, 5.0)
    pose_pub.publish(reset)
    assert wait_until(lambda: sim.state[0][0] == pytest.approx(3.0, abs=1e-6), 5.0)
    assert sim.state[0] == pytest.approx([3.0, -2.0, 1.0], abs=1e-6)


@pytest.mark.ros
@pytest.mark.slow
def test_stale_odometry_stops_commanding_and_fresh_odometry_resumes(graph):
    pair = WallClockPair(graph, planner_params={'odom_timeout': 0.3, 'cmd_rate': 50.0})
    statuses = []
    pair.node.create_subscription(DiagnosticArray, '/diagnostics',
                                  lambda m: statuses.extend(m.status), 100)
    pair.send_reference()
    assert wait_until(lambda: any(abs(m.linear.x) > 0.1 for m in pair.published['cmd_vel']), 10)
    graph.executor.remove_node(pair.sim)  # the robot's odometry stops
    assert wait_until(lambda: pair.planner.live.staleness.now, 5.0)
    sequences = len(pair.published['control_sequence'])
    # commands sent before the planner knew may still be on their way: let five more pass
    received = len(pair.published['cmd_vel'])
    assert wait_until(lambda: len(pair.published['cmd_vel']) > received + 5, 5.0)
    pair.published['cmd_vel'][:received + 5] = []
    # slowed along itself at max_decel (1 m/s^2: at most 0.7 s from v_max), then at rest
    assert wait_until(lambda: len(pair.published['cmd_vel']) > 60, 5.0)
    speeds = np.array([abs(m.linear.x) for m in pair.published['cmd_vel']])
    assert (np.diff(speeds) <= 1e-9).all()
    assert all(m.linear.x == 0.0 and m.angular.z == 0.0 for m in pair.published['cmd_vel'][-20:])
    # no new plan while stale, but one to brake (an effort-driven robot coasts on zero effort),
    # renewed at each replan (a driver drops a sequence not renewed within its timeout)
    received = len(pair.published['cmd_vel'])
    assert wait_until(lambda: len(pair.published['cmd_vel']) > received + 20, 5.0)
    renewed = pair.published['control_sequence'][sequences:]
    assert len(renewed) > 3 and all(m == renewed[-1] for m in renewed[-3:])
    assert wait_until(lambda: any(s.level == DiagnosticStatus.STALE for s in statuses), 5.0)
    graph.executor.add_node(pair.sim)  # odometry is back
    assert wait_until(lambda: not pair.planner.live.staleness.now, 5.0)
    assert wait_until(lambda: len(pair.published['control_sequence']) > sequences + 3, 5.0)
    assert wait_until(lambda: abs(pair.published['cmd_vel'][-1].linear.x) > 0.1, 5.0)


@pytest.mark.ros
@pytest.mark.slow
def test_solver_faults_fall_back_with_a_warning_and_never_publish_nan(graph):
    pair = WallClockPair(graph)
    statuses = []
    pair.node.create_subscription(DiagnosticArray, '/diagnostics',
                                  lambda m: statuses.extend(m.status), 100)
    pair.send_reference()
    planner = pair.planner.planner
    real = planner.method
    for fault, reason in (('raise', 'injected solver fault'), ('nan', 'non-finite values')):
        stats = planner.stats
        before = stats.shifted + stats.fallbacks
        planner.method = Faulty(fault, real)
        assert wait_until(lambda: stats.shifted + stats.fallbacks > before + 3, 10.0), reason
        assert wait_until(lambda: any(s.level == DiagnosticStatus.WARN and reason in s.message
                                      for s in statuses), 5.0), reason
        planner.method = real
    # a solver that cannot meet its deadline: late plans are discarded, the old one shifted
    stats = pair.planner.planner.stats
    before = stats.shifted + stats.fallbacks
    # (10 us: a warm replan by Newton steps takes 0.3-0.5 ms, so 1 ms would often be met)
    assert pair.planner.set_parameters([Parameter('max_solve_time', value=1e-5)])[0].successful
    assert wait_until(lambda: stats.shifted + stats.fallbacks > before + 3, 10.0)
    assert wait_until(lambda: any(s.level == DiagnosticStatus.WARN and 'deadline' in s.message
                                  for s in statuses), 5.0)
    assert pair.planner.set_parameters([Parameter('max_solve_time', value=0.25)])[0].successful
    optimal = pair.planner.planner.stats.optimal
    assert wait_until(lambda: pair.planner.planner.stats.optimal > optimal + 3, 10.0)
    assert pair.planner.problems.errors == 0 and _finite_outputs(pair)


@pytest.mark.ros
@pytest.mark.slow
def test_a_user_model_drives_the_planner_and_simulator_by_its_module_path(graph):
    """Drive a user's car-like robot, named in the ``model`` parameter of both nodes.

    It is test/user_robots.py, not in the package: the declared parameters come from its
    spec, the control sequence has its two joints, and the loop tracks a straight reference
    generated by its dynamics.
    """
    import nh_tracking as nht

    ns = unique_namespace()
    car = nht.models.create('user_robots:CAR')
    start = [0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    reference = nht.simulate(car, start[:4], start[4:], np.linspace(0.0, 60.0, 601))
    sim = graph.add(SimulatorNode, namespace=ns, parameter_overrides=parameters(
        model='user_robots:CAR', initial_state=start))
    planner = graph.add(PlannerNode, namespace=ns, parameter_overrides=parameters(
        model='user_robots:CAR', L=0.5))
    assert planner.get_parameter('I_steer').value == 0.05  # declared from the user's spec
    probe = graph.plain_node('probe', ns)
    sequences, odom = [], []
    probe.create_subscription(JointTrajectory, 'control_sequence', sequences.append, 10)
    probe.create_subscription(Odometry, 'odom', odom.append, 100)
    pub = probe.create_publisher(Path, 'reference_path', 10)
    assert wait_until(lambda: pub.get_subscription_count() > 0, 10.0)
    msg = msgs.reference_message(reference, planner.pose_map, 0.0, 'path')
    msg.header.stamp = msgs.time_msg(0)  # starts on receipt, as the robot sets off
    pub.publish(msg)
    assert wait_until(lambda: len(sequences) > 20, 30.0)
    assert sequences[-1].joint_names == ['drive', 'steer']
    xy = np.array([[m.pose.pose.position.x, m.pose.pose.position.y] for m in odom[-50:]])
    assert xy[-1, 0] > 1.0  # it drove
    assert cross_track_error(xy, reference.q[:, :2]).max() < 0.05
    assert planner.planner.stats.optimal > 10
    assert planner.problems.errors == 0 and sim.problems.errors == 0


@pytest.mark.ros
@pytest.mark.slow
def test_an_underactuated_snakeboard_runs_through_the_nodes(graph):
    """The planner's control sequence carries the r = 2 torques, which the simulator applies.

    The reference is a path the snakeboard makes with its own rotor and steering torques. The
    shape (psi, phi) is in neither a Path nor Odometry, so the planner cannot see the steering
    angle it drives: over seconds phi drifts to the edge of its domain (a known limit, noted in
    the user guide). Checked over the first plans: the torques go through and move the robot.
    """
    import nh_tracking as nht

    ns = unique_namespace()
    board = nht.models.create('snakeboard')

    def gait(s, q, v):  # rotor and steering torques making psi, phi follow out-of-phase waves
        psi, phi = np.sin(np.pi * s), 0.4 * np.sin(np.pi * s + 1.2)
        dpsi, dphi = np.pi * np.cos(np.pi * s), 0.4 * np.pi * np.cos(np.pi * s + 1.2)
        return [8 * (psi - q[3]) + (dpsi - v[1]), 2 * (phi - q[4]) + 0.3 * (dphi - v[2])]

    t = np.linspace(0.0, 30.0, 301)
    reference = nht.simulate(board, np.zeros(5), [0.5, 0.0, 0.0], t, gait, rtol=1e-8)
    sim = graph.add(SimulatorNode, namespace=ns, parameter_overrides=parameters(
        model='snakeboard', initial_state=[0.0] * 5 + [0.5, 0.0, 0.0]))
    planner = graph.add(PlannerNode, namespace=ns, parameter_overrides=parameters(
        model='snakeboard', horizon=2.0, steps=20))
    probe = graph.plain_node('probe', ns)
    sequences, odom = [], []
    probe.create_subscription(JointTrajectory, 'control_sequence', sequences.append, 10)
    probe.create_subscription(Odometry, 'odom', odom.append, 100)
    pub = probe.create_publisher(Path, 'reference_path', 10)
    assert wait_until(lambda: pub.get_subscription_count() > 0, 10.0)
    msg = msgs.reference_message(reference, planner.pose_map, 0.0, 'path')
    msg.header.stamp = msgs.time_msg(0)
    pub.publish(msg)
    assert wait_until(lambda: len(sequences) > 5, 60.0)
    assert sequences[-1].joint_names == ['rotor_torque', 'steering_torque']
    efforts = np.array([p.effort for m in sequences for p in m.points])
    assert efforts.shape[1] == 2 and np.all(np.isfinite(efforts)) and np.abs(efforts).max() > 0
    xy = np.array([[m.pose.pose.position.x, m.pose.pose.position.y] for m in odom])
    assert xy[-1, 0] > 0.1  # it moved along the path
    assert cross_track_error(xy, reference.q[:, :2]).max() < 0.2
    assert planner.planner.stats.optimal > 3 and planner.problems.errors == 0
    assert sim.problems.rejected_inputs == 0  # every control sequence had the board's two joints


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('kind', ['markers', 'costmap'])
def test_limits_and_obstacles_through_ros(graph, kind):
    """A unicycle tracks a line through two obstacles, accelerations limited to 0.15.

    The obstacles are sent as markers on ``obstacles``, or as a Nav2-style OccupancyGrid on
    ``costmap``: no collision in the simulator, controls never above the limit, and the robot
    back on the line (< 0.05 m) afterwards.
    """
    from nh_tracking.examples import obstacles as scenario

    loop, reference = scenario.run(graph, kind, duration=25.0, namespace=unique_namespace())
    t, xy, _, efforts = loop.record()
    assert loop.sim is not None and t[-1] >= scenario.START + 25.0 - 0.1
    assert loop.sim.collisions == 0
    assert loop.sim.problems.errors == 0 and loop.planner.problems.errors == 0
    gaps = [np.hypot(*(xy - c[:2]).T).min() - c[2] for c in scenario.OBSTACLES]
    assert min(gaps) >= scenario.ROBOT_RADIUS and xy[-1, 0] > 10.0  # past both of them
    assert np.abs(efforts).max() <= scenario.U_LIMIT + 1e-6
    assert np.abs(efforts).max() > 0.9 * scenario.U_LIMIT  # swerving needs all of it
    settled = t >= t[-1] - 3.0
    assert cross_track_error(xy[settled], reference.q[:, :2]).max() < 0.05
