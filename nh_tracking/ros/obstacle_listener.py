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

import threading

from nav_msgs.msg import OccupancyGrid
import numpy as np
from visualization_msgs.msg import MarkerArray

from nh_tracking.navigation.costmap import costmap_discs
from nh_tracking.planning.command_guard import NO_CELLS, OccupiedCells
from nh_tracking.problem.limits import nearest_discs, obstacle_discs
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.guarded import guarded, GuardedNode
from nh_tracking.ros.obstacle_bytes import read_grid, read_markers, Unreadable
from nh_tracking.ros.obstacle_messages import MarkerObstacles, occupied_cells
from nh_tracking.ros.obstacle_receiver import ObstacleReceiver

DISC_SIZE = 0.5  # [m] the largest costmap disc; wider groups of cells are cut in pieces


class ObstacleListener(GuardedNode):
    """Subscribes to both topics; bad messages are rejected and the set in force stays.

    What a reading thread makes is committed under a lock, and only while the listening that
    received it goes on: a cleanup (or a new configure) never sees an old message land.
    """

    frame: str
    costmap_threshold: int
    obstacle_receiver: ObstacleReceiver | None = None

    def listen_for_obstacles(self) -> None:
        """Start taking both topics (until :meth:`stop_listening_for_obstacles`)."""
        self._commit = threading.Lock()
        self.marker_obstacles = MarkerObstacles(self.frame)
        self._costmap_discs = np.zeros((0, 5))  # drawn once per costmap, at rest
        self.costmap_cells = NO_CELLS  # the same cells, indexed for the command guard
        self.obstacle_receiver = ObstacleReceiver(self, {
            'obstacles': (MarkerArray, self.on_obstacles),
            'costmap': (OccupancyGrid, self.on_costmap)})

    def stop_listening_for_obstacles(self) -> None:
        if self.obstacle_receiver is None:
            return
        with self._commit:
            receiver, self.obstacle_receiver = self.obstacle_receiver, None
        if receiver is not None:
            receiver.close()

    @guarded('obstacles')
    def on_obstacles(self, msg: MarkerArray | bytes, receiver: ObstacleReceiver) -> None:
        try:
            markers = read_markers(msg)
        except Unreadable as exc:
            raise cv.InputRejected(str(exc)) from None
        with self._commit:
            if receiver is self.obstacle_receiver:
                self.marker_obstacles.apply(markers)
                self.obstacles_changed()

    @guarded('costmap')
    def on_costmap(self, msg: OccupancyGrid | bytes, receiver: ObstacleReceiver) -> None:
        try:
            grid = read_grid(msg)
        except Unreadable as exc:
            raise cv.InputRejected(str(exc)) from None
        cells, size = occupied_cells(grid, self.frame, self.costmap_threshold)
        reduced = self.reduce_costmap(cells, size)
        with self._commit:
            if receiver is self.obstacle_receiver:
                self.costmap_reduced(reduced)
                self.obstacles_changed()

    def reduce_costmap(self, cells: np.ndarray, size: float) -> tuple:
        """Return the cells as discs for the plans, and indexed for the command guard."""
        return obstacle_discs(costmap_discs(cells, size, DISC_SIZE)), OccupiedCells(cells, size)

    def costmap_reduced(self, reduced: tuple) -> None:
        """Put what :meth:`reduce_costmap` made in force."""
        self._costmap_discs, self.costmap_cells = reduced

    def costmap_discs_near(self, centre: np.ndarray, reach: float, count: int) -> np.ndarray:
        """Return up to ``count`` discs (M, 5) covering the costmap within reach of centre."""
        return nearest_discs(self._costmap_discs, centre, count, reach)

    def obstacles_changed(self) -> None:
        """React to a new obstacle set (the node's own business)."""
