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
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp

from nh_tracking.core.regularity import describe
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.core.trajectory import Trajectory

ControlLaw = Callable[[float, np.ndarray, np.ndarray], ArrayLike]
MAX_EVALUATIONS = 500_000  # of the dynamics per simulation: past a singularity steps shrink


class _Exhausted(Exception):
    pass


class LeftDomain(RuntimeError):
    """The state reached the edge of the model's domain (a steering angle at its stop)."""


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
    max_evaluations: int = MAX_EVALUATIONS,
) -> Trajectory:
    """Integrate from (q0, v0), reporting at the times ``t``.

    ``u`` is None (free motion), an (len(t) - 1, r) array held constant on each interval
    (zero-order hold: each interval is integrated separately, so the control's jumps are not
    smoothed over), or a feedback law ``u(t, q, v)``. Tolerances are tight by default because
    simulations serve as the ground truth that plans and solvers are checked against. The work
    is bounded (``max_evaluations`` of the dynamics) and the state must stay in the model's
    domain: otherwise a RuntimeError says at which time the simulation stopped and why.
    """
    times = np.asarray(t, dtype=float).reshape(-1)
    if len(times) < 2 or np.any(np.diff(times) <= 0) or not np.all(np.isfinite(times)):
        raise ValueError('t must be finite, strictly increasing, with at least two times')
    x0 = np.concatenate([system.check_configuration(q0, 'q0'), system.as_velocity(v0)])
    if not np.all(np.isfinite(x0)):
        raise ValueError('initial state must be finite')
    n, r = system.n, system.r
    reached = [times[0]]
    budget = [int(max_evaluations)]
    events = _domain_events(system)

    def rhs(control: Callable[[float, np.ndarray], np.ndarray]):
        def f(s: float, x: np.ndarray) -> np.ndarray:
            budget[0] -= 1
            if budget[0] < 0:
                raise _Exhausted()
            reached[0] = s
            return np.asarray(system.ode_fn(x, control(s, x))).ravel()
        return f

    def integrate(span: np.ndarray, x: np.ndarray, control) -> np.ndarray:
        try:
            sol = solve_ivp(rhs(control), (span[0], span[-1]), x, method=method, t_eval=span,
                            rtol=rtol, atol=atol, events=events)
        except _Exhausted:
            raise RuntimeError(f'integration stopped at t = {reached[0]:.6g}: '
                               f'{max_evaluations} evaluations of the dynamics used up (a '
                               'singularity ahead, or very stiff dynamics)') from None
        if sol.status == 1:
            t_out = sol.t_events[0][0] if len(sol.t_events[0]) else sol.t[-1]
            state = sol.y_events[0][0] if len(sol.y_events[0]) else sol.y[:, -1]
            where = describe(system.coordinates, state[:n])
            raise LeftDomain(f'integration stopped at t = {t_out:.6g}: the state left the '
                             f"model's domain ({where})")
        if not sol.success or not np.all(np.isfinite(sol.y)):
            raise RuntimeError(f'integration failed at t = {reached[0]:.6g}: {sol.message}')
        return sol.y.T

    if u is None or callable(u):
        law = u
        control = (lambda s, x: np.zeros(r)) if law is None else (
            lambda s, x: _control(law(s, x[:n], x[n:]), r))
        states = integrate(times, x0, control)
        controls = np.array([control(s, x) for s, x in zip(times[:-1], states[:-1])])
    else:
        controls = np.asarray(u, dtype=float)
        if controls.shape != (len(times) - 1, r) or not np.all(np.isfinite(controls)):
            raise ValueError(f'u must be a finite ({len(times) - 1}, {r}) array')
        knots = [x0]
        for i, ui in enumerate(controls):
            knots.append(integrate(times[i:i + 2], knots[-1], lambda s, x, ui=ui: ui)[-1])
        states = np.array(knots)
    return Trajectory(t=times, q=states[:, :n], v=states[:, n:], u=controls)


def held_rk4(system: NonholonomicSystem, x: Any, u: Any, h: Any, substeps: int) -> Any:
    """Return the state after ``h`` with ``u`` held: ``substeps`` fixed RK4 steps.

    Symbolic (SX: one expression, for what replays or rolls out held controls many times) or
    numeric on numpy columns, one interval each (x (n + k, N), u (r, N), h (1, N)): evaluated
    without building a CasADi function (which would wait on CasADi while it builds an NLP).
    """
    numeric = isinstance(x, np.ndarray)

    def ode(x: Any, u: Any) -> Any:
        rate = system.ode_fn(x, u)
        return np.asarray(rate) if numeric else rate

    return rk4(ode, x, u, h, substeps)


def rk4(ode: Callable[[Any, Any], Any], x: Any, u: Any, h: Any, substeps: int) -> Any:
    """Return the state after ``h`` of xdot = ode(x, u) with ``u`` held: fixed RK4 steps."""
    dt = h / substeps
    for _ in range(substeps):
        k1 = ode(x, u)
        k2 = ode(x + dt / 2 * k1, u)
        k3 = ode(x + dt / 2 * k2, u)
        k4 = ode(x + dt * k3, u)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def drive(system: NonholonomicSystem, q0: ArrayLike, v: ArrayLike, duration: float, *,
          rtol: float = 1e-9, atol: float = 1e-11) -> np.ndarray:
    """Move for ``duration`` at the constant quasi-velocities ``v``; return the configuration.

    Kinematics only, qdot = rho(q) v: a velocity-controlled robot, whose drives hold the
    commanded velocities whatever its actuation.
    """
    q0 = system.check_configuration(q0, 'q0')
    v = system.as_velocity(v)
    if duration <= 0:
        return q0
    sol = solve_ivp(lambda s, q: np.asarray(system.rho_fn(q)) @ v, (0.0, duration), q0,
                    method='DOP853', rtol=rtol, atol=atol)
    if not sol.success or not np.all(np.isfinite(sol.y)):
        raise RuntimeError(f'kinematic integration failed: {sol.message}')
    return sol.y[:, -1]


def _domain_events(system: NonholonomicSystem) -> list[Callable[[float, np.ndarray], float]]:
    """Stop the integration (a terminal event) where the state reaches the domain's edge."""
    box = system.domain
    bounded = np.isfinite(box.lower) | np.isfinite(box.upper)
    if not bounded.any():
        return []
    lower, upper = box.lower[bounded], box.upper[bounded]
    index = np.flatnonzero(bounded)

    def edge(s: float, x: np.ndarray) -> float:
        q = x[index]
        return float(min(np.min(q - lower), np.min(upper - q)))

    edge.terminal = True  # type: ignore[attr-defined]  # solve_ivp's event flag
    return [edge]


def _control(value: ArrayLike, r: int) -> np.ndarray:
    u = np.asarray(value, dtype=float).reshape(-1)
    if u.size != r or not np.all(np.isfinite(u)):
        raise ValueError(f'control law must return {r} finite values, got {value!r}')
    return u
