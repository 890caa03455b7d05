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

"""Occupied cells of a costmap as discs an NLP can keep clear of, and the gap to them.

A costmap (nav_msgs/OccupancyGrid) marks cells; the planner's obstacles are discs. Touching
cells become one disc, and large groups are cut on a grid fixed in the frame, so the discs do
not move with the robot.
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def costmap_discs(cells: np.ndarray, cell_size: float, size: float) -> np.ndarray:
    """Discs (x, y, r) covering occupied square cells of side ``cell_size``, from them alone.

    ``cells``: (K, 2) cell centres. Each group of touching cells (diagonals included) is one
    disc, the smallest about the group's mean holding its cells whole, when that disc's radius
    is at most ``size`` (plus half a cell's diagonal); a larger group is cut along a grid of
    side ``size`` fixed in the frame, a disc per piece. Never drawn about where the robot is:
    discs that moved with the robot would put a plan that hugs one inside the next, and the
    next solve would start from a plan that breaks a limit.
    """
    cells = np.asarray(cells, dtype=float).reshape(-1, 2)
    if not len(cells):
        return np.zeros((0, 3))
    pairs = cKDTree(cells).query_pairs(1.5 * cell_size, output_type='ndarray')
    links = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                       shape=(len(cells), len(cells)))
    _, group = connected_components(links, directed=False)
    half_diagonal = cell_size / np.sqrt(2.0)
    large = (_enclosing(cells, group, half_diagonal)[:, 2] > size + half_diagonal)[group]
    squares = np.floor(cells / size).astype(np.int64)  # (a grid fixed in the frame)
    squares = np.where(large[:, None], squares - squares.min(axis=0), 0)
    _, square = np.unique(squares[:, 0] * (squares[:, 1].max() + 1) + squares[:, 1],
                          return_inverse=True)  # (numbered 0..K-1: no product overflows)
    _, piece = np.unique(group * (square.max() + 1) + square.ravel(), return_inverse=True)
    return _enclosing(cells, piece.ravel(), half_diagonal)


def _enclosing(cells: np.ndarray, labels: np.ndarray, half_diagonal: float) -> np.ndarray:
    """Return for each label 0..L-1 the disc about its cells' mean that holds them whole."""
    count = np.bincount(labels)
    middle = np.c_[np.bincount(labels, cells[:, 0]), np.bincount(labels, cells[:, 1])] \
        / count[:, None]
    order = np.argsort(labels, kind='stable')
    reach = np.hypot(*(cells[order] - middle[labels[order]]).T)
    radius = np.maximum.reduceat(reach, np.r_[0, np.cumsum(count)[:-1]])
    return np.c_[middle, radius + half_diagonal]


class CellsByX:
    """Occupied square cells sorted by x once, for the gap to those near a point."""

    def __init__(self, cells: np.ndarray, cell_size: float) -> None:
        cells = np.asarray(cells, dtype=float).reshape(-1, 2)
        self.cells, self.cell_size = cells[np.argsort(cells[:, 0], kind='stable')], cell_size

    def near(self, point: np.ndarray, reach: float) -> np.ndarray:
        """Return the cells whose squares come within ``reach`` of ``point`` along x and y."""
        within = reach + self.cell_size / 2
        lo, hi = np.searchsorted(self.cells[:, 0], [point[0] - within, point[0] + within])
        band = self.cells[lo:hi]
        return band[np.abs(band[:, 1] - point[1]) <= within]


NO_CELLS_BY_X = CellsByX(np.zeros((0, 2)), 0.0)


def gap(point: np.ndarray, discs: np.ndarray, cells: np.ndarray, cell_size: float) -> float:
    """Distance from ``point`` (x, y) to the nearest disc edge or occupied square cell.

    Exact for both (0 inside a cell; inf if there are none): what a footprint touches.
    """
    point = np.asarray(point, dtype=float)[:2]
    to_discs = np.hypot(*(discs[:, :2] - point).T) - discs[:, 2]
    to_cells = np.hypot(*np.maximum(np.abs(cells - point) - cell_size / 2, 0.0).T)
    return float(min(np.min(to_discs, initial=np.inf), np.min(to_cells, initial=np.inf)))
