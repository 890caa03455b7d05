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

"""Heavy obstacle inputs never stall the commands: planner and simulator as deployed.

A 2000 x 2000 costmap (100 m square, walls on 5 % of it) at 5 Hz and 5,000 obstacle markers
at 10 Hz, for 20 s, while the robot follows a straight route clear of them
(config/diff_drive.yaml, velocity mode; both nodes listen to both topics). What is checked:
``cmd_vel`` never pauses longer than a period + 0.1 s, the robot stays on its route at its
speed, the planner uses inputs (the newest) and says WARN naming the one it drops, and once the
flood stops its diagnostics are back to OK — nothing left queued.
"""
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import OccupancyGrid
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from nh_tracking.examples.nav2 import polyline, route_msg
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.graph import wait_until
from nh_tracking.ros.obstacle_bytes import read_markers
from nh_tracking.ros.obstacle_receiver import ObstacleReceiver, RECENT
from nh_tracking.ros.planner_interface import LATCHED
from processes import cpu_seconds
from test_nav2 import nav2_pair, SPEED
from test_ros import unique_namespace

pytestmark = pytest.mark.timeout(300)
PERIOD = 1 / 20.0  # diff_drive.yaml's cmd_rate
FLOOD = 20.0  # [s]
CORRIDOR = 2.0  # [m] |y| kept free of walls and markers, the route along y = 0


def costmap_bytes(rng: np.random.Generator) -> bytes:
    """Return a 2000 x 2000 costmap of 5 cm cells about the origin, walls off the corridor."""
    grid = OccupancyGrid()
    grid.header.frame_id = 'odom'
    grid.info.resolution, grid.info.width, grid.info.height = 0.05, 2000, 2000
    grid.info.origin.position.x = grid.info.origin.position.y = -50.0
    cells = np.zeros((2000, 2000), dtype=np.int8)
    while np.count_nonzero(cells) < 0.05 * cells.size:
        col, row = rng.integers(0, 1980, 2)
        cells[row:row + rng.integers(1, 20), col:col + rng.integers(1, 20)] = 100
    free = np.abs((np.arange(2000) + 0.5) * 0.05 - 50.0) < CORRIDOR
    cells[free] = 0
    grid.data = cells.ravel()
    return serialize_message(grid)


def marker_bytes(rng: np.random.Generator, stamp_s: int) -> bytes:
    """Return 5,000 cylinders (r = 0.1 m) off the corridor, at one stamp."""
    y = rng.uniform(CORRIDOR, 40.0, 5000) * rng.choice([-1.0, 1.0], 5000)
    markers = []
    for i, (x, y_i) in enumerate(zip(rng.uniform(-40.0, 40.0, 5000), y)):
        marker = Marker(ns='people', id=i, type=Marker.CYLINDER)
        marker.header.frame_id, marker.header.stamp.sec = 'odom', stamp_s
        marker.pose.position.x, marker.pose.position.y = float(x), float(y_i)
        marker.pose.orientation.w, marker.scale.x = 1.0, 0.2
        markers.append(marker)
    return serialize_message(MarkerArray(markers=markers))


