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


"""The Newton backends on their own, on small problems whose solutions are known independently.

Each solves min 1/2 |r(w)|^2 subject to lower <= g(w) <= upper (rows with equal bounds are
equalities): the filter line search (cold starts) and the working set (warm starts), against a
KKT system solved by numpy, scipy's bounded least squares and SLSQP.
"""
import casadi as ca
import numpy as np
import pytest
from scipy.optimize import lsq_linear, minimize

from nh_tracking.core.numeric import NumericFunction
from nh_tracking.solvers.compiled import wait_for_builds
from nh_tracking.solvers.line_search import line_search_solve, LineSearchOptions
from nh_tracking.solvers.newton import NewtonStep
from nh_tracking.solvers.nlp import Pace
from nh_tracking.solvers.working_set import working_set_solve, WorkingSetOptions

pytestmark = pytest.mark.unit

RNG = np.random.default_rng(7)
A, B = RNG.normal(size=(5, 3)), RNG.normal(size=5)
C, D = np.array([[1.0, 2.0, -1.0]]), np.array([0.5])


class Problem:
    """min 1/2 |r(w)|^2 s.t. lower <= g(w) <= upper, its Newton step and g as a function."""

    def __init__(self, residual, g, lower, upper, size, compiled=False):
        self.w, p = ca.SX.sym('w', size), ca.SX.sym('p', 0)
        r, rows = residual(self.w), g(self.w)
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        inequality = np.flatnonzero(self.lower != self.upper)
        self.step = NewtonStep(self.w, p, r, rows, inequality, compiled)
        self.g = NumericFunction(ca.Function('g', [self.w, p], [rows]))
        self.cost = ca.Function('f', [self.w], [0.5 * ca.sumsqr(r)])

    def line_search(self, w0):
        outcome = line_search_solve(self.step, np.asarray(w0, float), np.zeros(0), self.lower,
                                    self.upper, None)
        return outcome, outcome.iterate.w

    def working_set(self, w0):
        return working_set_solve(self.step, self.g, np.asarray(w0, float), np.zeros(0),
                                 self.lower, self.upper,
                                 np.zeros(len(self.lower), dtype=bool), Pace(None))


def _kkt_solution(a, b, c, d):
    """Equality-constrained least squares by its KKT system (numpy)."""
    n, m = a.shape[1], c.shape[0]
    matrix = np.block([[a.T @ a, c.T], [c, np.zeros((m, m))]])
    return np.linalg.solve(matrix, np.concatenate([a.T @ b, d]))[:n]


def test_an_equality_constrained_least_squares_qp():
    problem = Problem(lambda w: ca.mtimes(ca.DM(A), w) - B,
                      lambda w: ca.mtimes(ca.DM(C), w) - D, [0.0], [0.0], 3)
    expected = _kkt_solution(A, B, C, D)
    outcome, w = problem.line_search(np.zeros(3))
    assert outcome.success and outcome.minimum
    assert w == pytest.approx(expected, abs=1e-9)
    held = problem.working_set(expected + 0.01)
    assert held is not None and held.w == pytest.approx(expected, abs=1e-9)


def test_each_backend_takes_its_options():
    """Budgets from the options dataclasses: one too small hands the solve over, and says so."""
    problem = Problem(lambda w: ca.mtimes(ca.DM(A), w) - B,
                      lambda w: ca.mtimes(ca.DM(C), w) - D, [0.0], [0.0], 3)
    expected = _kkt_solution(A, B, C, D)
    held = problem.working_set(expected + 0.01)
    assert held is not None and held.factorisations >= 2
    assert working_set_solve(problem.step, problem.g, expected + 0.01, np.zeros(0),
                             problem.lower, problem.upper, np.zeros(1, dtype=bool), Pace(None),
                             options=WorkingSetOptions(max_factorisations=1)) is None
    outcome = line_search_solve(problem.step, np.zeros(3), np.zeros(0), problem.lower,
                                problem.upper, None, LineSearchOptions(max_iterations=1))
    assert not outcome.success and outcome.message == 'iteration budget spent'
    for bad in ({'max_qp_factorisations': 0}, {'max_iterations': 2.5}):
        with pytest.raises(ValueError, match='must be an integer >= 1'):
            LineSearchOptions(**bad)
    with pytest.raises(ValueError, match='max_factorisations must be an integer >= 1'):
        WorkingSetOptions(max_factorisations=0)


def test_a_bounded_least_squares_qp_with_active_bounds():
    lo, hi = np.array([-0.2, -1.0, 0.0]), np.array([0.2, 1.0, 0.1])
    expected = lsq_linear(A, B, bounds=(lo, hi), tol=1e-12).x
    assert np.any(np.isclose(expected, lo) | np.isclose(expected, hi))  # some bound active
    problem = Problem(lambda w: ca.mtimes(ca.DM(A), w) - B, lambda w: w, lo, hi, 3)
    outcome, w = problem.line_search(np.array([1.0, -2.0, 0.5]))  # a cold start off bounds
    assert outcome.success and w == pytest.approx(expected, abs=1e-7)
    held = problem.working_set(np.clip(expected + 0.05, lo, hi))
    assert held is not None and held.w == pytest.approx(expected, abs=1e-7)
    assert held.active == int(np.sum(np.isclose(expected, lo) | np.isclose(expected, hi)))


