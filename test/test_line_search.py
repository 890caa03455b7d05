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

"""Cold solves by Newton steps with a filter line search, checked against the interior point.

The interior point (fatrop, ``Variational(newton=False)``) is the independent solver: from the
same guess both must reach the same plan, multipliers included, and where the line search
gives up the solve must be the interior point's own.
"""
import dataclasses

import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.examples.experiments import particle_problem, sleigh_problem
from nh_tracking.solvers import line_search, routes, Variational
from nh_tracking.solvers.inequalities import Shape
from nh_tracking.solvers.midpoint import transcription, working_set_step
from nh_tracking.solvers.routes import default_guess
from systems import coupled_system, inclined_knife_edge

LINE_SEARCH = 'newton (line search)'


def _problem(system, q_ref0, v_ref0, q0, v0, horizon, steps, eps, terminal='cost'):
    reference = nht.simulate(system, q_ref0, v_ref0, np.linspace(0, 5, 101))
    return nht.TrackingProblem(system, reference, q0=q0, v0=v0, horizon=horizon, steps=steps,
                               epsilon=eps, terminal=terminal, omega=2.0)


CASES = {
    'sleigh_literal': lambda: sleigh_problem(wrap_angles=False),
    'sleigh_wrapped_cost': lambda: sleigh_problem(wrap_angles=True, terminal='cost'),
    'particle_2': lambda: particle_problem(2),
    'knife_edge': lambda: _problem(inclined_knife_edge(), [0, 0, 0], [0.5, 0.3],
                                   [0.3, 0.2, 0.5], [0.2, 0.0], 3.0, 40, 2.0, 'equality'),
    'rolling_disk': lambda: _problem(nht.models.rolling_disk(), [0, 0, 0, 0], [0.5, 2.0],
                                     [0.399, -0.3339, -0.2747, -0.266], [-0.1747, 1.7042],
                                     4.089, 54, 2.155),
    'snakeboard_underactuated': lambda: _problem(
        nht.models.snakeboard(), [0, 0, 0, 0, 0], [0.3, 0.1, 0.2],
        [0.1008, -0.192, 0.1766, -0.7809, 0.331], [-0.1497, 0.9612, 0.0558], 2.26, 37, 0.306),
    'coupled': lambda: _problem(coupled_system(), [0.1, 0.2, 0.0, 0.1], [0.3, 0.2],
                                [0.7619, 0.3501, -0.8634, -0.8869], [0.142, 0.8471], 1.928, 16,
                                2.683),
}


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('make', CASES.values(), ids=CASES.keys())
def test_a_cold_solve_by_line_search_is_the_interior_points_plan(make):
    """Same cost, plan and costates as fatrop from the reference, on seven systems.

    Among them an underactuated one (controls as unknowns) and a made-up coupled one.
    """
    problem = make()
    ours = nht.solve(problem, Variational(), second_look=False)
    interior = nht.solve(problem, Variational(newton=False), second_look=False)
    assert ours.route == LINE_SEARCH and ours.success and interior.route == 'fatrop'
    assert ours.cost == pytest.approx(interior.cost, rel=1e-9)
    assert np.abs(ours.q - interior.q).max() < 1e-7
    assert np.abs(ours.v - interior.v).max() < 1e-7
    assert np.abs(ours.u - interior.u).max() < 1e-6
    for mine, theirs in zip(ours.costates, interior.costates):
        assert np.abs(mine - theirs).max() < 1e-6 * max(1.0, np.abs(theirs).max())
    assert ours.details['admissibility_residual'] < 1e-9


def _line_search_alone(problem):
    tr = transcription(problem.system, problem.steps, problem.terminal)
    step = working_set_step(problem.system, problem.steps, problem.terminal, Shape()).step
    q, v = default_guess(problem)
    if problem.terminal == 'equality':
        q[-1], v[-1] = problem.reference_samples[0][-1], problem.reference_samples[1][-1]
    bounds = tr.bounds(problem)
    return line_search.line_search_solve(step, tr.pack(q, v, None), tr.parameters(problem, q),
                                         bounds['lbg'], bounds['ubg'], None)


