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
start's shape (relative to the speed, so a slow path implies what a fast one does); where the
path hardly moves (at rest, or turning on the spot, where no steering makes it) nothing is
implied and the last value holds. The other hidden coordinates (a rolling angle, a rotor's)
are what the motion integrates.
"""
from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from nh_tracking.core.regularity import random_configurations
from nh_tracking.core.system import NonholonomicSystem

ITERATIONS = 12
PRIOR_WEIGHT = 1e-3  # z's pull toward the start's shape, times the squared pose rates
VELOCITY_WEIGHT = 1e-6  # fixes v along basis fields that move no pose axis (a steering rate)
AT_REST = 1e-4  # [m/s] slower than this, and than MOVING of the path's top speed, ...
MOVING = 0.1  # ... a sample implies no shape (spline ringing about a stop)


class ImpliedShape:
    """Solves a path's implied coordinates, for a system and the coordinates its pose shows."""

    def __init__(self, system: NonholonomicSystem, pose_rows: Sequence[int],
                 hidden: Sequence[int], translation: Sequence[int]) -> None:
        """Take ``translation``: which of the pose rows are a position's (rates: a speed)."""
        self.system = system
        self.indices = _implied(system, list(pose_rows), list(hidden))
        self.translation = list(translation)
        self._step = self._gauss_newton(list(pose_rows)) if self.indices else None

    def _gauss_newton(self, pose_rows: list[int]) -> ca.Function:
        """(q, z, v, z0, rates, w) -> (z, v) after a Gauss-Newton step; w weighs the prior."""
        system, m = self.system, len(self.indices)
        q, z0, w = ca.SX.sym('q', system.n), ca.SX.sym('z0', m), ca.SX.sym('w')
        rates, v = ca.SX.sym('rates', len(pose_rows)), ca.SX.sym('v', system.k)
        z = ca.SX.sym('z', m)
        full = ca.vertcat(*[z[self.indices.index(i)] if i in self.indices else q[i]
                            for i in range(system.n)])
        x = ca.vertcat(z, v)
        residual = ca.vertcat(system.rho_fn(full)[pose_rows, :] @ v - rates,
                              ca.sqrt(w) * (z - z0), np.sqrt(VELOCITY_WEIGHT) * v)
        jac = ca.jacobian(residual, x)
        step = -ca.solve(jac.T @ jac, jac.T @ residual)
        return ca.Function('implied_step', [q, z, v, z0, rates, w],
                           [z + step[:m], v + step[m:]])

    def solve(self, q: np.ndarray, v: np.ndarray, rates: np.ndarray) -> np.ndarray:
        """(N, m) implied coordinates along configurations q (N, n) from velocities v (N, k).

        ``rates`` (N, p) are the pose rows' rates; q's implied columns are the start's shape.
        """
        count = len(q)
        z0 = q[:, self.indices]
        if self._step is None or count == 0:
            return z0
        rates = np.asarray(rates, dtype=float)
        speed = np.linalg.norm(rates[:, self.translation], axis=1)
        moving = speed > max(AT_REST, MOVING * speed.max())
        weight = PRIOR_WEIGHT * np.maximum(np.sum(rates ** 2, axis=1), AT_REST ** 2)
        step = self._step.map(count)
        z, v = z0.T, np.asarray(v, dtype=float).T
        for _ in range(ITERATIONS):
            z_new, v_new = step(q.T, z, v, z0.T, rates.T, weight[None, :])
            z = self.system.domain.inside(np.array(z_new).T, self.indices).T
            v = np.array(v_new)
        return _held_at_rest(z.T, moving, z0)


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
