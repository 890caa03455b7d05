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

"""Symbolic geometry of a nonholonomic system (G, V, D) in an adapted basis of D.

Everything here takes CasADi SX expressions in the coordinates ``q`` and returns SX expressions,
so the equations of the paper are *derived* (by automatic differentiation) from the system data
instead of typed in. Conventions follow the paper: ``rho`` is the (n, k) matrix of the basis
``e_A = rho^i_A d/dq^i``, ``G_D = rho^T G rho`` the metric on D, and the Christoffel symbols are
``nabla_{e_A} e_B = Gamma^C_{AB} e_C`` for the Levi-Civita connection of ``G_D`` whose torsion
is the nonholonomic bracket ``[[X, Y]] = P[X, Y]`` (P: G-orthogonal projection onto D).
"""
from __future__ import annotations

from collections.abc import Sequence
import itertools

import casadi as ca
import numpy as np

from nh_tracking.core import regularity


def directional_derivative(expr: ca.SX, q: ca.SX, direction: ca.SX) -> ca.SX:
    """Return D expr/dq . direction, for a matrix-valued ``expr`` (shape kept)."""
    flat = ca.reshape(expr, -1, 1)
    return ca.reshape(ca.jtimes(flat, q, direction), expr.shape[0], expr.shape[1])


def lie_bracket(x: ca.SX, y: ca.SX, q: ca.SX) -> ca.SX:
    """Coordinate Lie bracket [X, Y] = (dY/dq) X - (dX/dq) Y of two vector fields."""
    return ca.jtimes(y, q, x) - ca.jtimes(x, q, y)


def metric_on_distribution(metric: ca.SX, rho: ca.SX) -> ca.SX:
    """G_D(e_A, e_B) = rho^T G rho."""
    return rho.T @ metric @ rho


def basis_coefficients(metric: ca.SX, rho: ca.SX, w: ca.SX) -> ca.SX:
    """Coefficients in the basis e_A of the G-orthogonal projection P w of a vector onto D."""
    return ca.solve(metric_on_distribution(metric, rho), rho.T @ metric @ w)


def structure_functions(metric: ca.SX, rho: ca.SX, q: ca.SX) -> list[list[ca.SX]]:
    """C[A][B] = coefficients of the nonholonomic bracket [[e_A, e_B]] = P[e_A, e_B]."""
    k = rho.shape[1]
    c = [[ca.SX.zeros(k, 1) for _ in range(k)] for _ in range(k)]
    for a, b in itertools.combinations(range(k), 2):
        coeff = basis_coefficients(metric, rho, lie_bracket(rho[:, a], rho[:, b], q))
        c[a][b] = coeff
        c[b][a] = -coeff
    return c


def christoffel(metric: ca.SX, rho: ca.SX, q: ca.SX) -> ca.SX:
    """Christoffel symbols Gamma^C_{AB} of the nonholonomic connection, by the Koszul formula.

    Returned as a (k, k*k) matrix: row C, column A*k + B. Valid in any basis of D; the paper's
    formula (relation), built from structure constants alone, holds only in a G_D-orthonormal
    basis (docs/theory.md C2), so it is not used here.
    """
    k = rho.shape[1]
    g = metric_on_distribution(metric, rho)
    c = structure_functions(metric, rho, q)
    # e_A(g_BC): derivative of the metric on D along each basis field.
    dg = [directional_derivative(g, q, rho[:, a]) for a in range(k)]
    lowered = ca.SX.zeros(k, k * k)  # Gamma_{AB,C} = g(nabla_{e_A} e_B, e_C)
    for a, b, cc in itertools.product(range(k), repeat=3):
        lowered[cc, a * k + b] = 0.5 * (
            dg[a][b, cc] + dg[b][a, cc] - dg[cc][a, b]
            + (g @ c[a][b])[cc] - (g @ c[a][cc])[b] - (g @ c[b][cc])[a]
        )
    return ca.solve(g, lowered)


def quadratic_christoffel(gamma: ca.SX, v: ca.SX) -> ca.SX:
    """Gamma(v, v)^C = Gamma^C_{AB} v^A v^B, from the (k, k*k) layout of :func:`christoffel`."""
    return gamma @ ca.vec(v @ v.T)


def potential_force(metric: ca.SX, rho: ca.SX, potential: ca.SX, q: ca.SX) -> ca.SX:
    """grad_{G_D} V in the basis: G_D^{-1} rho^T dV/dq."""
    return ca.solve(metric_on_distribution(metric, rho), rho.T @ ca.gradient(potential, q))


def input_matrix(metric: ca.SX, rho: ca.SX, actuators: ca.SX | None) -> ca.SX:
    """Return B = G_D^{-1} rho^T F: how forces along the actuators' directions F move v.

    The identity when there are no actuators (one control per basis field).
    """
    if actuators is None:
        return ca.SX.eye(rho.shape[1])
    return ca.solve(metric_on_distribution(metric, rho), rho.T @ actuators)


