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

"""The command guard: what no command may do, whatever plan it came from.

The last stage before a command leaves, independent of how its plan was made (solved, shifted,
fallback, braking). On the model's quasi-velocities v, with the body twist ``M(q) v``
(:meth:`PoseMap.twist_matrix`) for what is physical:

- **velocity bounds** (v_min, v_max): a command outside is scaled back along itself (its path's
  curvature kept) until every component is inside;
- **a speed limit** (Nav2's SpeedLimit: percent of the robot's maximum speed, or m/s): the
  translational speed is capped the same way;
- **acceleration**: the translational speed changes by at most ``max_accel`` (faster) or
  ``max_decel`` (slower) per second from the command before; a limit lowered under the robot
  is reached at ``max_decel``, never above the velocity bounds;
- **obstacles**: the robot's disc swept along what the command does for ``lookahead`` seconds
  and then braking at ``max_decel`` must not come nearer an obstacle than it is (touching one
  it does not touch now); the speed is cut to the largest that stops short, to zero if need be.
  A stop may be harder than ``max_decel``: an obstacle comes first.

No solve: a few dozen small numpy operations a call (timings in docs/performance.md). Nothing
here knows ROS.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from scipy.spatial import cKDTree

from nh_tracking.core.settings import check_fields, setting, ValueEnum
from nh_tracking.problem.limits import obstacle_discs

SWEEP_STEP = 0.01  # [m] the swept disc is checked this often along its path
MAX_SWEEP_POINTS = 400
BOUND_TOL = 1e-9
CONTACT_TOL = 0.005  # [m] a sweep that dips this little into an obstacle's margin is clear


class GuardAction(ValueEnum):
    """What the guard did to a command."""

    VELOCITY_BOUND = 'velocity bound'
    SPEED_LIMIT = 'speed limit'
    ACCELERATION = 'acceleration'
    OBSTACLE = 'obstacle'


@dataclass(frozen=True)
class GuardNote:
    """One thing the guard did, with its figures in ``text``."""

    action: GuardAction
    text: str


@dataclass(frozen=True)
class GuardSettings:
    """The command guard's own limits (the velocity bounds and max_accel are the planner's)."""

    max_decel: float = setting(1.0, 'largest deceleration commanded, and the one stopping '
                               'distances before obstacles are reckoned with', 'm/s^2',
                               (1e-3, 100.0))

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class SpeedLimit:
    """Nav2's speed limit: ``limit`` percent of the robot's maximum speed, or m/s; 0: none."""

    limit: float = 0.0
    percentage: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.limit) and self.limit >= 0.0) or (
                self.percentage and self.limit > 100.0):
            raise ValueError(f'a speed limit must be 0 (none) or positive'
                             f'{", at most 100 %" if self.percentage else " m/s"}, '
                             f'got {self.limit!r}')

    def cap(self, max_speed: float) -> float:
        """Return the translational speed allowed [m/s] (inf: none) for a robot's maximum."""
        if self.limit == 0.0:
            return math.inf
        return self.limit / 100.0 * max_speed if self.percentage else self.limit

    def __str__(self) -> str:
        if self.limit == 0.0:
            return 'none'
        return f'{self.limit:g} %' if self.percentage else f'{self.limit:g} m/s'


class OccupiedCells:
    """Occupied costmap cells: centres (K, 2) of side ``size``, indexed once for look-ups.

    Each cell counts as the disc through its corners.
    """

    def __init__(self, centres: np.ndarray, size: float) -> None:
        self.centres = np.asarray(centres, dtype=float).reshape(-1, 2)
        self.radius = size / math.sqrt(2.0)
        self._tree = cKDTree(self.centres) if len(self.centres) else None

    def __len__(self) -> int:
        return len(self.centres)

    def gaps(self, points: np.ndarray) -> np.ndarray:
        """Distances (P,) from points (P, 2) to the nearest cell's disc (inf if none)."""
        if self._tree is None:
            return np.full(len(points), np.inf)
        return self._tree.query(points)[0] - self.radius


NO_CELLS = OccupiedCells(np.zeros((0, 2)), 0.0)


