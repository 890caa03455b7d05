"""Discrete variational (midpoint) transcription of the tracking problem (paper §5).

Unknowns are the knots x_k = (q_k, v_k), k = 1..N, of a curve on D. The discrete Lagrangian
is h L(q_{k+1/2}, v_{k+1/2}, v_{k,k+1}) — L written in (q, v, vdot) by eliminating the control,
u = vdot + Gamma(v, v) + grad V — and the discrete admissibility constraint is the corrected
Psi_d (ERRATA #13): (q_{k+1} - q_k)/h = rho(q_{k+1/2}) v_{k+1/2}, k = 0..N-1.

The NLP is built once per (system, N, terminal kind); everything that changes between solves
(initial state, reference samples, h, eps, omega) is a parameter, so replanning only updates
numbers and warm-starts.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from nh_tracking.problem import (Solution, TrackingProblem, terminal_cost, terminal_error,
                                 tracking_lagrangian)
from nh_tracking.solvers.cache import PerSystemCache
from nh_tracking.system import NonholonomicSystem

IPOPT_OPTIONS = {
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "print_time": False,
    "ipopt.tol": 1e-10,
    "ipopt.constr_viol_tol": 1e-12,
    "ipopt.max_iter": 500,
}


@dataclass
class Transcription:
    """The compiled NLP of one structure, and functions to read a solution back."""

    system: NonholonomicSystem
    steps: int
    terminal: str
    solver: ca.Function
    controls: ca.Function  # (x, p) -> u (k, N)
    residual: ca.Function  # (x, p) -> Psi_d (n, N)
    discrete_cost: ca.Function  # (x, p) -> running part of the discrete cost

    def parameters(self, problem: TrackingProblem) -> np.ndarray:
        mid = problem.grid[:-1] + 0.5 * problem.h
        q_mid, v_mid = problem.reference_at(mid)
        q_end, v_end = problem.reference_at(problem.grid[-1])
        return np.concatenate([
            problem.q0, problem.v0, q_mid.ravel(), v_mid.ravel(), q_end.ravel(), v_end.ravel(),
            [problem.h, problem.epsilon, problem.omega],
        ])


_CACHE: PerSystemCache[Transcription] = PerSystemCache()


def transcription(system: NonholonomicSystem, steps: int, terminal: str,
                  max_time: float | None = None) -> Transcription:
    """The NLP for this structure (and time limit), built on first use, cached on the system."""
    return _CACHE.get(system, (steps, terminal, max_time),
                      lambda: _build(system, steps, terminal, max_time))


def ipopt_options(max_time: float | None) -> dict:
    """IPOPT settings; ``max_time`` bounds the wall time of one solve (a replanning deadline)."""
    return IPOPT_OPTIONS if max_time is None else {**IPOPT_OPTIONS,
                                                   "ipopt.max_wall_time": float(max_time)}


def _build(system: NonholonomicSystem, steps: int, terminal: str,
           max_time: float | None) -> Transcription:
    n, k, big_n = system.n, system.k, steps
    x = ca.SX.sym("x", (n + k) * big_n)  # knots 1..N, stage-wise (q_k, v_k)
    q0, v0 = ca.SX.sym("q0", n), ca.SX.sym("v0", k)
    q_mid, v_mid = ca.SX.sym("q_r", n * big_n), ca.SX.sym("v_r", k * big_n)
    q_end, v_end = ca.SX.sym("q_rT", n), ca.SX.sym("v_rT", k)
    h, eps, omega = ca.SX.sym("h"), ca.SX.sym("eps"), ca.SX.sym("omega")
    p = ca.vertcat(q0, v0, q_mid, v_mid, q_end, v_end, h, eps, omega)

    lagrangian = tracking_lagrangian(system)
    knots_q = [q0] + [x[i * (n + k):i * (n + k) + n] for i in range(big_n)]
    knots_v = [v0] + [x[i * (n + k) + n:(i + 1) * (n + k)] for i in range(big_n)]
    running, residuals, controls = 0, [], []
    for i in range(big_n):
        qm = 0.5 * (knots_q[i] + knots_q[i + 1])
        vm = 0.5 * (knots_v[i] + knots_v[i + 1])
        vdot = (knots_v[i + 1] - knots_v[i]) / h
        u = vdot - system.dynamics_fn(qm, vm, ca.DM.zeros(k))[1]
        running += h * lagrangian(qm, vm, u, q_mid[i * n:(i + 1) * n],
                                  v_mid[i * k:(i + 1) * k], eps)
        residuals.append((knots_q[i + 1] - knots_q[i]) / h - system.rho_fn(qm) @ vm)
        controls.append(u)
    objective = running
    if terminal == "cost":
        objective += 0.5 * omega * ca.sumsqr(knots_q[-1] - q_end)
    g = ca.vertcat(*residuals)
    solver = ca.nlpsol(f"variational_{system.name}_{big_n}", "ipopt",
                       {"x": x, "p": p, "f": objective, "g": g}, ipopt_options(max_time))
    return Transcription(
        system=system, steps=big_n, terminal=terminal, solver=solver,
        controls=ca.Function("controls", [x, p], [ca.horzcat(*controls)]),
        residual=ca.Function("residual", [x, p], [ca.horzcat(*residuals)]),
        discrete_cost=ca.Function("running_cost", [x, p], [running]),
    )


def default_guess(problem: TrackingProblem) -> np.ndarray:
    """The reference itself (on q0's branch) as the first guess of the knots 1..N."""
    q, v = problem.reference_at(problem.grid[1:])
    return np.hstack([q, v]).ravel()


def solve_variational(problem: TrackingProblem, initial_guess: np.ndarray | None = None,
                      max_time: float | None = None) -> Solution:
    """Solve the discrete variational NLP; ``initial_guess`` is the flat knots 1..N."""
    tr = transcription(problem.system, problem.steps, problem.terminal, max_time)
    n, k, big_n = problem.system.n, problem.system.k, problem.steps
    p = tr.parameters(problem)
    x0 = default_guess(problem) if initial_guess is None else np.asarray(initial_guess, float)
    lbx, ubx = np.full(x0.size, -np.inf), np.full(x0.size, np.inf)
    if problem.terminal == "equality":
        q_end, v_end = problem.reference_at(problem.grid[-1])
        lbx[-(n + k):] = ubx[-(n + k):] = np.concatenate([q_end[0], v_end[0]])
        x0 = x0.copy()
        x0[-(n + k):] = lbx[-(n + k):]
    start = time.perf_counter()
    result = tr.solver(x0=x0, p=p, lbx=lbx, ubx=ubx, lbg=0, ubg=0)
    elapsed = time.perf_counter() - start
    stats = tr.solver.stats()
    xs = np.array(result["x"]).ravel()
    knots = np.vstack([np.concatenate([problem.q0, problem.v0]), xs.reshape(big_n, n + k)])
    q, v = knots[:, :n], knots[:, n:]
    u = np.array(tr.controls(xs, p)).T
    residual = float(np.abs(np.array(tr.residual(xs, p))).max())
    lam_g = np.array(result["lam_g"]).ravel()
    # Discrete costates: lambda from the admissibility multipliers, mu from u* = -mu/eps.
    lam = -lam_g.reshape(big_n, n) / problem.h
    cost = float(tr.discrete_cost(xs, p)) + terminal_cost(problem, q[-1])
    success = bool(stats["success"]) and np.all(np.isfinite(knots))
    return Solution(
        t=problem.grid, q=q, v=v, u=u, cost=cost, success=success,
        iterations=int(stats["iter_count"]), solve_time=elapsed,
        terminal_error=terminal_error(problem, q[-1], v[-1]), method="variational",
        message=stats["return_status"], route="ipopt",
        costates=(lam, -problem.epsilon * u),
        details={"admissibility_residual": residual},
    )
