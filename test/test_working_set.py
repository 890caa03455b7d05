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

"""Warm replanning by Newton steps on a working set of the limit rows, against the interior point.

The working set is checked against fatrop solving the same problem from the same guess (the
independent solver), on built-in models and made-up systems with several kinds of limits — and
without limits, where the set is empty and the steps are Newton's on the KKT conditions — and
its saddle test on a problem whose two KKT points are known by hand.
"""
import casadi as ca
import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.core.numeric import NumericFunction
import nh_tracking.planning.receding_horizon as rh
from nh_tracking.solvers import routes, sample_plan, variational
from nh_tracking.solvers.inequalities import Shape
from nh_tracking.solvers.midpoint import working_set_step
from nh_tracking.solvers.newton import NewtonStep
from nh_tracking.solvers.nlp import Pace
from nh_tracking.solvers.working_set import working_set_solve
from systems import coupled_system, inclined_knife_edge


@pytest.mark.unit
def test_the_working_set_tells_the_minimum_beside_an_obstacle_from_the_saddle():
    """Nearest point to (0.5, 0) outside the unit disc: (1, 0); (-1, 0) is a KKT point too.

    There the multiplier has the right sign (-0.75) but the distance is largest along the
    circle: a saddle, which Newton's method converges to from (-1, 0.05) — and must refuse.
    """
    w, p = ca.SX.sym('w', 2), ca.SX.sym('p', 0)
    g = ca.sumsqr(w)
    step = NewtonStep(w, p, w - ca.DM([0.5, 0.0]), g)
    values = NumericFunction(ca.Function('g', [w, p], [g]))
    lower, upper, convex = np.ones(1), np.full(1, np.inf), np.ones(1, dtype=bool)
    found = working_set_solve(step, values, np.array([0.9, 0.5]), np.zeros(0), lower, upper,
                              convex, Pace(None))
    assert found is not None and found.active == 1
    assert np.allclose(found.w, [1.0, 0.0], atol=1e-8)
    assert found.multipliers[0] == pytest.approx(-0.25, abs=1e-8)  # CasADi's sign: lower bound
    assert working_set_solve(step, values, np.array([-1.0, 0.05]), np.zeros(0), lower, upper,
                             convex, Pace(None)) is None
    # unconstrained in effect (the target outside the disc): no row held, no check needed
    found = working_set_solve(NewtonStep(w, p, w - ca.DM([2.0, 1.0]), g), values,
                              np.array([1.5, 0.5]), np.zeros(0), lower, upper, convex, Pace(None))
    assert found is not None and found.active == 0 and np.allclose(found.w, [2.0, 1.0])


def _line(duration: float, speed: float = 0.5) -> nht.Trajectory:
    t = np.linspace(0.0, duration, int(duration * 10) + 1)
    return nht.Trajectory(t, np.stack([speed * t, 0 * t, 0 * t], axis=1),
                          np.tile([speed, 0.0], (len(t), 1)), np.zeros((len(t) - 1, 2)))


