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

"""Discrete variational (midpoint) transcription of the tracking problem (paper §5).

Unknowns are the knots x_k = (q_k, v_k), k = 1..N, of a curve on D. The discrete Lagrangian
is h L(q_{k+1/2}, v_{k+1/2}, v_{k,k+1}) — L written in (q, v, vdot) by eliminating the control,
u = vdot + Gamma(v, v) + grad V — and the discrete admissibility constraint is the corrected
Psi_d (docs/theory.md C13): (q_{k+1} - q_k)/h = rho(q_{k+1/2}) v_{k+1/2}, k = 0..N-1.

The NLP is built once per (system, N, terminal kind); everything that changes between solves
(initial state, reference samples, h, eps, omega) is a parameter, so replanning only updates
numbers and warm-starts.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import time
from typing import Any, ClassVar, Literal

import casadi as ca
import numpy as np

from nh_tracking.numeric import NumericFunction
from nh_tracking.problem import (Solution, terminal_cost, terminal_error, tracking_lagrangian,
                                 TrackingProblem)
from nh_tracking.solvers.base import Guess, ipopt_options, Method, Structure
from nh_tracking.solvers.cache import PerSystemCache
from nh_tracking.solvers.compiled import compiled_library
from nh_tracking.system import NonholonomicSystem

BACKENDS = ('fatrop', 'ipopt')
FATROP_OPTIONS = {'print_level': 0, 'tol': 1e-10, 'max_iter': 500}
FATROP_DEADLINE_ITERATIONS = 50  # fatrop has no wall-time limit: under a deadline, this bound
CONTINUATION_MIN_STEPS = 100  # cold solves with this many intervals or more start coarse
COARSE_STEPS = 50


@dataclass
class Transcription:
    """The compiled NLP of one structure, and functions to read a solution back.

    Stage-wise unknowns w = [x_0, u_0, ..., x_{N-1}, u_{N-1}, x_N] with x_k = (q_k, v_k) and
    u_k = (v_{k+1}, z_k): z_k is the midpoint q_{k+1/2}, so the dynamics are explicit,
    x_{k+1} = (2 z_k - q_k, v_{k+1}), and the discrete admissibility constraint becomes the
    stage equality z_k - q_k = h/2 rho(z_k) v_{k+1/2} — the same discrete problem, in the
    form a structure-exploiting OCP solver (fatrop) takes.
    """

    system: NonholonomicSystem
    steps: int
    terminal: str
    solver: ca.Function
    # (w, p) -> q (n, N+1), v (k, N+1), u (k, N), max |Psi_d| (from the knots), running cost:
    # one buffered call, since separate calls cost more than a warm solve's iteration
    readout: NumericFunction
    admissibility_rows: np.ndarray  # indices in g of the constraints z - q - h/2 rho v = 0

    def parameters(self, problem: TrackingProblem) -> np.ndarray:
        q_knots, v_knots, q_mid, v_mid = problem.reference_samples
        return np.concatenate([
            problem.q0, problem.v0, q_mid.ravel(), v_mid.ravel(), q_knots[-1], v_knots[-1],
            [problem.h, problem.epsilon, problem.omega],
        ])

    def pack(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Stage-wise unknowns from knots q (N+1, n), v (N+1, k)."""
        mid = 0.5 * (q[1:] + q[:-1])
        stages = np.hstack([q[:-1], v[:-1], v[1:], mid])
        return np.concatenate([stages.ravel(), q[-1], v[-1]])


_CACHE: PerSystemCache[Transcription] = PerSystemCache()


def transcription(system: NonholonomicSystem, steps: int, terminal: str,
                  max_time: float | None = None, solver: str = 'fatrop',
                  compiled: bool = False) -> Transcription:
    """Return the NLP for this structure (solver, time limit, compiled or interpreted).

    Built on first use and cached.
    """
    if solver not in BACKENDS:
        raise ValueError(f'unknown NLP solver {solver!r}; choose one of {BACKENDS}')
    # IPOPT takes the wall-time limit itself, so it is part of its NLP; fatrop only needs to
    # know whether its iterations are bounded
    wall_time = max_time if solver == 'ipopt' else None
    bounded = max_time is not None
    return _CACHE.get(system, (steps, terminal, solver, compiled, wall_time, bounded),
                      lambda: _build(system, steps, terminal, solver, compiled, wall_time,
                                     bounded))


