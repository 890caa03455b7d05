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

"""A plan's multipliers carried to the next replan: placed right, and worth a factorisation."""
import dataclasses

import casadi as ca
import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.examples.obstacles import line_reference
from nh_tracking.planning import receding_horizon as rh
from nh_tracking.solvers import Guess, sample_plan
from nh_tracking.solvers.duals import carried_multipliers
from nh_tracking.solvers.inequalities import Shape
from nh_tracking.solvers.midpoint import transcription
from nh_tracking.solvers.variational import solve_variational


def _carried(tr, problem, guess):
    """Return carried_multipliers with the solve's parameters (discs nearest the guess)."""
    return carried_multipliers(tr, problem, guess, tr.parameters(problem, np.asarray(guess[0])))


def _problem(model_name: str = 'unicycle', **limits) -> nht.TrackingProblem:
    return nht.TrackingProblem(getattr(nht.models, model_name)(), line_reference(10.0),
                               np.array([0.0, 0.3, 0.0]), np.array([0.5, 0.0]), 2.0, 20,
                               terminal='cost', omega=10.0, t0=1.0, **limits)


def _rows(problem):
    return transcription(problem.system, problem.steps, problem.terminal, False, 'fatrop',
                         False, Shape.of(problem.limits), 0)


def _at(values, blocks, position):
    """Return the values of ``blocks`` at a fractional block ``position``, the last held."""
    if position >= len(blocks) - 1:
        return values[blocks[-1]]
    low = int(np.floor(position))
    return (low + 1 - position) * values[blocks[low]] + (position - low) * values[blocks[low + 1]]


@pytest.mark.unit
@pytest.mark.parametrize('later', [0.1, 0.05, 0.03, 0.27])  # 1, 1/2, a 100 Hz tick, 2.7
def test_multipliers_move_with_the_plan(later):
    """Admissibility, control-bound and clearance rows take the old plan's values at that time.

    (The unicycle is fully actuated: its controls are eliminated, u = dv/dt - f(q, v), so their
    bounds are curved rows.) Velocity bounds and the other linear rows start from zero.
    """
    problem = _problem(obstacles=[(1.2, 0.05, 0.3)], robot_radius=0.2,
                       control_bounds=(-0.15, 0.15), velocity_bounds=(-1.0, 1.0))
    plan = solve_variational(problem)
    assert plan.success and plan.multipliers is not None
    moved = dataclasses.replace(problem, t0=1.0 + later)
    tr = _rows(moved)
    carried = _carried(tr, moved, sample_plan(moved, plan))
    assert carried is not None
    old = plan.multipliers.values
    stages = later / problem.h
    adm = tr.admissibility_rows.reshape(problem.steps, -1)
    controls = np.flatnonzero(tr.limits.inequality_mask(tr.rows, ('u',)))
    clear = np.flatnonzero(tr.limits.inequality_mask(tr.rows, ('clear',)))
    assert np.abs(old[clear]).max() > 1e-3 and np.abs(old[controls]).max() > 1e-3  # both held
    half = clear.reshape(2 * problem.steps, -1)  # midpoint 0, knot 1, midpoint 1, ...
    for blocks, by in ((adm, stages), (controls.reshape(problem.steps, -1), stages),
                       (half, 2 * stages)):
        for k, rows in enumerate(blocks):
            np.testing.assert_allclose(carried[rows], _at(old, blocks, k + by), atol=1e-12)
    linear = np.setdiff1d(np.arange(tr.rows), np.concatenate([adm.ravel(), controls, clear]))
    assert not carried[linear].any()  # rows without curvature start from zero


@pytest.mark.solve
def test_a_point_keeps_its_clearance_multipliers_while_its_discs_stay_the_same():
    """Five discs, four a point: a disc moved costs the multipliers of the points it is in.

    The points whose nearest four are the unmoved discs (before and after the shift) keep
    theirs. (Bounded speed: unbounded, this robot's plan would jump a disc between two points.)
    """
    discs = [(1.2, 0.05, 0.3), (1.3, -0.6, 0.2), (0.0, 1.2, 0.2),  # the third: early points'
             (1.3, 1.0, 0.1), (1.6, -0.2, 0.1)]  # (nearer than it to the late points)
    problem = _problem(obstacles=discs, robot_radius=0.2, velocity_bounds=(-1.0, 1.0))
    plan = solve_variational(problem, sample_plan(problem, solve_variational(problem)))
    assert plan.success
    later = dataclasses.replace(problem, t0=1.1,
                                obstacles=discs[:2] + [(0.0, 1.3, 0.2)] + discs[3:])
    tr = _rows(later)
    guess = sample_plan(later, plan)
    carried = _carried(tr, later, guess)
    half = np.flatnonzero(tr.limits.inequality_mask(tr.rows, ('clear',))).reshape(40, 4)
    before = tr.limits.assigned_discs(plan.multipliers.obstacles.ravel()).reshape(40, 4, 4)
    now = tr.limits.assigned_discs(tr.parameters(later, guess.q)).reshape(40, 4, 4)
    kept = lost = 0
    for k, rows in enumerate(half):
        if np.array_equal(now[k], before[min(k + 2, 39)]):  # 1 interval: 2 points on
            np.testing.assert_allclose(carried[rows], _at(plan.multipliers.values, half, k + 2),
                                       atol=1e-12)
            kept += 1
        else:
            assert not carried[rows].any()
            lost += 1
    assert kept and lost
    assert np.abs(carried[half]).max() > 1e-3  # the first disc's contact is carried


