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

"""What a tracking session takes and gives: its settings, a state estimate, a plan result."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import threading
import time

import numpy as np

from nh_tracking.core.settings import check_fields, setting
from nh_tracking.planning.receding_horizon import PlanOutcome

Clock = Callable[[], int]  # now, in integer nanoseconds


@dataclass(frozen=True)
class SessionSettings:
    """How a session runs: when it replans, how often it commands, when odometry is stale."""

    replan_period: float = setting(0.1, 'time between replans', 's', (1e-3, 60.0))
    replan_on_odom: bool = setting(False, 'also replan on every odometry message')
    cmd_rate: float = setting(20.0, 'velocity command rate', 'Hz', (0.1, 1000.0))
    display_rate: float = setting(10.0, 'planned_path and planned_markers rate, at most one '
                                  'per plan (what people look at, off the replanning path)',
                                  'Hz', (0.1, 1000.0))
    odom_timeout: float = setting(0.5, 'odometry older than this is stale: commands slow to '
                                  'rest, no plans', 's', (1e-3, 3600.0))
    max_clock_skew: float = setting(0.1, 'odometry stamped further ahead of this clock is '
                                    'refused (clocks out of step)', 's', (1e-3, 60.0))
    reference_max_speed: float = setting(10.0, 'references faster than this are refused '
                                         '(0: not checked)', 'm/s', (0.0, 1e3))
    reference_max_accel: float = setting(20.0, 'references accelerating more than this (over '
                                         '0.2 s) are refused (0: not checked)', 'm/s^2',
                                         (0.0, 1e4))

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class StateEstimate:
    """The robot's state from one odometry message."""

    ns: int
    q: np.ndarray
    v: np.ndarray
    received: float  # time.perf_counter() at receipt, for latency figures


@dataclass(frozen=True)
class PlanResult:
    """What one replanning attempt produced: an outcome to publish, or why there is none."""

    outcome: PlanOutcome | None
    state: StateEstimate | None
    reason: str


class ClockSkew(ValueError):
    """A state stamped ahead of the clock that receives it."""


WINDOW = 1.0  # [s] the stale fraction is over this long (the diagnostics' period)


class Staleness:
    """Whether the odometry is stale now, and for what fraction of the last :data:`WINDOW`."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.now, self._clock = False, clock
        self._lock = threading.Lock()
        self._changes: list[tuple[float, bool]] = [(clock(), False)]  # (when, stale)

    def mark(self, stale: bool) -> bool:
        """Record whether it is stale now; return whether that changed."""
        with self._lock:
            if stale == self.now:
                return False
            now = self._clock()
            self.now = stale
            changes = self._changes  # kept: those in force at some time in the window
            self._changes = [c for c, after in zip(changes, changes[1:])
                             if after[0] > now - WINDOW] + [changes[-1], (now, stale)]
            return True

    def fraction(self) -> float:
        """Return the fraction of the last :data:`WINDOW` it was stale."""
        with self._lock:
            now = self._clock()
            stale_for, changes = 0.0, self._changes + [(now, self.now)]
            for (start, stale), (end, _) in zip(changes, changes[1:]):
                if stale:
                    stale_for += max(0.0, end - max(start, now - WINDOW))
            return stale_for / WINDOW
