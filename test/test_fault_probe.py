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

"""The fault probe's cases: ordinary input that could drive the robot wrong or end the planner.

Lifecycle requests by id (a separate planner process, as a lifecycle manager meets it), odometry
stamped ahead of the clock, references no robot can follow.
"""
from collections.abc import Iterator
from contextlib import contextmanager
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from nav_msgs.msg import Odometry, Path
import numpy as np
import pytest

from nh_tracking.ros import messages as msgs
from nh_tracking.ros.graph import parameters, wait_until
from nh_tracking.ros.planner_node import LATCHED, PlannerNode
from processes import domain_env, Peer, Process, rss_bytes
from test_ros import unique_namespace

pytestmark = pytest.mark.timeout(300)
LABELS = ('configure', 'cleanup', 'activate', 'deactivate', 'shutdown', 'transition_success',
          'transition_failure', 'transition_error', 'create', 'destroy', 'bogus')


@pytest.mark.ros
@pytest.mark.slow
def test_every_lifecycle_request_is_answered_in_every_state_and_never_ends_the_planner():
    with separate_planner('autostart:=false', 'steps:=10') as (planner, peer):
        node = peer.node
        get_state = node.create_client(GetState, 'nh_tracking_planner/get_state')
        change = node.create_client(ChangeState, 'nh_tracking_planner/change_state')
        assert get_state.wait_for_service(30.0) and change.wait_for_service(30.0)

        def call(client, request, timeout=60.0):
            future = client.call_async(request)
            assert wait_until(future.done, timeout), 'no answer'
            return future.result()

        def state() -> str:
            # asked again if unanswered: a first call can beat DDS matching its response
            # reader (the service's discovery race), and the question changes nothing
            for _ in range(5):
                future = get_state.call_async(GetState.Request())
                if wait_until(future.done, 10.0):
                    return future.result().current_state.label
            raise AssertionError('get_state: no answer')

        refused = 0
        # unconfigured -> inactive -> active -> (deactivate) inactive -> (cleanup) unconfigured
        for step in ('configure', 'activate', 'deactivate', 'cleanup', None):
            here = state()
            for transition in [Transition(id=i) for i in range(100)] + [
                    Transition(label=label) for label in LABELS]:
                valid = {'unconfigured': {1, 5}, 'inactive': {2, 3, 6}, 'active': {4, 7},
                         'finalized': set()}[here]
                named = {'configure': 1, 'cleanup': 2, 'activate': 3, 'deactivate': 4}
                if transition.label:
                    if transition.label == 'shutdown' or named.get(transition.label) in valid:
                        continue  # carried out below, in order
                elif transition.id in valid:
                    continue
                answer = call(change, ChangeState.Request(transition=transition))
                assert answer.success is False, (here, transition)
                refused += 1
                assert planner.proc.poll() is None, planner.output
            assert state() == here
            if step is not None:
                assert call(change, ChangeState.Request(
                    transition=Transition(label=step))).success, (here, step)
        assert state() == 'unconfigured' and refused > 5 * 95
        print(f'\n{refused} lifecycle requests refused over 5 visits; the planner lived')
        assert 'Traceback' not in planner.output and 'RCLError' not in planner.output
        assert planner.interrupt() == 0, planner.output  # after configure-cleanup cycles too


@contextmanager
def separate_planner(*params: str) -> Iterator[tuple[Process, Peer]]:
    """Start a planner process on a fresh domain (``params``: ``name:=value``), and a peer."""
    env = domain_env()
    planner = Process('planner', ['--ros-args', *[a for p in params for a in ('-p', p)]], env)
    peer = Peer(env)
    try:
        yield planner, peer
    finally:
        peer.close()
        planner.kill()  # (if it is still running)


@contextmanager
def odometry_stream(odom) -> Iterator[None]:
    """Publish the robot at rest at the origin, at 50 Hz on the wall clock, while in the block."""
    import threading

    stop = threading.Event()

    def send() -> None:
        while not stop.wait(0.02):
            odom.publish(msgs.odometry_msg('odom', 'base_link', time.time_ns(), np.zeros(4),
                                           np.zeros(4)))
    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=1.0)


