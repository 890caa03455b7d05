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

"""A problem's limits as NLP rows: bounds given per solve, obstacles as parameters.

An NLP is built for a *shape* of limits — which kinds are bounded, how many obstacle slots
each clearance point has — so replanning with new bound values or moving obstacles only changes
numbers. Each knot and midpoint has slots of its own, filled with the discs nearest it on the
guess (parameters of the solve): all of them while they fit, the nearest
:data:`.obstacles.POINT_SLOTS` of more, so past that many obstacles the NLP's size does not grow
with them (every disc in every point's rows would make every replan costlier, in contact or
not); how many, which, and what a plan that meets another calls for is :mod:`.obstacles`'s
policy. The plan is then checked against every disc, and re-solved where it touches one it was
not given. Clearance is written squared, |p - c|^2 - R^2 >= 0, which is smooth.

Soft form, for a start that itself breaks a limit (inside an obstacle, faster than a bound):
each row gets a slack s >= 0 (lo - s <= g <= hi + s) and the cost an exact L1 penalty
W sum(s) — the least-violating plan instead of an infeasible NLP.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from nh_tracking.core.regularity import Domain
from nh_tracking.problem.limits import Limits, plan_times, VIOLATION_TOL
from nh_tracking.problem.tracking_problem import LimitCheck, TrackingProblem
from nh_tracking.solvers.obstacles import limit_check, nearest_per_point, obstacle_slots

SOFT_WEIGHT = 1e4  # per unit of violation: above the multipliers of any sane tracking cost
DOMAIN_MARGIN = 1e-3  # a bounded plan stays this fraction of its interval inside the domain


@dataclass(frozen=True)
class Shape:
    """What an NLP's limit rows are built for."""

    controls: bool = False
    velocities: bool = False
    slots: int = 0
    soft: bool = False
    domain: bool = False  # the model's domain bounds the configurations

    @classmethod
    def of(cls, limits: Limits, soft: bool = False, every: bool = False,
           domain: bool = False) -> Shape:
        """Return the shape of ``limits``' NLP; a soft one has every disc at every point."""
        return cls(limits.bounded_controls, limits.bounded_velocities,
                   obstacle_slots(len(limits.obstacles), every or soft), soft, domain)


class ConstraintStack:
    """An NLP's constraint blocks in order, and the rows they fill: where the next one starts.

    Limits record the rows they occupy: summing the blocks' heights at each use would be
    quadratic in the horizon (the builder's hottest loop, holding the interpreter from the
    executor).
    """

    def __init__(self) -> None:
        self.blocks: list[ca.SX] = []
        self.rows = 0

    def add(self, *blocks: ca.SX) -> None:
        self.blocks.extend(blocks)
        self.rows += sum(b.shape[0] for b in blocks)


