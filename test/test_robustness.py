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

"""A numerical core that never hangs and never silently accepts bad data."""
import dataclasses
import time

import casadi as ca
import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.examples.experiments import sleigh_problem
from nh_tracking.solvers import sample_plan, Variational
from nh_tracking.solvers.search import random_guess
from nh_tracking.solvers.variational import proven_minimum

L = 0.5  # the snakeboard's half wheelbase


def _snakeboard_data(**extra):
    board = nht.models.snakeboard()

    def constraints(q):
        theta, phi = q[2], q[4]
        return ca.vertcat(
            ca.horzcat(-ca.sin(theta + phi), ca.cos(theta + phi), L * ca.cos(phi), 0, 0),
            ca.horzcat(-ca.sin(theta - phi), ca.cos(theta - phi), -L * ca.cos(phi), 0, 0))
    return nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'theta', 'psi', 'phi'], lambda q: board.metric_fn(q), constraints, **extra)


def _knife(**extra):
    return nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'theta'], lambda q: ca.SX.eye(3),
        lambda q: ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0), angles=['theta'], **extra)


@pytest.mark.unit
def test_a_rank_change_of_the_distribution_is_named():
    """Snakeboard constraints without a domain: D changes rank at phi = +-pi/2."""
    with pytest.raises(ValueError, match='constraints.*lose rank near phi = .?1.571.*domain='):
        _snakeboard_data(angles=['theta', 'psi', 'phi'])


@pytest.mark.unit
def test_an_auto_basis_stays_regular_where_it_is_used():
    """With its domain declared the auto-built basis is finite and independent on all of it.

    At phi = 0 (where a per-sample normalisation gave NaN before) and near the ends.
    """
    board = _snakeboard_data(angles=['theta', 'psi'], domain={'phi': (-np.pi / 2, np.pi / 2)})
    assert board.basis_condition >= 1e-3
    for phi in np.linspace(-1.5, 1.5, 61):
        for theta in (0.0, 1.0, -2.5):
            rho = board.rho([0.3, -0.2, theta, 0.1, phi])
            gram = rho.T @ board.metric([0, 0, theta, 0, phi]) @ rho
            assert np.all(np.isfinite(rho)) and np.linalg.eigvalsh(gram)[0] > 1e-3


@pytest.mark.unit
@pytest.mark.parametrize('extra, message', [
    ({'basis': lambda q: ca.horzcat(q[0] * ca.vertcat(ca.cos(q[2]), ca.sin(q[2]), 0),
                                    ca.vertcat(0, 0, 1))}, r'loses rank near x = 0\b'),
    ({'basis': lambda q: ca.horzcat(ca.vertcat(ca.cos(q[2]), ca.sin(q[2]), 0),
                                    ca.vertcat(0, 0, ca.sqrt(q[0] - 10)))}, 'not finite at'),
    ({'potential': lambda q: ca.log(q[1] - 100)}, r'potential\(q\) or its gradient is not'),
    ({'name': 'my-robot'}, 'system name'), ({'name': 'a.b'}, 'system name'),
    ({'name': 'a b'}, 'system name'), ({'name': 'a__b'}, 'system name'),
])
def test_irregular_data_is_refused_naming_where(extra, message):
    with pytest.raises(ValueError, match=message):
        _knife(**extra)


@pytest.mark.unit
def test_dependent_constraint_rows_are_refused():
    with pytest.raises(ValueError, match='rows are dependent'):
        nht.NonholonomicSystem.from_constraints(
            ['x', 'y', 'theta'], lambda q: ca.SX.eye(3),
            lambda q: ca.vertcat(ca.horzcat(-ca.sin(q[2]), ca.cos(q[2]), 0),
                                 ca.horzcat(-2 * ca.sin(q[2]), 2 * ca.cos(q[2]), 0)),
            angles=['theta'])


@pytest.mark.solve
def test_simulation_work_is_bounded_and_says_when_it_stopped():
    """V = x^4 cos(1/x^2) oscillates ever faster towards x = 0: steps shrink without end."""
    wild = nht.NonholonomicSystem.from_constraints(
        ['x'], lambda q: ca.SX(1), None, lambda q: q[0] ** 4 * ca.cos(1 / q[0] ** 2),
        domain={'x': (0.0, np.inf)})
    with pytest.raises(RuntimeError, match=r'stopped at t = 0\.5\d*: 20000 evaluations'):
        nht.simulate(wild, [0.5], [-1.0], [0.0, 5.0], max_evaluations=20_000)


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('method', ['variational', 'pmp'])
def test_a_huge_initial_velocity_ends_in_a_bounded_failure(method):
    problem = dataclasses.replace(sleigh_problem(wrap_angles=True), v0=np.array([1e6, 0.0]))
    started = time.perf_counter()
    sol = nht.solve(problem, method, max_time=3.0, second_look=False)
    assert not sol.success and sol.message
    assert time.perf_counter() - started < 10.0  # a bound on the guard, not a speed figure
    assert np.all(np.isfinite(sol.q))