def _build(system: NonholonomicSystem, steps: int, terminal: str, solver: str,
           compiled: bool, wall_time: float | None, bounded: bool) -> Transcription:
    n, k, big_n = system.n, system.k, steps
    nx = n + k
    xs = [ca.SX.sym(f'x{i}', nx) for i in range(big_n + 1)]
    us = [ca.SX.sym(f'u{i}', k + n) for i in range(big_n)]
    q0, v0 = ca.SX.sym('q0', n), ca.SX.sym('v0', k)
    q_mid, v_mid = ca.SX.sym('q_r', n * big_n), ca.SX.sym('v_r', k * big_n)
    q_end, v_end = ca.SX.sym('q_rT', n), ca.SX.sym('v_rT', k)
    h, eps, omega = ca.SX.sym('h'), ca.SX.sym('eps'), ca.SX.sym('omega')
    p = ca.vertcat(q0, v0, q_mid, v_mid, q_end, v_end, h, eps, omega)

    lagrangian = tracking_lagrangian(system)
    zero = ca.DM.zeros(k)
    w: list[ca.SX] = []
    g: list[ca.SX] = []
    residuals: list[ca.SX] = []
    controls: list[ca.SX] = []
    adm_rows: list[int] = []
    running = ca.SX(0)
    rows = 0
    for i in range(big_n):
        q, v = xs[i][:n], xs[i][n:]
        v_next, z = us[i][:k], us[i][k:]
        vm = 0.5 * (v + v_next)
        u = (v_next - v) / h - system.dynamics_fn(z, vm, zero)[1]
        running += h * lagrangian(z, vm, u, q_mid[i * n:(i + 1) * n], v_mid[i * k:(i + 1) * k],
                                  eps)
        controls.append(u)
        w += [xs[i], us[i]]
        stage = [xs[i + 1] - ca.vertcat(2 * z - q, v_next)]  # dynamics first (fatrop)
        if i == 0:
            stage.append(xs[0] - ca.vertcat(q0, v0))
        stage.append(z - q - 0.5 * h * system.rho_fn(z) @ vm)
        for c in stage:
            rows += c.shape[0]
        adm_rows.extend(range(rows - n, rows))
        g += stage
        q_next = xs[i + 1][:n]
        qm = 0.5 * (q + q_next)
        residuals.append((q_next - q) / h - system.rho_fn(qm) @ (0.5 * (v + xs[i + 1][n:])))
    w.append(xs[-1])
    objective = running
    if terminal == 'cost':
        objective += 0.5 * omega * ca.sumsqr(xs[-1][:n] - q_end)
    else:
        g.append(xs[-1] - ca.vertcat(q_end, v_end))
    unknowns, constraints = ca.vertcat(*w), ca.vertcat(*g)
    nlp = {'x': unknowns, 'p': p, 'f': objective, 'g': constraints}
    name = f'variational_{system.name}_{big_n}'
    if solver == 'fatrop':
        fatrop = dict(FATROP_OPTIONS)
        if bounded:
            fatrop['max_iter'] = FATROP_DEADLINE_ITERATIONS
        options: dict[str, Any] = {
            'structure_detection': 'auto', 'equality': [True] * constraints.shape[0],
            'print_time': False, 'fatrop': fatrop}
    else:
        options = ipopt_options(wall_time)
    options['show_eval_warnings'] = False  # failures are reported in the Solution instead
    nlp_solver = ca.nlpsol(name, solver, nlp, options)
    library = compiled_library(nlp_solver) if compiled else None
    if library is not None:
        nlp_solver = ca.nlpsol(name, solver, str(library), options)
    knots_q = ca.horzcat(*[x[:n] for x in xs])
    knots_v = ca.horzcat(*[x[n:] for x in xs])
    readout = ca.Function('readout', [unknowns, p],
                          [knots_q, knots_v, ca.horzcat(*controls),
                           ca.mmax(ca.fabs(ca.horzcat(*residuals))), running])
    return Transcription(
        system=system, steps=big_n, terminal=terminal, solver=nlp_solver,
        readout=NumericFunction(readout), admissibility_rows=np.array(adm_rows),
    )


def default_guess(problem: TrackingProblem) -> tuple[np.ndarray, np.ndarray]:
    """Return the reference itself (on q0's branch) as the first guess of the knots."""
    q, v = (a.copy() for a in problem.reference_samples[:2])
    q[0], v[0] = problem.q0, problem.v0
    return q, v


