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

"""The ``obstacles`` and ``costmap`` topics of a node: what it must keep clear of.

Read and reduced on threads of their own, newest message first (:mod:`obstacle_receiver`).
"""
from __future__ import annotations

from nav_msgs.msg import OccupancyGrid
import numpy as np
from visualization_msgs.msg import MarkerArray

from nh_tracking.command_guard import NO_CELLS, OccupiedCells
from nh_tracking.costmap import costmap_discs
from nh_tracking.limits import nearest_discs, obstacle_discs
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.guarded import guarded, GuardedNode
from nh_tracking.ros.obstacle_bytes import (grid_from_bytes, markers_from_bytes, Unreadable)
from nh_tracking.ros.obstacle_messages import MarkerObstacles, occupied_cells
from nh_tracking.ros.obstacle_receiver import ObstacleReceiver

DISC_SIZE = 0.5  # [m] the largest costmap disc; wider groups of cells are cut in pieces


class ObstacleListener(GuardedNode):
    """Subscribes to both topics; bad messages are rejected and the set in force stays."""

    frame: str
    costmap_threshold: int
    obstacle_receiver: ObstacleReceiver | None = None

    def listen_for_obstacles(self) -> None:
        """Start taking both topics (until :meth:`stop_listening_for_obstacles`)."""
        self.marker_obstacles = MarkerObstacles(self.frame)
        self.costmap: tuple[np.ndarray, float] = (np.zeros((0, 2)), 0.0)
        self._costmap_discs = np.zeros((0, 5))  # drawn once per costmap, at rest
        self.costmap_cells = NO_CELLS  # the same cells, indexed for the command guard
        self.obstacle_receiver = ObstacleReceiver(self, {
            'obstacles': (MarkerArray, self.on_obstacles),
            'costmap': (OccupancyGrid, self.on_costmap)})

    def stop_listening_for_obstacles(self) -> None:
        if self.obstacle_receiver is not None:
            self.obstacle_receiver.close()
            self.obstacle_receiver = None

    def input_problems(self) -> list[str]:
        """Return what the inputs lag or drop now (none: an empty list)."""
        return [] if self.obstacle_receiver is None else self.obstacle_receiver.problems()

    @guarded('obstacles')
    def on_obstacles(self, msg: MarkerArray | bytes) -> None:
        try:
            markers = markers_from_bytes(msg) if isinstance(msg, bytes) else msg
        except Unreadable as exc:
            raise cv.InputRejected(str(exc)) from None
        self.marker_obstacles.apply(markers)
        self.obstacles_changed()

    @guarded('costmap')
    def on_costmap(self, msg: OccupancyGrid | bytes) -> None:
        try:
            grid = grid_from_bytes(msg) if isinstance(msg, bytes) else msg
        except Unreadable as exc:
            raise cv.InputRejected(str(exc)) from None
        cells, size = occupied_cells(grid, self.frame, self.costmap_threshold)
        self.reduce_costmap(cells, size)
        self.costmap = (cells, size)
        self.obstacles_changed()

    def reduce_costmap(self, cells: np.ndarray, size: float) -> None:
        """Cover the cells with discs for the plans, and index them for the command guard."""
        self._costmap_discs = obstacle_discs(costmap_discs(cells, size, DISC_SIZE))
        self.costmap_cells = OccupiedCells(cells, size)

    def obstacle_discs(self, centre: np.ndarray, reach: float, count: int
                       ) -> tuple[np.ndarray, np.ndarray]:
        """Return the marker discs and up to ``count`` discs covering the costmap near centre.

        (M, 5) x, y, r, vx, vy where each was seen, and when (ns; 0 for the costmap's, at
        rest, and for markers without a stamp).
        """
        markers, stamps = self.marker_obstacles.sightings()
        costmap = nearest_discs(self._costmap_discs, centre, count, reach)
        return (np.vstack([markers, costmap]),
                np.concatenate([stamps, np.zeros(len(costmap), dtype=np.int64)]))

    def obstacles_changed(self) -> None:
        """React to a new obstacle set (the node's own business)."""