@pytest.mark.solve
def test_a_saddle_is_not_taken_and_the_interior_point_solves_instead():
    """A rolling disk whose line search converges to a saddle: refused, fatrop's plan given.

    The inertia of the KKT matrix at the point it reached has one negative eigenvalue too many.
    """
    problem = _problem(nht.models.rolling_disk(), [0, 0, 0, 0], [0.5, 2.0],
                       [-0.4042, 0.2755, -0.2222, 1.0376], [0.4756, 2.2511], 3.348, 49, 0.655,
                       'equality')
    alone = _line_search_alone(problem)
    assert not alone.success and alone.message == 'a saddle'
    ours = nht.solve(problem, Variational(), second_look=False)
    interior = nht.solve(problem, Variational(newton=False), second_look=False)
    assert ours.route == 'fatrop' and ours.success
    assert ours.cost == interior.cost and np.array_equal(ours.q, interior.q)


@pytest.mark.solve
def test_a_line_search_out_of_iterations_hands_over_to_the_interior_point(monkeypatch):
    problem = sleigh_problem(wrap_angles=False)
    monkeypatch.setattr(line_search, 'DEFAULTS', line_search.LineSearchOptions(max_iterations=3))
    alone = _line_search_alone(problem)
    assert not alone.success and alone.message == 'iteration budget spent'
    ours = nht.solve(problem, Variational(), second_look=False)
    interior = nht.solve(problem, Variational(newton=False), second_look=False)
    assert ours.route == 'fatrop' and ours.success and ours.cost == interior.cost


@pytest.mark.solve
def test_a_deadline_inside_the_line_search_is_reported_not_overrun():
    """Past its deadline the solve says so; it does not start the interior point."""
    problem = sleigh_problem(wrap_angles=False)
    nht.solve(problem, Variational(), max_time=60.0, second_look=False)  # built in time
    late = nht.solve(problem, Variational(), max_time=1e-5, second_look=False)
    assert not late.success and late.message == 'deadline reached'
    assert late.route == LINE_SEARCH and late.iterations == 0


@pytest.mark.solve
def test_steps_stalled_short_of_admissible_are_not_taken_for_converged():
    """A particle on a 0.2 s horizon at eps = 100: the KKT matrix's condition is ~1e13.

    Its unpivoted LDLᵀ leaves the Newton steps stalled 2e-5 from the solution with g at 1e-4;
    such a plan is not converged, and fatrop's (admissible to 1e-13) is given instead.
    """
    particle = nht.models.nonholonomic_particle()
    reference = nht.simulate(particle, np.zeros(3), np.array([0.5, 0.4]), np.linspace(0, 5, 101))
    problem = nht.TrackingProblem(particle, reference, q0=np.array([-0.09, -0.53, 1.67]),
                                  v0=np.array([0.85, -1.74]), horizon=0.2, steps=40,
                                  epsilon=100.0, terminal='equality')
    alone = _line_search_alone(problem)
    assert not alone.success and alone.message == 'stalled short of admissible'
    ours = nht.solve(problem, Variational(), second_look=False)
    interior = nht.solve(problem, Variational(newton=False), second_look=False)
    assert ours.route == 'fatrop' and ours.cost == interior.cost
    assert ours.details['admissibility_residual'] < 1e-9


@pytest.mark.solve
def test_the_line_search_runs_only_where_fatrop_would(monkeypatch):
    """``newton=False`` (its coarse grid too) and IPOPT never take it."""
    def refuse(*args):
        raise AssertionError('line search called')

    monkeypatch.setattr(routes, 'line_search_solve', refuse)
    fine = sleigh_problem(wrap_angles=True, steps=100)  # starts from a coarse grid's plan
    assert nht.solve(fine, Variational(newton=False), second_look=False).success
    problem = sleigh_problem(wrap_angles=True)
    assert nht.solve(problem, Variational(backend='ipopt'), second_look=False).route == 'ipopt'
    with pytest.raises(AssertionError, match='line search called'):
        nht.solve(problem, Variational(), second_look=False)


def _bounded(name, kind, fraction):
    """Return a case of CASES, its controls (or velocities) bounded by a fraction of its peak.

    Velocity bounds stay outside the start's own velocity (a start that breaks a limit is
    the soft NLP's, not this one's).
    """
    free = CASES[name]()
    plan = nht.solve(free, second_look=False)
    if kind == 'controls':
        peak = fraction * np.abs(plan.u).max(axis=0)
        return dataclasses.replace(free, control_bounds=(-peak, peak))
    peak = np.maximum(fraction * np.abs(plan.v).max(axis=0), np.abs(free.v0) + 1e-3)
    return dataclasses.replace(free, velocity_bounds=(-peak, peak))


