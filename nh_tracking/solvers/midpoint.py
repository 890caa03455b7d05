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

"""The discrete variational (midpoint) NLP of a problem's structure, in stage form.

Unknowns are the knots x_k = (q_k, v_k) of a curve on D and, per interval, the next velocity and
the midpoint configuration (and the control, when it cannot be eliminated); see
:class:`Transcription`. Built once per structure and family of systems
(:class:`~nh_tracking.core.family.DynamicsFamily`) and cached; the numbers of a problem, the
family's parameter values among them, are its parameters and bounds.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np

from nh_tracking.core.numeric import NumericFunction
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.problem.limits import clearance_points, plane
from nh_tracking.problem.tracking_problem import (tracking_lagrangian, tracking_residual,
                                                  TrackingProblem)
from nh_tracking.solvers.cache import by_steps, PerSystemCache
from nh_tracking.solvers.inequalities import ConstraintStack, Rows, Shape, soft_bounds, soften
from nh_tracking.solvers.newton import GaussNewtonStep, NewtonStep
from nh_tracking.solvers.nlp import BoundedNlp

BACKENDS = ('fatrop', 'ipopt')


@dataclass
class Transcription:
    """The compiled NLP of one structure, and functions to read a solution back.

    Stage-wise unknowns w = [x_0, u_0, ..., x_{N-1}, u_{N-1}, x_N] with x_k = (q_k, v_k) and
    u_k = (v_{k+1}, z_k[, u_k]): z_k is the midpoint q_{k+1/2}, so the dynamics are explicit,
    x_{k+1} = (2 z_k - q_k, v_{k+1}), and the discrete admissibility constraint becomes the
    stage equality z_k - q_k = h/2 rho(z_k) v_{k+1/2} — the same discrete problem, in the
    form a structure-exploiting OCP solver (fatrop) takes. The control u_k is an unknown only
    for an underactuated system.
    """

    controls: int  # r when the controls are unknowns (underactuated), else 0
    steps: int
    terminal: str
    nlp: BoundedNlp | None  # None: real-time iterations by Gauss-Newton steps (newton)
    # (w, p) -> q (n, N+1), v (k, N+1), u (r, N), max |Psi_d| (from the knots), cost, terminal
    # error: one buffered call, since separate calls cost more than a warm solve's iteration
    readout: NumericFunction
    admissibility_rows: np.ndarray  # indices in g of the constraints z - q - h/2 rho v = 0
    dynamics_rows: np.ndarray  # underactuated: of v_{k+1} - v_k - h (f + B u) = 0
    limits: Rows  # the rows of the problem's limits
    rows: int  # of the hard NLP's g
    unknowns: int  # of the hard NLP's x
    soft_index: np.ndarray | None  # softened: the inequality rows given slacks
    newton: GaussNewtonStep | None  # real-time iterations without limits

    @cached_property
    def curved_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the rows of g that may curve, by time: (N, .) an interval's, (2N, .) clearance.

        An interval's admissibility, underactuated dynamics and control-bound rows (a fully
        actuated system's u is eliminated, u = dv/dt - f(q, v)); a midpoint's clearance rows,
        then the next knot's, half an interval apart. A plan's multipliers move along them
        (:mod:`.duals`).
        """
        controls = np.flatnonzero(self.limits.inequality_mask(self.rows, ('u',)))
        interval = np.hstack([rows.reshape(self.steps, -1) for rows in (
            self.admissibility_rows, self.dynamics_rows, controls) if len(rows)])
        clearance = np.flatnonzero(self.limits.inequality_mask(self.rows, ('clear',)))
        return interval, clearance.reshape(2 * self.steps, -1)

    def parameters(self, problem: TrackingProblem, q: np.ndarray | None = None) -> np.ndarray:
        """Return the NLP's parameters for a guess with knots ``q`` (default: the reference).

        Each clearance point's discs are those nearest it on the guess.
        """
        q_knots, v_knots, q_mid, v_mid = problem.reference_samples
        return np.concatenate([
            problem.q0, problem.v0, q_mid.ravel(), v_mid.ravel(), q_knots[-1], v_knots[-1],
            [problem.h, problem.epsilon, problem.omega],
            self.limits.parameters(problem.limits,
                                   clearance_points(q_knots if q is None else q), problem.h),
            problem.system.family_values,
        ])

    def bounds(self, problem: TrackingProblem) -> dict[str, np.ndarray]:
        """lbg, ubg (and the slacks' lbx) of a solve: the limits' values go in here."""
        lower, upper = self.limits.bounds(self.rows, problem.limits, problem.system.domain)
        if self.soft_index is None:
            return {'lbg': lower, 'ubg': upper}
        lbg, ubg = soft_bounds(lower, upper, self.soft_index)
        lbx = np.concatenate([np.full(self.unknowns, -np.inf), np.zeros(len(self.soft_index))])
        return {'lbg': lbg, 'ubg': ubg, 'lbx': lbx}

    def pack(self, q: np.ndarray, v: np.ndarray, u: np.ndarray | None) -> np.ndarray:
        """Stage-wise unknowns from knots q (N+1, n), v (N+1, k) and controls u (N, r)."""
        mid = 0.5 * (q[1:] + q[:-1])
        parts = [q[:-1], v[:-1], v[1:], mid]
        if self.controls:
            parts.append(np.zeros((self.steps, self.controls)) if u is None else u)
        return np.concatenate([np.hstack(parts).ravel(), q[-1], v[-1]])