def _line(start_ns: int, length: float, duration: float, points: int = 11) -> Path:
    t = np.linspace(0.0, duration, points)
    poses = np.stack([t / duration * length, 0 * t, 0 * t, 0 * t], axis=1)
    return msgs.path_msg('odom', [start_ns + int(s * 1e9) for s in t], poses)


class Probe:
    """A planner in process and this test as its robot: odometry out, commands in."""

    def __init__(self, graph, **params) -> None:
        ns = unique_namespace()
        self.planner = graph.add(PlannerNode, namespace=ns, parameter_overrides=parameters(
            model='unicycle', steps=20, horizon=2.0, **params))
        self.node = graph.plain_node('probe', ns)
        self.cmd: list[tuple[float, float]] = []  # (monotonic, |v|)
        self.sequences: list[float] = []
        self.sequence_msgs: list = []  # (monotonic, message), as sequences
        self.stale: list[float] = []
        self.node.create_subscription(Twist, 'cmd_vel', lambda m: self.cmd.append(
            (time.monotonic(), abs(m.linear.x) + abs(m.angular.z))), 100)
        self.node.create_subscription(
            __import__('trajectory_msgs.msg', fromlist=['JointTrajectory']).JointTrajectory,
            'control_sequence', self._on_sequence, 100)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 100)
        self.odom = self.node.create_publisher(Odometry, 'odom', 10)
        self.reference = self.node.create_publisher(Path, 'reference_path', LATCHED)
        assert wait_until(lambda: self.odom.get_subscription_count() > 0, 10.0)

    def _on_sequence(self, msg) -> None:
        self.sequences.append(time.monotonic())
        self.sequence_msgs.append((self.sequences[-1], msg))

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.level == DiagnosticStatus.STALE and self.planner.get_name() in status.name:
                self.stale.append(time.monotonic())

    def now_ns(self) -> int:
        return self.planner.get_clock().now().nanoseconds

    def send_odom(self, ahead: float = 0.0, x: float = 0.0) -> None:
        self.odom.publish(msgs.odometry_msg('odom', 'base_link', self.now_ns() + int(ahead * 1e9),
                                            np.array([x, 0.0, 0.0, 0.0]), np.zeros(4)))


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('ahead', [2.0, 3600.0])
def test_odometry_stamped_ahead_is_refused_and_goes_stale_on_time(graph, ahead):
    probe = Probe(graph, odom_timeout=0.3)
    probe.reference.publish(_line(probe.now_ns(), 5.0, 20.0))
    for _ in range(60):  # 1.2 s of good odometry: plans are made
        probe.send_odom()
        time.sleep(0.02)
    assert wait_until(lambda: len(probe.sequences) > 3, 10.0)
    last_valid = time.monotonic()
    for _ in range(50):  # 1 s stamped ahead, then silence
        probe.send_odom(ahead)
        time.sleep(0.02)
    wait_until(lambda: False, 0.5)
    assert probe.planner.problems.rejected_inputs >= 40
    assert probe.stale, 'no STALE diagnostic'
    went_stale = probe.stale[0] - last_valid
    # after it, only the braking plan from the last valid state, renewed (the same message)
    late_plans = [m for t, m in probe.sequence_msgs if t > last_valid + 0.3 + 0.1]
    stopping = np.abs([v for t, v in probe.cmd if t > last_valid + 0.3 + 0.1])
    print(f'\n+{ahead:g} s: STALE {went_stale:.3f} s after the last valid odometry; '
          f'{len(late_plans)} plans after it; {len(stopping)} cmd_vel, max {stopping.max():g}')
    assert went_stale < 0.3 + 0.1
    assert all(m == late_plans[0] for m in late_plans)
    # slowing to rest (at max_decel) from the command before, then zero (a tracking command
    # sent before it knew may arrive first)
    ramp = stopping[int(np.argmax(stopping)):]
    assert len(stopping) > 10 and (np.diff(ramp) <= 0.0).all() and stopping[-1] == 0.0


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('duration', [10.0, 1000.0])
def test_a_reference_no_robot_can_follow_is_refused(graph, duration):
    probe = Probe(graph)
    for _ in range(10):
        probe.send_odom()
        time.sleep(0.02)
    probe.reference.publish(_line(probe.now_ns(), 100e3, duration))
    assert wait_until(lambda: probe.planner.problems.rejected_inputs > 0, 10.0)
    for _ in range(50):
        probe.send_odom()
        time.sleep(0.02)
    assert probe.planner.planner.reference is None
    problems = probe.planner.problems
    assert 'reference_max_speed' in problems.last_problem or problems.rejected_inputs
    assert probe.sequences == [] and all(v == 0.0 for _, v in probe.cmd)
    # a reference a robot can follow is still taken
    probe.reference.publish(_line(probe.now_ns(), 2.0, duration))
    assert wait_until(lambda: probe.planner.planner.reference is not None, 10.0)


