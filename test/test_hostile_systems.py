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

"""Systems of kinds no other test uses: a single input, a polar chart, wound headings.

Each solve returns, is judged inside the model's domain, and agrees across methods.
"""
import numpy as np
import pytest

import nh_tracking as nht
from systems import (inclined_knife_edge, polar_knife, polar_knife_past_the_origin, roller_racer,
                     rotor_sleigh)


@pytest.mark.unit
def test_a_polar_chart_whose_constraint_row_grows_with_r_is_a_valid_system():
    """Rows and fields are judged per configuration: r in (0.2, 100) is regular everywhere."""
    knife = polar_knife(r_max=100.0)
    assert knife.k == 2 and knife.basis_condition > 1e-3
    for r in (0.2 + 1e-6, 1.0, 99.0):
        mu = knife.constraints([r, 0.3, 1.1])
        assert np.abs(mu @ knife.rho([r, 0.3, 1.1])).max() < 1e-12


@pytest.mark.solve
@pytest.mark.slow
def test_a_reference_through_the_edge_of_the_domain_is_tracked_inside_it():
    """A straight line passing 0.1 m from the origin: in polar coordinates r dips below 0.2.

    The transcriptions hold the plan inside the domain (the variational one on a second route,
    the domain as bounds) and agree; PMP cannot bound its states and says its plan leaves.
    """
    problem = polar_knife_past_the_origin()
    costs = {}
    for method in ('variational', 'multiple_shooting'):
        solution = nht.solve(problem, method=method, max_time=30.0)
        assert solution.success, (method, solution.message)
        assert solution.q[:, 0].min() > 0.2
        costs[method] = solution.cost
    assert 'the domain as bounds' in nht.solve(problem, second_look=False).route
    print(f'\nplans held inside r > 0.2: {costs}')
    assert max(costs.values()) / min(costs.values()) < 1.01
    pmp = nht.solve(problem, method='pmp', max_time=30.0)
    assert not pmp.success
    assert "leaves the model's domain (r = " in pmp.message


@pytest.mark.solve
def test_headings_wound_several_turns_are_solved_and_looked_at_again_inside_the_domain():
    knife = polar_knife()
    q0 = np.array([2.0, 6 * np.pi, 6.5 * np.pi])  # as odometry that has turned three times
    t = np.linspace(0.0, 10.0, 201)
    reference = nht.simulate(knife, q0, [0.5, 0.3], t, lambda s, q, v: [0.1 * np.sin(s), 0.0])
    problem = nht.TrackingProblem(knife, reference, q0 + [0.05, 0.0, 0.05], reference.v[0],
                                  horizon=4.0, steps=40, terminal='cost')
    solution = nht.solve(problem, max_time=30.0)
    assert solution.success and solution.q[:, 0].min() > 0.2


@pytest.mark.solve
def test_the_deadline_covers_the_second_look():
    """With no time left after the first solve, the second look is not started."""
    board = nht.models.create('chaplygin_sleigh')
    t = np.linspace(0.0, 10.0, 201)
    reference = nht.simulate(board, [0.0, 0.5, 0.0], [1 / 3, 1.0], t)
    problem = nht.TrackingProblem(board, reference, [0.0, 0.6, 0.05], [1 / 3, 1.0],
                                  horizon=5.0, steps=37, terminal='cost')
    solution = nht.solve(problem, max_time=1e-4)
    assert not solution.success and 'deadline reached' in solution.message
    assert 'perturbed' not in solution.route


@pytest.fixture(scope='module')
def rotor_problem():
    sleigh = rotor_sleigh()
    t = np.linspace(0.0, 6.0, 121)
    reference = nht.simulate(sleigh, np.zeros(4), [0.0, 0.3, 0.0], t,
                             lambda s, q, v: [0.5 * np.sin(2 * s)])
    return nht.TrackingProblem(sleigh, reference, [0.0, 0.05, 0.0, 0.0], reference.v[0],
                               horizon=4.0, steps=40, epsilon=0.1, terminal='cost')


@pytest.mark.solve
@pytest.mark.slow
def test_a_sleigh_driven_by_its_rotor_alone_is_tracked_alike_by_every_method(rotor_problem):
    """One input (r = 1): PMP's held controls fit a single column too."""
    assert rotor_problem.system.r == 1
    costs = {}
    for method in ('variational', 'multiple_shooting', 'pmp'):
        solution = nht.solve(rotor_problem, method=method, max_time=120.0)
        assert solution.success, (method, solution.message)
        assert solution.u.shape == (40, 1) and np.isfinite(solution.u).all()
        costs[method] = solution.cost
    print(f'\nrotor sleigh costs: {costs}')
    assert max(costs.values()) / min(costs.values()) < 1.01


