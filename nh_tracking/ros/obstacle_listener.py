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

"""The ``obstacles`` and ``costmap`` topics of a node: what it must keep clear of."""
from __future__ import annotations

from nav_msgs.msg import OccupancyGrid
import numpy as np
from visualization_msgs.msg import MarkerArray

from nh_tracking.command_guard import NO_CELLS, OccupiedCells
from nh_tracking.costmap import costmap_discs
from nh_tracking.limits import nearest_discs, obstacle_discs
from nh_tracking.ros.guarded import guarded, GuardedNode
from nh_tracking.ros.obstacle_messages import MarkerObstacles, occupied_cells
from nh_tracking.ros.planner_interface import subscribe_latched

DISC_SIZE = 0.5  # [m] the largest costmap disc; wider groups of cells are cut in pieces


class ObstacleListener(GuardedNode):
    """Subscribes to both topics; bad messages are rejected and the set in force stays."""

    frame: str
    costmap_threshold: int

    def listen_for_obstacles(self) -> list:
        """Create the subscriptions (returned, for the node to release)."""
        self.marker_obstacles = MarkerObstacles(self.frame)
        self.costmap: tuple[np.ndarray, float] = (np.zeros((0, 2)), 0.0)
        self._costmap_discs = np.zeros((0, 5))  # drawn once per costmap, at rest
        self.costmap_cells = NO_CELLS  # the same cells, indexed for the command guard
        return (subscribe_latched(self, MarkerArray, 'obstacles', self.on_obstacles)
                + subscribe_latched(self, OccupancyGrid, 'costmap', self.on_costmap))

    @guarded('obstacles')
    def on_obstacles(self, msg: MarkerArray) -> None:
        self.marker_obstacles.apply(msg)
        self.obstacles_changed()

    @guarded('costmap')
    def on_costmap(self, msg: OccupancyGrid) -> None:
        cells, size = occupied_cells(msg, self.frame, self.costmap_threshold)
        self.costmap = (cells, size)
        self._costmap_discs = obstacle_discs(costmap_discs(cells, size, DISC_SIZE))
        self.costmap_cells = OccupiedCells(cells, size)
        self.obstacles_changed()

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