@pytest.mark.ros
@pytest.mark.slow
def test_memory_stays_bounded_through_a_storm_of_horizon_sizes(graph):
    from rclpy.parameter import Parameter

    probe = Probe(graph)
    probe.reference.publish(_line(probe.now_ns(), 2.0, 10.0))
    planner, growth = probe.planner, []
    start = rss_bytes() / 2**20
    for steps in range(10, 35):  # 25 distinct values, each a rebuild of every structure
        planner.set_parameters([Parameter('steps', value=steps)])
        assert wait_until(lambda: planner.planner.settings.steps == steps
                          and not planner.live.reconfiguring, 60.0), steps
        probe.send_odom()
        growth.append(rss_bytes() / 2**20 - start)
    print(f'\nRSS after 25 steps values: +{growth[-1]:.0f} MB (largest +{max(growth):.0f} MB; '
          f'after 5: +{growth[4]:.0f} MB)')
    assert max(growth) < 150.0
    assert wait_until(lambda: len(probe.sequences) > 0, 10.0)  # and it still plans


@pytest.mark.ros
def test_every_one_of_a_burst_of_plan_requests_is_answered():
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.srv import GetPlan
    from rclpy.qos import QoSProfile

    from nh_tracking.ros.planner_services import BACKLOG

    with separate_planner('model:=unicycle', 'steps:=20') as (planner, peer):
        node = peer.node
        reference = node.create_publisher(Path, 'reference_path', LATCHED)
        reference.publish(_line(time.time_ns(), 2.0, 10.0))
        # a client as deep as the burst: the default depth (10) drops answers not yet taken
        client = node.create_client(GetPlan, 'plan', qos_profile=QoSProfile(depth=1000))
        assert client.wait_for_service(30.0)
        request = GetPlan.Request(start=PoseStamped())
        request.start.header.frame_id = 'odom'

        def answered(count: int, timeout: float) -> list:
            futures = [client.call_async(request) for _ in range(count)]
            assert wait_until(lambda: all(f.done() for f in futures), timeout), (
                f'{sum(not f.done() for f in futures)} of {count} unanswered')
            return [len(f.result().plan.poses) for f in futures]

        assert wait_until(lambda: answered(1, 30.0)[0] > 0, 30.0)  # the reference is in force
        lengths = answered(200, 120.0)
        planned = sum(n > 0 for n in lengths)
        print(f'\n200 simultaneous plan requests: 200 answered, {planned} with a plan, '
              f'{200 - planned} busy')
        assert planned >= BACKLOG and set(lengths) <= {0, 21}
        assert planned == 200 or 'busy' in planner.output
        assert answered(1, 30.0)[0] == 21  # and it serves the next one
        assert planner.proc.poll() is None and 'Traceback' not in planner.output


@pytest.mark.ros
@pytest.mark.slow
def test_odometry_stale_between_reports_is_reported_not_ok(graph):
    probe = Probe(graph, odom_timeout=0.5)
    levels: list[tuple[int, str]] = []
    probe.node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: levels.extend(
        (s.level, s.message) for s in m.status if probe.planner.get_name() in s.name), 100)
    probe.reference.publish(_line(probe.now_ns(), 5.0, 20.0))
    for _ in range(6):  # 1 Hz odometry: fresh for 0.5 s of every second
        probe.send_odom()
        time.sleep(1.0)
    later = levels[2:]  # (the first reports: before the reference and odometry)
    print(f'\n1 Hz odometry, odom_timeout 0.5 s: {len(later)} reports, '
          f'{sum(level == DiagnosticStatus.OK for level, _ in later)} OK; e.g. {later[-1][1]!r}')
    assert later and not any(level == DiagnosticStatus.OK for level, _ in later), later
    assert any('% of the last second' in message for _, message in later), later


