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

"""Untimed routes (what Nav2's planners publish) timed into references a robot can follow.

A route is poses without times. It is driven from the robot's closest point on it to its last
pose, where it ends at rest: at ``reference_speed``, slower where ``v^2 * curvature`` would pass
``max_lateral_accel``, changing speed at most ``max_accel`` (a forward and a backward pass over
the speed limits). A cusp, where the route turns back on itself, is a stop and a change of
direction. Headings are the poses' own, or the route's tangent when the poses carry none (all
equal, as unset orientations are, on a route that turns).
"""
from __future__ import annotations

from dataclasses import dataclass
import enum

import numpy as np

from nh_tracking.settings import check_fields, setting

SPACING = 0.05  # [m] longer segments are cut: speeds change along a route, not between poses
MAX_POINTS = 20_000  # a longer route is cut more coarsely (a 100 km route: every 5 m)
CHORD = 0.1  # [m] the tangent at a point is the chord over this much of the route about it
CURVATURE_WINDOW = 0.2  # [m] curvature is the tangent's turn over this much of the route
CUSP_TURN = np.deg2rad(135.0)  # a turn sharper than this between two segments is a cusp
SEARCH_MARGIN = 1.0  # [m] the closest point is looked for this far past the robot's distance
EQUAL_HEADINGS = 1e-3  # [rad] headings closer than this are equal (identity: unset)
TANGENT_TOLERANCE = 0.1  # [rad] a route "turns" where its tangent leaves the poses' heading
JOIN = 0.1  # [m] a robot further from the route than this is first taken to it, straight
TURN_RATE, TURN_ACCEL = 1.0, 1.0  # [rad/s, rad/s^2] a turn in place to the goal's heading


class RouteHeadings(str, enum.Enum):
    """Where a route's headings come from."""

    AUTO = 'auto'  # the poses', unless they are all equal on a route that turns
    POSES = 'poses'
    TANGENT = 'tangent'

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class RouteSettings:
    """How untimed routes are timed."""

    reference_speed: float = setting(0.5, 'speed along untimed routes (paths whose poses all '
                                     'carry one stamp, as Nav2 planners publish them); 0: '
                                     'such paths are refused', 'm/s', (0.0, 100.0))
    max_accel: float = setting(0.5, 'largest change of speed along a route', 'm/s^2',
                               (1e-3, 100.0))
    max_lateral_accel: float = setting(0.5, 'routes are slowed where speed^2 * curvature '
                                       'would pass this', 'm/s^2', (1e-3, 100.0))
    route_headings: str = setting('auto', "a route's headings: the poses' (poses), the "
                                  "route's tangent (tangent), or the poses' unless they are "
                                  'all equal on a route that turns (auto)',
                                  choices=tuple(h.value for h in RouteHeadings))

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class TimedRoute:
    """A route with times: what a planner tracks (body twists derived, not splined)."""

    times: np.ndarray  # (N,) [s] from the start
    poses: np.ndarray  # (N, 4) x, y, z, yaw
    twists: np.ndarray  # (N, 4) body vx, vy, vz, yaw rate
    speeds: np.ndarray  # (N,) [m/s] along the route, negative where it is driven backwards
    headings: RouteHeadings  # POSES or TANGENT: what was used
    cusps: int

    @property
    def length(self) -> float:
        return float(np.hypot(*np.diff(self.poses[:, :2], axis=0).T).sum())


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


