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
keep clear of where each disc will be (:mod:`nh_tracking.limits`: discs (x, y, r, vx, vy)).
"""
from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

import numpy as np

from nh_tracking.limits import moved

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

    def seen(self, t: float, x: float, y: float, radius: float) -> DiscTrack:
        """Return the track with a new position; a new history where it jumped or t went back."""
        last_t, last = self.times[-1], self.positions[-1]
        if t == last_t and (x, y) == last:
            return DiscTrack(radius, self.times, self.positions)
        if t <= last_t or np.hypot(x - last[0], y - last[1]) > JUMP_SPEED * (t - last_t):
            return DiscTrack(radius, (t,), ((x, y),))
        keep = [i for i, s in enumerate(self.times) if t - s <= WINDOW][-(HISTORY - 1):]
        return DiscTrack(radius, tuple(self.times[i] for i in keep) + (t,),
                         tuple(self.positions[i] for i in keep) + ((x, y),))

    @property
    def velocity(self) -> np.ndarray:
        """The least-squares slope of the positions over time, at most MAX_SPEED (m/s)."""
        if len(self.times) < 2:
            return np.zeros(2)
        t = np.asarray(self.times) - self.times[-1]
        p = np.asarray(self.positions)
        dt = t - t.mean()
        slope = dt @ (p - p.mean(axis=0)) / (dt @ dt)
        speed = float(np.hypot(*slope))
        return slope * (MAX_SPEED / speed) if speed > MAX_SPEED else slope

    def disc(self, t: float | None) -> np.ndarray:
        """Return (x, y, r, vx, vy): where the disc will be at t (its last position if None).

        No more than :data:`.limits.PREDICTION` ahead of its last position.
        """
        seen = np.r_[self.positions[-1], self.radius, self.velocity]
        return moved(seen[None], 0.0 if t is None else t - self.times[-1])[0]


@dataclass(frozen=True)
class SeenWithout:
    """A disc seen without a time: where it was last put, at rest."""

    x: float
    y: float
    radius: float

    def disc(self, t: float | None) -> np.ndarray:
        return np.array([self.x, self.y, self.radius, 0.0, 0.0])

    @property
    def times(self) -> tuple[float, ...]:
        return (-np.inf,)  # (seen at no time: at rest whenever it is asked of)


class DiscTracks:
    """The discs by key, each with its velocity; changed by :meth:`seen` and :meth:`forget`."""

    def __init__(self, tracks: dict[Hashable, DiscTrack | SeenWithout] | None = None) -> None:
        self._tracks = dict(tracks or {})

    def copy(self) -> DiscTracks:
        """Return an independent copy, for changes to be kept all or none."""
        return DiscTracks(self._tracks)

    def seen(self, key: Hashable, t: float | None, x: float, y: float, radius: float) -> None:
        """Record disc ``key`` at (x, y) with ``radius`` at time t (None: no time, at rest)."""
        track = self._tracks.get(key)
        if t is None:
            self._tracks[key] = SeenWithout(x, y, radius)
        elif isinstance(track, DiscTrack):
            self._tracks[key] = track.seen(t, x, y, radius)
        else:
            self._tracks[key] = DiscTrack(radius, (t,), ((x, y),))

    def forget(self, key: Hashable | None = None) -> None:
        """Forget disc ``key`` (every disc if None)."""
        if key is None:
            self._tracks.clear()
        else:
            self._tracks.pop(key, None)

    def discs(self, t: float | None = None) -> np.ndarray:
        """Return where the discs will be at t (None: last seen), as (M, 5) x, y, r, vx, vy."""
        return np.array([track.disc(t) for track in self._tracks.values()]).reshape(-1, 5)

    def last_seen(self) -> np.ndarray:
        """Return when each disc of :meth:`discs` was last seen (-inf: seen without a time)."""
        return np.array([track.times[-1] for track in self._tracks.values()], dtype=float)
