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


"""The benchmark's peers, each set up the way its own users write it.

Each takes a problem as numbers only — the model's parameters, the sampled reference, the start,
h, N, epsilon, the terminal condition and the discs (grown by the robot's radius) — and writes the
model's equations by hand in its own API (the paper's sleigh in its quasi-velocities
v1 = sqrt(I) omega, v2 = sqrt(m) * forward speed; the unicycle in its body twist — so the cost is
the same function), never handed this package's derived expressions. Discs are kept clear at
every knot after the start, as their users write a constraint:

- do-mpc: its ``Model`` with the right-hand side typed in, its default orthogonal collocation and
  IPOPT; the reference as time-varying parameters; the terminal state fixed by terminal bounds.
- CasADi Opti + IPOPT, direct multiple shooting with one RK4 step per interval, as MPC tutorials
  write it; its guess is the start state at every knot (do-mpc's default guess).
- rockit + fatrop: an ``Ocp`` with the same multiple shooting (RK4, one step an interval), the
  reference and the start as parameters, fatrop with structure detection, called through
  ``ocp.to_function`` as rockit's MPC examples do.

A warm re-solve (``Contender.warm``) starts from the tool's previous solution with the start
moved by ``offset``: do-mpc's own warm start, rockit's function fed its last solution.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
import math
import time
from typing import Any
import warnings

import casadi as ca
import numpy as np

from nh_tracking.problem.tracking_problem import TrackingProblem

IPOPT_QUIET: dict[str, Any] = {'ipopt.print_level': 0, 'ipopt.sb': 'yes', 'print_time': 0}


def sleigh_rhs(x: Any, u: Any, m: float, J: float, a: float) -> Any:
    """Write out the Chaplygin sleigh: x = (x1, x2, theta, v1, v2), u = (torque, force).

    omega' = -(m a / I) v omega, v' = a omega^2 for the rotation omega and the speed v along the
    blade, I = J + m a^2 — in v1 = sqrt(I) omega, v2 = sqrt(m) v.
    """
    inertia = J + m * a * a
    eta = a * math.sqrt(m) / inertia
    theta, v1, v2 = x[2], x[3], x[4]
    return ca.vertcat(ca.cos(theta) * v2 / math.sqrt(m), ca.sin(theta) * v2 / math.sqrt(m),
                      v1 / math.sqrt(inertia), u[0] - eta * v1 * v2, u[1] + eta * v1 * v1)


def unicycle_rhs(x: Any, u: Any) -> Any:
    """Write out the dynamic unicycle: x = (x, y, theta, v, omega), u = accelerations."""
    return ca.vertcat(ca.cos(x[2]) * x[3], ca.sin(x[2]) * x[3], x[4], u[0], u[1])


def written_rhs(problem: TrackingProblem) -> Callable[[Any, Any], Any]:
    """Return the model's right-hand side as written by hand above (sleigh or unicycle)."""
    system = problem.system
    if system.name == 'chaplygin_sleigh':
        return partial(sleigh_rhs, **system.parameters)
    if system.name == 'unicycle':
        return unicycle_rhs
    raise ValueError(f'the peers know the sleigh and the unicycle, not {system.name}')


def _numbers(problem: TrackingProblem) -> tuple[np.ndarray, np.ndarray]:
    q_knots, v_knots = problem.reference_samples[:2]
    return np.hstack([q_knots, v_knots]), np.concatenate([problem.q0, problem.v0])


def _clearances(problem: TrackingProblem, x: Any) -> list[Any]:
    """Return |p - c|^2 - (r + R)^2 of state ``x`` for each disc: >= 0 to keep clear."""
    return [(x[0] - cx) ** 2 + (x[1] - cy) ** 2 - grown ** 2
            for cx, cy, grown in problem.limits.obstacles]


def _terminal(problem: TrackingProblem, x: Any, x_ref: Any) -> Any:
    """Return omega/2 |q_N - q_r(T)|^2 for a terminal cost, 0 for a terminal equality."""
    n = problem.system.n
    return 0.5 * problem.omega * ca.sumsqr(x[:n] - x_ref[:n]) if problem.terminal == 'cost' \
        else 0


