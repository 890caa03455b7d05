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

import nh_tracking as nht
from nh_tracking.detours import blocking_discs, detour_guesses


def _straight(system, speed_row, q0, v0, disc, duration=10.0):
    """A straight reference along x from the origin, and a problem with ``disc`` on it."""
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
    assert limits.plan_violation(plan.q, plan.v, plan.u) <= 1e-6  # knots and midpoints
    assert limits.swept(np.vstack([plan.q[:1], 0.5 * (plan.q[1:] + plan.q[:-1])])) == 0.0
    search = nht.solve(problem, starts=8)
    print(f'\n{case}: {plan.cost:.4f} ({plan.route}); starts=8: {search.minima}')
    assert plan.cost <= search.cost * 1.01


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
                               60, obstacles=[(x, 0.0, 0.1) for x in (0.6, 1.2, 1.8, 2.4)],
                               robot_radius=0.1)
    assert [s for _, s in detour_guesses(many, many.reference_samples[0])] == [
        (1, 1, 1, 1), (-1, -1, -1, -1)]  # past three discs: all on one side, then the other
