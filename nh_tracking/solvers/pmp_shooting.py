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

"""Guarded integration of the Pontryagin flow, and the shooting problems built on it.

Every integration is bounded (state size, right-hand-side evaluations, a deadline), so an
unstable flow ends in :class:`Diverged` or :class:`OutOfTime` instead of a hang; roots are
found with exact Jacobians from the flow's sensitivity equations.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import time

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import root

from nh_tracking.problem.tracking_problem import Solution, TrackingProblem
from nh_tracking.solvers.hamiltonian import pontryagin_flow

BLOW_UP = 1e6  # |state, costate| beyond this ends an integration as diverged
MAX_RHS_EVALS = 40_000  # per integration: bounded work, so a stiff blow-up cannot hang
DEADLINE_EVERY = 64  # right-hand sides between deadline checks (a few milliseconds)
RESIDUAL_TOL = 1e-7


class Diverged(Exception):
    pass


class OutOfTime(Exception):
    pass


@dataclass
class Arc:
    """One integrated piece of the flow: end state, its sensitivity, running cost, samples."""

    z_end: np.ndarray
    sensitivity: np.ndarray
    cost: float
    t: np.ndarray
    z: np.ndarray
    dense: Callable[[float], np.ndarray]  # the continuous solution of solve_ivp


class Shooter:
    """Integrates the flow over pieces of the horizon, guarded against blow-up and hangs."""

    def __init__(self, problem: TrackingProblem, deadline: float, rtol: float = 1e-10,
                 atol: float = 1e-10) -> None:
        self.problem = problem
        self.flow = pontryagin_flow(problem.system)
        self.rhs = self.flow.rhs
        self.deadline = deadline
        self.rtol, self.atol = rtol, atol
        self.n, self.k = problem.system.n, problem.system.k
        self.dim = self.flow.dim
        n, k = self.n, self.k
        # d(terminal residual)/d z(T): constant for both terminal kinds.
        jac = np.zeros((n + k, self.dim))
        if problem.terminal == 'cost':
            jac[:n, :n] = -problem.omega * np.eye(n)
            jac[:, n + k:] = np.eye(n + k)
        else:
            jac[:, :n + k] = np.eye(n + k)
        self.terminal_jacobian = jac

    def integrate(self, z0: np.ndarray, t_span: tuple[float, float],
                  t_eval: np.ndarray | None = None) -> Arc:
        if time.perf_counter() > self.deadline:
            raise OutOfTime()
        count = [0]
        eps, dim = self.problem.epsilon, self.dim
        bounds = self.problem.limits.controls

        def rhs(t: float, y: np.ndarray) -> np.ndarray:
            count[0] += 1
            if count[0] > MAX_RHS_EVALS:
                raise Diverged()
            if count[0] % DEADLINE_EVERY == 0 and time.perf_counter() > self.deadline:
                raise OutOfTime()  # one stiff integration can take seconds
            q_r, v_r = self.problem.reference_point(t)
            zdot, cost_rate, jac = self.rhs(y[:dim], q_r, v_r, eps, *bounds)
            phi_dot = jac @ y[dim + 1:].reshape(dim, dim)
            return np.concatenate([zdot, cost_rate, phi_dot.ravel()])

        def blow_up(t: float, y: np.ndarray) -> float:
            return BLOW_UP - np.abs(y[:dim]).max()

        blow_up.terminal = True  # type: ignore[attr-defined]  # solve_ivp's event flag
        y0 = np.concatenate([z0, [0.0], np.eye(dim).ravel()])
        try:
            sol = solve_ivp(rhs, t_span, y0, method='DOP853', rtol=self.rtol, atol=self.atol,
                            events=blow_up, t_eval=t_eval, dense_output=t_eval is not None)
        except (Diverged, FloatingPointError):
            raise Diverged() from None
        if sol.status != 0 or not np.all(np.isfinite(sol.y)):
            raise Diverged()
        end = sol.y[:, -1]
        return Arc(z_end=end[:dim], sensitivity=end[dim + 1:].reshape(dim, dim),
                   cost=float(end[dim]), t=sol.t, z=sol.y[:dim].T, dense=sol.sol)

    def control(self, z: np.ndarray) -> np.ndarray:
        """Return the optimal control u*(z), saturated at the problem's control bounds."""
        lo, hi = self.problem.limits.controls
        return np.asarray(self.flow.control(z[:self.dim], self.problem.epsilon, lo, hi)).ravel()

    def terminal_residual(self, z_end: np.ndarray) -> np.ndarray:
        n, k, prob = self.n, self.k, self.problem
        q_ref, v_ref = prob.reference_samples[0][-1], prob.reference_samples[1][-1]
        if prob.terminal == 'cost':  # transversality, docs/theory.md C5
            return np.concatenate([z_end[n + k:2 * n + k] - prob.omega * (z_end[:n] - q_ref),
                                   z_end[2 * n + k:]])
        return np.concatenate([z_end[:n] - q_ref, z_end[n:n + k] - v_ref])