@dataclass(frozen=True)
class Contender:
    """One tool's cold solve, set up: ``solve()`` runs it once and returns its objective."""

    solve: Callable[[], float]
    build_s: float  # set-up [s]: model, solver, and for Opti its first solve
    warm: Callable[[np.ndarray], float] | None = None  # start offset -> objective
    positions: Callable[[], np.ndarray] | None = None  # the last plan's (x, y) at its knots


def dompc(problem: TrackingProblem) -> Contender:
    """Set the problem up in do-mpc for cold solves."""
    with warnings.catch_warnings():  # do-mpc warns about its optional features on import
        warnings.simplefilter('ignore')
        import do_mpc
    with _legacy_numpy():
        start = time.perf_counter()
        mpc, x0 = _dompc_controller(do_mpc, problem)
        build = time.perf_counter() - start

    def solve() -> float:
        with _legacy_numpy():
            mpc.reset_history()
            mpc.x0 = x0
            mpc.set_initial_guess()
            mpc.make_step(x0)
        return float(mpc.solver_stats['iterations']['obj'][-1])

    def warm(offset: np.ndarray) -> float:  # from its previous solution, as make_step does
        with _legacy_numpy():
            mpc.make_step(x0 + offset)
        return float(mpc.solver_stats['iterations']['obj'][-1])

    def positions() -> np.ndarray:
        with _legacy_numpy():
            states = [np.array(mpc.opt_x_num['_x', i, 0, 0]).ravel()
                      for i in range(problem.steps + 1)]
        return np.array(states)[:, :2]

    return Contender(solve, build, warm, positions)


@contextmanager
def _legacy_numpy() -> Iterator[None]:
    """do-mpc relies on CasADi's legacy numpy behaviour; the rest of the process keeps its own."""
    mode = ca.GlobalOptions.getNumpyMode()
    ca.GlobalOptions.setNumpyMode(-1)
    try:
        yield
    finally:
        ca.GlobalOptions.setNumpyMode(mode)


def _dompc_controller(do_mpc, problem: TrackingProblem):
    reference, x0 = _numbers(problem)
    nx, nu = len(x0), problem.system.r
    model = do_mpc.model.Model('continuous', 'SX')
    x = model.set_variable('_x', 'x', (nx, 1))
    u = model.set_variable('_u', 'u', (nu, 1))
    x_r = model.set_variable('_tvp', 'x_r', (nx, 1))
    model.set_rhs('x', written_rhs(problem)(x, u))
    model.setup()
    mpc = do_mpc.controller.MPC(model)
    mpc.settings.n_horizon = problem.steps
    mpc.settings.t_step = problem.h
    mpc.settings.store_full_solution = False
    mpc.settings.nlpsol_opts = IPOPT_QUIET
    running = problem.h * 0.5 * (ca.sumsqr(x - x_r) + problem.epsilon * ca.sumsqr(u))
    mpc.set_objective(lterm=running, mterm=_terminal(problem, x, x_r) + ca.DM(0))
    mpc.set_rterm(u=0.0)
    for j, clearance in enumerate(_clearances(problem, x)):
        mpc.set_nl_cons(f'disc_{j}', -clearance, ub=0.0)
    if problem.terminal == 'equality':
        mpc.terminal_bounds['lower', 'x'] = reference[-1]
        mpc.terminal_bounds['upper', 'x'] = reference[-1]
    template = mpc.get_tvp_template()
    for i in range(problem.steps + 1):
        template['_tvp', i, 'x_r'] = reference[i]
    mpc.set_tvp_fun(lambda t_now: template)
    mpc.setup()
    return mpc, x0


