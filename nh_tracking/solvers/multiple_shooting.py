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

"""Direct multiple shooting with RK4 and piecewise-constant controls: the standard baseline.

This is what a user would write without the paper's geometry: states and controls at the knots,
continuity x_{k+1} = RK4(x_k, u_k), and the running cost integrated alongside by the same RK4.
"""
from __future__ import annotations

from dataclasses import dataclass
import time
from typing import ClassVar

import casadi as ca
import numpy as np

from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.problem.attempts import Attempt, Backend
from nh_tracking.problem.limits import clearance_points, plane, VIOLATION_TOL
from nh_tracking.problem.tracking_problem import (Solution, terminal_cost, terminal_error,
                                                  tracking_lagrangian, TrackingProblem)
from nh_tracking.solvers.base import Guess, Method, next_route, Structure, time_left
from nh_tracking.solvers.cache import by_steps, PerSystemCache
from nh_tracking.solvers.inequalities import (assess_limits, ConstraintStack, DOMAIN_MARGIN, Rows,
                                              Shape, soft_bounds, soften, start_violation)
from nh_tracking.solvers.nlp import BoundedNlp, deadline_after, Pace
from nh_tracking.solvers.obstacles import clear_of_every_disc

SUBSTEPS = 2  # RK4 steps per control interval


@dataclass
class ShootingTranscription:
    steps: int
    nlp: BoundedNlp
    running_cost: ca.Function  # (w, p) -> integrated running cost
    # (w, p) -> (points, n) the configurations at the clearance rows: knots, RK4 midpoints
    clearance_at: ca.Function
    limits: Rows
    rows: int  # of the hard NLP's g
    soft_index: np.ndarray | None  # softened: the inequality rows given slacks

    def parameters(self, problem: TrackingProblem, points: np.ndarray) -> np.ndarray:
        """Return the NLP's parameters; each clearance point's discs: those nearest ``points``.

        (Its configurations on the guess, in g's order.)
        """
        fine = problem.start + np.linspace(0.0, problem.horizon, 2 * SUBSTEPS * problem.steps + 1)
        q_ref, v_ref = problem.reference_at(fine)
        return np.concatenate([q_ref.ravel(), v_ref.ravel(),
                               [problem.h, problem.epsilon, problem.omega],
                               self.limits.parameters(problem.limits, points, problem.h)])


_CACHE: PerSystemCache[ShootingTranscription] = PerSystemCache(group=by_steps)


def shooting_transcription(system: NonholonomicSystem, steps: int, terminal: str,
                           bounded: bool = False, shape: Shape = Shape()) -> ShootingTranscription:
    return _CACHE.get(system, (steps, terminal, bool(bounded), shape),
                      lambda: _build(system, steps, terminal, bool(bounded), shape))