def test_rosenbrock_inside_the_unit_disc():
    """The constrained optimum lies on the circle; SLSQP finds it independently."""
    problem = Problem(lambda w: ca.vertcat(10 * (w[1] - w[0] ** 2), 1 - w[0]),
                      lambda w: ca.sumsqr(w), [-np.inf], [1.0], 2)
    f = lambda w: 0.5 * (100 * (w[1] - w[0] ** 2) ** 2 + (1 - w[0]) ** 2)  # noqa: E731
    expected = minimize(f, [0.0, 0.0], method='SLSQP', tol=1e-14, constraints=[
        {'type': 'ineq', 'fun': lambda w: 1.0 - w @ w}]).x
    assert expected @ expected == pytest.approx(1.0, abs=1e-8)
    outcome, w = problem.line_search([-1.0, 0.5])
    assert outcome.success and w == pytest.approx(expected, abs=1e-6)
    held = problem.working_set(0.99 * expected)
    assert held is not None and held.w == pytest.approx(expected, abs=1e-6)


def test_a_saddle_is_not_called_converged():
    """Residuals (w1^2 - 1, w2): minima at w1 = +-1, a saddle at the origin symmetry keeps."""
    problem = Problem(lambda w: ca.vertcat(w[0] ** 2 - 1, w[1]), lambda w: w[1], [-10.0],
                      [10.0], 2)
    for start in ([0.0, 0.3], [0.2, 0.3], [-0.1, -2.0]):  # where it curves down: handed over
        outcome, w = problem.line_search(start)
        assert not outcome.success or abs(abs(w[0]) - 1.0) < 1e-8, (start, outcome.message, w)
    outcome, w = problem.line_search([0.0, 0.3])
    assert not outcome.success and outcome.message in ('a saddle', 'nonconvex')
    outcome, w = problem.line_search([0.8, 0.3])  # where it curves up: the minimum
    assert outcome.success and outcome.minimum and w == pytest.approx([1.0, 0.0], abs=1e-8)


def test_the_compiled_step_is_the_interpreted_one_and_tells_the_saddle_by_its_inertia():
    """The compiled step, its inertia and direction agree with the interpreted ones.

    The line search's direction shifted or not, its rows inside or outside their bounds; the
    inertia also with the formula. On the saddle's problem the Hessian's first entry is
    6 w1^2 - 2 (+ 1e-10), so the KKT matrix has one negative eigenvalue per row of g (a
    minimum) exactly where |w1| > 1/sqrt(3).
    """
    residual, g = (lambda w: ca.vertcat(w[0] ** 2 - 1, w[1])), (lambda w: w[1])
    interpreted = Problem(residual, g, [-10.0], [10.0], 2)
    compiled = Problem(residual, g, [-10.0], [10.0], 2, compiled=True)
    wait_for_builds()
    assert compiled.step.compiled and compiled.step.direction_compiled
    assert not interpreted.step.compiled and not interpreted.step.direction_compiled
    for w1 in (-1.3, -0.6, -0.5, 0.0, 0.3, 0.58, 0.6, 1.0):
        for active in (0.0, 1.0):
            args = (np.array([w1, 0.3]), np.zeros(0), np.array([active]), np.array([0.0]),
                    np.array([0.2]))
            expected = 6 * w1 ** 2 - 2 > 0
            assert compiled.step.minimum(*args) == interpreted.step.minimum(*args) == expected
            for a, b in zip(compiled.step(*args), interpreted.step(*args)):
                assert np.asarray(a) == pytest.approx(np.asarray(b), abs=1e-12)
            for shift, bounds in ((0.0, ([-10.0], [10.0])), (2.5, ([0.4], [0.5]))):
                view = (*args, shift, *map(np.array, bounds))
                for a, b in zip(compiled.step.direction(*view),
                                interpreted.step.direction(*view)):
                    assert np.asarray(a) == pytest.approx(np.asarray(b), rel=1e-9, abs=1e-12)
    equality = [Problem(residual, g, [0.0], [0.0], 2, compiled=c) for c in (True, False)]
    wait_for_builds()  # (rows held at 0: a direction without inequality rows)
    assert equality[0].step.direction_compiled
    for w1 in (-1.3, 0.0, 0.6):
        view = (np.array([w1, 0.3]), np.zeros(0), np.ones(1), np.zeros(1), np.zeros(1), 0.5,
                np.zeros(0), np.zeros(0))
        for a, b in zip(*(e.step.direction(*view) for e in equality)):
            assert np.asarray(a) == pytest.approx(np.asarray(b), rel=1e-9, abs=1e-12)
    outcome, w = compiled.line_search([0.8, 0.3])
    assert outcome.success and outcome.minimum and w == pytest.approx([1.0, 0.0], abs=1e-8)
    held = compiled.working_set([0.9, 0.1])
    assert held is not None and held.w == pytest.approx([1.0, 0.0], abs=1e-8)


def test_infeasible_bounds_are_no_success():
    problem = Problem(lambda w: w - 3.0, lambda w: ca.vertcat(w[0], w[0]), [1.0, -2.0],
                      [2.0, -1.0], 1)
    outcome, _ = problem.line_search([0.0])
    assert not outcome.success
    assert problem.working_set([1.5]) is None


def test_an_ill_conditioned_least_squares_qp():
    """Residual weights over eight orders of magnitude, one equality."""
    weights, target = np.array([1e4, 1.0, 1e-4]), np.array([1.0, -2.0, 3.0])
    a, b = np.diag(weights), weights * target
    c, d = np.ones((1, 3)), np.array([1.0])
    expected = _kkt_solution(a, b, c, d)
    problem = Problem(lambda w: ca.mtimes(ca.DM(a), w) - b, lambda w: ca.sum1(w) - 1.0, [0.0],
                      [0.0], 3)
    outcome, w = problem.line_search(np.zeros(3))
    assert outcome.success
    assert w == pytest.approx(expected, rel=1e-6, abs=1e-8)