_CACHE: PerSystemCache[Transcription] = PerSystemCache(group=by_steps)


def transcription(system: NonholonomicSystem, steps: int, terminal: str,
                  bounded: bool = False, solver: str = 'fatrop',
                  compiled: bool = False, shape: Shape = Shape(),
                  iterations: int = 0) -> Transcription:
    """Return the NLP for this structure, built on first use and cached.

    The structure: backend, deadlines or not, compiled or interpreted, the shape of its limits
    and an iteration budget (0: to convergence). A soft shape is always solved by IPOPT to
    convergence: its slacks break the stage structure fatrop needs.
    """
    if solver not in BACKENDS:
        raise ValueError(f'unknown NLP solver {solver!r}; choose one of {BACKENDS}')
    if shape.soft:
        solver, compiled, iterations = 'ipopt', False, 0
    return _CACHE.get(system.family, (steps, terminal, solver, compiled, bool(bounded), shape,
                                      iterations),
                      lambda: _build(system, steps, terminal, solver, compiled, bool(bounded),
                                     shape, iterations))


@dataclass
class _StageForm:
    """The symbolic NLP of one structure, before any solver is made of it."""

    unknowns: ca.SX
    p: ca.SX
    objective: ca.SX
    constraints: ca.SX
    cost_residuals: ca.SX  # the objective is 1/2 |cost_residuals|^2 (Gauss-Newton steps)
    limits: Rows
    # q (n, N+1), v (k, N+1), u (r, N), max |Psi_d|, cost, terminal error |x_N - x_r(T)|
    readout: list[ca.SX]
    admissibility_rows: list[int]
    dynamics_rows: list[int]


# the interior point and the working set's Newton step of one structure share its form;
# one horizon size per system is kept (a form at thousands of intervals is large)
_FORMS: PerSystemCache[_StageForm] = PerSystemCache(group=by_steps, groups=1)


def _shared_form(system: NonholonomicSystem, steps: int, terminal: str,
                 shape: Shape) -> _StageForm:
    return _FORMS.get(system.family, (steps, terminal, shape),
                      lambda: _stage_form(system, steps, terminal, shape))