class Clearance:
    """Distances from points in the plane to the nearest obstacle edge.

    ``discs``: (x, y, r) or (x, y, r, vx, vy) rows where they are now (moving ones move on with
    time); ``cells``: a costmap's occupied cells.
    """

    def __init__(self, discs: np.ndarray | None = None,
                 cells: OccupiedCells = NO_CELLS) -> None:
        self.discs = np.zeros((0, 5)) if discs is None else obstacle_discs(discs)
        self.cells = cells

    @property
    def empty(self) -> bool:
        return not len(self.discs) and not len(self.cells)

    def __call__(self, points: np.ndarray, times: np.ndarray | None = None) -> np.ndarray:
        """Distances (P,) from points (P, 2), at ``times`` (P,) from now for moving discs."""
        out = self.cells.gaps(points)
        if len(self.discs):
            at = np.zeros(len(points)) if times is None else times
            centres = self.discs[None, :, :2] + at[:, None, None] * self.discs[None, :, 3:5]
            gaps = np.hypot(*np.moveaxis(centres - points[:, None, :], -1, 0))
            out = np.minimum(out, (gaps - self.discs[None, :, 2]).min(axis=1))
        return out


def arc(pose: np.ndarray, twist: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Positions (T, 2) at ``times`` of a body moving from ``pose`` (x, y, ., yaw) at ``twist``.

    ``twist``: body frame (vx, vy, vz, wz), held: a circular arc (a line when wz = 0).
    """
    vx, vy, wz = twist[0], twist[1], twist[3]
    angle = wz * times
    small = np.abs(angle) < 1e-6
    safe = np.where(small, 1.0, wz)
    sin_term = np.where(small, times, np.sin(angle) / safe)
    cos_term = np.where(small, 0.5 * wz * times ** 2, (1.0 - np.cos(angle)) / safe)
    local = np.c_[sin_term * vx - cos_term * vy, cos_term * vx + sin_term * vy]
    c, s = math.cos(pose[3]), math.sin(pose[3])
    return pose[:2] + local @ np.array([[c, s], [-s, c]])


def free_distance(clearance: Clearance, pose: np.ndarray, twist: np.ndarray, radius: float,
                  length: float) -> float:
    """How far [m] the disc of ``radius`` goes along the motion of ``twist`` before contact.

    Checked every :data:`SWEEP_STEP` up to ``length``; inf if it is clear that far. Contact:
    nearer an obstacle than the disc's edge (by :data:`CONTACT_TOL`: a plan rounding one at
    the margin), or (already touching one) deeper than at the start.
    """
    speed = math.hypot(twist[0], twist[1])
    if clearance.empty or speed <= 0.0 or length <= 0.0:
        return math.inf
    count = min(MAX_SWEEP_POINTS, int(math.ceil(length / SWEEP_STEP)))
    distances = np.linspace(0.0, length, count + 1)
    times = distances / speed
    gaps = clearance(arc(pose, twist, times), times) - radius
    allowed = min(0.0, gaps[0])
    hit = np.flatnonzero(gaps[1:] < allowed - CONTACT_TOL)
    return math.inf if not len(hit) else float(distances[hit[0]])


def stopping_speed(distance: float, lookahead: float, decel: float) -> float:
    """Return the largest speed that, held ``lookahead`` s then braked at ``decel``, stops."""
    if math.isinf(distance):
        return math.inf
    return max(0.0, decel * (-lookahead + math.sqrt(lookahead ** 2 + 2.0 * distance / decel)))


@dataclass(frozen=True)
class Guarded:
    """A command the guard let pass: quasi-velocities ``v`` and what it did to get them."""

    v: np.ndarray
    notes: tuple[GuardNote, ...] = ()

    @property
    def changed(self) -> bool:
        return bool(self.notes)


@dataclass(frozen=True)
class CommandGuard:
    """The limits in force on commands: ``bounds`` (2, k) of v (None: none) and the rest.

    Thread-safe: immutable; a change is a new guard.
    """

    bounds: np.ndarray | None
    max_accel: float
    max_decel: float
    robot_radius: float = 0.0
    speed_limit: SpeedLimit = SpeedLimit()

    def max_speed(self, twist_matrix: np.ndarray) -> float:
        """Return the largest translational speed [m/s] the velocity bounds allow at ``M(q)``."""
        if self.bounds is None:
            return math.inf
        planar = twist_matrix[:2]
        used = np.flatnonzero(np.abs(planar).max(axis=0) > 0.0)
        if not np.isfinite(self.bounds[:, used]).all():
            return math.inf
        corners = np.array(np.meshgrid(*self.bounds[:, used].T)).reshape(len(used), -1)
        return float(np.hypot(*(planar[:, used] @ corners)).max()) if len(used) else 0.0

    def velocity(self, v: np.ndarray, twist_matrix: np.ndarray, previous: np.ndarray,
                 dt: float, pose: np.ndarray | None = None,
                 clearance: Clearance | None = None, lookahead: float = 0.0,
                 from_state: bool = False) -> Guarded:
        """Guard the command ``v`` following ``previous`` (``dt`` s before), at ``M(q)``.

        ``pose``, ``clearance``, ``lookahead``: where the robot is, the obstacles, and how long
        the command will be in force (one command period and the state's age).
        ``from_state``: ``previous`` is the robot's velocity, not a command: from beyond the
        bounds it is slowed into them at ``max_decel`` (a state ``dt`` later, as a plan has),
        where a command is brought inside at once.
        """
        notes: list[GuardNote] = []
        speed_of = _speed_of(twist_matrix)
        wanted = speed_of(v)
        v = self._within_bounds(v, notes)
        cap = self.speed_limit.cap(self.max_speed(twist_matrix) if self.speed_limit.percentage
                                   else math.inf)
        if speed_of(v) > cap * (1.0 + BOUND_TOL):
            notes.append(GuardNote(GuardAction.SPEED_LIMIT, f'speed limited to {cap:.2f} m/s by '
                                                            f'speed_limit ({self.speed_limit})'))
            v = v * (cap / speed_of(v))
        # from a command inside the bounds: above them, however fast before, is never asked
        v = self._accelerating(v, previous if from_state else self._within_bounds(previous, []),
                               dt, speed_of, notes)
        if clearance is not None and pose is not None and not clearance.empty:
            v = self._short_of(v, twist_matrix, pose, clearance, lookahead, notes)
        if notes and notes[0].action is GuardAction.VELOCITY_BOUND:
            notes[0] = GuardNote(GuardAction.VELOCITY_BOUND, f'command cut from {wanted:.2f} '
                                 f'to {speed_of(v):.2f} m/s by the velocity bounds')
        return Guarded(v, tuple(notes))

    def _within_bounds(self, v: np.ndarray, notes: list[GuardNote]) -> np.ndarray:
        """Scale ``v`` back along itself into the bounds (clip where zero is outside them)."""
        if self.bounds is None:
            return v
        lo, hi = self.bounds
        if ((v >= lo - BOUND_TOL * np.abs(lo)) & (v <= hi + BOUND_TOL * np.abs(hi))).all():
            return v
        notes.append(GuardNote(GuardAction.VELOCITY_BOUND, 'velocity bounds'))
        if (lo > 0).any() or (hi < 0).any():
            return np.clip(v, lo, hi)
        with np.errstate(all='ignore'):
            room = np.where(v > 0, hi / v, np.where(v < 0, lo / v, np.inf))
        return v * min(1.0, float(room.min()))

    def _accelerating(self, v: np.ndarray, previous: np.ndarray, dt: float, speed_of,
                      notes: list[GuardNote]) -> np.ndarray:
        """Move from ``previous`` toward ``v`` by at most what max_accel/max_decel allow."""
        change = speed_of(v - previous)
        faster = speed_of(v) > speed_of(previous)
        allowed = (self.max_accel if faster else self.max_decel) * dt
        if change <= allowed * (1.0 + 1e-6) or dt <= 0.0:
            return v
        guarded = previous + (v - previous) * (allowed / change)
        notes.append(GuardNote(GuardAction.ACCELERATION, (
            f'{"acceleration" if faster else "deceleration"} limited to '
            f'{self.max_accel if faster else self.max_decel:g} m/s^2 '
            f'({speed_of(v):.2f} m/s asked, {speed_of(guarded):.2f} m/s commanded)')))
        return guarded

    def _short_of(self, v: np.ndarray, twist_matrix: np.ndarray, pose: np.ndarray,
                  clearance: Clearance, lookahead: float,
                  notes: list[GuardNote]) -> np.ndarray:
        """Cut ``v`` to the largest speed that stops short of every obstacle."""
        twist = twist_matrix @ v
        speed = math.hypot(twist[0], twist[1])
        if speed <= 0.0:
            return v
        reach = speed * lookahead + speed ** 2 / (2.0 * self.max_decel)
        distance = free_distance(clearance, pose, twist, self.robot_radius, reach)
        allowed = stopping_speed(distance, lookahead, self.max_decel)
        if allowed >= speed:
            return v
        if allowed <= 1e-3:
            notes.append(GuardNote(GuardAction.OBSTACLE, f'stopped {distance:.2f} m before '
                                                         f'an obstacle (from {speed:.2f} m/s)'))
            return np.zeros_like(v)
        notes.append(GuardNote(GuardAction.OBSTACLE, f'slowed from {speed:.2f} to '
                                                     f'{allowed:.2f} m/s: an obstacle '
                                                     f'{distance:.2f} m ahead'))
        return v * (allowed / speed)


def _speed_of(twist_matrix: np.ndarray):
    """Return the translational speed [m/s] of quasi-velocities at ``M(q)``, as a function."""
    planar = twist_matrix[:2]

    def speed(v: np.ndarray) -> float:
        return float(math.hypot(*(planar @ v)))
    return speed
