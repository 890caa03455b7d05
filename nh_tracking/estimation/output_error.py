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

"""A robot's physical parameters from its own motion: output-error least squares.

From configurations q measured at times t and the controls u held on each interval, find the
parameters and the states (q, v) at every sample that satisfy the derived dynamics (the
midpoint rule between samples) and come closest to the measurements. Velocities are never
measured: they are unknowns. Outliers are found twice — against the median of each sample's
neighbours before the fit, against the fit's residuals after it — and left out; each coordinate
is weighted by the noise its residuals show. The parameters' covariance is the inverse of the
fit's information about them (the Gauss-Newton one, marginalised over the initial state): the
data *excite* the parameters when it pins every direction of them down to ``EXCITED`` relative
standard deviation, and only then are new values returned.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike
import scipy.sparse
import scipy.sparse.linalg

from nh_tracking import models
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.models.spec import ModelSpec

EXCITED = 0.05  # largest relative standard deviation, in any direction, of estimates returned
PRIOR = 1.0  # the pull toward the starting values: a prior standard deviation of 100 %
OUTLIER = 6.0  # residuals beyond this many robust standard deviations are outliers
NEIGHBOURS = 2  # on each side, for the median an outlier is first found against
RESOLUTION = 1e-4  # no odometry is finer than this: smaller residuals are not noise
PASSES = 3  # fits at most: each after the outliers or the noise they show changed
MOVE = 10.0  # one estimate moves a positive parameter by at most this factor from its start
HOPELESS = 4.0  # times EXCITED, before any fit: no fit is tried
CONVERGED = ('Solve_Succeeded', 'Solved_To_Acceptable_Level',
             'Search_Direction_Becomes_Too_Small')  # IPOPT's: at the noise floor, no further


@dataclass(frozen=True)
class ParameterEstimate:
    """Estimated physical parameters.

    ``values`` and ``std`` by name (std: one standard deviation; inf when the data say nothing
    about it); ``excited``: the data tell every parameter apart to within ``EXCITED`` relative
    standard deviation — otherwise ``values`` are the starting ones. ``noise`` is each
    coordinate's residual scale (empty without a fit), ``outliers`` how many samples were left
    out.
    """

    values: dict[str, float]
    std: dict[str, float]
    excited: bool
    noise: dict[str, float]
    outliers: int
    message: str


def estimate_parameters(
    model: str | ModelSpec,
    t: ArrayLike,
    q: ArrayLike,
    u: ArrayLike,
    names: Sequence[str],
    *,
    fixed: Mapping[str, float] | None = None,
    start: Mapping[str, float] | None = None,
) -> ParameterEstimate:
    """Estimate the physical parameters ``names`` of ``model`` from a log of its motion.

    ``t`` (T,) strictly increasing times; ``q`` (T, n) configurations (angles wrapped or not);
    ``u`` (T - 1, r) the controls held on each interval. The parameters not named are at
    ``fixed`` or the model's defaults; the fit starts from ``start`` (default: the same), is
    kept inside the model's ranges and within a factor ``MOVE`` of ``start``, and pulled weakly
    toward ``start``. Bad input is a ValueError.
    """
    spec = models.spec(model) if isinstance(model, str) else model
    if not isinstance(spec, ModelSpec):
        raise ValueError(f'model must be a model name or a ModelSpec, got {type(model).__name__}')
    fixed = dict(fixed or {})
    overlap = set(fixed) & set(names)
    if overlap:
        raise ValueError(f'parameters {sorted(overlap)} are both estimated and fixed')
    system = spec.parametrised(names, **{**fixed, **dict(start or {})})
    times, measured, controls = _checked_log(system, t, q, u)
    fit = _Fit(spec, system, times, controls)
    outliers, noise = _against_neighbours(measured)
    x = _first_guess(system, times, measured)
    delta = np.zeros(len(system.family.names))
    covariance = fit.covariance(x, delta, ~outliers, noise)
    if _worst(covariance) > HOPELESS * EXCITED:  # no fit can pin them down: spare the work
        return _estimate(system, fit.scale, delta, covariance, noise, int(outliers.sum()))
    for _ in range(PASSES):
        try:
            x, delta = fit.solve(measured, ~outliers, noise, x, delta)
        except _NotFitted as failure:
            return _unfitted(system, f'the fit did not converge ({failure}): starting values '
                             'kept; is u what this model takes as controls?')
        residual = measured - x[:system.n].T
        kept = ~outliers
        new_noise = _robust_scale(residual[kept])
        new_outliers = outliers | np.any(
            (np.abs(residual) > OUTLIER * new_noise) & (np.abs(residual) > RESOLUTION), axis=1)
        settled = np.array_equal(new_outliers, outliers) and np.all(
            np.abs(np.log(new_noise / noise)) < math.log(2.0))
        outliers, noise = new_outliers, new_noise
        if settled:
            break
    covariance = fit.covariance(x, delta, ~outliers, noise)
    return _estimate(system, fit.scale, delta, covariance, noise, int(outliers.sum()))


def _checked_log(system: NonholonomicSystem, t: ArrayLike, q: ArrayLike,
                 u: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    times = np.asarray(t, dtype=float).reshape(-1)
    count = len(times)
    if count < 3 or not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise ValueError('t must be finite and strictly increasing, with at least 3 times')
    measured = np.array(q, dtype=float)
    if measured.shape != (count, system.n) or not np.all(np.isfinite(measured)):
        raise ValueError(f'q must be a finite ({count}, {system.n}) array of '
                         f'{system.coordinates}, got shape {np.shape(q)}')
    controls = np.asarray(u, dtype=float)
    if controls.shape != (count - 1, system.r) or not np.all(np.isfinite(controls)):
        raise ValueError(f'u must be a finite ({count - 1}, {system.r}) array (the controls '
                         f'held on each interval), got shape {np.shape(u)}')
    measured[:, system.angle_mask] = np.unwrap(measured[:, system.angle_mask], axis=0)
    return times, measured, controls


def _against_neighbours(measured: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flag samples far from the median of their neighbours, far beyond the typical step.

    Also return each coordinate's noise as those deviations show it, to weight the first fit.
    """
    count = len(measured)
    window = [measured[max(0, i - NEIGHBOURS):i + NEIGHBOURS + 1] for i in range(count)]
    deviation = np.abs(measured - np.array([np.median(w, axis=0) for w in window]))
    noise = _robust_scale(deviation)
    typical = np.maximum(noise, np.median(np.abs(np.diff(measured, axis=0)), axis=0))
    return np.any(deviation > 10 * typical, axis=1), noise


