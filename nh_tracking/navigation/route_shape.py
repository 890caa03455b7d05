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

"""The shape of an untimed route: where it goes, which way the robot faces, how it bends.

From the robot's closest point on the route (a robot further than :data:`JOIN` is taken to it
first, straight) to its last pose; segments cut to :data:`SPACING`; split at cusps (a turn back
of more than :data:`CUSP_TURN`) into pieces driven alternately forward and backward; headings
the poses' or the tangent's; curvature from chord tangents, exact on a circle, smooth over a
grid planner's jogs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nh_tracking.core.settings import ValueEnum

SPACING = 0.05  # [m] longer segments are cut: speeds change along a route, not between poses
MAX_POINTS = 20_000  # a longer route is cut more coarsely (a 100 km route: every 5 m)
CHORD = 0.1  # [m] the tangent at a point is the chord over this much of the route about it
CURVATURE_WINDOW = 0.2  # [m] curvature is the tangent's turn over this much of the route
CUSP_TURN = np.deg2rad(135.0)  # a turn sharper than this between two segments is a cusp
SEARCH_MARGIN = 1.0  # [m] the closest point is looked for this far past the robot's distance
EQUAL_HEADINGS = 1e-3  # [rad] headings closer than this are equal (identity: unset)
TANGENT_TOLERANCE = 0.1  # [rad] a route "turns" where its tangent leaves the poses' heading
JOIN = 0.1  # [m] a robot further from the route than this is first taken to it, straight


class RouteHeadings(ValueEnum):
    """Where a route's headings come from."""

    AUTO = 'auto'  # the poses', unless they are all equal on a route that turns
    POSES = 'poses'
    TANGENT = 'tangent'


@dataclass(frozen=True)
class RouteShape:
    """A route's points from the robot on, with all that timing it needs."""

    positions: np.ndarray  # (N, 2)
    z: np.ndarray  # (N,)
    yaw: np.ndarray  # (N,) unwrapped: the heading the robot is to have there
    lengths: np.ndarray  # (N - 1,) of the segments
    direction: np.ndarray  # (N - 1,) of travel along each segment
    curvature: np.ndarray  # (N,) |curvature|
    piece: np.ndarray  # (N,) of a point, and of the segment from it on; cusps start pieces
    gears: np.ndarray  # (pieces,) +1 forward, -1 backward
    cusp_at: np.ndarray  # indices of the cusps
    headings: RouteHeadings  # POSES or TANGENT: what was used
    goal: float | None  # a heading the route's last pose asks for beyond its tangent's

    @property
    def at_goal(self) -> bool:
        return len(self.positions) == 1


def shape_route(poses: np.ndarray, start: np.ndarray, choice: RouteHeadings) -> RouteShape:
    """Return the shape of route ``poses`` (N, 4) from the robot at ``start`` (x, y) on."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 4)
    keep = np.r_[True, np.hypot(*np.diff(poses[:, :2], axis=0).T) > 1e-9]
    poses = poses[keep]
    goal = _goal_heading(poses[:, 3])
    reach = float(np.hypot(*(poses[0, :2] - start[:2]))) + SEARCH_MARGIN
    i, foot = closest_point(poses[:, :2], start[:2], reach)
    first = poses[i].copy()
    first[:2] = foot
    poses = np.vstack([first, poses[i + 1:]])
    if len(poses) > 1 and np.hypot(*(poses[1, :2] - foot)) < 1e-9:
        poses = poses[1:]
    if np.hypot(*(foot - start[:2])) > JOIN:
        poses = np.vstack([np.r_[start[:2], poses[0, 2:]], poses])
    if len(poses) == 1:  # at the goal
        empty = np.zeros(0)
        return RouteShape(poses[:, :2], poses[:, 2], poses[:, 3], empty, empty, np.zeros(1),
                          np.zeros(1, dtype=int), np.ones(1), np.zeros(0, dtype=int),
                          RouteHeadings.POSES, None)
    poses = _resampled(poses)
    positions = poses[:, :2]
    step = np.diff(positions, axis=0)
    direction = np.arctan2(step[:, 1], step[:, 0])
    cusp_at = np.flatnonzero(np.abs(wrap(np.diff(direction))) > CUSP_TURN) + 1
    piece = np.zeros(len(poses), dtype=int)
    for c in cusp_at:
        piece[c:] += 1  # a cusp starts the piece that leaves it
    tangent = _tangent(positions, piece)
    headings = _choose_headings(poses[:, 3], tangent, piece, cusp_at, choice)
    if headings is RouteHeadings.TANGENT:
        gears = (-1.0) ** np.arange(len(cusp_at) + 1)  # forward first, reversing at each cusp
        yaw = tangent + np.where(gears[piece] < 0, np.pi, 0.0)
    else:
        yaw = np.unwrap(poses[:, 3])
        along = np.cos(yaw[:-1] - direction)  # each segment: driven facing its way or not
        gears = np.array([1.0 if along[piece[:-1] == p].sum() >= 0 else -1.0
                          for p in range(len(cusp_at) + 1)])
        goal = None  # (the poses' own headings end on it)
    return RouteShape(positions, poses[:, 2], np.unwrap(yaw), np.hypot(*step.T), direction,
                      _curvature(positions, tangent, piece), piece, gears, cusp_at, headings,
                      goal)


def closest_point(positions: np.ndarray, point: np.ndarray, reach: float = np.inf
                  ) -> tuple[int, np.ndarray]:
    """(segment index, point on it) nearest ``point`` among segments starting within ``reach``.

    Reach is arc length from the first position: a route that ends where it starts (a loop)
    is not taken as finished.
    """
    positions, point = np.asarray(positions, dtype=float), np.asarray(point, dtype=float)
    if len(positions) == 1:
        return 0, positions[0].copy()
    a, b = positions[:-1], positions[1:]
    arc = np.r_[0.0, np.cumsum(np.hypot(*(b - a).T))][:-1]
    a, b = a[arc <= reach], b[arc <= reach]
    d = b - a
    lengths = np.maximum(np.einsum('ij,ij->i', d, d), 1e-300)
    s = np.clip(np.einsum('ij,ij->i', point - a, d) / lengths, 0.0, 1.0)
    foot = a + s[:, None] * d
    i = int(np.argmin(np.hypot(*(foot - point).T)))
    return i, foot[i]


def _goal_heading(yaw: np.ndarray) -> float | None:
    """Return the last pose's heading, unless every pose's is the identity's (none is set)."""
    return None if np.abs(wrap(yaw)).max() <= EQUAL_HEADINGS else float(yaw[-1])


