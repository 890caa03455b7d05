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

"""The robot's latest state from odometry and joint states, on a session's clock.

Odometry and joint states arrive on one thread (the planner's odometry receiver); the state is
read by the solver and executor threads.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
import dataclasses
import threading

import numpy as np

from nh_tracking.core.joints import JointMap, JointReading, JointsRejected, observe
from nh_tracking.core.poses import carried, PoseMap
from nh_tracking.session.interface import Clock, ClockSkew, StateEstimate

LEAD = 0.05  # s: odometry stamped this far ahead of the clock keeps its stamp (a tick)


class RobotState:
    """Pose, twist and joints in; :class:`StateEstimate` (q, v at a stamp) out.

    ``joint_names``: ``coordinate:joint`` entries for joints not named as the model's
    coordinates (ValueError for a bad one). Odometry or joints stamped over
    ``max_clock_skew`` [s] ahead of the clock are refused, joints older than ``odom_timeout``
    [s] too; a joint that has gone that long without news is dead-reckoned.
    """

    def __init__(self, pose_map: PoseMap, clock: Clock, joint_names: Sequence[str] = (),
                 odom_timeout: float = 0.5,
                 log: Callable[[str, str], None] = lambda level, text: None) -> None:
        self.pose_map = pose_map
        self.clock = clock
        self.odom_timeout = odom_timeout
        self.max_clock_skew = 0.1
        self.log = log
        self.joint_names = tuple(joint_names)
        self.joint_map = JointMap(pose_map, joint_names)
        self.measured: list[int] | None = None  # hidden coordinates measured (None: no state)
        self.ever_measured: set[int] = set()
        self.joints_lost = False  # some once measured are dead-reckoned now
        self._said_unmatched = False
        self._joints = JointReading.empty(pose_map.system.n)
        self._latest: StateEstimate | None = None
        self._lock = threading.Lock()

    def set_pose_map(self, pose_map: PoseMap) -> None:
        """Read poses and joints for a model with new physical parameters from now on.

        The latest state's velocities are carried into the new basis (which may scale with
        the values), so the next plan does not start from the old one's.
        """
        joint_map = JointMap(pose_map, self.joint_names)
        with self._lock:
            latest, old = self._latest, self.pose_map.system
            if latest is not None:
                self._latest = dataclasses.replace(latest, v=carried(
                    old, pose_map.system, latest.q, latest.v)[0])
            self.pose_map, self.joint_map = pose_map, joint_map

    @property
    def latest(self) -> StateEstimate | None:
        with self._lock:
            return self._latest

    def _checked_stamp(self, ns: int) -> tuple[int, int]:
        """(``ns`` no later than LEAD past the clock, the clock); ClockSkew beyond max_clock_skew.

        A stamp up to LEAD ahead keeps its time: on sim time odometry often arrives before the
        /clock tick it was stamped with, and dating it at receipt would start every plan from
        it one tick early. Further ahead (clocks out of step) it is dated LEAD past the clock,
        so the watchdog gives it at most LEAD more.
        """
        now = self.clock()
        ahead = (ns - now) * 1e-9
        if ahead > self.max_clock_skew:
            raise ClockSkew(f'stamped {ahead:.3f} s ahead of this clock (max_clock_skew is '
                            f'{self.max_clock_skew:g} s): clocks out of step?')
        return min(ns, now + int(LEAD * 1e9)), now

    def set_joints(self, ns: int, names: Sequence[str], positions: Sequence[float] | np.ndarray,
                   velocities: Sequence[float] | np.ndarray) -> bool:
        """Take joint states; False if none of them is a hidden coordinate.

        ClockSkew or JointsRejected for a message that cannot be used.
        """
        ns, now = self._checked_stamp(ns)
        age = (now - ns) * 1e-9
        if age > self.odom_timeout:
            raise JointsRejected(f'stamped {age:.3f} s ago, older than odom_timeout '
                                 f'({self.odom_timeout:g} s)')
        with self._lock:
            reading = self.joint_map.read(ns, names, positions, velocities, self._joints,
                                          self.odom_timeout)
            if reading is not None:
                self._joints = reading
        if reading is None and not self._said_unmatched and self.pose_map.hidden:
            self._said_unmatched = True
            self.log('info', f"joint_states without {', '.join(self.joint_map.by_joint)}: "
                             'ignored (joint_names maps joints named otherwise)')
        return reading is not None

    def set_odometry(self, ns: int, pose: np.ndarray, twist: np.ndarray,
                     received: float) -> StateEstimate:
        """Take the latest pose and body twist, with the joints (:mod:`joints`).

        ClockSkew if stamped over max_clock_skew ahead.
        """
        ns = self._checked_stamp(ns)[0]
        with self._lock:
            prev, joints = self._latest, self._joints
        q, v, measured = observe(self.pose_map, ns, pose, twist, joints, self.odom_timeout,
                                 None if prev is None else (prev.ns, prev.q, prev.v))
        state = StateEstimate(ns, q, v, received)
        with self._lock:
            self._latest = state
        if measured != self.measured:
            self._say_hidden(measured)
        return state

    def _say_hidden(self, measured: list[int]) -> None:
        """Say once which hidden coordinates come from joint_states and which are dead-reckoned."""
        self.ever_measured |= set(measured)
        self.joints_lost = bool(self.ever_measured - set(measured))
        self.measured = measured
        if self.pose_map.hidden:
            self.log('warn' if self.joints_lost else 'info',
                     f'hidden coordinates: {self.hidden_status}')

    @property
    def hidden_status(self) -> str:
        """Where the coordinates a pose does not show come from ('' for a model with none)."""
        names, measured = self.pose_map.system.coordinates, self.measured or []
        reckoned = [h for h in self.pose_map.hidden if h not in measured]
        groups = [(measured, 'from joint_states'),
                  ([h for h in reckoned if h in self.ever_measured],
                   'dead-reckoned (joint_states stale)'),
                  ([h for h in reckoned if h not in self.ever_measured],
                   'dead-reckoned (no joint_states for them)')]
        parts = [f"{', '.join(names[h] for h in group)} {how}" for group, how in groups if group]
        return '; '.join(parts)
