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

"""Steps on the KKT conditions, each one CasADi call: real-time iterations and working sets.

The tracking cost is a sum of squares, 1/2 |r(w, p)|^2, so its Gauss-Newton Hessian JᵀJ needs
no multipliers and is positive definite wherever the controls enter r (they always do: eps > 0).
Without inequalities a real-time iteration is then the equality-constrained QP

    [JᵀJ + ρI   Gᵀ ] [dw]   [-Jᵀr]
    [G         -δI ] [λ ] = [-g  ]

(ρ, δ tiny: the matrix becomes quasi-definite, so a sparse LDLᵀ needs no pivoting; δ shifts the
fixed point by δλ in g, so it is kept far below any tolerance), assembled and
factorised inside one CasADi function: no solver set-up per call, one call per step. λ are the
multipliers of g = 0 in CasADi's sign convention (∇f + Gᵀλ = 0 at a solution). The working
set's step (:class:`NewtonStep`) holds only some rows and takes the Lagrangian's exact Hessian,
which may be indefinite: the same LDLᵀ then leaves a residual (about 4e-4 relative) that the
next step corrects (docs/theory.md §5).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

import casadi as ca
import numpy as np

from nh_tracking.core.numeric import NumericFunction
from nh_tracking.solvers.compiled import LibraryBuild

Symbolic = TypeVar('Symbolic', ca.SX, ca.MX)

REGULARISATION = 1e-10  # of JᵀJ: the step only, no bias at the solution
DUAL_REGULARISATION = 1e-13  # of the (2, 2) block: the solution moves by about this times λ
# ... of the working set's Newton step, which takes the last multipliers: a proximal term,
# -δ(λ - λ_last), so the solution does not move, and a δ large enough for the unpivoted LDLᵀ to
# stay accurate on an indefinite Hessian
PROXIMAL_REGULARISATION = 1e-10
DIRECTION_LDL = 'newton_direction_ldl'  # the line search's direction, written out (compiled)


def _kkt(w: ca.SX, residual: ca.SX, g: ca.SX, active: ca.SX | ca.DM, target: ca.SX | ca.DM,
         hessian: ca.SX | None, dual_regularisation: float = DUAL_REGULARISATION,
         last: ca.SX | int = 0) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
    """Return the KKT matrix and right-hand side of a step, G and Jᵀr.

    Rows of g with ``active`` 1 are held at ``target`` (linearised: g_i + G_i Δw = target_i),
    the others are free (their λ_i = 0: the row reads -λ_i = 0 in the same matrix, so one
    sparsity and one factorisation pattern serve every working set). The Hessian is
    ``hessian``, or JᵀJ if None (Gauss-Newton). Held rows read G_i Δw - δ(λ_i - last_i) =
    target_i - g_i: at a fixed point with λ = ``last`` they hold exactly.
    """
    jac_r, jac_g = ca.jacobian(residual, w), ca.jacobian(g, w)
    held = ca.mtimes(ca.diag(active), jac_g)  # the sparsity of G, rows off (no dense mask)
    if hessian is None:
        hessian = ca.mtimes(jac_r.T, jac_r)
    hessian = hessian + REGULARISATION * ca.SX.eye(w.shape[0])
    dual = ca.diag(1 - active + dual_regularisation * active)
    gradient = ca.mtimes(jac_r.T, residual)
    return (ca.blockcat([[hessian, held.T], [held, -dual]]),
            ca.vertcat(-gradient, active * (target - g - dual_regularisation * last)), jac_g,
            gradient)


def _solve(w: ca.SX, p: ca.SX, inputs: list[ca.SX], matrix: ca.SX, vector: ca.SX,
           extra: list[ca.SX]) -> tuple[list[ca.MX], ca.MX, ca.MX, list[ca.MX]]:
    """Return MX inputs, Δw, λ and ``extra`` of the step: assembled as SX, factorised as MX."""
    assemble = ca.Function('gauss_newton_system', [w, p, *inputs], [matrix, vector, *extra])
    symbols = [ca.MX.sym(f'input{i}', x.sparsity()) for i, x in enumerate([w, p, *inputs])]
    matrix_mx, vector_mx, *extra_mx = assemble(*symbols)
    step = ca.solve(matrix_mx, vector_mx, 'ldl')
    return symbols, step[:w.shape[0]], step[w.shape[0]:], extra_mx


def _written_out_solve(w: ca.SX, p: ca.SX, inputs: list[ca.SX], matrix: ca.SX, vector: ca.SX,
                       extra: list[ca.SX]) -> tuple[list[ca.SX], ca.SX, ca.SX, list[ca.SX]]:
    """:func:`_solve` with the LDLᵀ written out: expressions throughout (to compile)."""
    solution, _ = _written_out_ldl(matrix, vector)
    return [w, p, *inputs], solution[:w.shape[0]], solution[w.shape[0]:], extra


def _violation(g: Symbolic, inequality: np.ndarray, lower: Symbolic,
               upper: Symbolic) -> tuple[Symbolic, Symbolic]:
    """Return how far g breaks its rows: |g| of the equalities, and the inequality rows'.

    (lower <= g[inequality] <= upper: max(lower - g, g - upper, 0).) Without inequality rows
    g itself: no indexing, the same expressions as an equality-only NLP's.
    """
    if not len(inequality):
        return ca.fabs(g), type(g)(0, 1)
    equality = np.setdiff1d(np.arange(g.shape[0]), inequality)
    held = g[inequality.tolist()]
    return (ca.fabs(g[equality.tolist()]) if len(equality) else type(g)(0, 1),
            ca.fmax(ca.fmax(lower - held, held - upper), 0))


def _merit(residual: ca.SX, g: ca.SX, inequality: np.ndarray, lower: ca.SX,
           upper: ca.SX) -> list[ca.SX]:
    """Return f = 1/2 |r|^2 and the infeasibility: the sum of :func:`_violation`."""
    equalities, inequalities = _violation(g, inequality, lower, upper)
    return [0.5 * ca.sumsqr(residual), ca.sum1(equalities) + ca.sum1(inequalities)]


def _direction(w: ca.SX, p: ca.SX, inputs: list[ca.SX], matrix: ca.SX, vector: ca.SX,
               extra: list[ca.SX], inequality: np.ndarray, merit: ca.Function,
               written_out: bool = False) -> ca.Function:
    """Return the step of ``matrix`` with a shift on its Hessian block, and its merits.

    dwᵀ(H + shift I)dw comes from the KKT rows themselves, -∇fᵀdw - λᵀG dw: no product
    with the Hessian is formed. ``written_out``: the LDLᵀ as expressions (to compile).
    """
    n, rows = w.shape[0], matrix.shape[0] - w.shape[0]
    shift = ca.SX.sym('shift')
    lower, upper = (ca.SX.sym(name, len(inequality)) for name in ('lower', 'upper'))
    shifted = matrix + ca.diagcat(shift * ca.SX.eye(n), ca.SX(rows, rows))
    solve: Callable[..., tuple[list[Any], Any, Any, list[Any]]] = \
        _written_out_solve if written_out else _solve
    symbols, dw, multipliers, (g, jac_g, gradient) = solve(
        w, p, [*inputs, shift, lower, upper], shifted, vector, extra)
    slope = ca.dot(gradient, dw)
    linearised = ca.mtimes(jac_g, dw)
    curvature = -slope - ca.dot(multipliers, linearised)
    lower_mx, upper_mx = symbols[-2:]
    worst = ca.mmax(ca.vertcat(*_violation(g, inequality, lower_mx, upper_mx)))
    full = merit(symbols[0] + dw, symbols[1], lower_mx, upper_mx)
    reached = (g + linearised)[inequality.tolist()]
    return ca.Function(DIRECTION_LDL if written_out else 'newton_direction', symbols,
                       [dw, multipliers, slope, curvature, worst, *full, reached])


class GaussNewtonStep:
    """(w, p) -> (w + dw, λ, *readout at w + dw) for min 1/2 |residual|^2 subject to g = 0.

    The read-out of the new unknowns (the plan, its admissibility) comes with the step: one
    call fewer per step. Interpreted, the KKT system is factorised by CasADi's sparse LDLᵀ;
    ``compiled``, the factorisation is written out symbolically (fill-reducing order: slower
    than CasADi's LDLᵀ interpreted, faster as C), compiled in the background (:mod:`.compiled`)
    and swapped in when ready.
    """

    def __init__(self, w: ca.SX, p: ca.SX, residual: ca.SX, g: ca.SX, readout: list[ca.SX],
                 compiled: bool = False) -> None:
        rows = g.shape[0]
        matrix, vector, _, _ = _kkt(w, residual, g, ca.DM.ones(rows), ca.DM.zeros(rows), None)
        symbols, dw, multipliers, _ = _solve(w, p, [], matrix, vector, [])
        read = ca.Function('readout', [w, p], readout)
        stepped = symbols[0] + dw
        self._call = NumericFunction(ca.Function(
            'gauss_newton_step', symbols, [stepped, multipliers, *read(stepped, symbols[1])]))
        self.compiled = False
        if compiled:
            step, _ = _written_out_ldl(matrix, vector)
            new = w + step[:w.shape[0]]
            function = ca.Function('gauss_newton_step_ldl', [w, p],
                                   [new, step[w.shape[0]:], *read(new, p)])
            LibraryBuild.of_function(function).when_ready(self._use_library)

    def _use_library(self, library: Path) -> None:
        """Switch to the compiled step (on the compiler's thread; steps go on meanwhile)."""
        self._call = NumericFunction(ca.external('gauss_newton_step_ldl', str(library)))
        self.compiled = True

    def __call__(self, w: np.ndarray, p: np.ndarray) -> list[np.ndarray]:
        return self._call(w, p)


class Inertia(ca.Callback):
    """KKT matrix -> its number of negative eigenvalues (an LDLᵀ factorisation's D).

    A callback, so a Function computes the matrix and hands it over as CasADi's own matrix:
    assembled from numpy arguments through buffers, the check skips a plain Function call's
    conversions. Its factorisation's pattern is analysed on the first call.
    One call at a time: its one caller is a :class:`~nh_tracking.core.numeric.NumericFunction`,
    whose lock covers the call (steps are shared by the planners of a process).
    """

    def __init__(self, sparsity: ca.Sparsity) -> None:
        ca.Callback.__init__(self)
        self._sparsity = sparsity
        self._linsol: ca.Linsol | None = None
        self.construct('kkt_inertia', {})

    def get_n_in(self) -> int:
        return 1

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return self._sparsity

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(1, 1)

    def eval(self, arg: Sequence[ca.DM]) -> list[ca.DM]:  # noqa: A003 (CasADi calls it)
        matrix = arg[0]
        if self._linsol is None:
            self._linsol = ca.Linsol('kkt_ldl', 'ldl', self._sparsity)
            self._linsol.sfact(matrix)
        self._linsol.nfact(matrix)
        return [ca.DM(self._linsol.neig(matrix))]


def _written_out_ldl(matrix: ca.SX, vector: ca.SX) -> tuple[ca.SX, ca.SX]:
    """Return matrix⁻¹ vector and D, by CasADi's fill-reducing LDLᵀ written out symbolically."""
    d, lt, order = ca.ldl(matrix, True)
    return ca.ldl_solve(vector, d, lt, order), d


def _written_out_step(inputs: list[ca.SX], matrix: ca.SX, vector: ca.SX, g: ca.SX,
                      jac_g: ca.SX, gradient: ca.SX) -> ca.Function:
    """Return :class:`NewtonStep`'s step with its inertia, the LDLᵀ written out (to compile).

    The same fill-reducing, unpivoted factorisation as CasADi's sparse ``ldl``: D's negative
    entries count the KKT matrix's negative eigenvalues.
    """
    w = inputs[0]
    solution, d = _written_out_ldl(matrix, vector)
    dw, multipliers = solution[:w.shape[0]], solution[w.shape[0]:]
    return ca.Function('newton_step_ldl', inputs, [
        w + dw, multipliers, g + ca.mtimes(jac_g, dw),
        ca.mmax(ca.fabs(gradient + ca.mtimes(jac_g.T, multipliers))), ca.sum1(d < 0)])


class _Outputs:
    """Some of a function's outputs: the compiled step gives the inertia beside the step."""

    def __init__(self, function: NumericFunction, outputs: slice) -> None:
        self._function, self._outputs = function, outputs

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        return self._function(*args)[self._outputs]


class NewtonStep:
    """(w, p, active, target, curvature) -> (w + dw, λ, g + G dw, |stationarity|).

    The Newton step of min 1/2 |residual|^2 subject to the rows of g in the working set
    (``active`` 1) held at ``target``, the others free (see :func:`_kkt`); equalities are rows
    always held at 0. Its Hessian is the Lagrangian's: JᵀJ + Σ r_i ∇²r_i + Σ λ_i ∇²g_i with λ
    = ``curvature`` (the last multipliers) — an obstacle's curvature 2λ on the held positions
    is what Gauss-Newton leaves out. Stationarity is |Jᵀr + Gᵀλ|∞ at w with the new
    multipliers: zero at a KKT point. ``compiled``: the step, its factorisation written out
    (the same fill-reducing LDLᵀ) with the inertia beside it, and the line search's direction
    likewise (where a line search may ask for it: ``searched``), as C built in the background
    and swapped in when ready.
    """

    def __init__(self, w: ca.SX, p: ca.SX, residual: ca.SX, g: ca.SX,
                 inequality: np.ndarray | None = None, compiled: bool = False,
                 searched: bool = True) -> None:
        self.rows = g.shape[0]
        # the rows of g with bounds: a line search's infeasibility counts them apart
        self.inequality = np.zeros(0, dtype=int) if inequality is None else np.asarray(
            inequality, dtype=int)
        active, target, curvature = (ca.SX.sym(name, self.rows)
                                     for name in ('active', 'target', 'curvature'))
        # JᵀJ + Σ r_i ∇²r_i + Σ λ_i ∇²g_i in one differentiation: fewer instructions than in parts
        lagrangian = ca.hessian(0.5 * ca.sumsqr(residual) + ca.dot(curvature, g), w)[0]
        matrix, vector, jac_g, gradient = _kkt(w, residual, g, active, target, lagrangian,
                                               PROXIMAL_REGULARISATION, curvature)
        inputs = [active, target, curvature]
        symbols, dw, multipliers, (values, jacobian, grad) = _solve(
            w, p, inputs, matrix, vector, [g, jac_g, gradient])
        stationarity = ca.mmax(ca.fabs(grad + ca.mtimes(jacobian.T, multipliers)))
        self._step: Callable[..., list[np.ndarray]] = NumericFunction(ca.Function(
            'newton_step', symbols,
            [symbols[0] + dw, multipliers, values + ca.mtimes(jacobian, dw), stationarity]))
        lower, upper = (ca.SX.sym(name, len(self.inequality)) for name in ('lower', 'upper'))
        merit = ca.Function('merit', [w, p, lower, upper],
                            _merit(residual, g, self.inequality, lower, upper))
        # (w, p, lower, upper) -> f, infeasibility: a line search's trial points
        self.merit = NumericFunction(merit)
        self._direction = NumericFunction(_direction(w, p, inputs, matrix, vector,
                                                     [g, jac_g, gradient], self.inequality,
                                                     merit))
        self.direction_compiled = False
        kkt = ca.Function('newton_kkt', [w, p, *inputs], [matrix])
        self._inertia = Inertia(matrix.sparsity())  # (kept: the Function below calls it)
        self._negative: Callable[..., list[np.ndarray]] = NumericFunction(ca.Function(
            'newton_inertia', symbols, [self._inertia(kkt(*symbols))]))
        self.compiled = False
        if compiled:  # swapped in when built
            LibraryBuild.of_function(_written_out_step(
                [w, p, *inputs], matrix, vector, g, jac_g, gradient)).when_ready(
                    self._use_library)
        if compiled and searched:
            LibraryBuild.of_function(_direction(
                w, p, inputs, matrix, vector, [g, jac_g, gradient], self.inequality, merit,
                written_out=True)).when_ready(self._use_direction_library)

    def _use_library(self, library: Path) -> None:
        """Switch to the compiled step (on the compiler's thread; steps go on meanwhile)."""
        step = NumericFunction(ca.external('newton_step_ldl', str(library)))
        self._step, self._negative = _Outputs(step, slice(0, 4)), _Outputs(step, slice(4, 5))
        self.compiled = True

    def _use_direction_library(self, library: Path) -> None:
        """Switch to the compiled direction (on the compiler's thread)."""
        self._direction = NumericFunction(ca.external(DIRECTION_LDL, str(library)))
        self.direction_compiled = True

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        return self._step(*args)

    def direction(self, *args: np.ndarray | float) -> list[np.ndarray]:
        """(w, p, active, target, curvature, shift, lower, upper) -> a line search's view.

        The step of the KKT system with ``shift`` added to the Hessian's diagonal, and
        (dw, λ, ∇fᵀdw, dwᵀ(H + shift I)dw, the largest violation at w, f and the
        infeasibility at w + dw, g + G dw of the inequality rows): what
        :func:`.line_search.line_search_solve` decides on, in one call. ``lower``, ``upper``:
        the bounds of the inequality rows (equalities are g = 0).
        """
        return self._direction(*args)

    def minimum(self, *args: np.ndarray) -> bool:
        """Whether the model at (w, p, active, target, curvature) curves up on the held rows.

        Its KKT matrix then has exactly one negative eigenvalue per row of g (Sylvester's law
        of inertia on an LDLᵀ factorisation); one more is a direction of negative curvature
        along the held limits — a saddle, which Newton's method converges to as readily as
        to a minimum (going round an obstacle is not convex).
        """
        return int(self._negative(*args)[0][0]) == self.rows


def newton_steps(step: Callable[[np.ndarray, np.ndarray], list[np.ndarray]], w: np.ndarray,
                 p: np.ndarray, iterations: int, residual: Callable[[list[np.ndarray]], float],
                 tolerance: float, most: int
                 ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], int]:
    """Take ``iterations`` steps from w, then more while the residual is above ``tolerance``.

    At most ``most`` steps in all, and none once the residual grows (far from the solution,
    where Gauss-Newton without a line search diverges: a converged solve is the caller's
    remedy). ``residual`` reads it from what a step returns beside (w, λ). Returns the
    unknowns, the last multipliers, what came with them and the number of steps taken. A step
    is one CasADi call, far cheaper than a converged solve, so a plan that one step leaves short
    of admissible (the robot off the previous plan by centimetres) gets another step instead.
    """
    multipliers, read, taken, last = np.zeros(0), [], 0, np.inf
    while taken < most:
        w, multipliers, *read = step(w, p)
        taken += 1
        if taken >= iterations:
            now = residual(read)
            if now <= tolerance or now >= last:
                break
            last = now
    return w, multipliers, read, taken
