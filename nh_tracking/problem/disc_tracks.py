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

"""Discs seen again and again under one key: a velocity for each from its last positions.

An obstacle tracker (a person detector, another robot) republishes a disc under the same key as
it moves. Its velocity is the least-squares slope of its positions over the last
:data:`WINDOW` seconds (at most :data:`HISTORY` of them), no faster than :data:`MAX_SPEED`. A
position farther from the last than :data:`JUMP_SPEED` allows, a time earlier than the last (a
replayed log, a reset simulation) or another position at the same time starts the disc's
history again, at rest; a disc seen without a time is at rest. A disc is moved on from where
it was last seen by at most :data:`.limits.PREDICTION` seconds (:func:`.limits.moved`); plans
keep clear of where each disc will be (:mod:`nh_tracking.problem.limits`: discs (x, y, r, vx, vy)).
"""
from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass, field
import math

import numpy as np

from nh_tracking.problem.limits import moved

WINDOW = 1.0  # [s] positions older than this (before the last) do not count
HISTORY = 5  # positions a velocity is fitted to, at most
MAX_SPEED = 3.0  # [m/s] faster estimates are scaled down to this
JUMP_SPEED = 10.0  # [m/s] a disc that seems to move faster has jumped: a new history


@dataclass(frozen=True)
class DiscTrack:
    """One disc's radius and its last positions (x, y) at times t (seconds), oldest first."""

    radius: float
    times: tuple[float, ...]
    positions: tuple[tuple[float, float], ...]
    row: tuple[float, ...] = field(init=False, repr=False, compare=False)  # x, y, r, vx, vy

    def __post_init__(self) -> None:
        object.__setattr__(self, 'row', (*self.positions[-1], self.radius,
                                         *_slope(self.times, self.positions)))

    def seen(self, t: float, x: float, y: float, radius: float) -> DiscTrack:
        """Return the track with a new position; a new history where it jumped or t went back."""
        last_t, last = self.times[-1], self.positions[-1]
        if t == last_t and (x, y) == last:
            return self if radius == self.radius else DiscTrack(radius, self.times,
                                                                self.positions)
        if t <= last_t or math.hypot(x - last[0], y - last[1]) > JUMP_SPEED * (t - last_t):
            return DiscTrack(radius, (t,), ((x, y),))
        keep = [i for i, s in enumerate(self.times) if t - s <= WINDOW][-(HISTORY - 1):]
        return DiscTrack(radius, tuple(self.times[i] for i in keep) + (t,),
                         tuple(self.positions[i] for i in keep) + ((x, y),))


def _slope(times: tuple[float, ...], positions: tuple[tuple[float, float], ...]
           ) -> tuple[float, float]:
    """Return the least-squares slope of positions over times, at most MAX_SPEED (0 for one)."""
    count = len(times)
    if count < 2:
        return 0.0, 0.0
    t = [s - times[-1] for s in times]  # (relative: stamps are ~1e9 s)
    t_mean = sum(t) / count
    dt = [s - t_mean for s in t]
    xs, ys = zip(*positions)
    x_mean, y_mean = sum(xs) / count, sum(ys) / count
    scale = 1.0 / sum(d * d for d in dt)
    vx = sum(d * (x - x_mean) for d, x in zip(dt, xs)) * scale
    vy = sum(d * (y - y_mean) for d, y in zip(dt, ys)) * scale
    speed = math.hypot(vx, vy)
    shrink = MAX_SPEED / speed if speed > MAX_SPEED else 1.0
    return vx * shrink, vy * shrink


@dataclass(frozen=True)
class SeenWithout:
    """A disc seen without a time: where it was last put, at rest."""

    x: float
    y: float
    radius: float

    @property
    def row(self) -> tuple[float, ...]:
        return (self.x, self.y, self.radius, 0.0, 0.0)

    @property
    def times(self) -> tuple[float, ...]:
        return (-np.inf,)  # (seen at no time: at rest whenever it is asked of)


class DiscTracks:
    """The discs by key, each with its velocity; changed by :meth:`seen` and :meth:`forget`."""

    def __init__(self, tracks: dict[Hashable, DiscTrack | SeenWithout] | None = None) -> None:
        self._tracks = dict(tracks or {})
        self._rows: tuple[np.ndarray, np.ndarray] | None = None  # discs, last seen: made once

    def copy(self) -> DiscTracks:
        """Return an independent copy, for changes to be kept all or none."""
        return DiscTracks(self._tracks)

    def seen(self, key: Hashable, t: float | None, x: float, y: float, radius: float) -> None:
        """Record disc ``key`` at (x, y) with ``radius`` at time t (None: no time, at rest)."""
        track, self._rows = self._tracks.get(key), None
        if t is None:
            self._tracks[key] = SeenWithout(x, y, radius)
        elif isinstance(track, DiscTrack):
            self._tracks[key] = track.seen(t, x, y, radius)
        else:
            self._tracks[key] = DiscTrack(radius, (t,), ((x, y),))

    def forget(self, key: Hashable | None = None) -> None:
        """Forget disc ``key`` (every disc if None)."""
        self._rows = None
        if key is None:
            self._tracks.clear()
        else:
            self._tracks.pop(key, None)

    def discs(self, t: float | None = None) -> np.ndarray:
        """Return where the discs will be at t (None: last seen), as (M, 5) x, y, r, vx, vy.

        No more than :data:`.limits.PREDICTION` ahead of where each was last seen.
        """
        rows, seen = self._arrays()
        return rows.copy() if t is None else moved(rows, t - seen)

    def last_seen(self) -> np.ndarray:
        """Return when each disc of :meth:`discs` was last seen (-inf: seen without a time)."""
        return self._arrays()[1].copy()

    def _arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if self._rows is None:
            tracks = self._tracks.values()
            self._rows = (np.array([track.row for track in tracks], dtype=float).reshape(-1, 5),
                          np.array([track.times[-1] for track in tracks], dtype=float))
        return self._rows