@pytest.mark.ros
@pytest.mark.slow
def test_a_flood_of_costmaps_and_markers_never_stalls_the_commands():
    rng = np.random.default_rng(7)
    grids = [costmap_bytes(rng) for _ in range(2)]
    now_s = int(time.time())
    marker_sets = [marker_bytes(rng, now_s + i) for i in range(4)]  # moving a little each
    stamped = 'cmd_vel_stamped:=true'
    with nav2_pair(stamped, sim=('mode:=velocity', stamped)) as (robot, planner, sim):
        node = robot.node
        commands: list[float] = []  # when the planner sent each (its stamp: system time)
        node.create_subscription(TwistStamped, 'cmd_vel', lambda m: commands.append(
            cv.stamp_ns(m.header.stamp) * 1e-9), 100)
        statuses: list[tuple[float, bytes, str, dict]] = []
        node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: statuses.extend(
            (time.monotonic(), s.level, s.message, {kv.key: kv.value for kv in s.values})
            for s in m.status if s.name.endswith(': planning')), 100)
        costmap = node.create_publisher(OccupancyGrid, 'costmap', LATCHED)
        obstacles = node.create_publisher(MarkerArray, 'obstacles', LATCHED)
        robot.reference.publish(route_msg(polyline((0, 0), (16, 0))))
        assert wait_until(lambda: robot.odometry[-1][4] > 0.8 * SPEED, 20.0), \
            planner.output[-2000:]

        cpu = [cpu_seconds(p.proc.pid) for p in (planner, sim)]
        started, started_ns = time.monotonic(), time.time_ns()
        stop = threading.Event()

        def flood() -> None:
            tick = 0
            while not stop.wait(0.1):
                obstacles.publish(marker_sets[tick % len(marker_sets)])
                if tick % 2 == 0:
                    costmap.publish(grids[tick // 2 % len(grids)])
                tick += 1
        flooding = threading.Thread(target=flood, daemon=True)
        flooding.start()
        time.sleep(FLOOD)
        stop.set()
        flooding.join()
        stopped, stopped_ns = time.monotonic(), time.time_ns()
        cpu = [(cpu_seconds(p.proc.pid) - c) / FLOOD for p, c in zip((planner, sim), cpu)]
        calm = wait_until(lambda: statuses[-1][1] == DiagnosticStatus.OK, RECENT + 5.0)

        times = np.array(commands)
        start, stop_s = started_ns * 1e-9, stopped_ns * 1e-9
        during = times[(times > start) & (times < stop_s)]
        after = times[(times > stop_s + 0.5) & (times < stop_s + 2.5)]
        track = robot.track
        flooded = track[(track[:, 0] > started) & (track[:, 0] < stopped)]
        speed = (flooded[-1, 1] - flooded[0, 1]) / (flooded[-1, 0] - flooded[0, 0])
        lagging = [s[2] for s in statuses if started < s[0] < stopped + 1.0 and s[1] ==
                   DiagnosticStatus.WARN and ('costmap' in s[2] or 'obstacles' in s[2])]
        last = statuses[-1]
        inputs = {k: v for k, v in last[3].items() if k.startswith(('costmap', 'obstacles'))}
        print(f'\nflood {FLOOD:.0f} s: cmd_vel {len(during) / FLOOD:.1f} Hz, longest gap '
              f'{np.diff(during).max():.3f} s (odometry: {np.diff(flooded[:, 0]).max():.3f} s); '
              f'after it {len(after) / 2.0:.1f} Hz; robot {speed:.3f} m/s, |y| <= '
              f'{np.abs(flooded[:, 2]).max():.3f} m; WARN {lagging[:1]}; then {last[2]!r} '
              f'{inputs}; CPU planner {cpu[0]:.2f}, simulator {cpu[1]:.2f} cores')
        assert np.diff(during).max() <= PERIOD + 0.1
        assert len(after) >= 0.9 * 2.0 / PERIOD and np.diff(after).max() <= PERIOD + 0.1
        assert speed >= 0.8 * SPEED and np.abs(flooded[:, 2]).max() < 0.1
        dropped = int(inputs['costmap_dropped']) + int(inputs['obstacles_dropped'])
        assert calm and (lagging or not dropped), last  # WARN while dropping, then OK again
        assert int(inputs['costmap_used']) >= 3 and int(inputs['obstacles_used']) >= 3
        assert 'messages come faster than they can be read' in planner.output or not dropped


@pytest.mark.ros
def test_a_burst_is_read_newest_first_and_what_it_replaced_is_counted_and_told(graph):
    """Six messages at once to a reader that takes 0.3 s a message: the newest is used.

    Of the messages waiting while one is read (or before the first is taken, on a loaded
    machine), only the newest is read next: the rest are dropped, counted and told.
    """
    ns = unique_namespace()
    owner, sender = graph.plain_node('owner', ns), graph.plain_node('sender', ns)
    used: list[int] = []
    receiver = ObstacleReceiver(owner, {'obstacles': (MarkerArray, lambda msg, _: (
        used.append(read_markers(msg).keys[0][1]), time.sleep(0.3)))})
    try:
        publisher = sender.create_publisher(MarkerArray, 'obstacles', LATCHED)
        assert wait_until(lambda: publisher.get_subscription_count() >= 2, 10.0)
        for i in range(6):
            publisher.publish(MarkerArray(markers=[Marker(ns='burst', id=i)]))
        assert wait_until(lambda: used and used[-1] == 5, 10.0), used
        time.sleep(0.5)  # (nothing more comes)
        load = receiver.loads['obstacles']
        print(f'\nburst of 6: used {used}, dropped {load.dropped}; said: {receiver.problems()}')
        assert used[-1] == 5 and len(used) + load.dropped == 6 and load.dropped >= 1
        assert receiver.problems() and receiver.problems()[0].startswith('obstacles: ')
    finally:
        receiver.close()
