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

"""The simulator across pauses and clock jumps: time that passed is integrated, a jump is not."""
import threading

from geometry_msgs.msg import Twist
import numpy as np
import pytest
from rcl_interfaces.msg import Log
from rosgraph_msgs.msg import Clock as ClockMsg

from nh_tracking.ros import messages as msgs
from nh_tracking.ros import SimulatorNode
from nh_tracking.ros.graph import parameters, wait_until
from test_ros import unique_namespace

pytestmark = pytest.mark.timeout(120)


@pytest.mark.ros
@pytest.mark.slow
def test_a_paused_simulator_drives_a_velocity_command_only_until_its_timeout(graph):
    """cmd_vel 0.5 m/s sent once, the simulator paused 3 s: 0.25 m at most, not 1.5 m."""
    sim = graph.add(SimulatorNode, namespace=unique_namespace(), parameter_overrides=parameters(
        model='unicycle', mode='velocity', control_timeout=0.5, rate=50.0))
    probe = graph.plain_node('probe', sim.get_namespace())
    pub = probe.create_publisher(Twist, 'cmd_vel', 10)
    assert wait_until(lambda: pub.get_subscription_count() > 0, 10.0)
    command = Twist()
    command.linear.x = 0.5
    pub.publish(command)
    assert wait_until(lambda: sim.state[0][0] > 0.0, 5.0)
    graph.executor.remove_node(sim)  # paused: no step for 3 s
    wait_until(lambda: False, 3.0)
    graph.executor.add_node(sim)
    assert wait_until(lambda: sim.state[1][0] == 0.0, 5.0)
    x = sim.state[0][0]
    print(f'\n0.5 m/s for control_timeout 0.5 s, paused 3 s: moved {x:.3f} m')
    # from receipt to its timeout, and the step it arrived in (20 ms; 0.1 s when busy)
    assert 0.0 < x <= 0.5 * (0.5 + 0.1)


@pytest.mark.ros
def test_a_clock_jump_is_not_integrated_as_motion(graph):
    """On /clock, a unicycle coasting at 0.5 m/s; the clock jumps +3600 s: no 1800 m step."""
    ns = unique_namespace()
    sim = graph.add(SimulatorNode, namespace=ns, parameter_overrides=parameters(
        model='unicycle', initial_state=[0.0, 0.0, 0.0, 0.5, 0.0], rate=50.0,
        use_sim_time=True))
    probe = graph.plain_node('probe', ns)
    logs: list[str] = []
    probe.create_subscription(Log, '/rosout', lambda m: logs.append(m.msg), 100)
    clock = probe.create_publisher(ClockMsg, '/clock', 10)
    assert wait_until(lambda: clock.get_subscription_count() > 0, 10.0)
    stop, now, lock = threading.Event(), [int(100e9)], threading.Lock()

    def tick() -> None:  # 10 ms of sim time every 10 ms
        while not stop.wait(0.01):
            with lock:
                now[0] += int(10e6)
                clock.publish(ClockMsg(clock=msgs.time_msg(now[0])))
    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    try:
        assert wait_until(lambda: sim.state[0][0] > 0.2, 10.0)
        with lock:
            before = sim.state[0][0], now[0]
            now[0] += int(3600e9)
        assert wait_until(lambda: now[0] > before[1] + int(3600.5e9), 10.0)
        assert wait_until(lambda: any('the clock jumped +3600' in m for m in logs), 5.0), logs
        after = sim.state[0][0], now[0]
    finally:
        stop.set()
        ticker.join()
    moved, passed = after[0] - before[0], (after[1] - before[1]) * 1e-9 - 3600.0
    print(f'\n/clock +3600 s: moved {moved:.3f} m in {passed:.2f} s of clock besides')
    assert 0.0 < moved <= 0.5 * passed + 0.05 and np.isfinite(after[0])
