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

"""One Gauss-Newton step on the KKT conditions: a real-time iteration in a single call.

The tracking cost is a sum of squares, 1/2 |r(w, p)|^2, so its Gauss-Newton Hessian JᵀJ needs
no multipliers and is positive definite wherever the controls enter r (they always do: eps > 0).
Without inequalities a real-time iteration is then the equality-constrained QP

    [JᵀJ + ρI   Gᵀ ] [dw]   [-Jᵀr]
    [G         -δI ] [λ ] = [-g  ]

(ρ, δ tiny: the matrix becomes quasi-definite, so a sparse LDLᵀ needs no pivoting; δ shifts the
fixed point by δλ in g, so it is kept far below any tolerance), assembled and
factorised inside one CasADi function: no solver set-up per call, one call per step. λ are the
multipliers of g = 0 in CasADi's sign convention (∇f + Gᵀλ = 0 at a solution).
"""
from __future__ import annotations

from collections.abc import Callable

import casadi as ca
import numpy as np

from nh_tracking.numeric import NumericFunction

REGULARISATION = 1e-10  # of JᵀJ: the step only, no bias at the solution
DUAL_REGULARISATION = 1e-13  # of the (2, 2) block: the solution moves by about this times λ


class GaussNewtonStep:
    """(w, p, active, target, curvature, weight) -> (w + dw, λ, g + G dw, |stationarity|).

    The step of min 1/2 |residual|^2 subject to the rows of g in the working set (``active``
    1) held at ``target`` — linearised, g_i + G_i dw = target_i — and the others left free
    (their λ_i = 0): a free row becomes -λ_i = 0 in the same matrix, so one function, one
    sparsity and one factorisation pattern serve every working set. Equalities are rows always
    active with target 0. The Hessian is JᵀJ (Gauss-Newton, positive semi-definite); built
    ``exact``, it adds ``weight`` times the residuals' own curvature and the constraints'
    curvature weighted by ``curvature`` (the last multipliers): the Lagrangian's Hessian at
    weight 1. Built not exact (a real-time iteration's step), the last two inputs are unused
    and the matrix has less fill-in. Stationarity is |Jᵀr + Gᵀλ|∞ at w with the new
    multipliers: zero at a KKT point.
    """

    def __init__(self, w: ca.SX, p: ca.SX, residual: ca.SX, g: ca.SX, exact: bool) -> None:
        jac_r, jac_g = ca.jacobian(residual, w), ca.jacobian(g, w)
        nw, self.rows = w.shape[0], g.shape[0]
        active, target = ca.SX.sym('active', self.rows), ca.SX.sym('target', self.rows)
        curvature, weight = ca.SX.sym('curvature', self.rows), ca.SX.sym('exact')
        held = ca.times(ca.repmat(active, 1, nw), jac_g)  # the sparsity of G, rows off
        hessian = ca.mtimes(jac_r.T, jac_r) + REGULARISATION * ca.SX.eye(nw)
        if exact:  # + sum r_i Hess r_i (the rest of Hess 1/2|r|^2) + sum lambda_i Hess g_i
            weights = ca.SX.sym('weights', residual.shape[0])
            hessian += ca.substitute(ca.hessian(ca.dot(weights, residual), w)[0], weights,
                                     weight * residual)
            hessian += ca.hessian(ca.dot(curvature, g), w)[0]
        dual = ca.diag(1 - active + DUAL_REGULARISATION * active)
        kkt = ca.blockcat([[hessian, held.T], [held, -dual]])
        gradient = ca.mtimes(jac_r.T, residual)
        rhs = ca.vertcat(-gradient, active * (target - g))
        inputs = [w, p, active, target, curvature, weight]
        self._sparsity = kkt.sparsity()  # the matrix as its nonzeros: a fast buffered call
        self._kkt = NumericFunction(ca.Function('gauss_newton_kkt', inputs, [kkt.nz[:]]))
        assemble = ca.Function('gauss_newton_system', inputs, [kkt, rhs, g, jac_g, gradient])
        symbols = [ca.MX.sym('w', nw), ca.MX.sym('p', p.shape[0])] + [
            ca.MX.sym(name, self.rows) for name in ('active', 'target', 'curvature')] + [
            ca.MX.sym('exact')]
        matrix, vector, values, jacobian, grad = assemble(*symbols)
        step = ca.solve(matrix, vector, 'ldl')
        dw, multipliers = step[:nw], step[nw:]
        stationarity = ca.mmax(ca.fabs(grad + ca.mtimes(jacobian.T, multipliers)))
        self._step = NumericFunction(ca.Function(
            'gauss_newton_step', symbols,
            [symbols[0] + dw, multipliers, values + ca.mtimes(jacobian, dw), stationarity]))
        self._inertia: ca.Linsol | None = None

    def __call__(self, *args: np.ndarray | float) -> list[np.ndarray]:
        return self._step(*args)

    def minimum(self, *args: np.ndarray | float) -> bool:
        """Whether the model at (w, p, active, target, curvature) curves up on the held rows.

        Its KKT matrix then has exactly one negative eigenvalue per row of g (Sylvester's law
        of inertia on an LDLᵀ factorisation); one more is a direction of negative curvature
        along the held limits — a saddle, which Newton's method converges to as readily as
        to a minimum (going round an obstacle is not convex).
        """
        matrix = ca.DM(self._sparsity, self._kkt(*args)[0])
        if self._inertia is None:
            self._inertia = ca.Linsol('gauss_newton_inertia', 'ldl', self._sparsity)
            self._inertia.sfact(matrix)
        self._inertia.nfact(matrix)
        return int(self._inertia.neig(matrix)) == self.rows


def newton_steps(step: GaussNewtonStep, w: np.ndarray, p: np.ndarray, iterations: int,
                 residual: Callable[[np.ndarray], float], tolerance: float, most: int
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """Take ``iterations`` steps from w, then more while the residual is above ``tolerance``.

    At most ``most`` steps in all, and none once the residual grows (far from the solution,
    where Gauss-Newton without a line search diverges: a converged solve is the caller's
    remedy). Returns the unknowns, the last multipliers and the number of steps taken; the
    last call of ``residual`` was at the unknowns returned (callers reuse what it read). A step
    costs a tenth of a millisecond, so a plan that one step leaves short of admissible (the
    robot off the previous plan by centimetres) gets another rather than a converged solve.
    """
    multipliers, taken, last = np.zeros(0), 0, np.inf
    every, zero = np.ones(step.rows), np.zeros(step.rows)  # equalities: all held at 0
    while taken < most:
        w, multipliers = step(w, p, every, zero, zero, 0.0)[:2]
        taken += 1
        if taken >= iterations:
            now = residual(w)
            if now <= tolerance or now >= last:
                break
            last = now
    return w, multipliers, taken