@pytest.mark.unit
def test_constraints_as_rows_of_expressions_are_taken_and_wrong_sizes_name_the_argument():
    import casadi as ca

    knife = nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'theta'], lambda q: ca.SX.eye(3),
        lambda q: [[ca.sin(q[2]), -ca.cos(q[2]), 0]], angles=['theta'])
    assert knife.k == 2
    with pytest.raises(ValueError, match=r'constraints\(q\) must be a CasADi SX matrix'):
        nht.NonholonomicSystem.from_constraints(['x', 'y'], lambda q: ca.SX.eye(2),
                                                lambda q: 'x = y')
    reference = nht.simulate(knife, np.zeros(3), [1.0, 0.0], np.linspace(0.0, 5.0, 51))
    with pytest.raises(ValueError, match='q0 must have 3 entries, got 2'):
        nht.TrackingProblem(knife, reference, [0.0, 0.0], [1.0, 0.0], horizon=2.0, steps=10)
    with pytest.raises(ValueError, match='v0 must have 2 entries, got 3'):
        nht.TrackingProblem(knife, reference, np.zeros(3), [1.0, 0.0, 0.0], horizon=2.0,
                            steps=10)


@pytest.mark.solve
def test_a_horizon_of_days_in_fifty_steps_is_no_success():
    """Its intervals do not replay on the continuous dynamics, whatever the solver reported."""
    knife = inclined_knife_edge()
    t = np.linspace(0.0, 10.0, 101)
    reference = nht.simulate(knife, [0.0, 0.0, 0.3], [0.5, 0.2], t)
    for horizon, replays in ((5.0, True), (1e6, False)):
        problem = nht.TrackingProblem(knife, reference, [0.0, 0.1, 0.3], [0.5, 0.2],
                                      horizon=horizon, steps=50)
        solution = nht.solve(problem, max_time=60.0)
        assert solution.success is replays, solution.message
        assert replays or ('does not replay' in solution.message
                           or 'converged' not in solution.message), solution.message
        if replays:
            assert solution.details['interval_gap'] < 1e-3


@pytest.mark.solve
def test_a_start_beyond_a_bound_is_told_apart_from_the_plan_after_it():
    """v0 beyond a velocity bound: the start breaks it by 0.3, the plan after it keeps it."""
    knife = inclined_knife_edge()
    reference = nht.simulate(knife, [0.0, 0.0, 0.3], [0.5, 0.2], np.linspace(0.0, 10.0, 101))
    assert np.abs(reference.v[:, 0]).max() < 8.5  # it swings across the slope
    problem = nht.TrackingProblem(knife, reference, [0.0, 0.1, 0.3], [9.3, 0.2], horizon=4.0,
                                  steps=40, velocity_bounds=([-9.0, -1.0], [9.0, 1.0]))
    for method in ('variational', 'multiple_shooting'):
        solution = nht.solve(problem, method=method, max_time=60.0)
        assert not solution.success, solution.message
        assert 'the start breaks a limit by 0.3, the plan after it keeps them' in \
            solution.message, solution.message


@pytest.mark.solve
@pytest.mark.slow
def test_multiple_shooting_falls_back_on_the_least_violating_plan_as_the_variational_does():
    """The rotor sleigh barely steers with |u| <= 0.05: no plan keeps clear of the disc."""
    sleigh = rotor_sleigh()
    t = np.linspace(0.0, 6.0, 121)
    reference = nht.simulate(sleigh, np.zeros(4), [0.4, 0.3, 0.0], t,
                             lambda s, q, v: [0.5 * np.sin(2 * s)])
    bound = np.array([1.0, 1.0, 0.2])
    problem = nht.TrackingProblem(sleigh, reference, [0.0, -0.15, 0.0, 0.0], reference.v[0],
                                  horizon=4.0, steps=40, epsilon=0.1, terminal='cost',
                                  velocity_bounds=(-bound, bound),
                                  control_bounds=([-0.05], [0.05]), obstacles=[[1.0, 0.0, 0.12]])
    plans = {method: nht.solve(problem, method=method, max_time=120.0)
             for method in ('variational', 'multiple_shooting')}
    shooting = plans['multiple_shooting']
    assert shooting.route.endswith('-> soft limits'), shooting.route
    assert 'least-violating plan' in shooting.message and not shooting.success
    violations = [plan.details['violation'] for plan in plans.values()]
    assert 0.0 < min(violations) and max(violations) / min(violations) < 1.01, violations


@pytest.mark.solve
@pytest.mark.slow
def test_a_roller_racer_driven_by_its_joint_alone_is_tracked_alike_by_every_method():
    """Two bodies, two wheel constraints, one joint torque; its basis as a user would write it.

    (Its automatic basis works too, at about six times the cost: an orthonormal basis of a
    configuration-dependent 4x4 metric makes its dynamics 985 CasADi instructions, against 177.)
    """
    racer = roller_racer(basis=True)
    assert (racer.n, racer.k, racer.r) == (4, 2, 1)
    t = np.linspace(0.0, 8.0, 161)
    reference = nht.simulate(racer, [0.0, 0.0, 0.0, 0.2], [0.5, 0.0], t,
                             lambda s, q, v: [0.3 * np.sin(1.5 * s)])
    problem = nht.TrackingProblem(racer, reference, [0.0, 0.05, 0.0, 0.2], reference.v[0],
                                  horizon=4.0, steps=40, epsilon=0.1, terminal='cost')
    costs = {}
    for method in ('variational', 'multiple_shooting', 'pmp'):
        solution = nht.solve(problem, method=method, max_time=120.0)
        assert solution.success, (method, solution.message)
        costs[method] = solution.cost
    print(f'\nroller racer costs: {costs}')
    assert max(costs.values()) / min(costs.values()) < 1.01
