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

"""What a plan may not do: actuator and velocity bounds, and discs it must keep clear of.

Bounds are (lo, hi) pairs, scalars or one value per channel, +-inf allowed; obstacles are discs
(x, y, r) in the plane of the model's pose position, to be cleared by the robot's radius, or
moving discs (x, y, r, vx, vy): where they are at the plan's start and their constant velocity
over the horizon. Each input is checked once, here, and a ValueError names the argument.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import functools

import numpy as np
from numpy.typing import ArrayLike

from nh_tracking.core.system import NonholonomicSystem

BoundsLike = tuple[ArrayLike, ArrayLike] | None


def bounds(value: BoundsLike, size: int, name: str) -> np.ndarray:
    """(2, size) array [lo; hi] from a (lo, hi) pair of scalars or length-``size`` arrays."""
    if value is None:
        return _unbounded(size)
    try:
        lo, hi = value
        pair = np.vstack([np.broadcast_to(np.asarray(b, dtype=float), (size,)) for b in (lo, hi)])
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be a (lo, hi) pair of numbers or arrays of length '
                         f'{size}, got {value!r}') from None
    if np.isnan(pair).any():
        raise ValueError(f'{name} has NaN: {value!r}')
    if (pair[0] > pair[1]).any():
        raise ValueError(f'{name} has lo > hi: {pair[0].tolist()} > {pair[1].tolist()}')
    return pair


@functools.lru_cache(maxsize=None)
def _unbounded(size: int) -> np.ndarray:
    """[-inf; inf] of ``size`` (read-only and shared: every problem without limits has one)."""
    pair = np.vstack([np.full(size, -np.inf), np.full(size, np.inf)])
    pair.flags.writeable = False
    return pair


def obstacle_discs(value: ArrayLike, name: str = 'obstacles') -> np.ndarray:
    """(M, 5) array of discs (x, y, r, vx, vy) from rows of (x, y, r) (at rest) or all five.

    Finite centres and velocities, finite radii >= 0.
    """
    if isinstance(value, np.ndarray) and value.size == 0:
        return np.zeros((0, 5))
    if isinstance(value, np.ndarray) and value.ndim == 2 and value.shape[1] in (3, 5):
        rows = value.astype(float)  # (the common case, several times a replan: no loop)
        return _checked_discs(np.c_[rows, np.zeros((len(rows), 5 - rows.shape[1]))], name)
    try:
        arrays = [np.asarray(row, dtype=float) for row in value]  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be a list of (x, y, r) or (x, y, r, vx, vy) discs, got '
                         f'{value!r:.80}') from None
    if not arrays:
        return np.zeros((0, 5))
    if any(a.shape not in ((3,), (5,)) for a in arrays):
        raise ValueError(f'{name} must be a list of (x, y, r) or (x, y, r, vx, vy) discs, got '
                         f'rows of {sorted({a.size for a in arrays})} values')
    return _checked_discs(np.array([np.concatenate([a, np.zeros(5 - a.size)]) for a in arrays]),
                          name)


def _checked_discs(discs: np.ndarray, name: str) -> np.ndarray:
    """Return ``discs`` (M, 5) if finite with radii >= 0, else raise ValueError naming them."""
    if not np.isfinite(discs).all():
        raise ValueError(f'{name} must have finite centres, radii and velocities')
    if (discs[:, 2] < 0).any():
        raise ValueError(f'{name} radii must be >= 0, got {discs[:, 2].tolist()}')
    return discs


VIOLATION_TOL = 1e-6  # a plan breaking a limit by more is no success
PREDICTION = 2.0  # [s] a moving disc not seen again for longer is held where it would be then


def moved(discs: np.ndarray, by: ArrayLike) -> np.ndarray:
    """Return discs (x, y, r, vx, vy) where their velocities take them in ``by`` seconds.

    ``by``: one time for all, or one per disc (since each was seen). Between 0 and
    :data:`PREDICTION` seconds on: told nothing newer for longer, a disc is held there, at rest
    (a tracker that stopped must not fling its last discs across the map); never back (a
    stamp ahead of the planner's clock leaves a disc where it was seen).
    """
    out = obstacle_discs(discs)
    ahead = np.broadcast_to(np.asarray(by, dtype=float), (len(out),))
    out[:, :2] += np.clip(ahead, 0.0, PREDICTION)[:, None] * out[:, 3:5]
    out[ahead > PREDICTION, 3:5] = 0.0
    return out


def centres_at(centres: np.ndarray, velocities: np.ndarray, t: ArrayLike) -> np.ndarray:
    """Return centres (M, 2) moved on by their velocities (M, 2) to times ``t``: (T, M, 2)."""
    return centres[None] + np.reshape(t, (-1, 1, 1)) * velocities[None]


def in_the_plane(system: NonholonomicSystem) -> bool:
    """Whether ``system`` declares a pose x and y: obstacles can be avoided only then."""
    return {'x', 'y'} <= set((system.pose or {}).values())


def plane(system: NonholonomicSystem) -> tuple[int, int]:
    """Return the indices in q of the pose's x and y: where obstacles are."""
    if not in_the_plane(system):
        raise ValueError(f'{system.name} declares no pose x and y (pose=...): obstacles '
                         'need to know where the robot is in the plane')
    axes = {axis: system.coordinates.index(c) for c, axis in (system.pose or {}).items()}
    return axes['x'], axes['y']


SWEPT_DEPTH = 0.1  # of a disc's radius: the most a plan's segment may cut into it (a chord)
SHORT_CHORD = 2 * np.sqrt(1 - (1 - SWEPT_DEPTH)**2)  # of the radius: a chord cutting that deep


@dataclass(frozen=True)
class Limits:
    """The bounds and obstacles of one problem, checked and in arrays."""

    controls: np.ndarray  # (2, r)
    velocities: np.ndarray  # (2, k)
    obstacles: np.ndarray  # (M, 3): x, y at the start, and r + the robot's radius
    plane: tuple[int, int] | None
    motion: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (M, 2): vx, vy

    @classmethod
    def of(cls, system: NonholonomicSystem, control_bounds: BoundsLike,
           velocity_bounds: BoundsLike, obstacles: ArrayLike,
           robot_radius: float) -> Limits:
        if isinstance(robot_radius, bool) or not isinstance(robot_radius, (int, float)) or not (
                np.isfinite(robot_radius) and robot_radius >= 0):
            raise ValueError(f'robot_radius must be a finite number >= 0, got {robot_radius!r}')
        discs = obstacle_discs(obstacles)
        if control_bounds is None and velocity_bounds is None and not len(discs):
            return _no_limits(system.r, system.k)
        grown = discs[:, :3].copy()
        grown[:, 2] += robot_radius
        return cls(bounds(control_bounds, system.r, 'control_bounds'),
                   bounds(velocity_bounds, system.k, 'velocity_bounds'), grown,
                   plane(system) if len(discs) else None, discs[:, 3:5].copy())

    @functools.cached_property
    def bounded_controls(self) -> bool:
        return bool(np.isfinite(self.controls).any())

    @functools.cached_property
    def bounded_velocities(self) -> bool:
        return bool(np.isfinite(self.velocities).any())

    @functools.cached_property
    def active(self) -> bool:
        """Whether anything is limited (these are asked several times per replan: cached)."""
        return self.bounded_controls or self.bounded_velocities or len(self.obstacles) > 0

    @functools.cached_property
    def moving(self) -> bool:
        """Whether a disc moves: then where a plan keeps clear of it depends on when."""
        return bool(np.any(self.motion))

    def centres(self, t: ArrayLike | None = None) -> np.ndarray:
        """Return the discs' centres at times ``t`` from the start: (T, M, 2), (1, M, 2) at rest.

        Raises ValueError for moving discs without times (a caller that forgot them).
        """
        if not self.moving:
            return self.obstacles[None, :, :2]
        if t is None:
            raise ValueError('moving obstacles: clearance needs the times of the configurations')
        return centres_at(self.obstacles[:, :2], self.motion, t)

    def clearance(self, q: np.ndarray, t: ArrayLike | None = None) -> np.ndarray:
        """Distance to each obstacle's edge (grown by the robot's radius) at configurations q.

        ``t``: the configurations' times from the start (needed only if a disc moves).
        """
        if self.plane is None:
            return np.zeros((len(np.atleast_2d(q)), 0))
        p = np.atleast_2d(q)[:, list(self.plane)]
        gaps = p[:, None, :] - self.centres(t)
        return np.linalg.norm(gaps, axis=2) - self.obstacles[None, :, 2]

    def violation(self, q: np.ndarray, v: np.ndarray, u: np.ndarray | None = None,
                  t: ArrayLike | None = None) -> float:
        """Largest amount by which states q (., n), v (., k) and controls u break a limit.

        ``t``: q's times from the start (needed only if a disc moves).
        """
        if not self.active:
            return 0.0
        worst = [0.0, float(np.max(-self.clearance(q, t), initial=0.0))]
        for value, (lo, hi) in ((v, self.velocities), (u, self.controls)):
            if value is not None and len(value):
                worst.append(float(np.max(np.maximum(lo - value, value - hi), initial=0.0)))
        return max(worst)

    def swept(self, path: np.ndarray, t: ArrayLike | None = None) -> float:
        """Return how far a path's straight segments cut into a disc beyond what is allowed.

        ``path``: configurations in time order (a plan's knots and midpoints), at times ``t``
        (needed only if a disc moves: each segment is then judged relative to the disc, in
        which it is straight too). A segment between two points on a disc's edge cuts in by
        its chord's sagitta; more than that, or than :data:`SWEPT_DEPTH` of the radius, and
        the path went through the disc between its points (a plan so fast that its points are
        farther apart than the disc is wide). Points inside a disc are :meth:`clearance`'s to
        report (short segments are not looked at: theirs can cut in deeper only from a point
        inside). A path that curves between its points is judged by its chords (a replay may
        go a little deeper).
        """
        if self.plane is None or len(path) < 2:
            return 0.0
        relative = np.asarray(path)[:, None, list(self.plane)] - self.centres(t)
        a, ab = relative[:-1], relative[1:] - relative[:-1]
        length2 = np.maximum(np.sum(ab**2, axis=2), 1e-300)
        if length2.max() <= (SHORT_CHORD * self.obstacles[:, 2].min())**2:
            return 0.0  # (a segment this short cuts in by less, if its ends are outside)
        radius = self.obstacles[None, :, 2]
        along = np.clip(-np.sum(a * ab, axis=2) / length2, 0.0, 1.0)
        depth = radius - np.linalg.norm(a + along[..., None] * ab, axis=2)
        sagitta = radius - np.sqrt(np.maximum(radius**2 - length2 / 4, 0.0))
        return float(np.max(depth - np.minimum(sagitta, SWEPT_DEPTH * radius), initial=0.0))

    def plan_violation(self, q: np.ndarray, v: np.ndarray, u: np.ndarray | None,
                       h: float) -> float:
        """:meth:`violation` of a plan's knots q (``h`` apart), v and controls u, and midpoints."""
        if not self.active:
            return 0.0
        return self.violation(plan_path(q), v, u, plan_times(len(q) - 1, h))


@functools.lru_cache(maxsize=None)
def _no_limits(controls: int, velocities: int) -> Limits:
    """Return the limits of a problem that has none: one per size, shared (answers cached)."""
    none, still = np.zeros((0, 3)), np.zeros((0, 2))
    none.flags.writeable = still.flags.writeable = False
    return Limits(_unbounded(controls), _unbounded(velocities), none, None, still)


def bounds_from_lists(lo: tuple, hi: tuple, size: int, name: str) -> tuple | None:
    """Return (lo, hi) from lists of 0, 1 or ``size`` values (ROS's ``name``_min, _max).

    Empty is unbounded on that side; None when both are.
    """
    if not lo and not hi:
        return None
    for side, values in (('min', lo), ('max', hi)):
        if len(values) not in (0, 1, size):
            raise ValueError(f'{name}_{side} must have 0, 1 or {size} values, got {len(values)}')
    pair = (np.asarray(lo) if lo else -np.inf, np.asarray(hi) if hi else np.inf)
    if np.any(np.broadcast_to(pair[0], size) > np.broadcast_to(pair[1], size)):
        raise ValueError(f'{name}_min must not exceed {name}_max, got {list(lo)} > {list(hi)}')
    return pair


def nearest_discs(discs: np.ndarray, point: np.ndarray, count: int,
                  reach: float = np.inf) -> np.ndarray:
    """Return the ``count`` discs whose edges are nearest ``point`` (x, y), nearest first.

    Only those whose edges are within ``reach`` of it. ``discs``: rows of (x, y, r, ...).
    """
    discs = np.asarray(discs, dtype=float)
    discs = discs.reshape(-1, discs.shape[-1] if discs.ndim == 2 else 3)
    to_point = np.hypot(*(discs[:, :2] - np.asarray(point, dtype=float)[:2]).T) - discs[:, 2]
    order = np.argsort(to_point, kind='stable')
    return discs[order[to_point[order] <= reach][:max(count, 0)]]


def clearance_points(q: np.ndarray) -> np.ndarray:
    """Return the configurations of a plan's clearance rows, in g's order.

    Each interval's midpoint, then its end knot (the start is data, not a decision): the
    order both transcriptions add them in.
    """
    points = np.empty((2 * (len(q) - 1), q.shape[1]))
    points[0::2], points[1::2] = 0.5 * (q[1:] + q[:-1]), q[1:]
    return points


def plan_path(q: np.ndarray) -> np.ndarray:
    """Return a plan's knots and midpoints in time order: the path its limits hold on."""
    return np.vstack([q[:1], clearance_points(q)])


def plan_times(steps: int, h: float) -> np.ndarray:
    """Return the times of :func:`plan_path`'s points from the start, for knots ``h`` apart."""
    return 0.5 * h * np.arange(2 * steps + 1)
