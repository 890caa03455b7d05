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

from collections.abc import Callable
import threading
from typing import Generic, NamedTuple, TypeVar

from nav_msgs.msg import OccupancyGrid
import numpy as np
from rclpy.node import Node
from visualization_msgs.msg import MarkerArray

from nh_tracking.navigation.costmap import costmap_discs
from nh_tracking.planning.command_guard import NO_CELLS, OccupiedCells
from nh_tracking.problem.limits import nearest_discs, obstacle_discs
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.guarded import guarded, ProblemLog
from nh_tracking.ros.obstacle_bytes import read_grid, read_markers, Unreadable
from nh_tracking.ros.obstacle_messages import MarkerObstacles, occupied_cells
from nh_tracking.ros.obstacle_receiver import ObstacleReceiver

DISC_SIZE = 0.5  # [m] the largest costmap disc; wider groups of cells are cut in pieces
C = TypeVar('C')  # what a costmap's occupied cells are made into


class CostmapDiscs(NamedTuple):
    """A costmap's occupied cells as discs for the plans, and indexed for the command guard."""

    discs: np.ndarray  # (M, 5), drawn once per costmap, at rest
    cells: OccupiedCells

    @classmethod
    def of(cls, cells: np.ndarray, size: float) -> CostmapDiscs:
        """Return the cells (N, 2) of side ``size`` as discs and indexed."""
        return cls(obstacle_discs(costmap_discs(cells, size, DISC_SIZE)),
                   OccupiedCells(cells, size))

    def near(self, centre: np.ndarray, reach: float, count: int) -> np.ndarray:
        """Return up to ``count`` discs (M, 5) covering the costmap within reach of centre."""
        return nearest_discs(self.discs, centre, count, reach)


NO_COSTMAP = CostmapDiscs(np.zeros((0, 5)), NO_CELLS)


class ObstacleListener(Generic[C]):
    """Takes both topics from construction until :meth:`close`; bad input leaves the set in force.

    :attr:`markers` are the discs of the markers in force; :attr:`costmap` is what
    ``reduce(cells, size)`` made of the newest costmap's occupied cells (``empty`` before one).
    What a reading thread makes is committed under a lock, and only until :meth:`close`: a
    cleanup never sees an old message land. ``on_change(self)`` follows each commit, under
    that lock.
    """

    def __init__(self, node: Node, problems: ProblemLog, frame: str, threshold: int,
                 reduce: Callable[[np.ndarray, float], C], empty: C,
                 on_change: Callable[[ObstacleListener[C]], None] | None = None) -> None:
        self.problems = problems
        self._frame, self._threshold = frame, threshold
        self._reduce, self._on_change = reduce, on_change
        self._commit = threading.Lock()
        self.markers = MarkerObstacles(frame)
        self.costmap: C = empty
        with self._commit:  # (a message read before the receiver is known waits for it)
            self.receiver: ObstacleReceiver | None = ObstacleReceiver(node, {
                'obstacles': (MarkerArray, self.on_obstacles),
                'costmap': (OccupancyGrid, self.on_costmap)})

    def close(self) -> None:
        """Stop taking both topics; what is in force stays readable."""
        with self._commit:
            receiver, self.receiver = self.receiver, None
        if receiver is not None:
            receiver.close()

    @guarded('obstacles')
    def on_obstacles(self, msg: MarkerArray | bytes, receiver: ObstacleReceiver) -> None:
        try:
            markers = read_markers(msg)
        except Unreadable as exc:
            raise cv.InputRejected(str(exc)) from None
        with self._commit:
            if receiver is self.receiver:
                self.markers.apply(markers)
                self._changed()

    @guarded('costmap')
    def on_costmap(self, msg: OccupancyGrid | bytes, receiver: ObstacleReceiver) -> None:
        try:
            grid = read_grid(msg)
        except Unreadable as exc:
            raise cv.InputRejected(str(exc)) from None
        cells, size = occupied_cells(grid, self._frame, self._threshold)
        reduced = self._reduce(cells, size)
        with self._commit:
            if receiver is self.receiver:
                self.costmap = reduced
                self._changed()

    def _changed(self) -> None:
        if self._on_change is not None:
            self._on_change(self)