def solve_variational(problem: TrackingProblem,
                      initial_guess: tuple[np.ndarray, np.ndarray] | None = None,
                      max_time: float | None = None, solver: str = 'fatrop',
                      compiled: bool = False) -> Solution:
    """Solve the discrete variational NLP from knots (q (N+1, n), v (N+1, k)) as the guess.

    Without a time limit, a fatrop failure is retried with IPOPT (the route says so). A cold
    solve on a fine grid starts from the plan of a coarse grid, interpolated (grid
    continuation): from the reference alone, fine grids spend most iterations backtracking.
    """
    coarse_time = 0.0
    if initial_guess is None and problem.steps >= CONTINUATION_MIN_STEPS:
        coarse = dataclasses.replace(problem, steps=COARSE_STEPS)
        coarse_plan = solve_variational(coarse, None, max_time, solver, compiled)
        coarse_time = coarse_plan.solve_time
        if coarse_plan.success:
            initial_guess = coarse_plan.trajectory().sample(problem.grid)
    result = _solve_with(problem, initial_guess, max_time, solver, compiled)
    result.solve_time += coarse_time
    if not result.success and solver == 'fatrop' and max_time is None:
        retry = _solve_with(problem, initial_guess, None, 'ipopt')
        retry.route = f'fatrop failed ({result.message}) -> ipopt'
        retry.solve_time += result.solve_time
        return retry
    return result


def _solve_with(problem: TrackingProblem, initial_guess, max_time: float | None,
                solver: str, compiled: bool = False) -> Solution:
    tr = transcription(problem.system, problem.steps, problem.terminal, max_time, solver,
                       compiled)
    q_g, v_g = default_guess(problem) if initial_guess is None else initial_guess
    q_g, v_g = np.array(q_g, dtype=float), np.array(v_g, dtype=float)
    q_g[0], v_g[0] = problem.q0, problem.v0
    if problem.terminal == 'equality':
        q_g[-1], v_g[-1] = problem.reference_samples[0][-1], problem.reference_samples[1][-1]
    p = tr.parameters(problem)
    start = time.perf_counter()
    w0 = tr.pack(q_g, v_g)
    if not all(np.all(np.isfinite(a)) for a in tr.readout(w0, p)):
        # fatrop never returns from a non-finite starting point (its line search cannot
        # recover): refuse to start, and say why
        return _failed(problem, q_g, v_g, time.perf_counter() - start, solver,
                       'the NLP is not finite at the initial guess (the dynamics or cost give '
                       'NaN or Inf there)')
    result = tr.solver(x0=w0, p=p, lbg=0, ubg=0)
    elapsed = time.perf_counter() - start
    stats = tr.solver.stats()
    w = np.array(result['x']).ravel()
    q, v, u, residual, running = tr.readout(w, p)
    q, v, u, max_residual = q.T.copy(), v.T.copy(), u.T.copy(), float(residual[0])
    lam_g = np.array(result['lam_g']).ravel()
    # The paper's multipliers are lambda^k = (h/2) c_k (c_k: multiplier of the stage form of
    # the admissibility constraint); the reported costates are lambda = -lambda^k / h.
    lam = -0.5 * lam_g[tr.admissibility_rows].reshape(problem.steps, problem.system.n)
    cost = float(running[0]) + terminal_cost(problem, q[-1])
    success = bool(stats['success']) and bool(np.all(np.isfinite(w)))
    return Solution(
        t=problem.grid, q=q, v=v, u=u, cost=cost, success=success,
        iterations=int(stats.get('iter_count', -1)), solve_time=elapsed,
        terminal_error=terminal_error(problem, q[-1], v[-1]), method='variational',
        message=str(stats.get('return_status', 'Solve_Succeeded' if success else 'failed')),
        route=solver,
        costates=(lam, -problem.epsilon * u),
        details={'admissibility_residual': max_residual},
    )


def _failed(problem: TrackingProblem, q: np.ndarray, v: np.ndarray, elapsed: float,
            solver: str, message: str) -> Solution:
    return Solution(
        t=problem.grid, q=q, v=v, u=np.zeros((problem.steps, problem.system.k)),
        cost=float('inf'), success=False, iterations=0, solve_time=elapsed,
        terminal_error=float('inf'), method='variational', message=message, route=solver)


@dataclass(frozen=True)
class Variational(Method):
    """The paper's discrete variational (midpoint) transcription.

    Solved by ``backend`` (fatrop exploits the stage structure; IPOPT is the general fallback).
    ``compiled`` runs the NLP's derivatives as C, compiled once per structure and machine
    (:mod:`.compiled`).
    """

    backend: Literal['fatrop', 'ipopt'] = 'fatrop'
    compiled: bool = False
    name: ClassVar[str] = 'variational'

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f'variational backend must be one of {BACKENDS}, '
                             f'got {self.backend!r}')
        if not isinstance(self.compiled, bool):
            raise TypeError(f'variational option compiled must be a bool, got {self.compiled!r}')

    def prepare(self, system: NonholonomicSystem, structure: Structure) -> None:
        transcription(system, structure.steps, structure.terminal,
                      structure.deadline, self.backend, self.compiled)

    def solve(self, problem: TrackingProblem, guess: Guess | None = None,
              deadline: float | None = None) -> Solution:
        return solve_variational(problem, None if guess is None else guess[:2], deadline,
                                 self.backend, self.compiled)