def _build(system: NonholonomicSystem, steps: int, terminal: str,
           bounded: bool, shape: Shape) -> ShootingTranscription:
    n, k, r = system.n, system.k, system.r
    nx = n + k
    points = 2 * SUBSTEPS * steps + 1  # reference at every RK4 stage time
    q_ref, v_ref = ca.SX.sym('q_r', n, points), ca.SX.sym('v_r', k, points)
    h, eps, omega = ca.SX.sym('h'), ca.SX.sym('eps'), ca.SX.sym('omega')
    limits = Rows(shape, plane(system) if shape.slots else None, 2 * steps)
    p = ca.vertcat(ca.vec(q_ref), ca.vec(v_ref), h, eps, omega, limits.obstacles)
    lagrangian = tracking_lagrangian(system)

    def rate(x, u, j):
        xdot = system.ode_fn(x, u)
        return xdot, lagrangian(x[:n], x[n:], u, q_ref[:, j], v_ref[:, j], eps)

    w = ca.SX.sym('w', nx * (steps + 1) + r * steps)  # stage-wise x_0, u_0, x_1, ..., x_N
    xs = [w[i * (nx + r):i * (nx + r) + nx] for i in range(steps + 1)]
    us = [w[i * (nx + r) + nx:(i + 1) * (nx + r)] for i in range(steps)]
    running, g = ca.SX(0), ConstraintStack()

    dt = h / SUBSTEPS
    for i in range(steps):
        x = xs[i]
        if i > 0:  # the start is data, not a decision
            g.add(*limits.velocity(x[n:], g.rows))
            g.add(*limits.clearance(x[:n], g.rows))
        g.add(*limits.control(us[i], g.rows))
        for s in range(SUBSTEPS):
            if 2 * s == SUBSTEPS:  # the interval's midpoint
                g.add(*limits.clearance(x[:n], g.rows))
            j = 2 * (i * SUBSTEPS + s)
            k1, l1 = rate(x, us[i], j)
            k2, l2 = rate(x + dt / 2 * k1, us[i], j + 1)
            k3, l3 = rate(x + dt / 2 * k2, us[i], j + 1)
            k4, l4 = rate(x + dt * k3, us[i], j + 2)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            running += dt / 6 * (l1 + 2 * l2 + 2 * l3 + l4)
        g.add(x - xs[i + 1])
    g.add(*limits.velocity(xs[-1][n:], g.rows))
    g.add(*limits.clearance(xs[-1][:n], g.rows))
    limits.check_all_points_built()
    objective = running
    if terminal == 'cost':
        objective += 0.5 * omega * ca.sumsqr(xs[-1][:n] - q_ref[:, -1])
    nlp = {'x': w, 'p': p, 'f': objective, 'g': ca.vertcat(*g.blocks)}
    soft_index = None
    if shape.soft:
        nlp, soft_index = soften(nlp, limits)
    solver = BoundedNlp(f'multiple_shooting_{system.name}_{steps}', 'ipopt', nlp, {}, bounded)
    at = ca.horzcat(*limits.at).T if limits.at else ca.SX(0, n)
    return ShootingTranscription(steps=steps, nlp=solver,
                                 running_cost=ca.Function('running', [w, p], [running]),
                                 clearance_at=ca.Function('clearance_at', [w, p], [at]),
                                 limits=limits, rows=g.rows, soft_index=soft_index)


def solve_multiple_shooting(problem: TrackingProblem, initial_guess: Guess | None = None,
                            max_time: float | None = None) -> Solution:
    """Solve the baseline NLP; ``initial_guess`` is (q (N+1, n), v (N+1, k), u (N, r))."""
    return _solve_until(problem, initial_guess, deadline_after(max_time))


def _solve_until(problem: TrackingProblem, initial_guess: Guess | None,
                 stop: float | None) -> Solution:
    """Solve; after a failure with limits, the least-violating plan (soft limits) instead."""
    def route(soft: bool) -> Solution:
        return clear_of_every_disc(
            lambda guess, every: _solve_once(problem, guess, stop, every, soft),
            initial_guess, stop, problem)

    soft = start_violation(problem) > VIOLATION_TOL  # only the least-violating plan exists
    result = route(soft)
    if (not result.success and problem.limits.active and not soft and time_left(result, stop)
            and not result.limit_check.through_disc):
        result = next_route(result, f'ipopt failed ({result.message}) -> soft limits',
                            lambda: route(True))
    return result


