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

"""The variational route table: which backend runs where, and the typed record of what ran."""
import dataclasses
import time

import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.examples.experiments import particle_problem, sleigh_problem
from nh_tracking.problem.attempts import Backend, Status
from nh_tracking.solvers import sample_plan, Variational
from nh_tracking.solvers.base import Guess
from nh_tracking.solvers.routes import NOT_FINITE, PAUSE, PAUSE_AFTER, ROUTES
from nh_tracking.solvers.variational import RETRIES
from systems import polar_knife_past_the_origin

pytestmark = pytest.mark.solve


def _record(plan):
    return [(a.backend, a.status) for a in plan.attempts]


def _consistent(plan):
    """Check that a plan has attempts, and that they sum to no more than its solve time."""
    assert plan.attempts, plan.route
    assert sum(a.time for a in plan.attempts) <= plan.solve_time + 1e-9
    assert all(a.iterations >= 0 and a.time >= 0 for a in plan.attempts)


@pytest.mark.parametrize('problem', [sleigh_problem(wrap_angles=False),
                                     particle_problem(1)],
                         ids=['sleigh', 'particle'])
def test_each_row_runs_where_it_applies_and_says_so(problem):
    """Cold: the line search; warm: the working set; real-time: Gauss-Newton; else the NLP's."""
    cold = Variational().solve(problem)
    assert _record(cold) == [(Backend.LINE_SEARCH, Status.CONVERGED)]
    assert cold.route == Backend.LINE_SEARCH.value and cold.iterations == \
        cold.attempts[0].iterations
    moved = dataclasses.replace(problem, q0=problem.q0 + 1e-2)
    warm = Variational().solve(moved, Guess(cold.q, cold.v, cold.u, cold.multipliers))
    assert _record(warm) == [(Backend.WORKING_SET, Status.CONVERGED)]
    assert warm.route == Backend.WORKING_SET.value
    rti = Variational(iterations=1).solve(moved, Guess(cold.q, cold.v, cold.u))
    assert _record(rti) == [(Backend.GAUSS_NEWTON, Status.ITERATED)]
    for method, backend in ((Variational(newton=False), Backend.FATROP),
                            (Variational(backend='ipopt'), Backend.IPOPT)):
        plan = method.solve(problem)
        assert _record(plan) == [(backend, Status.CONVERGED)] and plan.route == backend.value
        assert plan.cost == pytest.approx(cold.cost, rel=1e-6)
    for plan in (cold, warm, rti):
        _consistent(plan)


def test_a_real_time_iteration_left_off_the_model_hands_over_to_a_converged_solve():
    """The sleigh from a guess at rest on the origin: the steps do not reach a trajectory."""
    problem = sleigh_problem(wrap_angles=False)
    steps, k, r = problem.steps, problem.system.k, problem.system.r
    guess = Guess(np.zeros((steps + 1, problem.system.n)), np.ones((steps + 1, k)),
                  np.zeros((steps, r)))
    plan = Variational(iterations=1).solve(problem, guess)
    assert plan.success
    assert _record(plan)[0] == (Backend.GAUSS_NEWTON, Status.HANDED_OVER)
    assert plan.attempts[-1].status is Status.CONVERGED
    _consistent(plan)


def test_a_line_search_that_does_not_settle_hands_over_to_the_interior_point():
    """A particle on a 0.2 s horizon at eps = 100: the line search stalls (test_line_search)."""
    particle = nht.models.nonholonomic_particle()
    reference = nht.simulate(particle, np.zeros(3), np.array([0.5, 0.4]), np.linspace(0, 5, 101))
    problem = nht.TrackingProblem(particle, reference, q0=np.array([-0.09, -0.53, 1.67]),
                                  v0=np.array([0.85, -1.74]), horizon=0.2, steps=40,
                                  epsilon=100.0, terminal='equality')
    plan = Variational().solve(problem)
    assert _record(plan) == [(Backend.LINE_SEARCH, Status.HANDED_OVER),
                             (Backend.FATROP, Status.CONVERGED)]
    assert plan.attempts[0].iterations > 0  # the factorisations it spent are on record
    assert plan.route == 'fatrop'
    _consistent(plan)


def test_a_guess_where_the_nlp_is_not_finite_is_refused_and_recorded():
    problem = sleigh_problem(wrap_angles=False)
    q, v = (a.copy() for a in problem.reference_samples[:2])
    q[5, 0] = np.nan
    plan = Variational().solve(problem, Guess(q, v, None))
    assert not plan.success and plan.message.startswith(NOT_FINITE)
    assert _record(plan)[0] == (Backend.FATROP, Status.NOT_FINITE)