@pytest.mark.ros
@pytest.mark.slow
def test_a_planner_started_after_latched_obstacles_and_reference_uses_both():
    """Obstacles and reference published latched, then simulator and planner started."""
    from visualization_msgs.msg import MarkerArray

    from nh_tracking.examples.obstacles import INFLATION, line_reference, OBSTACLES, ROBOT_RADIUS
    from nh_tracking.core.poses import PoseMap
    from nh_tracking.ros.markers import obstacle_markers
    import nh_tracking as nht

    env = domain_env()
    peer = Peer(env)
    planner = sim = None
    try:
        node, odometry = peer.node, []
        node.create_subscription(Odometry, 'odom', lambda m: odometry.append(
            (m.pose.pose.position.x, m.pose.pose.position.y)), 100)
        markers = node.create_publisher(MarkerArray, 'obstacles', LATCHED)
        markers.publish(MarkerArray(markers=obstacle_markers('odom', 0, OBSTACLES[:1])))
        reference = node.create_publisher(Path, 'reference_path', LATCHED)
        message = msgs.reference_message(line_reference(20.0), PoseMap(nht.models.unicycle()), 0.0,
                                         'path')
        message.header.stamp = msgs.time_msg(0)  # it starts when the planner takes it
        reference.publish(message)
        time.sleep(0.5)
        sim = Process('sim', ['--ros-args', '-p', 'model:=unicycle', '-p', 'rate:=50.0', '-p',
                              'initial_state:=[0.0, 0.0, 0.0, 0.0, 0.0]', '-p',
                              f'robot_radius:={ROBOT_RADIUS}'], env)
        planner = Process('planner', ['--ros-args', '-p', 'model:=unicycle', '-p',
                                      'horizon:=5.0', '-p', 'steps:=50', '-p',
                                      f'robot_radius:={ROBOT_RADIUS + INFLATION}'], env)
        assert planner.wait_for('new reference', 60.0), planner.output
        assert wait_until(lambda: odometry and odometry[-1][0] > OBSTACLES[0, 0] + 1.0, 60.0), (
            odometry[-1:], planner.output)
        xy = np.array(odometry)
        closest = np.hypot(*(xy - OBSTACLES[0, :2]).T).min() - OBSTACLES[0, 2]
        print(f'\nlatched before start: past the disc, closest approach {closest:.3f} m '
              f'(robot radius {ROBOT_RADIUS} m)')
        assert closest >= ROBOT_RADIUS and 'collision' not in sim.output, sim.output
    finally:
        peer.close()
        for process in (planner, sim):
            if process is not None:
                process.kill()


@pytest.mark.ros
@pytest.mark.slow
def test_a_dead_clock_stops_the_robot_and_says_so_and_a_clock_jumping_back_is_told():
    """Sim time: /clock (with odometry) stops for 3 s, resumes, then jumps back 1000 s."""
    from rosgraph_msgs.msg import Clock

    with separate_planner('model:=unicycle', 'steps:=20', 'horizon:=2.0',
                          'use_sim_time:=true') as (planner, peer):
        node = peer.node
        cmd: list[tuple[float, float]] = []
        diagnostics: list[tuple[float, int, str]] = []
        node.create_subscription(Twist, 'cmd_vel', lambda m: cmd.append(
            (time.monotonic(), abs(m.linear.x) + abs(m.angular.z))), 100)
        node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: diagnostics.extend(
            (time.monotonic(), ord(s.level), s.message) for s in m.status
            if 'planner' in s.name), 100)
        clock = node.create_publisher(Clock, '/clock', 10)
        odom = node.create_publisher(Odometry, 'odom', 10)
        reference = node.create_publisher(Path, 'reference_path', LATCHED)
        sim_ns = 1000 * 10**9

        def tick(seconds: float) -> None:  # 50 Hz of clock and odometry (the robot stays put)
            nonlocal sim_ns
            for _ in range(int(seconds / 0.02)):
                sim_ns += 20_000_000
                clock.publish(Clock(clock=msgs.time_msg(sim_ns)))
                odom.publish(msgs.odometry_msg('odom', 'base_link', sim_ns, np.zeros(4),
                                               np.zeros(4)))
                time.sleep(0.02)

        assert wait_until(lambda: odom.get_subscription_count() > 0, 60.0), planner.output
        tick(1.0)
        reference.publish(_line(sim_ns, 10.0, 20.0))
        tick(3.0)
        assert cmd and max(v for _, v in cmd[-10:]) > 0.0, planner.output
        stopped = time.monotonic()
        time.sleep(3.0)  # the clock and the simulator are dead
        during = [(t, v) for t, v in cmd if t > stopped]
        first_zero = next(t for t, v in during if v == 0.0) - stopped
        told = [m for t, level, m in diagnostics if t > stopped and 'clock' in m]
        print(f'\n/clock dead: zero cmd_vel {first_zero:.2f} s after it stopped, then '
              f'{len(during)} commands, max {max(v for _, v in during):g} after it; {told[:1]}')
        assert first_zero < 1.0
        assert all(v == 0.0 for t, v in during if t > stopped + first_zero + 0.01)
        assert told and any(level == 3 for t, level, m in diagnostics if t > stopped)
        resumed = time.monotonic()
        tick(2.0)
        assert max(v for t, v in cmd if t > resumed) > 0.0  # commanding again
        sim_ns -= 1000 * 10**9  # back to the start of time: the reference now lies 1000 s ahead
        jumped = time.monotonic()
        tick(2.5)
        ahead = [m for t, _, m in diagnostics if t > jumped and 'reference starts' in m]
        print(f'clock 1000 s back: {ahead[:1]}')
        assert ahead and 'jumped back' in planner.output
        assert max(v for t, v in cmd if t > jumped + 0.5) < 1e-9  # it holds still (at rest)
        assert planner.proc.poll() is None and 'Traceback' not in planner.output