def _solve_once(problem: TrackingProblem, initial_guess: Guess | None,
                stop: float | None, every: bool, soft: bool) -> Solution:
    sys, big_n = problem.system, problem.steps
    n, k, r = sys.n, sys.k, sys.r
    tr = shooting_transcription(sys, big_n, problem.terminal, stop is not None,
                                Shape.of(problem.limits, soft, every))
    q_g, v_g = problem.reference_samples[:2] if initial_guess is None else initial_guess[:2]
    u_g = None if initial_guess is None else initial_guess[2]
    if u_g is None:
        u_g = np.zeros((big_n, r))
    q_g, v_g = np.array(q_g, dtype=float), np.array(v_g, dtype=float)
    q_g[0], v_g[0] = problem.q0, problem.v0
    x_g = np.hstack([q_g, v_g])
    w0 = np.concatenate([np.concatenate([x_g[i], u_g[i]]) for i in range(big_n)] + [x_g[-1]])
    # each clearance point's discs: those nearest its configuration on the guess, the RK4
    # midpoints integrated from the knots (the discs are not in the dynamics: any will do)
    p = tr.parameters(problem, clearance_points(q_g))
    p = tr.parameters(problem, np.array(tr.clearance_at(w0, p)))
    lbw, ubw = _domain_bounds(sys, big_n)
    lbw[:n + k] = ubw[:n + k] = x_g[0]
    if problem.terminal == 'equality':
        q_knots, v_knots = problem.reference_samples[:2]
        lbw[-(n + k):] = ubw[-(n + k):] = w0[-(n + k):] = np.concatenate([q_knots[-1],
                                                                          v_knots[-1]])
    lbg, ubg = tr.limits.bounds(tr.rows, problem.limits)
    if tr.soft_index is not None:
        lbg, ubg = soft_bounds(lbg, ubg, tr.soft_index)
        slacks = len(tr.soft_index)
        w0, lbw, ubw = (np.concatenate([a, np.full(slacks, b)])
                        for a, b in ((w0, 0.0), (lbw, 0.0), (ubw, np.inf)))
    start = time.perf_counter()
    outcome = tr.nlp.solve(Pace(stop), x0=w0, p=p, lbx=lbw, ubx=ubw, lbg=lbg, ubg=ubg)
    elapsed = time.perf_counter() - start
    slacks = 0 if tr.soft_index is None else len(tr.soft_index)
    w = outcome.iterate.w[:len(w0) - slacks]
    stage = w[:-(n + k)].reshape(big_n, n + k + r)
    x = np.vstack([stage[:, :n + k], w[-(n + k):]])
    q, v, u = x[:, :n], x[:, n:], stage[:, n + k:]
    cost = float(tr.running_cost(w, p)) + terminal_cost(problem, q[-1])
    success, message, violation, check = assess_limits(
        tr.limits, problem.limits, tr.soft_index is not None,
        outcome.success and bool(np.all(np.isfinite(w))),
        np.vstack([q[:1], np.array(tr.clearance_at(w, p))]), v, u,  # knots, RK4 midpoints
        problem.h, outcome.message)
    return Solution(
        t=problem.grid, q=q, v=v, u=u, cost=cost, success=success,
        iterations=outcome.iterations, solve_time=elapsed,
        terminal_error=terminal_error(problem, q[-1], v[-1]), method='multiple_shooting',
        message=message, route='ipopt' if tr.soft_index is None else 'ipopt (soft limits)',
        details={'violation': violation}, limit_check=check,
        attempts=[Attempt(Backend.IPOPT, outcome.status, outcome.iterations, elapsed)])


def _domain_bounds(system: NonholonomicSystem, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounds on the stage-wise unknowns: the knots' configurations inside the model's domain."""
    n, width = system.n, system.n + system.k + system.r
    size = (steps + 1) * width - system.r  # x_0, u_0, ..., x_N
    lower, upper = np.full((steps + 1, width), -np.inf), np.full((steps + 1, width), np.inf)
    lower[:, :n], upper[:, :n] = system.domain.interior(range(n), DOMAIN_MARGIN)
    return lower.ravel()[:size], upper.ravel()[:size]


@dataclass(frozen=True)
class MultipleShooting(Method):
    """Direct multiple shooting (RK4, piecewise-constant controls) with IPOPT.

    The baseline a user would write without the geometry. It has no options.
    """

    name: ClassVar[str] = 'multiple_shooting'

    def prepare(self, system: NonholonomicSystem, structure: Structure) -> None:
        shooting_transcription(system, structure.steps, structure.terminal,
                               structure.deadline is not None, structure.limits)

    def solve_until(self, problem: TrackingProblem, guess: Guess | None,
                    stop: float | None) -> Solution:
        return _solve_until(problem, guess, stop)