def _solve_root(fun, w0: np.ndarray) -> tuple[np.ndarray, bool]:
    """Newton-type root finding with exact Jacobians; a diverged flow counts as a failure."""
    try:
        result = root(fun, w0, jac=True, method='hybr', options={'xtol': 1e-13, 'maxfev': 100})
        return result.x, bool(np.linalg.norm(fun(result.x)[0]) < RESIDUAL_TOL)
    except Diverged:
        return w0, False


def shoot_whole(shooter: Shooter, p0: np.ndarray) -> tuple[list[np.ndarray], bool]:
    """Root of the terminal conditions in the initial costates p(t0)."""
    prob = shooter.problem
    x0 = np.concatenate([prob.q0, prob.v0])
    span = (prob.grid[0], prob.grid[-1])
    nx = x0.size

    def fun(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        arc = shooter.integrate(np.concatenate([x0, p]), span)
        return (shooter.terminal_residual(arc.z_end),
                shooter.terminal_jacobian @ arc.sensitivity[:, nx:])

    p, ok = _solve_root(fun, p0)
    return [np.concatenate([x0, p])], ok


def shoot_arcs(shooter: Shooter, guess: Solution,
               nodes: np.ndarray) -> tuple[list[np.ndarray], bool]:
    """PMP boundary-value problem on segments between ``nodes`` (knot indices).

    Unknowns are p(t0) and the full z at interior nodes; residuals are the matching and terminal
    conditions. Each segment is short, so the unstable directions of the flow cannot blow up.
    """
    prob = shooter.problem
    n, k, dim = shooter.n, shooter.k, shooter.dim
    times = prob.grid[nodes]
    assert guess.costates is not None  # a Variational solution's
    lam, mu = guess.costates
    z_guess = np.hstack([guess.q, guess.v, np.vstack([lam, lam[-1]]), mu_knots(mu)])
    x0 = np.concatenate([prob.q0, prob.v0])
    segments = len(nodes) - 1
    w0 = np.concatenate([z_guess[0, n + k:]] + [z_guess[i] for i in nodes[1:-1]])

    def starts(w: np.ndarray) -> list[np.ndarray]:
        return [np.concatenate([x0, w[:n + k]])] + list(w[n + k:].reshape(-1, dim))

    def fun(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z0s = starts(w)
        res, jac = np.zeros(w.size), np.zeros((w.size, w.size))
        for i, z0 in enumerate(z0s):
            arc = shooter.integrate(z0, (times[i], times[i + 1]))
            rows = slice(i * dim, i * dim + (dim if i + 1 < segments else n + k))
            cols = (slice(0, n + k) if i == 0
                    else slice(n + k + (i - 1) * dim, n + k + i * dim))
            sens = arc.sensitivity[:, n + k:] if i == 0 else arc.sensitivity
            if i + 1 < segments:
                res[rows] = arc.z_end - z0s[i + 1]
                jac[rows, cols] = sens
                jac[rows, n + k + i * dim:n + k + (i + 1) * dim] = -np.eye(dim)
            else:
                res[rows] = shooter.terminal_residual(arc.z_end)
                jac[rows, cols] = shooter.terminal_jacobian @ sens
        return res, jac

    w, ok = _solve_root(fun, w0)
    return starts(w), ok


def mu_knots(mu_intervals: np.ndarray) -> np.ndarray:
    """Costates mu at the N+1 knots from per-interval values (linear extrapolation at ends)."""
    inner = 0.5 * (mu_intervals[1:] + mu_intervals[:-1])
    first = 1.5 * mu_intervals[0] - 0.5 * mu_intervals[1]
    last = 1.5 * mu_intervals[-1] - 0.5 * mu_intervals[-2]
    return np.vstack([first, inner, last])
