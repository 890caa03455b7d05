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

"""The robot's state from a pose, a twist and joints: hidden coordinates measured or dead-reckoned.

Coordinates a pose does not show (a steering angle, a rotor's angle, a rolling angle) come from
joint states by name — the coordinate's own, or the joint a mapping gives it — with their rates
(a joint's velocity, or differenced when it has none). Each joint is taken at its own stamp and
carried to the pose's by its rate. Quasi-velocities are the least-squares solution of rho v =
the pose's and the joints' rates together. A hidden coordinate no joint gives (or whose joint
went stale) is dead-reckoned: integrated from the last estimate along the estimated motion.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nh_tracking.poses import PoseMap


class JointsRejected(ValueError):
    """A joint state that cannot be used; the message says why."""


def joint_mapping(entries: Sequence[str], pose_map: PoseMap) -> dict[str, int]:
    """Joint name -> hidden coordinate's index, from ``coordinate:joint`` entries.

    Hidden coordinates no entry names are their own joints. ValueError naming a bad entry.
    """
    coordinates = pose_map.system.coordinates
    hidden = {coordinates[i]: i for i in pose_map.hidden}
    named = {name: name for name in hidden}
    for entry in entries:
        coordinate, colon, joint = str(entry).partition(':')
        if not colon or not coordinate or not joint:
            raise ValueError(f'joint_names entry {entry!r} is not coordinate:joint_name')
        if coordinate not in hidden:
            shown = ', '.join(sorted(hidden)) or 'none'
            raise ValueError(f'joint_names entry {entry!r}: {coordinate!r} is not a coordinate '
                             f'the pose does not show (those of {pose_map.system.name}: {shown})')
        named[coordinate] = joint
    if len(set(named.values())) != len(named):
        raise ValueError(f'joint_names gives one joint to two coordinates: {named}')
    return {joint: hidden[coordinate] for coordinate, joint in named.items()}


@dataclass(frozen=True)
class JointReading:
    """The latest of each hidden coordinate's joint: (n,) arrays, NaN where never given."""

    positions: np.ndarray
    rates: np.ndarray  # NaN: not known yet (no velocity and nothing to difference with)
    stamps: np.ndarray  # [ns] int64

    @classmethod
    def empty(cls, n: int) -> JointReading:
        return cls(np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, dtype=np.int64))

    def fresh(self, ns: int, timeout: float) -> np.ndarray:
        """Return the indices of the coordinates given within ``timeout`` [s] before ``ns``."""
        return np.flatnonzero(np.isfinite(self.positions)
                              & ((ns - self.stamps) * 1e-9 <= timeout))


class JointMap:
    """Reads joint states into a :class:`JointReading` for one model's hidden coordinates."""

    def __init__(self, pose_map: PoseMap, entries: Sequence[str] = ()) -> None:
        self.pose_map = pose_map
        self.by_joint = joint_mapping(entries, pose_map)

    def read(self, ns: int, names: Sequence[str], positions: Sequence[float] | np.ndarray,
             velocities: Sequence[float] | np.ndarray,
             previous: JointReading) -> JointReading | None:
        """``previous`` updated with this message's joints (None if it has none of ours).

        JointsRejected for a message out of order, or a value not finite or outside the domain.
        """
        ours = [(i, self.by_joint[name]) for i, name in enumerate(names) if name in self.by_joint]
        if not ours:
            return None
        if len({c for _, c in ours}) != len(ours):
            raise JointsRejected(f'a joint is named twice in {list(names)}')
        system = self.pose_map.system
        reading = JointReading(previous.positions.copy(), previous.rates.copy(),
                               previous.stamps.copy())
        for i, c in ours:
            name = system.coordinates[c]
            position = float(positions[i])
            if ns < previous.stamps[c]:
                raise JointsRejected(f'{names[i]} is stamped before the last one given '
                                     f'({(previous.stamps[c] - ns) * 1e-9:.3f} s): out of order')
            if not np.isfinite(position):
                raise JointsRejected(f'{names[i]} ({name}) position is {position}')
            lo, hi = system.domain.lower[c], system.domain.upper[c]
            if not lo < position < hi:
                raise JointsRejected(f'{names[i]} ({name}) = {position:g} is outside the '
                                     f"model's domain ({lo:g}, {hi:g})")
            if len(velocities):
                rate = float(velocities[i])
                if not np.isfinite(rate):
                    raise JointsRejected(f'{names[i]} ({name}) velocity is {rate}')
            elif np.isfinite(previous.positions[c]) and previous.stamps[c] < ns:  # differenced
                rate = (position - previous.positions[c]) / ((ns - previous.stamps[c]) * 1e-9)
            else:
                rate = np.nan
            reading.positions[c], reading.rates[c], reading.stamps[c] = position, rate, ns
        return reading


def observe(pose_map: PoseMap, ns: int, pose: np.ndarray, twist: np.ndarray,
            joints: JointReading | None, timeout: float,
            previous: tuple[int, np.ndarray, np.ndarray] | None
            ) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """(q, v, hidden coordinates measured) at ``ns`` from a pose, a body twist and the joints.

    Joints older than ``timeout`` [s] are not used; ``previous`` is the last (ns, q, v), from
    which the hidden coordinates no joint gives are dead-reckoned (trapezoid rule).
    """
    q = pose_map.configuration(pose, None if previous is None else previous[1])
    measured = [] if joints is None else [int(i) for i in joints.fresh(ns, timeout)]
    rows: list[int] = []
    if joints is not None and measured:
        rates = joints.rates[measured]
        known = np.isfinite(rates)
        ahead = (ns - joints.stamps[measured]) * 1e-9
        carried = joints.positions[measured] + np.where(known, rates * ahead, 0.0)
        domain = pose_map.system.domain  # (a joint at its stop is not carried past it)
        q[measured] = np.where((carried > domain.lower[measured])
                               & (carried < domain.upper[measured]),
                               carried, joints.positions[measured])
        rows = [m for m, k in zip(measured, known) if k]
    v = pose_map.velocity(q, twist, rows, None if joints is None else joints.rates[rows])
    reckoned = [h for h in pose_map.hidden if h not in measured]
    if previous is not None and reckoned:
        ns_prev, q_prev, v_prev = previous
        rho = pose_map.system.rho
        rate = 0.5 * (rho(q_prev)[reckoned] @ v_prev + rho(q)[reckoned] @ v)
        q[reckoned] = q_prev[reckoned] + (ns - ns_prev) * 1e-9 * rate
    return q, v, measured