def _far_start():
    """Start the paper's sleigh 28 m away: fatrop needs 20 iterations, two chunks of 10."""
    return dataclasses.replace(sleigh_problem(wrap_angles=False), q0=np.array([20.0, 20.0, 0.0]))


@pytest.mark.solve
def test_max_time_is_a_wall_time_limit_on_every_route():
    """A long limit lets a solve run all the iterations it needs; a short one stops each method.

    The limit is on time alone: no iteration cap comes with it, whatever its value.
    """
    problem = _far_start()
    free = nht.solve(problem, second_look=False)
    limited = nht.solve(problem, max_time=1000.0, second_look=False)
    assert free.iterations > 10 and limited.success
    assert limited.cost == pytest.approx(free.cost, rel=1e-8)  # chunks restart: a few more
    for method in ('variational', 'multiple_shooting', 'pmp'):
        nht.solve(problem, method, max_time=60.0, second_look=False)  # builds its solver
        started = time.perf_counter()
        sol = nht.solve(problem, method, max_time=1e-3, second_look=False)
        assert not sol.success and 'deadline' in sol.message, (method, sol.message)
        assert time.perf_counter() - started < 2.0, method  # bound on the guard
    nht.solve(problem, 'variational', backend='ipopt', max_time=60.0, second_look=False)
    ipopt = nht.solve(problem, 'variational', backend='ipopt', max_time=1e-3, second_look=False)
    assert not ipopt.success and ipopt.message == 'deadline reached'
    for bad in (0, -1.0, float('nan'), '1'):
        with pytest.raises(ValueError, match='max_time'):
            nht.solve(problem, max_time=bad)


@pytest.fixture(scope='module')
def sideways():
    """Ask a sleigh at rest to slide sideways: turning left and right are equally good."""
    sleigh = nht.models.chaplygin_sleigh()
    t = np.linspace(0.0, 5.0, 51)
    reference = nht.Trajectory(t=t, q=np.c_[0 * t, 0.5 * t, 0 * t], v=np.zeros((51, 2)),
                               u=np.zeros((50, 2)))
    return lambda terminal: nht.TrackingProblem(sleigh, reference, np.zeros(3), np.zeros(2),
                                                5.0, 50, terminal=terminal, omega=10.0)


@pytest.mark.solve
@pytest.mark.parametrize('method', ['variational', 'multiple_shooting', 'pmp'])
def test_a_saddle_is_reported_and_left(sideways, method):
    problem = sideways('cost')
    first = nht.solve(problem, method, second_look=False)
    assert first.success and np.abs(first.q[:, 2]).max() < 1e-6  # symmetric: never turns
    sol = nht.solve(problem, method)
    assert sol.success and sol.cost < 0.5 * first.cost
    assert sol.details['saddle_cost'] == pytest.approx(first.cost, rel=1e-6)
    assert 'not a minimum' in sol.message and np.abs(sol.q[:, 2]).max() > 0.1


@pytest.mark.solve
def test_the_second_look_is_not_drawn_back_to_the_saddle(sideways):
    """Newton steps (a warm variational solve) go back to a saddle; the search's method leaves.

    They converge to the nearest stationary point: from a saddle perturbed by 1e-3, back to it
    (a warm solve checks the plan for a saddle only after a long first step). The second look
    and multi-start run the globalised method instead.
    """
    problem = sideways('cost')
    first = nht.solve(problem, second_look=False)
    perturbed = random_guess(problem, np.random.default_rng(0), (first.q, first.v, first.u),
                             1e-3)
    newton = Variational().solve(problem, perturbed)
    assert newton.route == 'newton (working set)'
    assert newton.cost == pytest.approx(first.cost, rel=1e-6)  # the saddle again
    # the inertia check it hands over tells, as the one worked out again from the plan does
    assert newton.minimum_check is not None and not newton.minimum_check()
    assert not proven_minimum(problem, dataclasses.replace(newton, minimum_check=None))
    globalised = Variational().globalised().solve(problem, perturbed)
    assert globalised.route == 'fatrop' and globalised.cost < 0.5 * first.cost