def acceleration(gamma: ca.SX, inputs: ca.SX, metric: ca.SX, rho: ca.SX, potential: ca.SX,
                 q: ca.SX, v: ca.SX, u: ca.SX) -> ca.SX:
    """Return vdot = -Gamma(v, v) - grad_{G_D} V + B u: the controlled equations in v."""
    return (-quadratic_christoffel(gamma, v) - potential_force(metric, rho, potential, q)
            + inputs @ u)


def constraint_kernel_candidates(constraints: ca.SX) -> list[ca.SX]:
    """Polynomial vector fields spanning ker mu(q): generalised cross products of mu's rows.

    For every set S of m+1 columns, w_{S_j} = (-1)^j det(mu[:, S without S_j]) is annihilated by
    each row of mu (Laplace expansion of a determinant with a repeated row). Unlike a numerical
    null space these are smooth in q, so a basis built from them is smooth too.
    """
    m, n = constraints.shape
    candidates = []
    for cols in itertools.combinations(range(n), m + 1):
        w = ca.SX.zeros(n, 1)
        for j, col in enumerate(cols):
            rest = [c for c in cols if c != col]
            minor = ca.det(constraints[:, rest]) if m else ca.SX(1)
            w[col] = (-1) ** j * minor
        candidates.append(w)
    return candidates


def gram_schmidt(metric: ca.SX, vectors: list[ca.SX]) -> ca.SX:
    """G-orthonormalise ``vectors`` (in order) into the columns of an (n, k) matrix."""
    basis: list[ca.SX] = []
    for w in vectors:
        for e in basis:
            w = w - (e.T @ metric @ w) * e
        basis.append(w / ca.sqrt(w.T @ metric @ w))
    return ca.horzcat(*basis)


def projected_coordinate_fields(metric: ca.SX, constraints: ca.SX) -> list[ca.SX]:
    """P d/dq^i: the G-orthogonal projections of the coordinate fields onto D = ker mu."""
    n = metric.shape[0]
    if constraints.shape[0] == 0:
        return [ca.SX.eye(n)[:, i] for i in range(n)]
    g_inv_mu = ca.solve(metric, constraints.T)
    projector = ca.SX.eye(n) - g_inv_mu @ ca.solve(constraints @ g_inv_mu, constraints)
    return [projector[:, i] for i in range(n)]


def select_best_conditioned(
    gram: np.ndarray, k: int, max_exhaustive: int = 500
) -> tuple[tuple[int, ...], float]:
    """Choose k of the candidate fields that stay farthest from dependent over the samples.

    ``gram`` has shape (samples, c, c): the G-Gram matrix of all c candidates at sample
    points. Each candidate is scaled by one constant (its RMS length over the samples), not per
    sample, so a field that vanishes somewhere scores low. Returns the chosen indices and their
    worst smallest Gram eigenvalue: near 0 means the fields become dependent somewhere sampled.
    """
    scale = np.sqrt(np.einsum('sii->i', gram) / gram.shape[0])
    scale[scale == 0] = np.inf
    scaled = gram / scale[None, :, None] / scale[None, None, :]

    def score(idx: tuple[int, ...]) -> float:
        sub = scaled[:, idx][:, :, idx]
        return float(np.linalg.eigvalsh(sub)[:, 0].min())

    c = gram.shape[1]
    combos = list(itertools.islice(itertools.combinations(range(c), k), max_exhaustive + 1))
    if len(combos) <= max_exhaustive:
        best = max(combos, key=score)
        return best, score(best)
    chosen: tuple[int, ...] = ()  # greedy when exhaustive search is too large
    for _ in range(k):
        chosen = max((chosen + (i,) for i in range(c) if i not in chosen), key=score)
    return chosen, score(chosen)


def orthonormal_basis(q: ca.SX, g: ca.SX, mu: ca.SX, k: int, samples: np.ndarray,
                      coordinates: Sequence[str]) -> tuple[ca.SX, float]:
    """G-orthonormalise the k best-conditioned candidate fields, judged before (a ValueError).

    Candidates are the smooth kernel fields of mu and the projected coordinate fields.
    """
    candidates = constraint_kernel_candidates(mu) + projected_coordinate_fields(g, mu)
    w = ca.horzcat(*candidates)
    gram_fn = ca.Function('gram', [q], [w.T @ g @ w])
    gram = np.stack([np.array(gram_fn(s)) for s in samples])
    chosen, _ = select_best_conditioned(gram, k)
    fields = [candidates[i] for i in chosen]
    condition = regularity.basis_condition(
        regularity.numeric_map(q, ca.horzcat(*fields), g), samples, coordinates,
        'the basis of D built from the constraints (pass basis= explicitly)')
    return gram_schmidt(g, fields), condition
