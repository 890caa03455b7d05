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

"""Odometry from any publisher, as deployed: best effort (sensor data) is heard; none is said.

Planner and simulator processes with config/diff_drive.yaml; the planner's odometry comes
through this process, republished best effort, or not at all.
"""
import time

from action_msgs.msg import GoalStatus
from nav2_msgs.action import FollowPath
from nav_msgs.msg import Odometry
import pytest
from rclpy.qos import qos_profile_sensor_data

from nh_tracking.examples.nav2 import polyline
from test_nav2 import nav2_pair, TOLERANCE

pytestmark = [pytest.mark.timeout(240), pytest.mark.ros, pytest.mark.slow]


def test_best_effort_odometry_is_heard_and_the_goal_is_reached():
    with nav2_pair(remap=('odom:=sensor_odom',)) as (robot, planner, sim):
        relay = robot.node.create_publisher(Odometry, 'sensor_odom', qos_profile_sensor_data)
        robot.node.create_subscription(Odometry, 'odom', relay.publish, 100)
        status, result = robot.result_of(robot.send_goal(polyline((0, 0), (3, 0))), 60.0)
        end = robot.odometry[-1]
        print(f'\nbest-effort odometry: goal {status}, ended at ({end[1]:.3f}, {end[2]:.3f}) m')
        assert status == GoalStatus.STATUS_SUCCEEDED and result.error_code == 0
        assert abs(end[1] - 3.0) < TOLERANCE and abs(end[2]) < TOLERANCE


def test_a_goal_without_odometry_fails_naming_the_topic():
    with nav2_pair('odom_timeout:=0.5', remap=('odom:=silent_odom',)) as (robot, planner, sim):
        sent = time.monotonic()
        status, result = robot.result_of(robot.send_goal(polyline((0, 0), (3, 0))), 30.0)
        took = time.monotonic() - sent
        print(f'\nno odometry: {result.error_msg!r} after {took:.1f} s')
        assert status == GoalStatus.STATUS_ABORTED
        assert result.error_code == FollowPath.Result.FAILED_TO_MAKE_PROGRESS
        assert 'no fresh odometry on /silent_odom for 5 s' in result.error_msg
        assert took < 10.0  # the acceptance's bound: 10 odom_timeouts and a tick