@pytest.mark.solve
def test_the_inertia_check_tells_a_saddle_from_a_minimum_and_spares_the_second_look(sideways):
    """A plan the KKT inertia proves a minimum is returned without a second look.

    The saddle is told by a perturbed restart going lower (above); the minimum by no restart
    from a perturbed copy of it going lower.
    """
    problem = sideways('cost')
    saddle = nht.solve(problem, second_look=False)
    assert not saddle.local_minimum and not proven_minimum(problem, saddle)
    assert proven_minimum(problem, nht.solve(problem))
    for problem in (sleigh_problem(), sleigh_problem(wrap_angles=True, terminal='cost')):
        plain = nht.solve(problem, second_look=False)
        assert proven_minimum(problem, plain)
        default = nht.solve(problem)
        assert default.local_minimum and default.cost == plain.cost  # no second look
        moved = dataclasses.replace(problem, q0=problem.q0 + 1e-2)
        warm = nht.solve(moved, initial_guess=plain)  # a working set: checked afterwards
        assert warm.route == 'newton (working set)' and warm.local_minimum
        unchecked = Variational().solve(moved, sample_plan(moved, plain))
        assert unchecked.minimum_check is not None and unchecked.minimum_check()
        assert proven_minimum(moved, dataclasses.replace(unchecked, minimum_check=None))
        for seed in range(3):
            guess = random_guess(problem, np.random.default_rng(seed),
                                 (plain.q, plain.v, plain.u), 0.05)
            again = Variational().globalised().solve(problem, guess)
            assert not again.success or again.cost >= plain.cost * (1 - 1e-6)


@pytest.mark.solve
def test_a_reachable_target_from_a_symmetric_start_is_reached(sideways):
    problem = sideways('equality')
    assert not nht.solve(problem, second_look=False).success  # the symmetric start stalls
    sol = nht.solve(problem)
    assert sol.success and sol.terminal_error < 1e-8 and 'perturbed start' in sol.message


@pytest.mark.solve
def test_past_the_reference_end_it_holds_still_at_its_last_configuration():
    reference = sleigh_problem().reference  # 6 s long
    sleigh = nht.models.chaplygin_sleigh()
    problem = nht.TrackingProblem(sleigh, reference, reference.q[0], reference.v[0],
                                  horizon=8.0, steps=80, terminal='equality', t0=1.0)
    q_r, v_r = problem.reference_samples[:2]
    past = problem.grid > reference.t[-1]
    assert past.sum() == 30 and np.all(v_r[past] == 0.0)
    assert np.allclose(q_r[past], reference.q[-1])
    sol = nht.solve(problem, second_look=False)
    assert sol.success and np.allclose(sol.v[-1], 0.0, atol=1e-8)
    early = nht.TrackingProblem(sleigh, reference, reference.q[0], [0, 0], 2.0, 20, t0=-1.0)
    q_e, v_e = early.reference_samples[:2]
    assert np.all(v_e[:10] == 0.0) and np.allclose(q_e[:10], reference.q[0])


BASE = {'system': nht.models.chaplygin_sleigh(), 'q0': [0, 0, 0], 'v0': [0, 0],
        'horizon': 5.0, 'steps': 50}


@pytest.mark.unit
@pytest.mark.parametrize('change, error, message', [
    ({'horizon': '5'}, TypeError, "horizon must be a number, got '5'"),
    ({'steps': 50.5}, ValueError, 'steps must be an integer'),
    ({'t0': 'now'}, TypeError, 't0 must be a number'),
    ({'reference': np.zeros((3, 3))}, TypeError, 'reference must be a Trajectory'),
    ({'reference': lambda t: (np.zeros((len(t), 2)), np.zeros((len(t), 2)))}, ValueError,
     r'reference\(times\) must return'),
    ({'q0': [0, 0]}, ValueError, 'q0 must have 3 entries'),
])
def test_bad_problem_arguments_get_errors_naming_them(change, error, message):
    args = {**BASE, 'reference': sleigh_problem().reference, **change}
    with pytest.raises(error, match=message):
        nht.TrackingProblem(**args)


