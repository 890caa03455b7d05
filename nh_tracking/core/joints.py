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

from nh_tracking.core.poses import PoseMap


EDGE = 1e-2  # a joint this far past the model's domain is at its edge (rounding, a stop)


class JointsRejected(ValueError):
    """A joint state that cannot be used; the message says why."""


def joint_mapping(entries: Sequence[str], pose_map: PoseMap) -> dict[str, int]:
    """Joint name -> hidden coordinate's index, from ``coordinate:joint`` entries.

    Hidden coordinates no entry names are their own joints. ValueError naming a bad entry.
    """
    system = pose_map.system
    hidden = {system.coordinates[i]: i for i in pose_map.hidden}
    named = {name: name for name in hidden}
    for entry in entries:
        coordinate, colon, joint = (part.strip() for part in str(entry).partition(':'))
        if not colon or not coordinate or not joint:
            raise ValueError(f'joint_names entry {entry!r} is not coordinate:joint_name')
        if coordinate not in hidden:
            raise ValueError(f'joint_names entry {entry!r}: {coordinate!r} is not a hidden '
                             f"coordinate of {system.name} ({', '.join(hidden) or 'it has none'})")
        named[coordinate] = joint
    if len(set(named.values())) != len(named):
        raise ValueError(f'joint_names gives one joint to two coordinates: {named} (a '
                         'coordinate not named in joint_names is its own joint)')
    return {joint: hidden[coordinate] for coordinate, joint in named.items()}


@dataclass(frozen=True)
class JointReading:
    """The latest of each hidden coordinate's joint: (n,) arrays, NaN where never given."""

    positions: np.ndarray
    rates: np.ndarray  # NaN: not known (no velocity, nothing to difference with)
    stamps: np.ndarray  # [ns] int64

    @classmethod
    def empty(cls, n: int) -> JointReading:
        return cls(np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, dtype=np.int64))

    def fresh(self, ns: int, timeout: float) -> np.ndarray:
        """Return the indices of the coordinates given within ``timeout`` [s] of ``ns``."""
        return np.flatnonzero(np.isfinite(self.positions)
                              & (np.abs(ns - self.stamps) * 1e-9 <= timeout))


class JointMap:
    """Reads joint states into a :class:`JointReading` for one model's hidden coordinates.

    Positions up to :data:`EDGE` past the model's domain are taken as at its edge (a joint at
    its stop), further ones refused; a continuous joint reported in (-pi, pi] is unwrapped.
    """

    def __init__(self, pose_map: PoseMap, entries: Sequence[str] = ()) -> None:
        self.system = pose_map.system
        self.by_joint = joint_mapping(entries, pose_map)

    def read(self, ns: int, names: Sequence[str], positions: Sequence[float] | np.ndarray,
             velocities: Sequence[float] | np.ndarray, previous: JointReading,
             timeout: float) -> JointReading | None:
        """``previous`` updated with this message's joints (None if it has none of ours).

        A joint's history counts within ``timeout`` [s]: older (or a clock that jumped back
        further) starts it afresh. JointsRejected for a message out of order, a joint named
        twice, a position not finite or outside the domain.
        """
        ours = [(i, self.by_joint[name]) for i, name in enumerate(names) if name in self.by_joint]
        if not ours:
            return None
        if len({c for _, c in ours}) != len(ours):
            raise JointsRejected(f'a joint is named twice in {list(names)}')
        reading = JointReading(previous.positions.copy(), previous.rates.copy(),
                               previous.stamps.copy())
        for i, c in ours:
            velocity = float(velocities[i]) if len(velocities) else np.nan
            reading.positions[c], reading.rates[c] = self._joint(
                names[i], c, float(positions[i]), velocity, previous, ns, timeout)
            reading.stamps[c] = ns
        return reading

    def _joint(self, joint: str, c: int, position: float, velocity: float,
               previous: JointReading, ns: int, timeout: float) -> tuple[float, float]:
        """(position, rate) of coordinate ``c`` from its joint's reading; JointsRejected."""
        what = f'{joint} ({self.system.coordinates[c]})'
        last, since = previous.positions[c], (ns - previous.stamps[c]) * 1e-9
        known = bool(np.isfinite(last)) and abs(since) <= timeout
        if known and since < 0:
            raise JointsRejected(f'{what} is stamped {-since:.3f} s before the last one '
                                 'given: out of order')
        if not np.isfinite(position):
            raise JointsRejected(f'{what} position is {position}')
        domain = self.system.domain
        lo, hi = domain.lower[c], domain.upper[c]
        if not lo - EDGE < position < hi + EDGE:
            raise JointsRejected(f"{what} = {position:g} is outside the model's domain "
                                 f'({lo:g}, {hi:g})')
        position = float(domain.inside(np.array([position]), [c])[0])
        if known and self.system.angle_mask[c]:  # continuous: the turn nearest the last
            position += 2 * np.pi * np.round((last - position) / (2 * np.pi))
        if np.isfinite(velocity):
            return position, velocity
        if known and since > 0:
            return position, (position - last) / since  # differenced
        return position, previous.rates[c] if known else np.nan


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
        q[measured] = pose_map.system.domain.inside(carried, measured)  # (not past a stop)
        rows = [m for m, k in zip(measured, known) if k]
    v = pose_map.velocity(q, twist, rows, None if joints is None else joints.rates[rows])
    reckoned = [h for h in pose_map.hidden if h not in measured]
    if previous is not None and reckoned:
        ns_prev, q_prev, v_prev = previous
        rho = pose_map.system.rho
        rate = 0.5 * (rho(q_prev)[reckoned] @ v_prev + rho(q)[reckoned] @ v)
        q[reckoned] = q_prev[reckoned] + (ns - ns_prev) * 1e-9 * rate
    return q, v, measured
