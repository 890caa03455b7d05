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

"""The shape a path of poses implies: a car's or a snakeboard's steering angle from its turning.

A hidden coordinate is *implied* when the pose rows of rho depend on it: only some of its values
let the robot move the way the path does (a car turns on the circle its steering sets). A
reference must carry those values; one holding the steering at its first value on a curve has
the planner fight its own plan. Each sample's implied coordinates z are found with its
velocities v by Gauss-Newton on rho_pose(q(z)) v = the pose rates, z drawn weakly toward the
start's shape; where the path is at rest nothing is implied and the last value holds. The other
hidden coordinates (a rolling angle, a rotor's) are what the motion integrates.
"""
from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from nh_tracking.regularity import random_configurations
from nh_tracking.system import NonholonomicSystem

ITERATIONS = 12
PRIOR_WEIGHT = 1e-3  # z's pull toward the start's shape, against rates of order 1
VELOCITY_WEIGHT = 1e-6  # fixes v along basis fields that move no pose axis (a steering rate)
AT_REST = 1e-6  # [pose units/s] below this no shape is implied
DOMAIN_MARGIN = 1e-3  # implied values stay this far inside the model's domain


class ImpliedShape:
    """Solves a path's implied coordinates, for a system and the coordinates its pose shows."""

    def __init__(self, system: NonholonomicSystem, pose_rows: Sequence[int],
                 hidden: Sequence[int]) -> None:
        self.system = system
        self.indices = _implied(system, list(pose_rows), list(hidden))
        self._step = self._gauss_newton(list(pose_rows)) if self.indices else None
        lo, hi = system.domain.lower[self.indices], system.domain.upper[self.indices]
        self._box = (lo + DOMAIN_MARGIN * np.minimum(1.0, hi - lo),
                     hi - DOMAIN_MARGIN * np.minimum(1.0, hi - lo))

    def _gauss_newton(self, pose_rows: list[int]) -> ca.Function:
        """(q, z0, rates) -> z after one Gauss-Newton step of the regularised least squares."""
        system, m = self.system, len(self.indices)
        q, z0 = ca.SX.sym('q', system.n), ca.SX.sym('z0', m)
        rates, v = ca.SX.sym('rates', len(pose_rows)), ca.SX.sym('v', system.k)
        z = ca.SX.sym('z', m)
        full = ca.vertcat(*[z[self.indices.index(i)] if i in self.indices else q[i]
                            for i in range(system.n)])
        x = ca.vertcat(z, v)
        residual = ca.vertcat(system.rho_fn(full)[pose_rows, :] @ v - rates,
                              np.sqrt(PRIOR_WEIGHT) * (z - z0), np.sqrt(VELOCITY_WEIGHT) * v)
        jac = ca.jacobian(residual, x)
        step = -ca.solve(jac.T @ jac, jac.T @ residual)
        return ca.Function('implied_step', [q, z, v, z0, rates], [z + step[:m], v + step[m:]])

    def solve(self, q: np.ndarray, v: np.ndarray, rates: np.ndarray) -> np.ndarray:
        """(N, m) implied coordinates along configurations q (N, n) from velocities v (N, k).

        ``rates`` (N, p) are the pose rows' rates; q's implied columns are the start's shape.
        """
        count = len(q)
        z0 = q[:, self.indices]
        if self._step is None or count == 0:
            return z0
        step = self._step.map(count)
        z, v = z0.T, np.asarray(v, dtype=float).T
        for _ in range(ITERATIONS):
            z_new, v_new = step(q.T, z, v, z0.T, np.asarray(rates, dtype=float).T)
            z = np.clip(np.array(z_new), self._box[0][:, None], self._box[1][:, None])
            v = np.array(v_new)
        return _held_at_rest(z.T, np.linalg.norm(rates, axis=1) > AT_REST, z0)


def _implied(system: NonholonomicSystem, pose_rows: list[int], hidden: list[int]) -> list[int]:
    """Hidden coordinates the pose rows of rho depend on, over sampled configurations."""
    if not hidden:
        return []
    q = ca.SX.sym('q', system.n)
    jac = ca.Function('d_rho_pose', [q], [ca.jacobian(
        ca.vec(system.rho_fn(q)[pose_rows, :]), q[hidden])])
    samples = random_configurations(system.coordinates, system.angles, system.domain,
                                    np.random.default_rng(1), 16)
    size = np.max([np.abs(np.array(jac(s))).max(axis=0) for s in samples], axis=0)
    return [h for h, s in zip(hidden, np.atleast_1d(size)) if s > 1e-9]


def _held_at_rest(z: np.ndarray, moving: np.ndarray, z0: np.ndarray) -> np.ndarray:
    """Z where the path moves; at rest the last moving value (before the first: the first).

    A path that never moves implies nothing: z0.
    """
    if not moving.any():
        return z0
    last = np.maximum.accumulate(np.where(moving, np.arange(len(z)), -1))
    first = int(np.argmax(moving))
    held = z[np.maximum(last, first)]
    return np.where((last >= 0)[:, None], held, z[first])
