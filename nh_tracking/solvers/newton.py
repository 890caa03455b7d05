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


def gauss_newton_step(w: ca.SX, p: ca.SX, residual: ca.SX, g: ca.SX) -> NumericFunction:
    """Return (w, p) -> (w + dw, λ) for min 1/2 |residual|^2 subject to g = 0."""
    jac_r, jac_g = ca.jacobian(residual, w), ca.jacobian(g, w)
    nw, ng = w.shape[0], g.shape[0]
    hessian = ca.mtimes(jac_r.T, jac_r) + REGULARISATION * ca.SX.eye(nw)
    kkt = ca.blockcat([[hessian, jac_g.T], [jac_g, -DUAL_REGULARISATION * ca.SX.eye(ng)]])
    rhs = ca.vertcat(-ca.mtimes(jac_r.T, residual), -g)
    assemble = ca.Function('gauss_newton_kkt', [w, p], [kkt, rhs])
    w_mx, p_mx = ca.MX.sym('w', nw), ca.MX.sym('p', p.shape[0])
    matrix, vector = assemble(w_mx, p_mx)
    step = ca.solve(matrix, vector, 'ldl')
    return NumericFunction(ca.Function('gauss_newton_step', [w_mx, p_mx],
                                       [w_mx + step[:nw], step[nw:]]))


def newton_steps(step: NumericFunction, w: np.ndarray, p: np.ndarray, iterations: int,
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
    while taken < most:
        w, multipliers = step(w, p)
        taken += 1
        if taken >= iterations:
            now = residual(w)
            if now <= tolerance or now >= last:
                break
            last = now
    return w, multipliers, taken