def _stage_form(system: NonholonomicSystem, steps: int, terminal: str,
                shape: Shape) -> _StageForm:
    n, k, r, big_n = system.n, system.k, system.r, steps
    eliminated = system.fully_actuated
    nx = n + k
    xs = [ca.SX.sym(f'x{i}', nx) for i in range(big_n + 1)]
    us = [ca.SX.sym(f'u{i}', k + n + (0 if eliminated else r)) for i in range(big_n)]
    q0, v0 = ca.SX.sym('q0', n), ca.SX.sym('v0', k)
    q_mid, v_mid = ca.SX.sym('q_r', n * big_n), ca.SX.sym('v_r', k * big_n)
    q_end, v_end = ca.SX.sym('q_rT', n), ca.SX.sym('v_rT', k)
    h, eps, omega = ca.SX.sym('h'), ca.SX.sym('eps'), ca.SX.sym('omega')
    limits = Rows(shape, plane(system) if shape.slots else None, 2 * steps,
                  system.domain.bounded_coordinates)
    family = system.family  # its NLP serves every member: the parameters' values are in p
    physical = ca.SX.sym('physical', len(family.names))
    p = ca.vertcat(q0, v0, q_mid, v_mid, q_end, v_end, h, eps, omega, limits.obstacles,
                   physical)

    lagrangian, residual = tracking_lagrangian(system), tracking_residual(system)
    cost_residuals: list[ca.SX] = []
    zero = ca.DM.zeros(r)
    w: list[ca.SX] = []
    g = ConstraintStack()
    residuals: list[ca.SX] = []
    controls: list[ca.SX] = []
    adm_rows: list[int] = []
    dyn_rows: list[int] = []
    running = ca.SX(0)

    def knot_limits(x: ca.SX) -> None:
        g.add(*limits.velocity(x[n:], g.rows))
        g.add(*limits.clearance(x[:n], g.rows))
        g.add(*limits.configuration(x[:n], g.rows))

    for i in range(big_n):
        q, v = xs[i][:n], xs[i][n:]
        v_next, z = us[i][:k], us[i][k:k + n]
        vm = 0.5 * (v + v_next)
        drift = family.dynamics(z, vm, zero, physical)[1]
        u = (v_next - v) / h - drift if eliminated else us[i][k + n:]
        reference = (q_mid[i * n:(i + 1) * n], v_mid[i * k:(i + 1) * k])
        running += h * lagrangian(z, vm, u, *reference, eps)
        cost_residuals.append(ca.sqrt(h) * residual(z, vm, u, *reference, eps))
        controls.append(u)
        w += [xs[i], us[i]]
        g.add(xs[i + 1] - ca.vertcat(2 * z - q, v_next))  # dynamics first (fatrop)
        if i == 0:
            g.add(xs[0] - ca.vertcat(q0, v0))
        adm_rows.extend(range(g.rows, g.rows + n))
        g.add(z - q - 0.5 * h * family.rho(z, physical) @ vm)
        if not eliminated:
            dyn_rows.extend(range(g.rows, g.rows + k))
            g.add(v_next - v - h * (drift + family.input_matrix(z, physical) @ u))
        if i > 0:  # the start is data, not a decision
            knot_limits(xs[i])
        g.add(*limits.clearance(z, g.rows))  # the midpoint, where L is evaluated
        g.add(*limits.configuration(z, g.rows))
        g.add(*limits.control(u, g.rows))
        q_next = xs[i + 1][:n]
        qm = 0.5 * (q + q_next)
        residuals.append((q_next - q) / h
                         - family.rho(qm, physical) @ (0.5 * (v + xs[i + 1][n:])))
    w.append(xs[-1])
    knot_limits(xs[-1])
    limits.check_all_points_built()
    objective = running
    if terminal == 'cost':
        objective += 0.5 * omega * ca.sumsqr(xs[-1][:n] - q_end)
        cost_residuals.append(ca.sqrt(omega) * (xs[-1][:n] - q_end))
    else:
        g.add(xs[-1] - ca.vertcat(q_end, v_end))
    readout = [ca.horzcat(*[x[:n] for x in xs]), ca.horzcat(*[x[n:] for x in xs]),
               ca.horzcat(*controls), ca.mmax(ca.fabs(ca.horzcat(*residuals))), objective,
               ca.norm_2(xs[-1] - ca.vertcat(q_end, v_end))]
    parts: list[ca.SX] = [objective, ca.vertcat(*g.blocks), ca.vertcat(*cost_residuals)]
    if family.names:  # each stage's terms of the parameters alone, computed once
        parts = [ca.cse(part) for part in parts]
    objective, constraints, costs = parts
    return _StageForm(ca.vertcat(*w), p, objective, constraints, costs, limits, readout,
                      adm_rows, dyn_rows)