@pytest.mark.unit
def test_the_clock_watch_tells_a_standing_a_resumed_and_a_backward_clock():
    from nh_tracking.ros.clock_watch import ClockEvent, ClockWatch

    watch = ClockWatch(timeout=0.5)
    looks = [(1_000, 0.0), (2_000, 0.1), (2_000, 0.5), (2_000, 0.7), (2_000, 0.9), (3_000, 1.0),
             (3_000, 1.2), (500, 1.3), (600, 1.4)]
    events = [watch.look(ns, steady) for ns, steady in looks]
    assert events == [None, None, None, ClockEvent.STOPPED, None, ClockEvent.RESUMED, None,
                      ClockEvent.JUMPED_BACK, None]
    assert watch.jumped_back_by == pytest.approx(2.5e-6) and not watch.stopped
    assert watch.standing_for(1.9) == pytest.approx(0.5)


@pytest.mark.ros
@pytest.mark.slow
def test_a_100000_pose_path_never_pauses_control():
    """The path's bytes are made beforehand: this process must not stall while it listens."""
    from rclpy.serialization import serialize_message
    from trajectory_msgs.msg import JointTrajectory

    with separate_planner('model:=unicycle', 'steps:=20', 'horizon:=2.0') as (planner, peer):
        node = peer.node
        arrivals: dict[str, list[float]] = {'cmd_vel': [], 'control_sequence': []}
        node.create_subscription(Twist, 'cmd_vel', lambda m: arrivals['cmd_vel'].append(
            time.monotonic()), 100)
        node.create_subscription(JointTrajectory, 'control_sequence', lambda m: arrivals[
            'control_sequence'].append(time.monotonic()), 100)
        odom = node.create_publisher(Odometry, 'odom', 10)
        reference = node.create_publisher(Path, 'reference_path', 10)
        assert wait_until(lambda: reference.get_subscription_count() > 0, 60.0), planner.output
        with odometry_stream(odom):
            reference.publish(_line(time.time_ns(), 2.0, 10.0))
            assert planner.wait_for('new reference: ', 30.0)
            t = np.linspace(0.0, 100.0, 100_000)
            start = time.time_ns()
            huge = serialize_message(msgs.path_msg('odom', [start + int(s * 1e9) for s in t],
                                                   np.c_[0.05 * t, 0 * t, 0 * t, 0 * t]))
            time.sleep(1.0)
            sent = time.monotonic()
            reference.publish(huge)
            assert planner.wait_for('points over 100.00 s', 60.0), planner.output
            time.sleep(1.0)
            gaps = {topic: float(np.diff([t for t in times if t > sent - 0.5]).max())
                    for topic, times in arrivals.items()}
            print(f'\n100,000-pose Path ({len(huge) / 1e6:.1f} MB): longest gaps ' + ', '.join(
                f'{topic} {gap * 1e3:.0f} ms' for topic, gap in gaps.items()))
            assert gaps['cmd_vel'] <= 1 / 20 + 0.1 and gaps['control_sequence'] <= 0.1 + 0.1
            assert 'Traceback' not in planner.output


