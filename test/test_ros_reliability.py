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

"""Reliability through ROS: fuzzed topics, an odometry flood, concurrent service calls.

And a soak with reference swaps and parameter changes — nothing crashes, nothing invalid is out.
"""
import time

from geometry_msgs.msg import PoseWithCovarianceStamped, Twist
from nav_msgs.msg import OccupancyGrid, Odometry, Path
from nav_msgs.srv import GetPlan
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint, MultiDOFJointTrajectory
from visualization_msgs.msg import Marker, MarkerArray

from nh_tracking.core.metrics import cross_track_error
from nh_tracking.examples.demo import ClosedLoop, sleigh_reference, START
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.graph import wait_until
from test_ros import WallClockPair

pytestmark = [pytest.mark.timeout(300), pytest.mark.ros, pytest.mark.slow]


class Fuzzer:
    """Malformed messages for every input topic, from valid ones with one field broken."""

    BAD = (float('nan'), float('inf'), -float('inf'), 1e300)

    def __init__(self, pair, seed=0):
        self.rng = np.random.default_rng(seed)
        self.pair = pair
        self.path = msgs.reference_message(pair.reference, pair.planner.pose_map, 0.0, 'path')
        self.trajectory = msgs.reference_message(pair.reference, pair.planner.pose_map, 0.0,
                                                 'trajectory')

    def bad(self):
        return float(self.rng.choice(self.BAD))

    def reference_path(self):
        msg = Path(header=self.path.header, poses=list(self.path.poses[:15]))
        kind = self.rng.integers(4)
        i = int(self.rng.integers(len(msg.poses)))
        pose = msgs.pose_msg(np.array([0.0, 0.0, 0.0, 0.0]))
        if kind == 0:
            pose.position.x = self.bad()
        elif kind == 1:
            pose.orientation.w = 3.0
        msg.poses[i] = type(msg.poses[i])(header=msg.poses[i].header, pose=pose)
        if kind == 2:
            msg.poses = []
        if kind == 3:
            msg.poses = msg.poses[:5] + msg.poses[:5]  # stamps go backwards
        return msg

    def reference_trajectory(self):
        msg = MultiDOFJointTrajectory(header=self.trajectory.header,
                                      joint_names=list(self.trajectory.joint_names),
                                      points=list(self.trajectory.points[:10]))
        if self.rng.integers(2):
            msg.joint_names = ['a', 'b']
        else:
            msg.points = [type(msg.points[0])(transforms=[], velocities=[])] + msg.points[1:]
        return msg

    def odom(self):
        msg = Odometry()
        msg.header.frame_id = 'odom' if self.rng.integers(2) else 'elsewhere'
        msg.pose.pose.orientation.w = 1.0
        msg.twist.twist.linear.x = self.bad()
        return msg

    def control_sequence(self):
        names = ['torque', 'force'] if self.rng.integers(2) else ['torque']
        return JointTrajectory(joint_names=names, points=[
            JointTrajectoryPoint(effort=[self.bad(), 0.0])])

    def cmd_vel(self):
        msg = Twist()
        msg.angular.z = self.bad()
        return msg

    def initialpose(self):
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = 'odom'
        msg.pose.pose.orientation.z = 2.0  # not a unit quaternion
        return msg

    def obstacles(self):
        marker = Marker(type=Marker.CYLINDER, action=Marker.ADD, id=int(self.rng.integers(3)))
        marker.header.frame_id = 'odom' if self.rng.integers(2) else 'map'
        marker.pose.position.x = self.bad()
        marker.scale.x = -1.0 if self.rng.integers(2) else self.bad()
        return MarkerArray(markers=[marker])

    def costmap(self):
        grid = OccupancyGrid()
        grid.header.frame_id = 'odom'
        grid.info.resolution = float(self.rng.choice([0.0, -0.05, self.bad()]))
        grid.info.width, grid.info.height = 4, 3
        grid.info.origin.orientation.w = 1.0
        grid.data = [100] * int(self.rng.choice([12, 5]))
        return grid


