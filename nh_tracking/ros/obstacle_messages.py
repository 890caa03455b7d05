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

"""Obstacles as ROS sends them: RViz-style marker arrays and Nav2-style occupancy grids.

``obstacles`` (visualization_msgs/MarkerArray): CYLINDER and SPHERE markers are discs of radius
scale.x / 2 at their pose; ADD/MODIFY move the marker of the same (ns, id), DELETE removes
it, DELETEALL clears the set; other marker types (labels, arrows) are ignored. A marker seen
again at a later header stamp moves: its velocity is estimated from its last positions
(:mod:`nh_tracking.problem.disc_tracks`); one stamped 0 is at rest. ``costmap``
(nav_msgs/OccupancyGrid): cells at or above a threshold are occupied — by default Nav2's
lethal cost, 100, so the inflation a Nav2 costmap carries (99 inscribed, 1-98 inflated) is not
taken for obstacle and then inflated again by the robot's radius; -1 (unknown) is free. A
message with a wrong frame or non-finite or negative numbers is refused whole: the set in force
stays.
"""
from __future__ import annotations

from nav_msgs.msg import OccupancyGrid
import numpy as np
from visualization_msgs.msg import Marker, MarkerArray

from nh_tracking.problem.disc_tracks import DiscTracks
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.obstacle_bytes import Grid, Markers

LETHAL = 100  # Nav2's lethal cost, and map_server's occupied cells
DISCS = (Marker.CYLINDER, Marker.SPHERE)
REMOVALS = (Marker.DELETE, Marker.DELETEALL)


class MarkerObstacles:
    """The set of discs a stream of MarkerArray messages describes, moving ones with velocity."""

    def __init__(self, frame: str) -> None:
        self.frame = frame
        self._tracks = DiscTracks()

    def sightings(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the discs (M, 5) where last seen, and when (ns; 0: seen without a time)."""
        tracks = self._tracks  # (one set: a message applied meanwhile replaces it whole)
        seen = tracks.last_seen()
        stamps = np.where(np.isfinite(seen), np.round(seen * 1e9), 0).astype(np.int64)
        return tracks.discs(), stamps

    def discs(self, now_ns: int | None = None) -> np.ndarray:
        """Return where the discs will be at ``now_ns`` (None: last seen): x, y, r, vx, vy rows."""
        return self._tracks.discs(None if now_ns is None else now_ns * 1e-9)

    def apply(self, markers: Markers | MarkerArray) -> None:
        """Apply a message, or raise InputRejected (and keep the set) if any marker is bad."""
        if isinstance(markers, MarkerArray):
            markers = Markers.of(markers)
        disc = np.isin(markers.types, DISCS) & ~np.isin(markers.actions, REMOVALS)
        for i in np.flatnonzero(disc).tolist():  # (a message has one frame, as a rule)
            if markers.frames[i] != markers.frames[i - 1] or i == 0 or not disc[i - 1]:
                cv.check_frame(markers.frames[i], self.frame, f'obstacle {markers.keys[i]}')
        radii = markers.diameters / 2
        bad = disc & ~((np.abs(markers.xy) <= cv.MAX_POSITION).all(axis=1)
                       & (radii >= 0) & (radii <= cv.MAX_POSITION))
        if bad.any():
            first = int(np.argmax(bad))
            (x, y), diameter = markers.xy[first], markers.diameters[first]
            raise cv.InputRejected(
                f'obstacle {markers.keys[first]} needs a finite position and a diameter scale.x '
                f'>= 0, got ({x}, {y}), {diameter}')
        seconds = np.where(markers.stamps != 0, markers.stamps * 1e-9, np.nan).tolist()
        xs, ys = markers.xy.T.tolist()
        rs: list[float] = radii.tolist()
        tracks = self._tracks.copy()
        for i, (key, action) in enumerate(zip(markers.keys, markers.actions.tolist())):
            if action == Marker.DELETEALL:
                tracks.forget()
            elif action == Marker.DELETE:
                tracks.forget(key)
            elif disc[i]:
                t = seconds[i]
                tracks.seen(key, None if t != t else t, xs[i], ys[i], rs[i])
        self._tracks = tracks


def occupied_cells(grid: Grid | OccupancyGrid, frame: str, threshold: int = LETHAL
                   ) -> tuple[np.ndarray, float]:
    """Centres (K, 2) of the cells at or above ``threshold`` in ``frame``, and the cell size."""
    if isinstance(grid, OccupancyGrid):
        grid = Grid.of(grid)
    cv.check_frame(grid.frame, frame, 'costmap')
    size, width, height = grid.resolution, grid.width, grid.height
    if not (0 < size <= cv.MAX_POSITION / max(width, height, 1)) or \
            len(grid.data) != width * height:
        raise cv.InputRejected(f'costmap needs a resolution > 0 and width x height = len(data), '
                               f'got {size}, {width} x {height} != {len(grid.data)}')
    origin = cv.pose_values(grid.origin, 'costmap origin')
    rows, cols = np.nonzero(grid.data.reshape(height, width) >= threshold)
    x, y = (cols + 0.5) * size, (rows + 0.5) * size
    c, s = np.cos(origin[3]), np.sin(origin[3])
    # (elementwise: a matrix product of this size wakes BLAS threads that spin a second core)
    world = np.c_[origin[0] + c * x - s * y, origin[1] + s * x + c * y]
    return world, float(size)
