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

"""A planner or a simulator launched twice under one name: the first keeps the robot."""
from collections.abc import Iterator
from contextlib import contextmanager
import time

from geometry_msgs.msg import Twist
import numpy as np
import pytest

from nh_tracking.examples.nav2 import polyline, route_msg
from nh_tracking.ros.graph import wait_until
from processes import Process
from test_nav2 import nav2_pair

pytestmark = [pytest.mark.timeout(240), pytest.mark.ros, pytest.mark.slow]
CMD_RATE, SIM_RATE = 20.0, 50.0  # config/diff_drive.yaml's


@contextmanager
def twin_of(process: Process, robot) -> Iterator[Process]:
    """Start ``process`` again under its name once the robot moves; both name the other."""
    robot.reference.publish(route_msg(polyline((0, 0), (8, 0)), time.time_ns()))
    assert wait_until(lambda: robot.odometry[-1][1] > 0.3, 20.0)
    twin = Process(process.executable, process.args, process.env)
    try:
        assert twin.wait_for('was on the graph first', 60.0), twin.output[-2000:]
        assert process.wait_for('started later: this one keeps the robot', 10.0)
        yield twin
    finally:
        twin.kill()


def test_a_second_planner_of_the_same_name_yields_and_names_its_twin():
    with nav2_pair() as (robot, planner, sim):
        stamps: list[float] = []
        robot.node.create_subscription(Twist, 'cmd_vel', lambda m: stamps.append(
            time.monotonic()), 100)
        with twin_of(planner, robot) as twin:
            since = time.monotonic()
            time.sleep(3.0)
            sent = sum(t > since for t in stamps) / (time.monotonic() - since)
            print(f'\ntwo planners named /nh_tracking_planner: cmd_vel at {sent:.1f} Hz '
                  f'(cmd_rate {CMD_RATE:g} Hz); the second says: '
                  f'{next(line for line in twin.lines if "graph first" in line).strip()}')
            assert sent <= 1.5 * CMD_RATE  # one planner's commands, not two
            assert robot.odometry[-1][1] > 1.0  # and the first drives on


def test_a_second_simulator_of_the_same_name_yields_and_names_its_twin():
    with nav2_pair() as (robot, planner, sim), twin_of(sim, robot):
        since = len(robot.odometry)
        time.sleep(3.0)
        track = robot.track[since:]
        rate = (len(track) - 1) / (track[-1, 0] - track[0, 0])
        print(f'\ntwo simulators named /nh_tracking_sim: odometry at {rate:.1f} Hz (rate '
              f'{SIM_RATE:g} Hz), x from {track[0, 1]:.2f} to {track[-1, 1]:.2f} m')
        assert rate <= 1.5 * SIM_RATE  # one simulator's odometry, not two
        assert np.all(np.diff(track[:, 1]) >= -1e-3)  # none from a twin back at the start