CASES = {  # model, start (q, v), reference, settings, obstacles
    'sleigh, |u| bounded': (
        nht.models.chaplygin_sleigh, ([0.0, 0.0, 0.3], [0.0, 0.0]), 'sleigh',
        {'u_min': (-0.2, -0.2), 'u_max': (0.2, 0.2)}, ()),
    'unicycle, v bounded and two discs': (
        nht.models.unicycle, ([0.0, 0.3, 0.0], [0.5, 0.0]), 'line',
        {'v_min': (-0.55, -0.6), 'v_max': (0.55, 0.6), 'robot_radius': 0.15},
        ((2.0, 0.05, 0.25), (4.0, -0.1, 0.2))),
    'knife edge on a slope, torque bounded, a disc': (
        inclined_knife_edge, ([0.0, -0.2, 0.0], [0.5, 0.0]), 'line',
        {'u_min': (-2.0, -1.0), 'u_max': (2.0, 1.0), 'robot_radius': 0.1},
        ((2.5, 0.0, 0.3),)),
}


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('case', CASES)
def test_warm_replans_with_limits_take_the_working_set_and_match_the_interior_point(
        case, monkeypatch):
    build, (q, v), kind, settings, discs = CASES[case]
    model = build()
    reference = (nht.simulate(model, [0.0, 0.0, 0.0], [0.6, 0.25, 0.0][:model.k],
                              np.linspace(0, 20, 401)) if kind == 'sleigh' else _line(30.0))
    planner = rh.RecedingHorizonPlanner(model, rh.PlannerSettings(horizon=4.0, steps=40,
                                                                  **settings))
    planner.prepare()  # builds the working set's step for its bounds; obstacles' on first need
    planner.set_reference(reference)
    planner.obstacles = np.array(discs).reshape(-1, 3)
    shape = Shape.of(planner.problem(0.0, np.array(q, dtype=float), np.array(v, dtype=float),
                                     planner.obstacles).limits)
    working_set_step(model, 40, 'cost', shape)  # as the background build would
    q, v, t = np.array(q, dtype=float), np.array(v, dtype=float), 0.0
    compared, worst_cost, worst_q, active = 0, 0.0, 0.0, 0
    for _ in range(60):
        previous = planner.previous
        plan = planner.plan(t, q, v).plan
        assert plan.success and plan.details['violation'] <= 1e-6
        if plan.route == 'newton (working set)':
            problem = planner.problem(t, q, v)
            with monkeypatch.context() as patch:
                patch.setattr(routes, 'working_set_solve', lambda *args: None)
                reference_plan = variational.solve_variational(problem,
                                                               sample_plan(problem, previous))
            assert reference_plan.success and 'working set' not in reference_plan.route
            compared += 1
            worst_cost = max(worst_cost, abs(plan.cost - reference_plan.cost)
                             / reference_plan.cost)
            worst_q = max(worst_q, float(np.abs(plan.q - reference_plan.q).max()))
            active += 'limit rows active' in plan.message and '(0 limit' not in plan.message
        step = nht.simulate(model, q, v, plan.t[:2], plan.u[:1])
        q, v, t = step.q[-1], step.v[-1], t + 0.1
    assert compared >= 45, f'only {compared} of 60 replans took the working set'
    assert active >= 5  # the limits mattered
    assert worst_cost <= 1e-6 and worst_q <= 1e-4, (worst_cost, worst_q)
    assert planner.stats.optimal == planner.stats.plans