@pytest.mark.unit
def test_the_stale_fraction_is_over_the_last_second():
    from nh_tracking.session.interface import Staleness

    now = [100.0]
    staleness = Staleness(lambda: now[0])
    for at, stale in [(100.2, True), (100.5, False), (100.9, True), (101.3, False)]:
        now[0] = at
        assert staleness.mark(stale) and not staleness.mark(stale)
    now[0] = 101.4  # the last second: stale 100.4-100.5 and 100.9-101.3
    assert staleness.fraction() == pytest.approx(0.5)
    now[0] = 103.0
    assert staleness.fraction() == 0.0 and not staleness.now


@pytest.mark.ros
def test_turning_compiled_off_stops_its_background_build(graph, tmp_path, monkeypatch):
    from rclpy.parameter import Parameter

    from nh_tracking.solvers import compiled

    if compiled.compiler() is None:
        pytest.skip('no C compiler here')
    monkeypatch.setenv('NH_TRACKING_CACHE', str(tmp_path))  # nothing built before
    probe = Probe(graph, compiled=True)
    planner = probe.planner

    def running() -> list:
        return [job for job in list(compiled._BUILDS.values())
                if job.child is not None and job.child.poll() is None]
    assert wait_until(lambda: running(), 30.0), 'no build started'
    children = running()
    planner.set_parameters([Parameter('compiled', value=False)])
    assert wait_until(lambda: not planner.planner.settings.compiled
                      and not planner.live.reconfiguring, 60.0)
    assert wait_until(lambda: all(job.child.poll() is not None for job in children), 10.0)
    assert not running() and not list(tmp_path.glob('*.so'))
    print(f'\ncompiled:=false stopped {len(children)} running build(s)')


@pytest.mark.ros
def test_a_reference_beyond_the_velocity_bounds_is_refused(graph):
    from rcl_interfaces.msg import Log

    probe, logs = Probe(graph, v_min=[-0.3], v_max=[0.3]), []
    probe.node.create_subscription(Log, '/rosout', lambda m: logs.append(m.msg), 100)
    probe.send_odom()
    probe.reference.publish(_line(probe.now_ns(), 5.0, 10.0))  # 0.5 m/s
    assert wait_until(lambda: any('v_max is 0.3' in line for line in logs), 10.0), logs
    assert probe.planner.planner.reference is None
    probe.reference.publish(_line(probe.now_ns(), 2.0, 10.0))  # 0.2 m/s: taken
    assert wait_until(lambda: probe.planner.planner.reference is not None, 10.0)
    print(f"\n{next(line for line in logs if 'v_max' in line)}")


@pytest.mark.ros
@pytest.mark.slow
def test_ctrl_c_stops_a_commanding_planner_with_a_zero_command():
    with separate_planner('model:=unicycle', 'steps:=20', 'horizon:=2.0') as (planner, peer):
        node, cmd = peer.node, []
        node.create_subscription(Twist, 'cmd_vel', lambda m: cmd.append(
            abs(m.linear.x) + abs(m.angular.z)), 100)
        odom = node.create_publisher(Odometry, 'odom', 10)
        reference = node.create_publisher(Path, 'reference_path', LATCHED)
        assert wait_until(lambda: odom.get_subscription_count() > 0, 60.0), planner.output
        with odometry_stream(odom):
            reference.publish(_line(time.time_ns(), 2.0, 10.0))
            assert wait_until(lambda: cmd and cmd[-1] > 0.0, 30.0), planner.output
            code = planner.interrupt()
            assert wait_until(lambda: cmd[-1] == 0.0, 2.0), cmd[-5:]
            print(f'\nCtrl-C while commanding {max(cmd):.3f}: exit code {code}, last cmd_vel '
                  f'{cmd[-1]:g}')
            assert code == 0 and 'Traceback' not in planner.output, planner.output