def time_route(poses: np.ndarray, start: np.ndarray, start_speed: float,
               settings: RouteSettings) -> TimedRoute:
    """Return ``poses`` (N, 4) timed from the closest point to ``start`` (x, y).

    A robot further than :data:`JOIN` from that point is taken to it first. ``start_speed`` is
    the robot's speed along its heading (negative: backwards); the route starts from it where
    it points the way the route is driven.
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 4)
    keep = np.r_[True, np.hypot(*np.diff(poses[:, :2], axis=0).T) > 1e-9]
    poses = poses[keep]
    reach = float(np.hypot(*(poses[0, :2] - start[:2]))) + SEARCH_MARGIN
    i, foot = closest_point(poses[:, :2], start[:2], reach)
    first = poses[i].copy()
    first[:2] = foot
    poses = np.vstack([first, poses[i + 1:]])
    if len(poses) > 1 and np.hypot(*(poses[1, :2] - foot)) < 1e-9:
        poses = poses[1:]
    if np.hypot(*(foot - start[:2])) > JOIN:
        poses = np.vstack([np.r_[start[:2], poses[0, 2:]], poses])
    if len(poses) == 1:  # at the goal: hold it
        return TimedRoute(np.array([0.0, 1.0]), np.repeat(poses, 2, axis=0), np.zeros((2, 4)),
                          np.zeros(2), RouteHeadings.POSES, 0)
    poses = _resampled(poses)
    positions = poses[:, :2]
    step = np.diff(positions, axis=0)
    lengths = np.hypot(*step.T)
    direction = np.arctan2(step[:, 1], step[:, 0])  # of each segment
    turn = np.abs(_wrap(np.diff(direction)))
    cusp_at = np.flatnonzero(turn > CUSP_TURN) + 1  # points where the route turns back
    piece = np.zeros(len(poses), dtype=int)  # of a point, and of the segment from it on
    for c in cusp_at:
        piece[c:] += 1  # a cusp starts the piece that leaves it
    tangent = _tangent(positions, piece)
    headings = _choose_headings(poses[:, 3], tangent, piece, cusp_at, settings)
    if headings is RouteHeadings.TANGENT:
        gears = (-1.0) ** np.arange(len(cusp_at) + 1)  # forward first, reversing at each cusp
        yaw = tangent + np.where(gears[piece] < 0, np.pi, 0.0)
    else:
        yaw = np.unwrap(poses[:, 3])
        along = np.cos(yaw[:-1] - direction)  # each segment: driven facing its way or not
        gears = np.array([1.0 if along[piece[:-1] == p].sum() >= 0 else -1.0
                          for p in range(len(cusp_at) + 1)])
    speed = _speed_profile(lengths, _curvature(positions, tangent, piece), cusp_at,
                           start_speed * gears[0], settings)
    times = np.r_[0.0, np.cumsum(_durations(lengths, speed, settings.max_accel))]
    yaw = np.unwrap(yaw)
    signed = speed * gears[piece]
    world = speed[:, None] * np.c_[np.cos(np.r_[direction, direction[-1]]),
                                   np.sin(np.r_[direction, direction[-1]])]
    c, s = np.cos(yaw), np.sin(yaw)
    yaw_rate = np.gradient(yaw, times) if len(times) > 2 else np.zeros(len(times))
    twists = np.c_[c * world[:, 0] + s * world[:, 1], -s * world[:, 0] + c * world[:, 1],
                   np.zeros(len(times)), yaw_rate]
    out = np.c_[positions, poses[:, 2], yaw]
    goal = _goal_heading(poses[:, 3])
    if headings is RouteHeadings.TANGENT and goal is not None:
        times, out, twists, signed = _turned_to(goal, times, out, twists, signed)
    return TimedRoute(times, out, twists, signed, headings, len(cusp_at))


def _goal_heading(yaw: np.ndarray) -> float | None:
    """The last pose's heading, unless every pose's is the identity's (then none is set)."""
    return None if np.abs(_wrap(yaw)).max() <= EQUAL_HEADINGS else float(yaw[-1])