def _robust_scale(deviations: np.ndarray) -> np.ndarray:
    """Return each column's standard deviation as its median absolute deviation shows it."""
    return np.maximum(RESOLUTION, 1.4826 * np.median(np.abs(deviations), axis=0))


def _first_guess(system: NonholonomicSystem, times: np.ndarray,
                 measured: np.ndarray) -> np.ndarray:
    """(n + k, T) states: the measured q, and v from central differences projected on D."""
    rates = np.gradient(measured, times, axis=0)
    v = system.family.velocity.map(len(times))(measured.T, rates.T, system.family_values)
    return np.vstack([measured.T, np.array(v)])


class _Fit:
    """The least-squares problem for one log's times and controls.

    Every sample's state is an unknown; consecutive ones are joined by the midpoint rule of the
    dynamics (second order).
    """

    def __init__(self, spec: ModelSpec, system: NonholonomicSystem, times: np.ndarray,
                 controls: np.ndarray) -> None:
        self.system = system
        count, nx, size = len(times), system.n + system.k, len(system.family.names)
        # delta = (value - start) / scale; a zero start is scaled by its default's size
        defaults = spec.defaults
        self.scale = np.array([abs(v) if v else max(abs(defaults[n]), 1.0)
                               for n, v in zip(system.family.names, system.family_values)])
        x0, x1, u = ca.SX.sym('x0', nx), ca.SX.sym('x1', nx), ca.SX.sym('u', system.r)
        delta, h = ca.SX.sym('delta', size), ca.SX.sym('h')
        values = system.family_values + self.scale * delta
        defect = ca.Function('defect', [x0, x1, u, delta, h], [
            x1 - x0 - h * system.family.ode((x0 + x1) / 2, u, values)])
        states = ca.MX.sym('X', nx, count)
        d = ca.MX.sym('d', size)
        weights = ca.MX.sym('w', system.n, count)  # 1 / noise, 0 for an outlier
        target = ca.MX.sym('q', system.n, count)
        dynamics = ca.vec(defect.map(count - 1)(
            states[:, :-1], states[:, 1:], controls.T, ca.repmat(d, 1, count - 1),
            np.diff(times)[None, :]))
        misfit = (states[:system.n, :] - target) * weights
        cost = (0.5 * ca.sumsqr(misfit) + 0.5 * PRIOR * ca.sumsqr(d)) / count
        bounds = {p.name: p.bounds for p in spec.parameters}
        move = [_move(v) for v in system.family_values]  # within a factor MOVE, the sign kept
        low = [max((bounds[n][0] - system.parameters[n]) / s, m[0])
               for n, s, m in zip(system.family.names, self.scale, move)]
        high = [min((bounds[n][1] - system.parameters[n]) / s, m[1])
                for n, s, m in zip(system.family.names, self.scale, move)]
        self.size, self.nx, self.count = size, nx, count
        self.bounds = (np.r_[np.full(nx * count, -np.inf), low],
                       np.r_[np.full(nx * count, np.inf), high])
        unknowns = ca.vertcat(ca.vec(states), d)
        self.solver = ca.nlpsol('estimate', 'ipopt', {
            'x': unknowns, 'p': ca.vertcat(ca.vec(weights), ca.vec(target)), 'f': cost,
            'g': dynamics}, {'print_time': False, 'ipopt.print_level': 0, 'ipopt.sb': 'yes',
                             'ipopt.max_iter': 200})
        self.linearised = ca.Function('linearised', [unknowns], [
            ca.jacobian(dynamics, ca.vec(states)), ca.jacobian(dynamics, d)])

    def solve(self, measured: np.ndarray, kept: np.ndarray, noise: np.ndarray, x: np.ndarray,
              delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        weights = (kept[:, None] / noise[None, :]).T
        result = self.solver(
            x0=np.r_[x.ravel(order='F'), delta], p=np.r_[weights.ravel(order='F'),
                                                         measured.T.ravel(order='F')],
            lbx=self.bounds[0], ubx=self.bounds[1], lbg=0, ubg=0)
        z = np.array(result['x']).ravel()
        stats = self.solver.stats()
        if not np.all(np.isfinite(z)) or stats['return_status'] not in CONVERGED:
            raise _NotFitted(stats['return_status'])
        states = z[:self.nx * self.count].reshape(self.nx, self.count, order='F')
        return states, z[self.nx * self.count:]

    def covariance(self, x: np.ndarray, delta: np.ndarray, kept: np.ndarray,
                   noise: np.ndarray) -> np.ndarray:
        """Delta's covariance: the inverse of its information, marginalised over the start.

        The free unknowns are the first state and delta; the dynamics fix the rest, so the
        sensitivity of every state to them solves the linearised dynamics (block bidiagonal).
        """
        by_state, by_delta = self.linearised(np.r_[x.ravel(order='F'), delta])
        by_state = scipy.sparse.csc_matrix(by_state.sparse())
        nx = self.nx
        later = -scipy.sparse.linalg.splu(by_state[:, nx:]).solve(np.hstack([
            by_state[:, :nx].toarray(), np.array(by_delta)]))
        sensitivity = np.vstack([np.hstack([np.eye(nx), np.zeros((nx, self.size))]), later])
        rows = (np.arange(self.count)[:, None] * nx + np.arange(self.system.n)[None, :]).ravel()
        weights = (kept[:, None] / noise[None, :]).ravel()
        weighted = sensitivity[rows] * weights[:, None]
        information = weighted.T @ weighted
        about_state, cross = information[:nx, :nx], information[:nx, nx:]
        marginal = information[nx:, nx:] - cross.T @ np.linalg.pinv(about_state) @ cross
        eigen = np.linalg.eigvalsh(marginal)
        if eigen[-1] <= 0 or eigen[0] <= 1e-12 * eigen[-1]:
            return np.full((self.size, self.size), np.inf)
        return np.linalg.inv(marginal)


def _move(start: float) -> tuple[float, float]:
    """Return the bounds of delta that keep a value within a factor MOVE of ``start``."""
    if start > 0:
        return -(1 - 1 / MOVE), MOVE - 1
    if start < 0:
        return -(MOVE - 1), 1 - 1 / MOVE
    return -MOVE, MOVE  # in units of the default's size


def _estimate(system: NonholonomicSystem, scale: np.ndarray, delta: np.ndarray,
              covariance: np.ndarray, noise: np.ndarray, outliers: int) -> ParameterEstimate:
    std = np.sqrt(np.abs(np.diag(covariance))) * scale
    relative = std / scale
    excited = bool(_worst(covariance) <= EXCITED)
    values = system.family_values + scale * delta if excited else system.family_values
    loose = [f'{n} (±{r:.0%})' if r < 10 else f'{n} (nothing)'
             for n, r in zip(system.family.names, relative) if not r <= EXCITED]
    message = 'excited' if excited else (
        'not excited: the data pin down ' + ', '.join(loose or system.family.names)
        + f' (together) to no better than {EXCITED:.0%}; starting values kept')
    return ParameterEstimate(
        values={n: float(v) for n, v in zip(system.family.names, values)},
        std={n: float(s) for n, s in zip(system.family.names, std)}, excited=excited,
        noise={c: float(s) for c, s in zip(system.coordinates, noise)}, outliers=outliers,
        message=message)


def _worst(covariance: np.ndarray) -> float:
    """Return the standard deviation along the least known direction of delta."""
    if not np.all(np.isfinite(covariance)):
        return math.inf
    return math.sqrt(max(np.linalg.eigvalsh(covariance)[-1], 0.0))


def _unfitted(system: NonholonomicSystem, message: str) -> ParameterEstimate:
    return ParameterEstimate(
        values={n: float(v) for n, v in zip(system.family.names, system.family_values)},
        std={n: math.inf for n in system.family.names}, excited=False,
        noise={}, outliers=0, message=message)


class _NotFitted(Exception):
    """IPOPT stopped without a fit; the argument is its status."""
