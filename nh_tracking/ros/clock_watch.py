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

from dataclasses import dataclass
import enum
import time

from rclpy.clock import Clock, ClockType

from nh_tracking.ros.guarded import guarded, GuardedNode

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


class ClockWatchdog(GuardedNode):
    """A node's clock watchdog: :meth:`on_clock_stopped` on every look while its clock stands."""

    def watch_clock(self) -> object:
        """Create the steady timer (returned, for the node to release)."""
        self.clock_watch = ClockWatch()
        self.steady_clock = Clock(clock_type=ClockType.STEADY_TIME)
        return self.create_timer(WATCH_PERIOD, self._look_at_clock, clock=self.steady_clock)

    def clock_problem(self) -> str:
        """Return what is wrong with the clock now ('' if nothing)."""
        if not self.clock_watch.stopped:
            return ''
        return (f'the clock has not advanced for '
                f'{self.clock_watch.standing_for(time.monotonic()):.1f} s (on sim time: is '
                '/clock published?): not commanding')

    @guarded('clock watchdog')
    def _look_at_clock(self) -> None:
        event = self.clock_watch.look(self.get_clock().now().nanoseconds, time.monotonic())
        if self.clock_watch.stopped:
            self.on_clock_stopped()
        if event is ClockEvent.STOPPED:
            self.get_logger().warn(self.clock_problem())
            self.on_problem()
        elif event is ClockEvent.RESUMED:
            self.get_logger().info('the clock advances again')
        elif event is ClockEvent.JUMPED_BACK:
            self.get_logger().warn(f'the clock jumped back {self.clock_watch.jumped_back_by:.3f}'
                                   ' s: stamps and references from before the jump lie ahead'
                                   f'{clock_sources(self.count_publishers("/clock"))}')
            self.on_problem()

    def other_clocks(self) -> str:
        """On sim time, a note naming the other /clock publishers ('' if there are none)."""
        if not self.get_parameter('use_sim_time').value:
            return ''
        return clock_sources(self.count_publishers('/clock'))

    def warn_of_other_clocks(self) -> None:
        """Say so when several nodes publish /clock (odometry is judged stale on it)."""
        if note := self.other_clocks():
            self.get_logger().warn(f'the odometry is judged on an interleaved clock{note}')

    def on_clock_stopped(self) -> None:
        """Make the robot safe while the clock stands (the node's business)."""