BOUNDED = [('sleigh_wrapped_cost', 'controls', 0.5), ('sleigh_wrapped_cost', 'velocities', 0.8),
           ('particle_2', 'velocities', 0.8), ('rolling_disk', 'controls', 0.5),
           ('snakeboard_underactuated', 'velocities', 0.8), ('coupled', 'controls', 0.6)]


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('name, kind, fraction', BOUNDED,
                         ids=[f'{n}-{k}' for n, k, _ in BOUNDED])
def test_a_cold_solve_with_bounds_by_line_search_is_ipopts_plan(name, kind, fraction):
    """Control or velocity bounds: a sequential QP on a working set, against IPOPT alone.

    IPOPT (not fatrop) is the reference: fatrop's interior point ends its active rows about
    2e-8 beyond their bounds, which makes its cost lower by about that times the multipliers.
    Here the bounds hold exactly and are active.
    """
    problem = _bounded(name, kind, fraction)
    ours = nht.solve(problem, Variational(), second_look=False)
    ipopt = nht.solve(problem, Variational(backend='ipopt', newton=False), second_look=False)
    assert ours.route == LINE_SEARCH and ours.success and ipopt.success
    assert ours.cost == pytest.approx(ipopt.cost, rel=1e-8)
    assert np.abs(ours.u - ipopt.u).max() < 1e-5 * max(1.0, np.abs(ipopt.u).max())
    assert np.abs(ours.q - ipopt.q).max() < 1e-6
    assert ours.details['violation'] <= 1e-12
    lo, hi = (problem.limits.controls if kind == 'controls' else problem.limits.velocities)
    values = ours.u if kind == 'controls' else ours.v[1:]
    assert np.min(np.minimum(values - lo, hi - values)) < 1e-9  # a bound is active
    assert ours.details['admissibility_residual'] < 1e-9


@pytest.mark.solve
def test_a_cold_solve_with_an_obstacle_is_the_interior_points():
    """From the reference through an obstacle the line search is not tried (see the module)."""
    free = CASES['sleigh_wrapped_cost']()
    problem = dataclasses.replace(free, obstacles=[(1.2, -0.45, 0.2)], robot_radius=0.05)
    assert problem.limits.plan_violation(*(getattr(nht.solve(free, second_look=False), a)
                                           for a in 'qvu'), problem.h) > 0.1  # on its way
    ours = nht.solve(problem, Variational(), second_look=False)
    interior = nht.solve(problem, Variational(newton=False), second_look=False)
    assert ours.route == 'fatrop' and ours.success and ours.cost == interior.cost


@pytest.mark.solve
def test_bounded_steps_that_crawl_are_given_up_early_for_the_interior_point(monkeypatch):
    """A unicycle whose bounded steps never settle the working set and crawl.

    Unchecked they go on for 40 factorisations (4.2x fatrop's time); they stop at the second
    step shorter than ``LineSearchOptions.crawl``, and the plan is fatrop's own.
    """
    unicycle = nht.models.unicycle()
    reference = nht.simulate(unicycle, [-0.2301, 0.2065, 0.1792], [-0.7722, -0.6769],
                             np.linspace(0, 6, 121))
    problem = nht.TrackingProblem(
        unicycle, reference, q0=[-0.2337, 0.5336, -0.0589], v0=[-0.9593, -0.4545],
        horizon=1.1977, steps=10, epsilon=7.934, terminal='equality', omega=2.0,
        control_bounds=([-np.inf, -5.3456], [np.inf, 6.44]),
        velocity_bounds=([-1.4073, -1.3478], [1.4073, 1.3478]))
    outcomes = []

    def recorded(*args):
        outcomes.append(line_search.line_search_solve(*args))
        return outcomes[-1]

    monkeypatch.setattr(routes, 'line_search_solve', recorded)
    ours = nht.solve(problem, Variational(), second_look=False)
    interior = nht.solve(problem, Variational(newton=False), second_look=False)
    assert [o.message for o in outcomes] == ['crawling']
    assert outcomes[0].iterations <= 20  # factorisations
    assert ours.route == 'fatrop' and ours.success and ours.cost == interior.cost