def _turned_to(goal: float, times: np.ndarray, poses: np.ndarray, twists: np.ndarray,
               speeds: np.ndarray) -> tuple[np.ndarray, ...]:
    """The route, then a turn in place to heading ``goal`` (:data:`TURN_RATE`, TURN_ACCEL)."""
    angle = float(_wrap(goal - poses[-1, 3]))
    if abs(angle) <= EQUAL_HEADINGS:
        return times, poses, twists, speeds
    size, w, a = abs(angle), TURN_RATE, TURN_ACCEL
    rate = min(w, np.sqrt(size * a))  # the highest rate the turn reaches
    duration = size / rate + rate / a
    t = np.linspace(0.0, duration, max(3, int(np.ceil(duration / 0.05)) + 1))[1:]
    up, down = np.minimum(t, rate / a), np.maximum(t - (duration - rate / a), 0.0)
    turned = a * up ** 2 / 2 + rate * (t - up) - a * down ** 2 / 2
    rates = a * up - a * down
    sign = np.sign(angle)
    extra = np.repeat(poses[-1:], len(t), axis=0)
    extra[:, 3] += sign * turned
    turning = np.zeros((len(t), 4))
    turning[:, 3] = sign * rates
    return (np.r_[times, times[-1] + t], np.vstack([poses, extra]),
            np.vstack([twists, turning]), np.r_[speeds, np.zeros(len(t))])


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def _resampled(poses: np.ndarray) -> np.ndarray:
    """``poses`` with every segment longer than :data:`SPACING` cut into equal parts.

    Or longer than a :data:`MAX_POINTS`-th of the route: the work stays bounded.
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
                     cusp_at: np.ndarray, settings: RouteSettings) -> RouteHeadings:
    """The poses' headings, unless ``auto`` finds them unset or not the route's.

    Unset: all but the last pose's equal (the last may carry the goal's, as NavFn's paths do)
    and the route leaves that heading — forward, or backward when it is not the identity's.
    """
    choice = RouteHeadings(settings.route_headings)
    if choice is not RouteHeadings.AUTO:
        return choice
    common = yaw[:-1] if len(yaw) > 2 else yaw
    if np.abs(_wrap(common - common[0])).max() > EQUAL_HEADINGS:
        return RouteHeadings.POSES  # headings of their own
    gears = (-1.0) ** np.arange(len(cusp_at) + 1)
    forward = tangent + np.where(gears[piece] < 0, np.pi, 0.0)
    along = np.abs(_wrap(forward - common[0])).max() <= TANGENT_TOLERANCE
    backward = abs(_wrap(common[0])) > EQUAL_HEADINGS and \
        np.abs(_wrap(forward + np.pi - common[0])).max() <= TANGENT_TOLERANCE
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


def _speed_profile(lengths: np.ndarray, curvature: np.ndarray, cusp_at: np.ndarray,
                   start_speed: float, settings: RouteSettings) -> np.ndarray:
    """Speeds [m/s] >= 0 at the points: the fastest within the limits, at rest at each stop."""
    with np.errstate(divide='ignore'):
        cap = np.minimum(settings.reference_speed,
                         np.sqrt(settings.max_lateral_accel / curvature))
    a = settings.max_accel
    arc = np.r_[0.0, np.cumsum(lengths)]
    # a robot faster than the limits slows down from its speed at max_accel, not at once
    cap = np.maximum(cap, np.sqrt(np.maximum(start_speed ** 2 - 2 * a * arc, 0.0)))
    cap[0] = max(start_speed, 0.0)
    cap[-1] = 0.0
    cap[cusp_at] = 0.0
    speed = cap.copy()
    for j in range(len(lengths)):
        speed[j + 1] = min(speed[j + 1], np.sqrt(speed[j] ** 2 + 2 * a * lengths[j]))
    for j in range(len(lengths) - 1, -1, -1):
        speed[j] = min(speed[j], np.sqrt(speed[j + 1] ** 2 + 2 * a * lengths[j]))
    return speed


def _durations(lengths: np.ndarray, speed: np.ndarray, max_accel: float) -> np.ndarray:
    """Each segment's time at constant acceleration between its end speeds."""
    mean = speed[:-1] + speed[1:]
    rest_to_rest = 2.0 * np.sqrt(lengths / max_accel)  # (a segment whose ends are both stops)
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.where(mean > 1e-9, 2.0 * lengths / np.where(mean > 1e-9, mean, 1.0),
                        rest_to_rest)
