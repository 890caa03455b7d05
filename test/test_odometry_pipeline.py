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

"""Odometry in, plan out: the receiving thread, remapping, the display's rate, latency figures."""
import math
import time

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry, Path
import numpy as np
import pytest
from trajectory_msgs.msg import JointTrajectory

from nh_tracking.core.poses import PoseMap
from nh_tracking.examples.demo import sleigh_reference
from nh_tracking.ros import conversions as cv
from nh_tracking.ros import messages as msgs
from nh_tracking.ros import PlannerNode
from nh_tracking.ros.graph import parameters, wait_until
from nh_tracking.ros.planner_interface import LATCHED
from test_ros import unique_namespace

pytestmark = [pytest.mark.timeout(120), pytest.mark.ros, pytest.mark.slow]


class Replay:
    """Publishes a reference and then odometry along it on ``odom_topic`` (the wall clock)."""

    def __init__(self, graph, planner, odom_topic):
        self.node = graph.plain_node('replay', planner.get_namespace())
        self.planner = planner
        self.reference = sleigh_reference(40.0)
        self.pose_map = PoseMap(planner.live.system)
        self.odom = self.node.create_publisher(Odometry, odom_topic, 10)
        self.got = {'path': [], 'control_sequence': [], 'diagnostics': []}
        self.node.create_subscription(Path, 'planned_path', self.got['path'].append, LATCHED)
        self.node.create_subscription(JointTrajectory, 'control_sequence',
                                      self.got['control_sequence'].append, LATCHED)
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      self.got['diagnostics'].append, 10)
        reference_pub = self.node.create_publisher(Path, 'reference_path', LATCHED)
        assert wait_until(lambda: reference_pub.get_subscription_count() > 0, 10.0)
        self.start = planner.get_clock().now().nanoseconds * 1e-9
        reference_pub.publish(msgs.reference_message(self.reference, self.pose_map, self.start,
                                                     'path'))
        assert wait_until(lambda: planner.planner.reference is not None, 10.0)

    def drive(self, seconds: float, rate: float) -> None:
        """Publish odometry of a robot on the reference, at ``rate`` Hz for ``seconds``."""
        until = time.monotonic() + seconds
        while time.monotonic() < until:
            now = self.planner.get_clock().now().nanoseconds
            q, v = self.reference.at(now * 1e-9 - self.start)
            self.odom.publish(msgs.odometry_msg('odom', 'base_link', now, self.pose_map.pose(q),
                                                self.pose_map.body_twist(q, v)))
            time.sleep(1.0 / rate)

    def health(self) -> dict[str, str]:
        ours = [s for m in self.got['diagnostics'] for s in m.status
                if s.hardware_id.startswith(self.planner.get_namespace() + '/')]
        return {kv.key: kv.value for kv in ours[-1].values} if ours else {}


def test_odometry_follows_the_planners_remapping(graph):
    """``-r odom:=wheel_odom`` moves the receiving thread's subscription with the planner."""
    ns = unique_namespace()
    planner = graph.add(PlannerNode, namespace=ns, cli_args=['--ros-args', '-r',
                                                             'odom:=wheel_odom'])
    replay = Replay(graph, planner, 'wheel_odom')
    stray = replay.node.create_publisher(Odometry, 'odom', 10)
    assert wait_until(lambda: replay.odom.get_subscription_count() == 1, 10.0)
    assert stray.get_subscription_count() == 0
    replay.drive(1.0, 50.0)
    assert planner.live.state is not None
    assert wait_until(lambda: planner.planner.stats.optimal >= 3, 20.0)


@pytest.mark.parametrize('model, display_rate', [('chaplygin_sleigh', 4.0), ('unicycle', 2.0)])
def test_plans_on_receipt_and_shows_them_at_the_display_rate(graph, model, display_rate):
    """With replan_on_odom every odometry message is planned for on its own thread.

    The timer's replans (solver thread) go on too, and no plan from an older state is published
    after a newer one; planned_path keeps ``display_rate``; /diagnostics reports the latency.
    """
    ns = unique_namespace()
    planner = graph.add(PlannerNode, namespace=ns, parameter_overrides=parameters(
        model=model, replan_on_odom=True, replan_period=0.05, iterations=1,
        display_rate=display_rate))
    replay = Replay(graph, planner, 'odom')
    assert wait_until(lambda: replay.odom.get_subscription_count() == 1, 10.0)
    seconds = 3.0
    replay.drive(seconds, 40.0)
    assert wait_until(lambda: replay.health().get('plans', '0') != '0', 5.0)
    plans, paths = len(replay.got['control_sequence']), len(replay.got['path'])
    print(f'\n{model}: {plans} control sequences, {paths} planned paths in {seconds:g} s')
    assert plans >= 30
    stamps = [cv.stamp_ns(m.header.stamp) for m in replay.got['control_sequence']]
    assert all(b >= a for a, b in zip(stamps, stamps[1:]))  # in the order of their states
    assert 1 <= paths <= display_rate * seconds + 2
    assert all(math.isfinite(e) for m in replay.got['control_sequence'] for p in m.points
               for e in p.effort)
    health = replay.health()
    latency = float(health['latency_p50_ms'])
    assert 0.0 < latency < 1e3 and float(health['latency_p99_ms']) >= latency
    assert np.isfinite(float(health['solve_time_p50_ms']))


@pytest.mark.parametrize('wire_bytes', [True, False], ids=['wire bytes', 'messages'])
def test_odometry_and_plans_as_wire_bytes_or_as_messages(graph, monkeypatch, wire_bytes):
    """Odometry and plans go as CDR bytes where the middleware agrees, else as messages.

    Where the middleware reads and writes the bytes :mod:`cdr` does, the planner takes odometry
    and publishes its control sequence as bytes; subscribers see the same sequences either way.
    """
    from nh_tracking.ros import cdr

    if not wire_bytes:
        monkeypatch.setattr(cdr, 'agrees_with_rmw', lambda: False)
    else:
        assert cdr.agrees_with_rmw()  # (rmw_fastrtps_cpp, the wheels' middleware)
    ns = unique_namespace()
    planner = graph.add(PlannerNode, namespace=ns, parameter_overrides=parameters(
        model='unicycle', replan_on_odom=True, replan_period=60.0, iterations=1, steps=12))
    assert planner._odometry.subscription.raw is wire_bytes
    replay = Replay(graph, planner, 'odom')
    assert wait_until(lambda: replay.odom.get_subscription_count() == 1, 10.0)
    replay.drive(1.0, 30.0)
    assert wait_until(lambda: len(replay.got['control_sequence']) >= 10, 10.0)
    last = replay.got['control_sequence'][-1]
    assert list(last.joint_names) == list(planner.live.system.control_names)
    assert last.header.frame_id == 'odom' and len(last.points) == 12
    offsets = [cv.duration_seconds(p.time_from_start) for p in last.points]
    assert offsets == pytest.approx(np.arange(12) * 3.0 / 12, abs=1e-9)
    assert all(len(p.effort) == 2 and all(map(math.isfinite, p.effort)) for p in last.points)
    assert planner.problems.rejected_inputs == 0 and planner.problems.errors == 0