def opti_multiple_shooting(problem: TrackingProblem) -> Contender:
    """Set the problem up with Opti + IPOPT (multiple shooting, RK4) for cold solves."""
    reference, x0 = _numbers(problem)
    nx, nu = len(x0), problem.system.r
    start = time.perf_counter()
    x, u = ca.SX.sym('x', nx), ca.SX.sym('u', nu)
    f = ca.Function('f', [x, u], [written_rhs(problem)(x, u)])
    h, big_n = problem.h, problem.steps
    k1 = f(x, u)
    k2 = f(x + h / 2 * k1, u)
    k3 = f(x + h / 2 * k2, u)
    k4 = f(x + h * k3, u)
    step = ca.Function('rk4', [x, u], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
    opti = ca.Opti()
    xs, us = opti.variable(nx, big_n + 1), opti.variable(nu, big_n)
    cost = _terminal(problem, xs[:, -1], reference[-1])
    for i in range(big_n):
        opti.subject_to(xs[:, i + 1] == step(xs[:, i], us[:, i]))
        cost += h * 0.5 * (ca.sumsqr(xs[:, i] - reference[i])
                           + problem.epsilon * ca.sumsqr(us[:, i]))
        for clearance in _clearances(problem, xs[:, i + 1]):
            opti.subject_to(clearance >= 0)
    opti.subject_to(xs[:, 0] == x0)
    if problem.terminal == 'equality':
        opti.subject_to(xs[:, -1] == reference[-1])
    opti.minimize(cost)
    opti.solver('ipopt', IPOPT_QUIET)
    opti.set_initial(xs, np.tile(x0[:, None], (1, big_n + 1)))
    last = [opti.solve()]  # the first solve builds IPOPT's functions: counted as set-up
    build = time.perf_counter() - start

    def solve() -> float:
        last[0] = opti.solve()
        return float(last[0].value(cost))

    return Contender(solve, build, positions=lambda: np.array(last[0].value(xs))[:2].T)


def rockit_fatrop(problem: TrackingProblem) -> Contender:
    """Set the problem up in rockit with fatrop, called through ``ocp.to_function``."""
    from rockit import MultipleShooting, Ocp  # (rockit-meco: the bench's extra)
    reference, x0 = _numbers(problem)
    nx, nu = len(x0), problem.system.r
    start = time.perf_counter()
    ocp = Ocp(T=problem.horizon)
    x, u = ocp.state(nx), ocp.control(nu)
    x_ref, x_start = ocp.parameter(nx, grid='control+'), ocp.parameter(nx)
    ocp.set_der(x, written_rhs(problem)(x, u))
    ocp.add_objective(ocp.sum(problem.h * 0.5 * (ca.sumsqr(x - x_ref)
                                                 + problem.epsilon * ca.sumsqr(u))))
    if problem.terminal == 'cost':
        ocp.add_objective(ocp.at_tf(_terminal(problem, x, x_ref)))
    ocp.subject_to(ocp.at_t0(x) == x_start)
    for clearance in _clearances(problem, x):
        ocp.subject_to(clearance >= 0, include_first=False)
    if problem.terminal == 'equality':
        ocp.subject_to(ocp.at_tf(x) == ocp.at_tf(x_ref))
    ocp.method(MultipleShooting(N=problem.steps, M=1, intg='rk'))
    ocp.solver('fatrop', {'structure_detection': 'auto', 'expand': True, 'print_time': False,
                          'fatrop.print_level': 0})
    ocp.set_value(x_ref, reference.T)
    ocp.set_value(x_start, x0)
    ocp.set_initial(x, x0)
    try:
        ocp.solve()  # builds the solver
    except RuntimeError:  # (not converged: the solver is built all the same)
        pass
    states, controls = ocp.sample(x, grid='control')[1], ocp.sample(u, grid='control-')[1]
    plan = ocp.to_function('plan', [x_start, ocp.sample(x_ref, grid='control')[1], states,
                                    controls], [states, controls])
    build = time.perf_counter() - start
    cold_guess = (np.tile(x0[:, None], (1, problem.steps + 1)), np.zeros((nu, problem.steps)))
    last = list(cold_guess)

    def run(start_state: np.ndarray, guess: tuple | list) -> float:
        xs, us = (np.array(a) for a in plan(start_state, reference.T, *guess))
        last[:] = [xs, us]
        n = problem.system.n
        end = 0.0 if problem.terminal != 'cost' else \
            0.5 * problem.omega * float(np.sum((xs[:n, -1] - reference[-1, :n]) ** 2))
        return end + problem.h * 0.5 * float(np.sum((xs[:, :-1] - reference[:-1].T) ** 2)
                                             + problem.epsilon * np.sum(us ** 2))

    return Contender(lambda: run(x0, cold_guess), build,
                     lambda offset: run(x0 + offset, last), lambda: last[0][:2].T)