def test_the_retries_run_in_the_tables_order_and_every_attempt_is_kept():
    """Out of the model's domain, then within it as bounds; inside a disc, the soft limits."""
    plan = nht.solve(polar_knife_past_the_origin(), second_look=False)
    assert plan.success and 'the domain as bounds' in plan.route
    assert len(plan.attempts) >= 2 and plan.attempts[-1].status is Status.CONVERGED
    _consistent(plan)
    unicycle, t = nht.models.unicycle(), np.linspace(0.0, 6.0, 121)
    line = nht.Trajectory(t, np.c_[t, 0 * t, 0 * t], np.c_[np.ones_like(t), 0 * t],
                          np.zeros((len(t) - 1, 2)))
    inside = nht.TrackingProblem(unicycle, line, [3.0, 0.2, 0.0], [1, 0], 6.0, 60,
                                 terminal='cost', omega=10.0, obstacles=[(3.0, 0.05, 0.5)],
                                 robot_radius=0.2)
    plan = nht.solve(inside, second_look=False)
    assert not plan.success and 'least-violating' in plan.message
    assert plan.route == 'ipopt (soft limits)'
    assert plan.attempts[-1].backend is Backend.IPOPT
    _consistent(plan)


def test_the_tables_are_what_the_docs_say():
    """The README shows both tables; their order is the order solves take them."""
    assert [row.backend for row in ROUTES] == [Backend.GAUSS_NEWTON, Backend.LINE_SEARCH,
                                               Backend.WORKING_SET, None]
    assert len(RETRIES) == 3
    probe = sleigh_problem(wrap_angles=False)
    plan = nht.solve(probe)  # the public call: the second look's attempts come along
    assert plan.attempts and plan.attempts[0].backend is Backend.LINE_SEARCH
    shooting = nht.solve(probe, 'multiple_shooting', second_look=False)
    assert _record(shooting) == [(Backend.IPOPT, Status.CONVERGED)]


def test_a_working_set_that_keeps_missing_pauses_by_the_plans_count_not_a_shared_one():
    """Misses in a row ride with the plans: the NLPs (shared by every planner) hold no count."""
    problem = sleigh_problem(wrap_angles=False)
    cold = Variational().solve(problem)
    moved = dataclasses.replace(problem, q0=problem.q0 + 1e-2)

    def warm(misses):
        return Variational().solve(moved, Guess(cold.q, cold.v, cold.u, cold.multipliers,
                                                misses))

    for misses in range(PAUSE_AFTER + 2 * PAUSE):
        plan = warm(misses)
        paused = misses >= PAUSE_AFTER and (misses - PAUSE_AFTER) % PAUSE != PAUSE - 1
        if paused:
            assert _record(plan) == [(Backend.WORKING_SET, Status.PAUSED),
                                     (Backend.FATROP, Status.CONVERGED)]
            assert plan.working_set_misses == misses + 1
        else:
            assert _record(plan) == [(Backend.WORKING_SET, Status.CONVERGED)]
            assert plan.working_set_misses == 0
        assert plan.success and plan.cost == pytest.approx(warm(0).cost, rel=1e-7)
    # the count comes along with a plan used as a warm start
    paused = warm(PAUSE_AFTER)
    assert sample_plan(moved, paused).working_set_misses == PAUSE_AFTER + 1


@pytest.mark.parametrize('backend', ['fatrop', 'ipopt'])
def test_an_interior_point_stopped_by_its_deadline_says_so_in_its_attempts(backend):
    """Stopped before it began or between iterations, the attempt's status is DEADLINE."""
    problem = sleigh_problem(wrap_angles=False)
    method = Variational(backend=backend, newton=False)
    assert method.solve(problem, deadline=60.0).success  # (builds the NLP under a deadline)
    for ahead in (-1.0, 1e-6):
        plan = method.solve_before(problem, None, time.perf_counter() + ahead)
        assert not plan.success and plan.ran_out_of_time, (ahead, plan.attempts)
        assert plan.attempts[-1].status is Status.DEADLINE


@pytest.mark.parametrize('backend, steps', [('fatrop', 1), ('ipopt', 2)])
def test_an_interior_point_stopped_mid_solve_says_so_in_its_attempts(backend, steps,
                                                                     monkeypatch):
    """Its pace lets it start and take a step, then stops it; the attempt says DEADLINE.

    fatrop's second chunk does not start (the sleigh a radian off its heading takes 18
    iterations, a chunk 10); IPOPT's callback (asked at its start, then after an iteration)
    stops it.
    """
    from nh_tracking.solvers import nlp

    problem = sleigh_problem(wrap_angles=False)
    problem = dataclasses.replace(problem, q0=problem.q0 + np.array([0.0, 0.0, 1.0]))
    method = Variational(backend=backend, newton=False)
    assert method.solve(problem, deadline=60.0).success  # (built; it converges with time)
    allowed = iter([True] * steps)
    monkeypatch.setattr(nlp.Pace, 'has_time_for_step', lambda self: next(allowed, False))
    plan = method.solve(problem, deadline=60.0)
    assert not plan.success and plan.ran_out_of_time, plan.attempts
    assert plan.attempts[-1].status is Status.DEADLINE and plan.attempts[-1].iterations > 0
