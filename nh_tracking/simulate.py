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

"""Integrate the controlled nonholonomic dynamics: the 'real' system that plans are judged on."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp

from nh_tracking.system import NonholonomicSystem
from nh_tracking.trajectory import Trajectory

ControlLaw = Callable[[float, np.ndarray, np.ndarray], ArrayLike]


def simulate(
    system: NonholonomicSystem,
    q0: ArrayLike,
    v0: ArrayLike,
    t: ArrayLike,
    u: np.ndarray | ControlLaw | None = None,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    method: str = 'DOP853',
) -> Trajectory:
    """Integrate from (q0, v0), reporting at the times ``t``.

    ``u`` is None (free motion), an (len(t) - 1, k) array held constant on each interval
    (zero-order hold: each interval is integrated separately, so the control's jumps are not
    smoothed over), or a feedback law ``u(t, q, v)``. Tolerances are tight by default because
    simulations serve as the ground truth that plans and solvers are checked against.
    """
    times = np.asarray(t, dtype=float).reshape(-1)
    if len(times) < 2 or np.any(np.diff(times) <= 0) or not np.all(np.isfinite(times)):
        raise ValueError('t must be finite, strictly increasing, with at least two times')
    x0 = np.concatenate([system.as_configuration(q0), system.as_velocity(v0)])
    if not np.all(np.isfinite(x0)):
        raise ValueError('initial state must be finite')
    n, k = system.n, system.k

    def rhs(control: Callable[[float, np.ndarray], np.ndarray]):
        return lambda s, x: np.asarray(system.ode_fn(x, control(s, x))).ravel()

    def integrate(span: np.ndarray, x: np.ndarray, control) -> np.ndarray:
        sol = solve_ivp(rhs(control), (span[0], span[-1]), x, method=method, t_eval=span,
                        rtol=rtol, atol=atol)
        if not sol.success or not np.all(np.isfinite(sol.y)):
            raise RuntimeError(f'integration failed at t = {sol.t[-1]:.6g}: {sol.message}')
        return sol.y.T

    if u is None or callable(u):
        law = u
        control = (lambda s, x: np.zeros(k)) if law is None else (
            lambda s, x: _control(law(s, x[:n], x[n:]), k))
        states = integrate(times, x0, control)
        controls = np.array([control(s, x) for s, x in zip(times[:-1], states[:-1])])
    else:
        controls = np.asarray(u, dtype=float)
        if controls.shape != (len(times) - 1, k) or not np.all(np.isfinite(controls)):
            raise ValueError(f'u must be a finite ({len(times) - 1}, {k}) array')
        knots = [x0]
        for i, ui in enumerate(controls):
            knots.append(integrate(times[i:i + 2], knots[-1], lambda s, x, ui=ui: ui)[-1])
        states = np.array(knots)
    return Trajectory(t=times, q=states[:, :n], v=states[:, n:], u=controls)


def _control(value: ArrayLike, k: int) -> np.ndarray:
    u = np.asarray(value, dtype=float).reshape(-1)
    if u.size != k or not np.all(np.isfinite(u)):
        raise ValueError(f'control law must return {k} finite values, got {value!r}')
    return u
