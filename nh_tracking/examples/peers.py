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

Both take the paper's sleigh problem as numbers only — its parameters (m, J, a), the sampled
reference, the start, h, N and epsilon — and write the sleigh's equations by hand in their own API
(the paper's quasi-velocities v1 = sqrt(I) omega, v2 = sqrt(m) * forward speed, so the cost is the
same function), never handed this package's derived expressions:

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
import math
import time
from typing import Any
import warnings

import casadi as ca
import numpy as np

from nh_tracking.problem import TrackingProblem

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


def _numbers(problem: TrackingProblem) -> tuple[dict[str, float], np.ndarray, np.ndarray]:
    q_knots, v_knots = problem.reference_samples[:2]
    x0 = np.concatenate([problem.q0, problem.v0])
    return problem.system.parameters, np.hstack([q_knots, v_knots]), x0


@dataclass(frozen=True)
class Contender:
    """One tool's cold solve, set up: ``solve()`` runs it once and returns its objective."""

    solve: Callable[[], float]
    build_s: float  # set-up [s]: model, solver, and for Opti its first solve
    warm: Callable[[np.ndarray], float] | None = None  # start offset -> objective


def dompc(problem: TrackingProblem) -> Contender:
    """Set the sleigh up in do-mpc for cold solves."""
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

    return Contender(solve, build, warm)


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
    parameters, reference, x0 = _numbers(problem)
    model = do_mpc.model.Model('continuous', 'SX')
    x = model.set_variable('_x', 'x', (5, 1))
    u = model.set_variable('_u', 'u', (2, 1))
    x_r = model.set_variable('_tvp', 'x_r', (5, 1))
    model.set_rhs('x', sleigh_rhs(x, u, **parameters))
    model.setup()
    mpc = do_mpc.controller.MPC(model)
    mpc.settings.n_horizon = problem.steps
    mpc.settings.t_step = problem.h
    mpc.settings.store_full_solution = False
    mpc.settings.nlpsol_opts = IPOPT_QUIET
    running = problem.h * 0.5 * (ca.sumsqr(x - x_r) + problem.epsilon * ca.sumsqr(u))
    mpc.set_objective(lterm=running, mterm=ca.DM(0))
    mpc.set_rterm(u=0.0)
    mpc.terminal_bounds['lower', 'x'] = reference[-1]
    mpc.terminal_bounds['upper', 'x'] = reference[-1]
    template = mpc.get_tvp_template()
    for i in range(problem.steps + 1):
        template['_tvp', i, 'x_r'] = reference[i]
    mpc.set_tvp_fun(lambda t_now: template)
    mpc.setup()
    return mpc, x0


def opti_multiple_shooting(problem: TrackingProblem) -> Contender:
    """Set the sleigh up with Opti + IPOPT (multiple shooting, RK4) for cold solves."""
    parameters, reference, x0 = _numbers(problem)
    start = time.perf_counter()
    x, u = ca.SX.sym('x', 5), ca.SX.sym('u', 2)
    f = ca.Function('f', [x, u], [sleigh_rhs(x, u, **parameters)])
    h, big_n = problem.h, problem.steps
    k1 = f(x, u)
    k2 = f(x + h / 2 * k1, u)
    k3 = f(x + h / 2 * k2, u)
    k4 = f(x + h * k3, u)
    step = ca.Function('rk4', [x, u], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
    opti = ca.Opti()
    xs, us = opti.variable(5, big_n + 1), opti.variable(2, big_n)
    cost = 0
    for i in range(big_n):
        opti.subject_to(xs[:, i + 1] == step(xs[:, i], us[:, i]))
        cost += h * 0.5 * (ca.sumsqr(xs[:, i] - reference[i])
                           + problem.epsilon * ca.sumsqr(us[:, i]))
    opti.subject_to(xs[:, 0] == x0)
    opti.subject_to(xs[:, -1] == reference[-1])
    opti.minimize(cost)
    opti.solver('ipopt', IPOPT_QUIET)
    opti.set_initial(xs, np.tile(x0[:, None], (1, big_n + 1)))
    opti.solve()  # the first solve builds IPOPT's functions: counted as set-up
    build = time.perf_counter() - start
    return Contender(lambda: float(opti.solve().value(cost)), build)


def rockit_fatrop(problem: TrackingProblem) -> Contender:
    """Set the sleigh up in rockit with fatrop, called through ``ocp.to_function``."""
    from rockit import MultipleShooting, Ocp  # (rockit-meco: the bench's extra)
    parameters, reference, x0 = _numbers(problem)
    start = time.perf_counter()
    ocp = Ocp(T=problem.horizon)
    x, u = ocp.state(5), ocp.control(2)
    x_ref, x_start = ocp.parameter(5, grid='control+'), ocp.parameter(5)
    ocp.set_der(x, sleigh_rhs(x, u, **parameters))
    ocp.add_objective(ocp.sum(problem.h * 0.5 * (ca.sumsqr(x - x_ref)
                                                 + problem.epsilon * ca.sumsqr(u))))
    ocp.subject_to(ocp.at_t0(x) == x_start)
    ocp.subject_to(ocp.at_tf(x) == ocp.at_tf(x_ref))
    ocp.method(MultipleShooting(N=problem.steps, M=1, intg='rk'))
    ocp.solver('fatrop', {'structure_detection': 'auto', 'expand': True, 'print_time': False,
                          'fatrop.print_level': 0})
    ocp.set_value(x_ref, reference.T)
    ocp.set_value(x_start, x0)
    ocp.set_initial(x, x0)
    ocp.solve()  # builds the solver
    states, controls = ocp.sample(x, grid='control')[1], ocp.sample(u, grid='control-')[1]
    plan = ocp.to_function('plan', [x_start, ocp.sample(x_ref, grid='control')[1], states,
                                    controls], [states, controls])
    build = time.perf_counter() - start
    cold_guess = (np.tile(x0[:, None], (1, problem.steps + 1)), np.zeros((2, problem.steps)))
    last = list(cold_guess)

    def run(start_state: np.ndarray, guess: tuple | list) -> float:
        xs, us = (np.array(a) for a in plan(start_state, reference.T, *guess))
        last[:] = [xs, us]
        return problem.h * 0.5 * float(np.sum((xs[:, :-1] - reference[:-1].T) ** 2)
                                       + problem.epsilon * np.sum(us ** 2))

    return Contender(lambda: run(x0, cold_guess), build,
                     lambda offset: run(x0 + offset, last))