@pytest.mark.unit
def test_multipliers_that_do_not_fit_are_not_carried():
    """Another disc, NLP, interval or an earlier start: no multipliers, or no clearance rows'."""
    problem = _problem(obstacles=[(1.2, 0.05, 0.3)], robot_radius=0.2)
    plan = solve_variational(problem)
    later = dataclasses.replace(problem, t0=1.1)
    tr = _rows(later)
    clear = np.flatnonzero(tr.limits.inequality_mask(tr.rows, ('clear',)))
    moved_disc = dataclasses.replace(later, obstacles=[(1.2, 0.1, 0.3)])
    tr_m = _rows(moved_disc)
    carried = _carried(tr_m, moved_disc, sample_plan(moved_disc, plan))
    assert carried is not None and not carried[clear].any() and carried.any()
    for other in (dataclasses.replace(problem, t0=0.9),  # the old plan starts later
                  dataclasses.replace(problem, t0=1.1, horizon=2.2),  # another h
                  dataclasses.replace(problem, t0=1.1, obstacles=[]),  # another NLP
                  dataclasses.replace(problem, t0=1.0 + problem.horizon)):  # its horizon gone
        tr_o = _rows(other)
        assert _carried(tr_o, other, sample_plan(other, plan)) is None
    plain = Guess(plan.q, plan.v, plan.u)  # a guess without multipliers
    assert _carried(tr, later, plain) is None
    assert _carried(tr, later, (plan.q, plan.v, plan.u)) is None
    guess = sample_plan(later, plan)
    for values in (plan.multipliers.values[:-5], np.full_like(plan.multipliers.values, np.nan)):
        broken = dataclasses.replace(plan.multipliers, values=values)
        assert _carried(tr, later, guess._replace(multipliers=broken)) is None


def _knife(actuated: bool) -> nht.NonholonomicSystem:
    """Return a knife edge on a slope, named like any user's system: actuators or none.

    Given, the actuators keep u an unknown of the NLP (its dynamics are rows); without, u is
    eliminated. The same name, q, v and u either way.
    """
    return nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'theta'], lambda q: ca.SX.eye(3),
        lambda q: ca.horzcat(ca.sin(q[2]), -ca.cos(q[2]), 0), potential=lambda q: 0.1 * q[0],
        actuators=(lambda q: ca.blockcat([[ca.cos(q[2]), 0], [ca.sin(q[2]), 0], [0, 2.0]]))
        if actuated else None, angles=['theta'])


@pytest.mark.solve
def test_a_plan_of_another_system_alike_in_name_and_size_is_a_guess_without_multipliers():
    """Two users' systems called alike, with the same (n, k, r), one with more rows in its NLP.

    Each one's plan warm-starts the other's solve without error; the multipliers stay behind.
    """
    plans = {}
    for actuated in (False, True):
        problem = nht.TrackingProblem(_knife(actuated), line_reference(10.0),
                                      np.array([0.0, 0.1, 0.0]), np.array([0.5, 0.0]), 1.0, 10,
                                      terminal='cost')
        plans[actuated] = (problem, nht.solve(problem, second_look=False))
        assert plans[actuated][1].success
    for actuated in (False, True):
        problem, own = plans[actuated]
        other = plans[not actuated][1]
        assert problem.system.name == plans[not actuated][0].system.name
        tr = _rows(problem)
        assert _carried(tr, problem, sample_plan(problem, other)) is None
        again = nht.solve(problem, initial_guess=other, second_look=False)
        assert again.success and abs(again.cost - own.cost) <= 1e-6 * own.cost


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('model_name, discs', [
    ('unicycle', ((3.0, 0.05, 0.3), (6.0, -0.05, 0.3))),
    ('nonholonomic_particle', ((2.5, -0.1, 0.25),))])
def test_carried_multipliers_save_factorisations_past_discs(model_name, discs):
    """The same replans, from the same guesses, with the previous plan's multipliers and without.

    With them, a replan sliding along a disc converges in fewer factorisations, to fatrop's plan
    (without them one replan of the unicycle's settled on a contact set 3.5e-5 worse).
    """
    model = getattr(nht.models, model_name)()
    planner = rh.RecedingHorizonPlanner(model, rh.PlannerSettings(horizon=5.0, steps=50,
                                                                  robot_radius=0.2))
    planner.obstacles = np.array(discs)
    planner.prepare()
    planner.set_reference(line_reference(30.0))
    q, v, t = np.zeros(model.n), np.zeros(model.k), 0.0
    q[1], v[0] = 0.3, 0.5
    with_them, without, compared = 0, 0, 0
    for _ in range(100):
        previous = planner.previous
        plan = planner.plan(t, q, v).plan
        if plan.route == 'newton (working set)' and previous is not None:
            avoidance = planner.avoidance(t)
            discs = avoidance.relevant(t, q, avoidance.from_start(q, v))
            problem = planner.problem(t, q, v, discs)
            guess = sample_plan(problem, previous)
            again = solve_variational(problem, guess)
            blind = solve_variational(problem, Guess(*guess[:3]))
            fatrop = solve_variational(problem, guess, newton=False)
            if again.route == blind.route == 'newton (working set)':
                compared += 1
                with_them += again.iterations
                without += blind.iterations
                assert abs(again.cost - fatrop.cost) <= 1e-6 * fatrop.cost
                assert np.abs(again.q - fatrop.q).max() <= 1e-6
                assert again.cost <= blind.cost * (1 + 1e-7)
        step = nht.simulate(model, q, v, plan.t[:2], plan.u[:1])
        q, v, t = step.q[-1], step.v[-1], t + 0.1
    print(f'\n{model_name}: {compared} replans, {with_them} factorisations with the previous '
          f'multipliers, {without} without')
    assert compared >= 60
    assert with_them <= 0.95 * without