@dataclass
class Rows:
    """Inequality rows of an NLP under construction, in the order they enter g."""

    shape: Shape
    plane: tuple[int, int] | None
    points: int  # clearance points: an interval's midpoint and end knot each
    bounded: tuple[int, ...] = ()  # the coordinates the domain bounds (if the shape says so)
    obstacles: ca.SX = field(init=False)  # parameters: (x, y, R, on) per point and slot
    kinds: list[tuple[int, int, str]] = field(default_factory=list)  # (first row, size, kind)
    at: list[ca.SX] = field(default_factory=list)  # the clearance points' configurations
    _index: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)
    _point: int = field(default=0, repr=False)  # the next clearance point's parameters

    def __post_init__(self) -> None:
        self.obstacles = ca.SX.sym('obstacles', 4 * self.shape.slots * self.points)

    def control(self, u: ca.SX, start: int) -> list[ca.SX]:
        return self._add(u, start, 'u') if self.shape.controls else []

    def velocity(self, v: ca.SX, start: int) -> list[ca.SX]:
        return self._add(v, start, 'v') if self.shape.velocities else []

    def configuration(self, q: ca.SX, start: int) -> list[ca.SX]:
        """Return the bounded coordinates of a knot or midpoint, if the shape bounds the domain."""
        if not self.shape.domain or not self.bounded:
            return []
        return self._add(ca.vertcat(*[q[i] for i in self.bounded]), start, 'q')

    def clearance(self, q: ca.SX, start: int) -> list[ca.SX]:
        if not self.shape.slots or self.plane is None:
            return []
        p = ca.vertcat(q[self.plane[0]], q[self.plane[1]])
        rows = []
        first = 4 * self.shape.slots * self._point
        self._point += 1
        self.at.append(q)
        for j in range(first, first + 4 * self.shape.slots, 4):
            c, radius, on = self.obstacles[j:j + 2], self.obstacles[j + 2], self.obstacles[j + 3]
            # an unused slot is the constant 1 >= 0: strictly feasible (an identically
            # zero row would pin an interior-point slack to its bound)
            rows.append(on * (ca.sumsqr(p - c) - radius**2) + (1 - on))
        return self._add(ca.vertcat(*rows), start, 'clear')

    def _add(self, expr: ca.SX, start: int, kind: str) -> list[ca.SX]:
        self.kinds.append((start, expr.shape[0], kind))
        return [expr]

    def assigned_discs(self, p: np.ndarray) -> np.ndarray:
        """Return the discs each clearance point has in parameters ``p`` (they come last).

        (points, 4 slots): the parameters of the point's rows.
        """
        size = 4 * self.shape.slots * self.points
        return p[len(p) - size:].reshape(self.points, 4 * self.shape.slots)

    def check_all_points_built(self) -> None:
        """Check that the NLP took every clearance point's parameters (none left, none more)."""
        if self.shape.slots and self.plane is not None and self._point != self.points:
            raise RuntimeError(f'{self._point} clearance points built for {self.points}')

    def parameters(self, limits: Limits, points: np.ndarray, h: float) -> np.ndarray:
        """Return each clearance point's discs: the nearest its configuration on the guess.

        ``points``: (points, n) the guess's configurations at the clearance rows, in g's order
        (half an interval ``h`` apart from the first midpoint: where moving discs are then).
        (points, slots, 4): x, y, R and 1 per disc, in the order of ``limits``' discs (a disc
        keeps its slot while it stays among the point's nearest: its multiplier is carried);
        0 (off) where there are fewer discs than slots. All of them at every point while they
        fit.
        """
        values = np.zeros((self.points, self.shape.slots, 4))
        discs, slots = limits.obstacles, self.shape.slots
        if not slots or self.plane is None or not len(discs):
            return values.ravel()
        centres = np.broadcast_to(limits.centres(plan_times(self.points // 2, h)[1:]),
                                  (self.points, len(discs), 2))
        if len(discs) <= slots:
            values[:, :len(discs), :2], values[:, :len(discs), 2] = centres, discs[:, 2]
            values[:, :len(discs), 3] = 1.0
            return values.ravel()
        nearest = nearest_per_point(points[:, list(self.plane)], centres, discs[:, 2], slots)
        values[:, :, :2] = np.take_along_axis(centres, nearest[..., None], axis=1)
        values[:, :, 2], values[:, :, 3] = discs[nearest, 2], 1.0
        return values.ravel()

    def bounds(self, rows: int, limits: Limits,
               domain: Domain | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of all ``rows`` of g: 0 for equalities, the limits else.

        The domain's rows (if any) are held :data:`DOMAIN_MARGIN` inside its open box.
        """
        lower, upper = np.zeros(rows), np.zeros(rows)
        pairs = [('u', limits.controls), ('v', limits.velocities)]
        if self.bounded and domain is not None:
            pairs.append(('q', np.array(domain.interior(self.bounded, DOMAIN_MARGIN))))
        for kind, pair in pairs:
            index, channel = self._rows(kind)
            lower[index], upper[index] = pair[0][channel], pair[1][channel]
        upper[self._rows('clear')[0]] = np.inf
        return lower, upper

    def inequality_mask(self, rows: int, kinds: tuple[str, ...] = ('u', 'v', 'clear', 'q')
                        ) -> np.ndarray:
        """Which of ``rows`` rows of g are limits of these kinds."""
        mask = np.zeros(rows, dtype=bool)
        for kind in kinds:
            mask[self._rows(kind)[0]] = True
        return mask

    def _rows(self, kind: str) -> tuple[np.ndarray, np.ndarray]:
        """Return the rows of g of one kind and their channels (or slots): read every solve."""
        if kind not in self._index:
            blocks = [(start, size) for start, size, k in self.kinds if k == kind]
            self._index[kind] = (
                np.array([start + j for start, size in blocks for j in range(size)], dtype=int),
                np.array([j for _, size in blocks for j in range(size)], dtype=int))
        return self._index[kind]


def soften(nlp: dict[str, ca.SX], rows: Rows) -> tuple[dict[str, ca.SX], np.ndarray]:
    """Return the NLP with slacks on every inequality row, and the rows' order for bounds.

    Each inequality g_j (lo_j <= g_j <= hi_j) becomes g_j + s_j >= lo_j and g_j - s_j <= hi_j
    with s_j >= 0 (the slacks are appended to x; g_j's row keeps its place as g_j + s_j and
    the g_j - s_j rows are appended at the end, in the same order).
    """
    g = nlp['g']
    mask = rows.inequality_mask(g.shape[0])
    index = np.flatnonzero(mask)
    slack = ca.SX.sym('slack', len(index))
    plus = ca.SX(g)
    for j, i in enumerate(index):
        plus[int(i)] = g[int(i)] + slack[j]
    minus = ca.vertcat(*[g[int(i)] - slack[j] for j, i in enumerate(index)])
    soft = {'x': ca.vertcat(nlp['x'], slack), 'p': nlp['p'],
            'f': nlp['f'] + SOFT_WEIGHT * ca.sum1(slack), 'g': ca.vertcat(plus, minus)}
    return soft, index


def soft_bounds(lower: np.ndarray, upper: np.ndarray,
                index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of a softened NLP's g from the hard ones (see :func:`soften`)."""
    lo, hi = lower.copy(), upper.copy()
    hi[index] = np.inf  # g + s >= lo
    return np.concatenate([lo, np.full(len(index), -np.inf)]), np.concatenate([hi, upper[index]])


def start_violation(problem: TrackingProblem) -> float:
    """How much the start itself breaks a limit: then only a soft NLP has a solution."""
    return problem.limits.violation(problem.q0[None], problem.v0[None], t=[0.0])


def assess_limits(rows: Rows, limits: Limits, soft: bool, converged: bool, path: np.ndarray,
                  v: np.ndarray, u: np.ndarray | None, h: float,
                  message: str) -> tuple[bool, str, float, LimitCheck]:
    """Return whether a plan succeeded within its limits, why not, its violation and check.

    ``path``: its configurations at the start and the clearance points, in time order (knots
    ``h`` apart: :func:`.limits.plan_path`). What the plan calls for is
    :func:`.obstacles.limit_check`'s. The violation: the most any limit is broken, at the
    points or between them.
    """
    t = plan_times(len(path) // 2, h)
    at_points, swept = limits.violation(path, v, u, t), limits.swept(path, t)
    violation = max(at_points, swept)
    success = converged and violation <= VIOLATION_TOL
    if soft and not success:
        message = f'{message}; least-violating plan: {_broken(limits, path, v, u, t)}'
    elif converged and swept > max(at_points, VIOLATION_TOL):
        message = (f'{message}; but the plan passes through a disc between its knots and '
                   f'midpoints (by {swept:.3g} m: they are too far apart for its speed; more '
                   'steps or velocity bounds)')
    return success, message, violation, limit_check(
        soft, converged, at_points, swept, len(limits.obstacles) > rows.shape.slots,
        VIOLATION_TOL)


def _broken(limits: Limits, path: np.ndarray, v: np.ndarray, u: np.ndarray | None,
            t: np.ndarray) -> str:
    """Say by how much the start, which no plan can change, and the rest break the limits."""
    start = limits.violation(path[:1], v[:1], t=t[:1])
    rest = max(limits.violation(path[1:], v[1:], u, t[1:]), limits.swept(path[1:], t[1:]))
    if start <= VIOLATION_TOL:
        return f'limits broken by {rest:.3g}'
    after = (f'the plan after it by {rest:.3g}' if rest > VIOLATION_TOL
             else 'the plan after it keeps them')
    return f'the start breaks a limit by {start:.3g}, {after}'