@pytest.mark.unit
def test_bad_solve_arguments_get_errors_naming_them():
    problem = sleigh_problem(wrap_angles=True)
    wrong_width = nht.Trajectory(t=[0.0, 5.0], q=np.zeros((2, 2)), v=np.zeros((2, 2)),
                                 u=np.zeros((1, 2)))
    with pytest.raises(ValueError, match='q and v of widths'):
        nht.TrackingProblem(**{**BASE, 'reference': wrong_width})
    with pytest.raises(TypeError, match='initial_guess must be a Solution or a Trajectory'):
        nht.solve(problem, initial_guess=np.zeros((51, 3)))
    board_plan = nht.Trajectory(t=problem.grid, q=np.zeros((51, 5)), v=np.zeros((51, 3)),
                                u=np.zeros((50, 2)))
    with pytest.raises(ValueError, match='another system'):
        nht.solve(problem, initial_guess=board_plan)
    with pytest.raises(dataclasses.FrozenInstanceError, match="'steps'"):
        problem.steps = 0
    with pytest.raises(ValueError, match='starts must be an integer'):
        nht.solve(problem, starts=0)


@pytest.mark.solve
@pytest.mark.slow
def test_multi_start_honours_the_guess_the_time_limit_and_every_method():
    problem = sleigh_problem(wrap_angles=False)
    single = nht.solve(problem, second_look=False)
    pmp = nht.solve(problem, 'pmp', starts=3, initial_guess=single, seed=2, processes=2)
    assert pmp.success and pmp.cost == pytest.approx(42.369, rel=5e-3)
    assert 'zero-costates' not in pmp.message  # started from the guess's costates
    late = nht.solve(_far_start(), starts=3, max_time=1e-3, processes=2)
    assert not late.success and 'deadline' in late.message


@pytest.mark.solve
def test_a_plan_that_does_not_replay_is_no_minimum():
    from nh_tracking.solvers.search import _best_with_minima, replay_gap

    problem = sleigh_problem(wrap_angles=True)
    good = nht.solve(problem, second_look=False)
    artefact = dataclasses.replace(good, cost=good.cost - 1.0, v=good.v * 50.0, details={})
    good.details['replay_gap'] = replay_gap(problem, good)
    artefact.details['replay_gap'] = replay_gap(problem, artefact)
    assert good.details['replay_gap'] < 0.01 < 0.1 < artefact.details['replay_gap']
    best = _best_with_minima([artefact, good])
    assert best is good and best.minima == [(good.cost, 1)] and best.details['artefacts'] == 1


@pytest.mark.solve
def test_solver_messages_are_words():
    from nh_tracking.solvers.nlp import status_message

    from nh_tracking.solvers import Variational

    problem = sleigh_problem(wrap_angles=True)
    sol = nht.solve(problem, Variational(newton=False), second_look=False)
    assert sol.route == 'fatrop' and sol.message == 'converged'
    sol = nht.solve(problem, second_look=False)
    assert sol.route == 'newton (line search)' and sol.message == 'converged'
    assert status_message(1) == 'maximum iterations reached'
    assert status_message('4') == 'locally infeasible'
    assert status_message('Maximum_Iterations_Exceeded') == 'maximum iterations exceeded'


@pytest.mark.solve
@pytest.mark.slow
def test_pmp_controls_replay_their_plan():
    """``control_law(t)`` replays PMP's plan exactly; ``u``, held per interval, to O(h^2).

    The held controls are fitted to the plan: they replay it better than the continuous law's
    midpoint samples and as well as the variational plan's controls.
    """
    problem = sleigh_problem(wrap_angles=True, terminal='cost')
    sol = nht.solve(problem, 'pmp', second_look=False)
    assert sol.success
    gaps = replay_gaps(problem, sol)
    assert gaps['law'] < 1e-6
    assert gaps['held'] < 0.5 * gaps['midpoint samples'] and gaps['held'] < 0.01


def replay_gaps(problem, sol) -> dict:
    """Return how far the plan's controls, replayed on the continuous dynamics, stray from it."""
    mids = sol.t[:-1] + 0.5 * np.diff(sol.t)
    controls = {'held': sol.u, 'midpoint samples': np.array([sol.control_law(t) for t in mids]),
                'law': lambda t, q, v: sol.control_law(t)}
    gaps = {}
    for name, u in controls.items():
        try:
            replayed = nht.simulate(problem.system, sol.q[0], sol.v[0], sol.t, u, rtol=1e-11)
        except RuntimeError:  # e.g. it drifted out of the model's domain
            gaps[name] = np.inf
            continue
        gaps[name] = np.abs(np.hstack([replayed.q - sol.q, replayed.v - sol.v])).max()
    return gaps