FREE_CASES = {  # model, the reference's start (q, v), the robot's offset from it
    'sleigh': (nht.models.chaplygin_sleigh, ([0.0, 0.0, 0.0], [0.6, 0.25]), [0.1, -0.1, 0.2]),
    'rolling disk': (nht.models.rolling_disk, ([0.0, 0.0, 0.0, 0.0], [0.8, 0.3]),
                     [0.05, 0.1, -0.1, 0.3]),
    'snakeboard (underactuated)': (nht.models.snakeboard, ([0.0] * 5, [0.5, 0.0, 0.0]),
                                   [0.0, 0.1, 0.1, 0.0, 0.0]),
    'coupled (no pose, a potential)': (coupled_system, ([0.1, 0.2, 0.0, 0.3], [0.4, -0.2]),
                                       [0.05, -0.05, 0.05, 0.0]),
}


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('case', FREE_CASES)
def test_warm_replans_without_limits_take_newton_steps_and_match_the_interior_point(case):
    """No limits: the set is empty, and a converged replan is Newton steps on the KKT system.

    The interior point only where they do not settle; the same plan as fatrop's from the same
    guess (newton=False), to the Newton steps' tolerance: they may stop once the next step
    would move the plan by less than about 1e-9 (relative) and g is within 1e-8 of zero — the
    admissibility residual read from the knots, (q' - q)/h - rho v, then within 2e-8/h.
    """
    build, (q_r, v_r), offset = FREE_CASES[case]
    model = build()
    reference = nht.simulate(model, q_r, v_r, np.linspace(0.0, 10.0, 101))
    planner = rh.RecedingHorizonPlanner(model, rh.PlannerSettings(horizon=2.0, steps=20))
    planner.prepare()
    planner.set_reference(reference)
    q, v = np.array(q_r) + offset, np.array(v_r, dtype=float)
    t, compared, worst_cost, worst_q, worst_residual = 0.0, 0, 0.0, 0.0, 0.0
    for _ in range(30):
        previous = planner.previous
        plan = planner.plan(t, q, v).plan
        assert plan.success
        if plan.route == 'newton (working set)':
            problem = planner.problem(t, q, v)
            fatrop = variational.solve_variational(problem, sample_plan(problem, previous),
                                                   newton=False)
            assert fatrop.success and fatrop.route == 'fatrop'
            compared += 1
            worst_cost = max(worst_cost, abs(plan.cost - fatrop.cost) / fatrop.cost)
            worst_q = max(worst_q, float(np.abs(plan.q - fatrop.q).max()))
            worst_residual = max(worst_residual, plan.details['admissibility_residual'])
        step = nht.simulate(model, q, v, plan.t[:2], plan.u[:1])
        q, v, t = step.q[-1], step.v[-1], t + 0.1
    print(f'\n{case}: {compared} of 30 replans by Newton steps; cost within {worst_cost:.1e}, '
          f'plan within {worst_q:.1e} of fatrop, admissible to {worst_residual:.1e}')
    assert compared >= 25, f'only {compared} of 30 replans took Newton steps'
    assert worst_cost <= 1e-6 and worst_q <= 1e-7 and worst_residual <= 2e-8 / 0.1, (
        worst_cost, worst_q, worst_residual)


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('model_name, terminal, epsilon', [
    ('unicycle', 'equality', 0.01), ('nonholonomic_particle', 'cost', 0.1)])
def test_after_a_jump_and_a_push_newton_plans_are_never_worse_than_fatrop(model_name, terminal,
                                                                          epsilon):
    """A plan reached after a long first step is checked to be a minimum.

    Far from the previous plan, Newton's steps may end on a saddle: once on this unicycle a
    plan cost 31.4 where fatrop's from the same guess cost 8.9.
    """
    model = nht.models.create(model_name)
    q_r, v_r = np.zeros(model.n), np.array([0.6, 0.25])
    reference = nht.simulate(model, q_r, v_r, np.linspace(0.0, 20.0, 201))
    planner = rh.RecedingHorizonPlanner(model, rh.PlannerSettings(
        horizon=1.0, steps=40, epsilon=epsilon, terminal=terminal))
    planner.prepare()
    planner.set_reference(reference)
    rng = np.random.default_rng(1)
    q, v, t, newton, worst = q_r + 0.1 * rng.normal(size=model.n), v_r.copy(), 0.0, 0, 0.0
    for i in range(45):
        if i == 15:  # the reference jumps
            planner.set_reference(nht.Trajectory(reference.t, reference.q + [0.8, -0.6, 0.0],
                                                 reference.v, reference.u))
        if i == 30:  # the robot is pushed far off
            q = q + [2.0, 1.5, 1.0]
        previous, problem = planner.previous, planner.problem(t, q, v)
        plan = planner.plan(t, q, v).plan
        assert plan.success
        if plan.route == 'newton (working set)':
            fatrop = variational.solve_variational(problem, sample_plan(problem, previous),
                                                   newton=False)
            newton += 1
            worst = max(worst, (plan.cost - fatrop.cost) / fatrop.cost)
        step = nht.simulate(model, q, v, plan.t[:2], plan.u[:1])
        q, v, t = step.q[-1], step.v[-1], t + 0.025
    print(f'\n{model_name}: {newton} of 45 plans by Newton steps, worst cost {worst:.1e} above '
          'fatrop')
    assert newton >= 30 and worst <= 1e-6, (newton, worst)
