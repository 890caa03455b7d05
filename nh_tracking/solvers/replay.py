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

"""Controls held on each interval that replay a plan on the continuous dynamics.

A plan whose control varies within an interval (PMP's continuous optimal control) drifts when
its samples are held piecewise constant: on an unstable flow the O(h^2) per-interval errors
grow along the horizon. Here each interval's held control is fitted (Gauss–Newton on an RK4
step with sensitivities) so the dynamics carry the *replayed* state to the plan's next knot —
errors are corrected interval by interval instead of accumulating.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from nh_tracking.core.numeric import NumericFunction
from nh_tracking.core.simulate import held_rk4
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.solvers.cache import PerSystemCache

SUBSTEPS = 8  # RK4 steps per interval: their error is far below the fit's
ITERATIONS = 4
REPLAY_RTOL = 0.1  # a plan whose replay strays further (relative to its size) is an artefact
CHECK_SUBSTEPS = 2  # RK4 steps per interval in interval_gap: O(h^5) against the plans' O(h^3)

_CACHE: PerSystemCache[NumericFunction] = PerSystemCache()
_ENDS: PerSystemCache[NumericFunction] = PerSystemCache()  # by N: apart from _step's cache


def _step(system: NonholonomicSystem) -> NumericFunction:
    """(x, u, h) -> (x after h with u held, d x_end / d u, d x_end / d x)."""
    def build() -> NumericFunction:
        x = ca.SX.sym('x', system.n + system.k)
        u, h = ca.SX.sym('u', system.r), ca.SX.sym('h')
        end = held_rk4(system, x, u, h, SUBSTEPS)
        return NumericFunction(ca.Function('held_step', [x, u, h],
                                           [end, ca.jacobian(end, u), ca.jacobian(end, x)]))
    return _CACHE.get(system, 'step', build)


def _interval_ends(system: NonholonomicSystem, intervals: int) -> NumericFunction | None:
    """(x (n + k, N), u (r, N), h (1, N)) -> each interval's end, u held; None until built."""
    def build() -> NumericFunction:
        x = ca.SX.sym('x', system.n + system.k)
        u, h = ca.SX.sym('u', system.r), ca.SX.sym('h')
        end = ca.Function('held_end', [x, u, h], [held_rk4(system, x, u, h, CHECK_SUBSTEPS)])
        return NumericFunction(end.map(intervals))
    return _ENDS.ready(system, intervals, build)


def interval_gap(system: NonholonomicSystem, t: np.ndarray, q: np.ndarray, v: np.ndarray,
                 u: np.ndarray) -> float:
    """Largest gap between a plan's knots and each interval replayed from the knot before it.

    Relative to the plan's size (inf if the replay is not finite). A plan past
    :data:`REPLAY_RTOL` does not describe the continuous dynamics: its steps are too long for
    them (a horizon of days in 50 steps), whatever its solver reported.
    """
    knots, held = np.hstack([q, v]), np.reshape(u, (len(t) - 1, -1))
    ends = _interval_ends(system, len(t) - 1)  # (its first calls: slower, numerically)
    with np.errstate(all='ignore'):
        if ends is None:
            end = held_rk4(system, knots[:-1].T, held.T, np.diff(t)[None, :],
                           CHECK_SUBSTEPS).T
        else:  # (rows of an (N, m) array in C order are the columns of CasADi's (m, N))
            flat = ends(knots[:-1], held, np.diff(t))[0]
            end = flat.reshape(knots.shape[1], -1, order='F').T
        gap = float(np.abs(end - knots[1:]).max() / (1.0 + np.abs(knots).max()))
    return gap if np.isfinite(gap) else float('inf')


def held_controls(system: NonholonomicSystem, t: np.ndarray, q: np.ndarray, v: np.ndarray,
                  u: np.ndarray, bounds: np.ndarray | None = None) -> np.ndarray:
    """Fit controls (N, r), one held per interval of ``t``, replaying the knots (q, v), from u.

    Receding fit: at each interval the next few controls (enough to reach every state
    coordinate) are fitted to the next few knots from the replayed state, and the first is
    kept — so an error in the configuration, which the controls reach only through the
    velocities, is worked off over the following intervals instead of accumulating. The
    controls stay within ``bounds`` ((2, r) lo; hi).
    """
    step = _step(system)
    knots = np.hstack([q, v])
    fitted = np.array(u, dtype=float)
    r, big_n = system.r, len(t) - 1
    window = -(-knots.shape[1] // r) + 1  # ceil((n + k) / r) + 1 intervals ahead
    x = knots[0].copy()
    for i in range(big_n):
        span = range(i, min(i + window, big_n))
        for _ in range(ITERATIONS):
            gaps, jac = _window(step, x, fitted, t, knots, span)
            if not (np.all(np.isfinite(gaps)) and np.all(np.isfinite(jac))):
                break
            delta = np.linalg.lstsq(jac, gaps, rcond=None)[0].reshape(len(span), r)
            fitted[i:i + len(span)] += delta
            if bounds is not None:
                fitted[i:i + len(span)] = np.clip(fitted[i:i + len(span)], *bounds)
            if np.abs(delta).max() <= 1e-12 * (1 + np.abs(fitted[i]).max()):
                break
        x = step(x, fitted[i], t[i + 1] - t[i])[0]
    return fitted


def _window(step: NumericFunction, x: np.ndarray, u: np.ndarray, t: np.ndarray,
            knots: np.ndarray, span: range) -> tuple[np.ndarray, np.ndarray]:
    """Gaps to the knots after each interval of ``span`` from x, and their Jacobian in u."""
    dim, r = len(x), u.shape[1]
    gaps = np.zeros(len(span) * dim)
    jac = np.zeros((len(span) * dim, len(span) * r))
    sens = np.zeros((dim, 0))  # d x / d (controls so far)
    for j, i in enumerate(span):
        end, d_u, d_x = step(x, u[i], t[i + 1] - t[i])
        # (a single control's Jacobian comes back as a vector)
        sens = np.hstack([np.reshape(d_x, (dim, dim)) @ sens, np.reshape(d_u, (dim, r))])
        gaps[j * dim:(j + 1) * dim] = knots[i + 1] - end
        jac[j * dim:(j + 1) * dim, :sens.shape[1]] = sens
        x = end
    return gaps, jac