def _build(system: NonholonomicSystem, steps: int, terminal: str, solver: str,
           compiled: bool, bounded: bool, shape: Shape, iterations: int = 0) -> Transcription:
    form = _shared_form(system, steps, terminal, shape)
    limits, constraints = form.limits, form.constraints
    nlp = {'x': form.unknowns, 'p': form.p, 'f': form.objective, 'g': constraints}
    soft_index = None
    if shape.soft:
        nlp, soft_index = soften(nlp, limits)
    options: dict[str, Any] = {'print_time': False, 'show_eval_warnings': False}  # failures
    if solver == 'fatrop':  # are reported in the Solution
        options.update({'structure_detection': 'auto',
                        'equality': [bool(e) for e in
                                     ~limits.inequality_mask(constraints.shape[0])]})
    # a real-time iteration without limits is one Gauss-Newton step in one call: no NLP solver
    newton, bounded_nlp = None, None
    if iterations and not limits.kinds:
        newton = GaussNewtonStep(form.unknowns, form.p, form.cost_residuals, constraints,
                                 form.readout, compiled)
    else:
        bounded_nlp = BoundedNlp(f'variational_{system.name}_{steps}', solver, nlp, options,
                                 bounded, compiled, bool(limits.kinds), iterations)
    return Transcription(
        controls=0 if system.fully_actuated else system.r, steps=steps, terminal=terminal,
        nlp=bounded_nlp,
        readout=NumericFunction(ca.Function('readout', [form.unknowns, form.p], form.readout)),
        admissibility_rows=np.array(form.admissibility_rows, dtype=int),
        dynamics_rows=np.array(form.dynamics_rows, dtype=int), limits=limits,
        rows=constraints.shape[0], unknowns=form.unknowns.shape[0], soft_index=soft_index,
        newton=newton)


@dataclass
class WorkingSetStep:
    """The exact Newton step of an NLP with hard limits, and what a working set needs of it."""

    step: NewtonStep
    constraints: NumericFunction  # (w, p) -> g
    nonconvex: np.ndarray  # the clearance rows: a plan held at one is checked for a saddle


_STEPS: PerSystemCache[WorkingSetStep] = PerSystemCache(group=by_steps)


def working_set_step(system: NonholonomicSystem, steps: int, terminal: str,
                     shape: Shape, compiled: bool = False) -> WorkingSetStep:
    """Return the step for warm replans with hard limits of this shape, built on first use.

    A planner prepares it for the limits it has when it starts (its obstacles included); a
    shape met later inside a replanning loop is built in the background (NotPrepared until
    then: those replans are interior points). ``compiled``: its step as C (:class:`.NewtonStep`).
    """
    return _STEPS.get(system.family, (steps, terminal, shape, compiled),
                      lambda: _working_set_step(system, steps, terminal, shape, compiled))


def _working_set_step(system: NonholonomicSystem, steps: int, terminal: str,
                      shape: Shape, compiled: bool) -> WorkingSetStep:
    form = _shared_form(system, steps, terminal, shape)
    rows = form.constraints.shape[0]
    return WorkingSetStep(
        NewtonStep(form.unknowns, form.p, form.cost_residuals, form.constraints,
                   np.flatnonzero(form.limits.inequality_mask(rows)), compiled,
                   searched=not shape.slots),  # (a line search never meets obstacles)
        NumericFunction(ca.Function('constraints', [form.unknowns, form.p],
                                    [form.constraints])),
        form.limits.inequality_mask(rows, ('clear',)))