def wrap(angle: np.ndarray) -> np.ndarray:
    """Angle(s) in [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def _resampled(poses: np.ndarray) -> np.ndarray:
    """Return ``poses`` with every segment longer than :data:`SPACING` cut into equal parts.

    The parts are at least a :data:`MAX_POINTS`-th of the route: the work stays bounded.
    """
    lengths = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    spacing = max(SPACING, lengths.sum() / MAX_POINTS)
    parts = np.maximum(1, np.ceil(lengths / spacing - 1e-9).astype(int))
    if (parts == 1).all():
        return poses
    poses = np.c_[poses[:, :3], np.unwrap(poses[:, 3])]
    segment = np.repeat(np.arange(len(parts)), parts)
    fraction = (np.arange(parts.sum()) - np.repeat(np.cumsum(parts) - parts, parts) + 1) \
        / np.repeat(parts, parts)
    cut = poses[segment] + fraction[:, None] * (poses[segment + 1] - poses[segment])
    return np.vstack([poses[:1], cut])


def _choose_headings(yaw: np.ndarray, tangent: np.ndarray, piece: np.ndarray,
                     cusp_at: np.ndarray, choice: RouteHeadings) -> RouteHeadings:
    """Choose the poses' headings, unless ``auto`` finds them unset or not the route's.

    Unset: all but the last pose's equal (the last may carry the goal's, as NavFn's paths do)
    and the route leaves that heading — forward, or backward when it is not the identity's.
    """
    if choice is not RouteHeadings.AUTO:
        return choice
    common = yaw[:-1] if len(yaw) > 2 else yaw
    if np.abs(wrap(common - common[0])).max() > EQUAL_HEADINGS:
        return RouteHeadings.POSES  # headings of their own
    gears = (-1.0) ** np.arange(len(cusp_at) + 1)
    forward = tangent + np.where(gears[piece] < 0, np.pi, 0.0)
    along = np.abs(wrap(forward - common[0])).max() <= TANGENT_TOLERANCE
    backward = abs(wrap(common[0])) > EQUAL_HEADINGS and \
        np.abs(wrap(forward + np.pi - common[0])).max() <= TANGENT_TOLERANCE
    return RouteHeadings.POSES if along or backward else RouteHeadings.TANGENT


def _tangent(positions: np.ndarray, piece: np.ndarray) -> np.ndarray:
    """Direction of travel at each point: the chord over :data:`CHORD` about it.

    Within its piece (a cusp starts the piece that leaves it), so a corner's heading turns
    over the stretch where its speed is lowered, not at one pose.
    """
    arc = np.r_[0.0, np.cumsum(np.hypot(*np.diff(positions, axis=0).T))]
    out = np.zeros(len(positions))
    half = CHORD / 2
    for p in np.unique(piece):
        members = np.flatnonzero(piece == p)
        s, xy = arc[members], positions[members]
        if len(members) == 1:  # (the last pose, alone past a cusp)
            out[members] = out[members[0] - 1] if members[0] else 0.0
            continue
        ahead = np.stack([np.interp(np.minimum(s + half, s[-1]), s, xy[:, j]) for j in (0, 1)],
                         axis=1)
        behind = np.stack([np.interp(np.maximum(s - half, s[0]), s, xy[:, j]) for j in (0, 1)],
                          axis=1)
        d = ahead - behind
        out[members] = np.arctan2(d[:, 1], d[:, 0])
    return out


def _curvature(positions: np.ndarray, tangent: np.ndarray, piece: np.ndarray) -> np.ndarray:
    """|curvature| at each point: the turn of the chord tangent over :data:`CURVATURE_WINDOW`.

    Chords smooth a grid planner's jogs (a staircase is a straight diagonal) and are exact on a
    circle.
    """
    arc = np.r_[0.0, np.cumsum(np.hypot(*np.diff(positions, axis=0).T))]
    out = np.zeros(len(positions))
    half = CURVATURE_WINDOW / 2
    for p in np.unique(piece):
        members = np.flatnonzero(piece == p)
        s, heading = arc[members], np.unwrap(tangent[members])
        lo, hi = np.maximum(s - half, s[0]), np.minimum(s + half, s[-1])
        span = hi - lo
        turn = np.abs(np.interp(hi, s, heading) - np.interp(lo, s, heading))
        out[members] = np.where(span > 1e-9, turn / np.maximum(span, 1e-9), 0.0)
    return out
