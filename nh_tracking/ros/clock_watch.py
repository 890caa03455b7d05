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

"""A watchdog for the node's own clock, on the steady clock: a stopped or backward /clock.

On sim time every timer runs on /clock: when /clock stops, nothing would command the robot or
say why. This watchdog runs on the steady clock instead; the node gives a zero command while
its clock stands, reports it, and says when the clock jumps back.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import enum
import time

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from nh_tracking.ros.guarded import guarded, ProblemLog

WATCH_PERIOD = 0.1  # [s, steady] how often the clock is looked at
CLOCK_TIMEOUT = 0.5  # [s, steady] without the node's clock advancing: it has stopped


class ClockEvent(enum.Enum):
    STOPPED = 'stopped'
    RESUMED = 'resumed'
    JUMPED_BACK = 'jumped back'


@dataclass
class ClockWatch:
    """Judges the node's clock (ns) against the steady clock (s), one look at a time."""

    timeout: float = CLOCK_TIMEOUT
    stopped: bool = False
    _last_ns: int | None = None
    _advanced: float = 0.0  # steady time it last advanced
    jumped_back_by: float = 0.0  # [s] the last jump back

    def look(self, clock_ns: int, steady: float) -> ClockEvent | None:
        """Record the clocks now; return what changed, if anything."""
        last, self._last_ns = self._last_ns, clock_ns
        if last is None or clock_ns != last:
            self._advanced = steady
            was_stopped, self.stopped = self.stopped, False
            if last is not None and clock_ns < last:
                self.jumped_back_by = (last - clock_ns) * 1e-9
                return ClockEvent.JUMPED_BACK
            return ClockEvent.RESUMED if was_stopped else None
        if not self.stopped and steady - self._advanced > self.timeout:
            self.stopped = True
            return ClockEvent.STOPPED
        return None

    def standing_for(self, steady: float) -> float:
        """Return how long [s] the clock has not advanced."""
        return steady - self._advanced


def clock_sources(publishers: int) -> str:
    """Say why a clock jumps when several nodes publish it: their times interleave."""
    if publishers <= 1:
        return ''
    return (f'; {publishers} nodes publish /clock (simulators of other robots or tests on this '
            'ROS_DOMAIN_ID?): give each simulated world a domain of its own')


def other_clocks(node: Node) -> str:
    """On sim time, a note naming the other /clock publishers ('' if there are none)."""
    if not node.get_parameter('use_sim_time').value:
        return ''
    return clock_sources(node.count_publishers('/clock'))


def warn_of_other_clocks(node: Node) -> None:
    """Say so when several nodes publish /clock (odometry is judged stale on it)."""
    if note := other_clocks(node):
        node.get_logger().warn(f'the odometry is judged on an interleaved clock{note}')


class ClockWatchdog:
    """Looks at ``node``'s clock on the steady clock every :data:`WATCH_PERIOD` until closed.

    While the clock stands, ``on_stopped()`` is called at every look (the node makes the robot
    safe); its stopping and a jump back are logged and reported at once, its resuming logged.
    """

    def __init__(self, node: Node, problems: ProblemLog, on_stopped: Callable[[], None]) -> None:
        self.node, self.problems, self._on_stopped = node, problems, on_stopped
        self.watch = ClockWatch()
        self._timer = node.create_timer(WATCH_PERIOD, self._look,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def close(self) -> None:
        """Stop looking (destroy the timer)."""
        self.node.destroy_timer(self._timer)

    def problem(self) -> str:
        """Return what is wrong with the clock now ('' if nothing)."""
        if not self.watch.stopped:
            return ''
        return (f'the clock has not advanced for '
                f'{self.watch.standing_for(time.monotonic()):.1f} s (on sim time: is '
                '/clock published?): not commanding')

    @guarded('clock watchdog')
    def _look(self) -> None:
        node = self.node
        event = self.watch.look(node.get_clock().now().nanoseconds, time.monotonic())
        if self.watch.stopped:
            self._on_stopped()
        if event is ClockEvent.STOPPED:
            node.get_logger().warn(self.problem())
            self.problems.report()
        elif event is ClockEvent.RESUMED:
            node.get_logger().info('the clock advances again')
        elif event is ClockEvent.JUMPED_BACK:
            node.get_logger().warn(f'the clock jumped back {self.watch.jumped_back_by:.3f}'
                                   ' s: stamps and references from before the jump lie ahead'
                                   f'{clock_sources(node.count_publishers("/clock"))}')
            self.problems.report()