def test_fuzz_flood_and_concurrent_calls_leave_the_loop_tracking(graph):
    pair = WallClockPair(graph, planner_params={'replan_on_odom': True})
    pair.send_reference()
    published = _record_outputs(pair.planner)  # the fuzzer writes to cmd_vel and
    fuzz = Fuzzer(pair)                         # control_sequence too: check at the source
    topics = {'reference_path': Path, 'reference_trajectory': MultiDOFJointTrajectory,
              'odom': Odometry, 'control_sequence': JointTrajectory, 'cmd_vel': Twist,
              'initialpose': PoseWithCovarianceStamped, 'obstacles': MarkerArray,
              'costmap': OccupancyGrid}
    pubs = {t: pair.publisher(m, t) for t, m in topics.items()}
    sent = dict.fromkeys(topics, 0)
    # fuzz every input topic of both nodes: 1200 messages (a count, not a time: how many fit
    # in a second depends on the machine)
    for _ in range(1200):
        topic = list(topics)[int(fuzz.rng.integers(len(topics)))]
        pubs[topic].publish(getattr(fuzz, topic)())
        sent[topic] += 1
        time.sleep(0.0005)
    # flood odometry, 1000 messages back to back: the robot's true state, re-sent by a chatty
    # driver
    msg, flood_start = None, time.monotonic()
    for flood in range(1000):
        if flood % 10 == 0:  # refresh the state now and then, re-stamp every time
            q, v = pair.sim.state
            msg = msgs.odometry_msg('odom', 'base_link', 0, pair.planner.pose_map.pose(q),
                                    pair.planner.pose_map.body_twist(q, v))
        msg.header.stamp = msgs.time_msg(pair.planner.get_clock().now().nanoseconds)
        pubs['odom'].publish(msg)
    flood_rate = 1000 / (time.monotonic() - flood_start)
    # 20 plan calls at once
    client = pair.node.create_client(GetPlan, f'{pair.ns}/plan',
                                     qos_profile=QoSProfile(depth=100))
    assert client.wait_for_service(timeout_sec=10.0)
    futures = [client.call_async(GetPlan.Request()) for _ in range(20)]
    assert wait_until(lambda: all(f.done() for f in futures), 60.0)
    answers = [f.result() for f in futures]
    print(f'fuzzed {sum(sent.values())} messages {sent}; odometry flood of 1000 at '
          f'{flood_rate / 1e3:.0f} kHz; '
          f'20 plan calls answered; rejected: planner {pair.planner.problems.rejected_inputs}, '
          f'simulator {pair.sim.problems.rejected_inputs}')
    assert all(len(a.plan.poses) == 31 for a in answers)
    assert all(np.isfinite(p.pose.position.x) for a in answers for p in a.plan.poses)
    assert pair.planner.problems.rejected_inputs > 0 and pair.sim.problems.rejected_inputs > 0
    assert pair.planner.problems.errors == 0 and pair.sim.problems.errors == 0
    assert sum(len(m) for m in published.values()) > 100
    assert all(_finite_message(m) for msgs in published.values() for m in msgs)
    # both nodes alive and the loop still tracking
    count, plans = len(pair.odom), pair.planner.planner.stats.plans
    assert wait_until(lambda: len(pair.odom) > count + 100, 10.0)
    assert pair.planner.planner.stats.plans > plans
    xy = np.array([[m.pose.pose.position.x, m.pose.pose.position.y] for m in pair.odom[-50:]])
    assert cross_track_error(xy, pair.reference.q[:, :2]).max() < 0.05


def _record_outputs(node) -> dict[str, list]:
    """Every message the planner publishes, recorded at its publishers."""
    published = {}
    for name in ('pub_path', 'pub_controls', 'pub_cmd'):
        publisher, seen = getattr(node.outputs, name), []
        original = publisher.publish

        def publish(msg, original=original, seen=seen):
            seen.append(msg)
            original(msg)

        publisher.publish = publish
        published[name] = seen
    return published


def _finite_message(msg) -> bool:
    """No NaN or Inf in any float field, however deep."""
    if isinstance(msg, float):
        return np.isfinite(msg)
    if isinstance(msg, (list, tuple)) or type(msg).__name__ == 'array':
        return all(_finite_message(x) for x in msg)
    if hasattr(msg, 'get_fields_and_field_types'):
        return all(_finite_message(getattr(msg, f)) for f in msg.get_fields_and_field_types())
    return True


def _process_figures() -> tuple[float, int]:
    """(resident memory [MiB], threads) of this process, from /proc."""
    fields = dict(line.split(':', 1) for line in open('/proc/self/status'))
    return int(fields['VmRSS'].split()[0]) / 1024, int(fields['Threads'])


def test_soak_with_reference_swaps_and_parameter_changes(graph):
    """Soak for >= 60 s simulated: memory and threads stay flat, the loop keeps tracking.

    A reference swap (Path <-> MultiDOF) and a parameter change every 5 s.
    """
    loop = ClosedLoop(graph, namespace='/soak')
    reference = sleigh_reference(120.0)
    loop.start(reference, 'path', time_scale=10.0)
    samples, kinds = [], ['trajectory', 'path']
    changes = [('horizon', 2.5), ('epsilon', 0.8), ('horizon', 3.0), ('epsilon', 1.0)]
    for step in range(13):
        target = START + 5.0 * (step + 1)
        assert wait_until(lambda: loop.sim_time() >= target, 60.0)
        loop.send_reference(reference, kinds[step % 2])
        name, value = changes[step % len(changes)]
        assert loop.planner.set_parameters([Parameter(name, value=value)])[0].successful
        samples.append(_process_figures())
    t, xy = loop.track()
    memory = np.array([m for m, _ in samples])
    threads = [n for _, n in samples]
    growth = memory[-1] - memory[2]
    print(f'soak: {t[-1] - START:.0f} s simulated, {loop.planner.planner.stats.plans} plans; '
          f'RSS {memory[2]:.1f} -> {memory[-1]:.1f} MiB (growth {growth:.1f} MiB); '
          f'threads {threads}')
    assert t[-1] - START >= 60.0
    assert growth < 15.0  # MiB over the last 50 s: flat, not accumulating per plan
    # never more than at the start (a previous test's DDS participant may end meanwhile, when
    # its Context is collected: that drops the count by its threads)
    assert max(threads[2:]) <= threads[2]
    error = cross_track_error(xy[t - START > 55.0], reference.q[:, :2])
    assert error.max() < 0.05
    assert loop.planner.problems.errors == 0 and loop.planner.planner.stats.fallbacks == 0
