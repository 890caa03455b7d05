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

"""Cold solves round an obstacle on the reference: both ways tried, the cheaper kept.

The cheaper way is checked against a multi-start search (eight starts, random excursions),
an independent way of finding the minima; clearance at knots, midpoints and between them.
"""
import numpy as np
import pytest
from test_following import Loop, polyline

import nh_tracking as nht
from nh_tracking.navigation.goal_checking import GoalState
import nh_tracking.planning.receding_horizon as rh
from nh_tracking.problem.detours import blocking_discs, detour_guesses


def _straight(system, speed_row, q0, v0, disc, duration=10.0):
    """Return a problem with ``disc`` on a straight reference along x from the origin."""
    reference = nht.simulate(system, np.zeros(system.n), speed_row, np.linspace(0, duration, 101))
    return nht.TrackingProblem(system, reference, np.asarray(q0, float), np.asarray(v0, float),
                               6.0, 60, terminal='cost', omega=10.0, obstacles=[disc],
                               robot_radius=0.2)


CASES = {
    'unicycle, disc centred on the line': (
        nht.models.unicycle(), [0.5, 0.0], [0, 0, 0], [0.5, 0], (1.5, 0.0, 0.3)),
    'unicycle, start 0.3 m off, disc 5 cm off the line': (
        nht.models.unicycle(), [0.5, 0.0], [0, 0.3, 0], [0.5, 0], (1.5, 0.05, 0.3)),
    'sleigh, disc centred on its straight coast': (
        nht.models.chaplygin_sleigh(), [0.0, 0.5], [0, 0, 0], [0, 0.5], (1.2, 0.0, 0.25)),
}


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('case', CASES)
def test_a_cold_solve_goes_round_the_cheaper_side_of_a_disc_on_the_reference(case):
    system, speed, q0, v0, disc = CASES[case]
    problem = _straight(system, speed, q0, v0, disc)
    q = problem.reference_samples[0]
    assert len(blocking_discs(problem, q)) == 1  # the reference runs through it
    plan = nht.solve(problem)
    assert plan.success, plan.message
    assert 'way round the obstacles' in plan.route
    limits = problem.limits
    assert limits.plan_violation(plan.q, plan.v, plan.u, problem.h) <= 1e-6  # knots and midpoints
    assert limits.swept(np.vstack([plan.q[:1], 0.5 * (plan.q[1:] + plan.q[:-1])])) == 0.0
    search = nht.solve(problem, starts=8, initial_guess=problem.reference)  # no detours
    print(f'\n{case}: {plan.cost:.4f} ({plan.route}); starts=8: {search.minima}')
    assert plan.cost <= search.cost * 1.01


@pytest.mark.unit
def test_detour_guesses_pass_each_disc_on_either_side():
    problem = _straight(nht.models.unicycle(), [0.5, 0.0], [0, 0, 0], [0.5, 0],
                        (1.5, 0.0, 0.3))
    q = problem.reference_samples[0].copy()
    guesses = detour_guesses(problem, q)
    assert [sides for _, sides in guesses] == [(1,), (-1,)]
    for knots, (side,) in guesses:
        assert problem.limits.clearance(knots).min() > 0.0
        assert np.sign(knots[np.argmin(np.abs(knots[:, 0] - 1.5)), 1]) == side  # left is +y
        assert np.array_equal(knots[0], q[0])
    clear = _straight(nht.models.unicycle(), [0.5, 0.0], [0, 0, 0], [0.5, 0], (1.5, 2.0, 0.3))
    assert detour_guesses(clear, clear.reference_samples[0]) == []
    many = nht.TrackingProblem(problem.system, problem.reference, problem.q0, problem.v0, 6.0,
                               60, obstacles=[(x, 0.06 * (-1) ** i, 0.1) for i, x in
                                              enumerate((0.6, 1.2, 1.8, 2.4))],
                               robot_radius=0.1)
    assert [s for _, s in detour_guesses(many, many.reference_samples[0])] == [
        (-1, 1, -1, 1), (1, 1, 1, 1), (-1, -1, -1, -1)]  # past three: the nearer sides, all
    # on one side, all on the other


def _follow(model, discs, seconds=30.0):
    """Follow a 6 m route with ``discs`` on it; rows (t, x, y, ...) until arrived or blocked."""
    loop = Loop(model, epsilon=0.05, robot_radius=0.2)
    loop.session.set_obstacles(np.array(discs, dtype=float).reshape(-1, 3))
    loop.session.following.set_route(polyline((0, 0), (6, 0)))
    rows = []
    for _ in range(int(seconds / loop.dt)):
        rows.append(loop.run(loop.dt)[-1])
        if loop.session.following.status.state is GoalState.ARRIVED:
            break
    return loop.session.following.status.state, np.array(rows)


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('model', ['unicycle', 'rolling_disk'])
def test_replanning_goes_round_a_disc_centred_on_the_route(model, monkeypatch):
    """Warm replans pressed against a disc's near side stopped there; the other way is tried.

    Every fifth replan, while the plan stops short of a disc the reference runs through.
    """
    disc = (3.0, 0.0, 0.3)
    free, rows_free = _follow(model, [])
    state, rows = _follow(model, [disc])
    assert free is GoalState.ARRIVED and state is GoalState.ARRIVED
    print(f'\n{model}: arrived after {rows[-1, 0]:.1f} s ({rows_free[-1, 0]:.1f} s without '
          'the disc)')
    assert rows[-1, 0] <= 1.5 * rows_free[-1, 0]
    gaps = np.hypot(rows[:, 1] - disc[0], rows[:, 2] - disc[1]) - disc[2] - 0.2
    assert gaps.min() >= -1e-3
    beside = np.abs(rows[:, 1] - disc[0]) < disc[2]
    assert len(set(np.sign(rows[beside, 2]))) == 1  # one way round, no dithering
    monkeypatch.setattr(rh, 'DETOUR_EVERY', 10**9)  # warm replans alone
    state, rows = _follow(model, [disc], seconds=20.0)
    assert state is GoalState.BLOCKED and rows[-1, 1] < disc[0] - disc[2]


@pytest.mark.solve
@pytest.mark.slow
def test_random_scenes_of_discs_on_and_near_the_route_are_got_past():
    """Ten seeded scenes of 3-6 discs within 0.5 m of a 6 m route: at least 9 arrive.

    Neighbours too close to pass between are gone round as one cluster; a robot held up
    behind its reference looks for detours along its way back to it.
    """
    rng, arrived, closest = np.random.default_rng(0), 0, np.inf
    for _ in range(10):
        count = rng.integers(3, 7)
        discs = np.c_[rng.uniform(1.0, 5.0, count), rng.uniform(-0.5, 0.5, count),
                      rng.uniform(0.1, 0.3, count)]
        state, rows = _follow('unicycle', discs, seconds=25.0)
        arrived += state is GoalState.ARRIVED
        gaps = np.hypot(rows[:, None, 1] - discs[:, 0], rows[:, None, 2] - discs[:, 1])
        closest = min(closest, float((gaps - discs[:, 2] - 0.2).min()))
    print(f'\n10 scenes of 3-6 discs: {arrived} arrived, closest approach {closest:+.4f} m')
    assert arrived >= 9 and closest >= -0.02
