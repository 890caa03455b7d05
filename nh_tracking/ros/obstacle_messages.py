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
(:mod:`nh_tracking.disc_tracks`); one stamped 0 is at rest. ``costmap``
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

from nh_tracking.disc_tracks import DiscTracks
from nh_tracking.ros import conversions as cv

LETHAL = 100  # Nav2's lethal cost, and map_server's occupied cells
DISCS = (Marker.CYLINDER, Marker.SPHERE)


class MarkerObstacles:
    """The set of discs a stream of MarkerArray messages describes, moving ones with velocity."""

    def __init__(self, frame: str) -> None:
        self.frame = frame
        self._tracks = DiscTracks()

    def sightings(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the discs (M, 5) where last seen, and when (ns; 0: seen without a stamp)."""
        seen = self._tracks.last_seen()
        stamps = np.where(np.isfinite(seen), np.round(seen * 1e9), 0).astype(np.int64)
        return self._tracks.discs(), stamps

    def discs(self, now_ns: int | None = None) -> np.ndarray:
        """Return where the discs will be at ``now_ns`` (None: last seen): x, y, r, vx, vy rows."""
        return self._tracks.discs(None if now_ns is None else now_ns * 1e-9)

    def apply(self, msg: MarkerArray) -> None:
        """Apply a message, or raise InputRejected (and keep the set) if any marker is bad."""
        tracks = self._tracks.copy()
        for marker in msg.markers:
            key = (marker.ns, marker.id)
            if marker.action == Marker.DELETEALL:
                tracks.forget()
            elif marker.action == Marker.DELETE:
                tracks.forget(key)
            elif marker.type in DISCS:
                cv.check_frame(marker.header.frame_id, self.frame, f'obstacle {key}')
                x, y = marker.pose.position.x, marker.pose.position.y
                radius = marker.scale.x / 2
                if not (np.all(np.abs([x, y, radius]) <= cv.MAX_POSITION) and radius >= 0):
                    raise cv.InputRejected(
                        f'obstacle {key} needs a finite position and a diameter scale.x >= 0, '
                        f'got ({x}, {y}), {marker.scale.x}')
                stamp = cv.stamp_ns(marker.header.stamp)
                tracks.seen(key, stamp * 1e-9 if stamp else None, x, y, radius)
        self._tracks = tracks


def occupied_cells(msg: OccupancyGrid, frame: str, threshold: int = LETHAL
                   ) -> tuple[np.ndarray, float]:
    """Centres (K, 2) of the cells at or above ``threshold`` in ``frame``, and the cell size."""
    cv.check_frame(msg.header.frame_id, frame, 'costmap')
    info = msg.info
    size, width, height = info.resolution, info.width, info.height
    if not (0 < size <= cv.MAX_POSITION / max(width, height, 1)) or \
            len(msg.data) != width * height:
        raise cv.InputRejected(f'costmap needs a resolution > 0 and width x height = len(data), '
                               f'got {size}, {width} x {height} != {len(msg.data)}')
    origin = cv.pose_array(info.origin, 'costmap origin')
    grid = np.asarray(msg.data, dtype=np.int16).reshape(height, width)
    rows, cols = np.nonzero(grid >= threshold)
    local = np.c_[(cols + 0.5) * size, (rows + 0.5) * size]
    c, s = np.cos(origin[3]), np.sin(origin[3])
    world = local @ np.array([[c, s], [-s, c]]) + origin[:2]
    return world, float(size)
