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

"""The three tracking solvers: the paper's figures, mutual agreement, optimality conditions."""
import casadi as ca
import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.examples.experiments import particle_problem, replay, sleigh_problem
from systems import inclined_knife_edge


@pytest.fixture(scope='module')
def sleigh_literal():
    problem = sleigh_problem(wrap_angles=False)
    return problem, nht.solve(problem, 'variational')


@pytest.mark.solve
def test_sleigh_reproduces_the_paper(sleigh_literal):
    """§5 literal formulation: discrete cost 42.369 (independent prototype).

    Exact terminal state, admissible to round-off; the controls replayed on the continuous dynamics
    land within 0.01 of the planned end state.
    """
    problem, sol = sleigh_literal
    assert sol.success
    assert abs(sol.cost - 42.369) / 42.369 < 2e-3
    assert sol.terminal_error <= 1e-8
    assert sol.details['admissibility_residual'] <= 1e-10
    replayed = replay(problem, sol.u)
    end_gap = np.linalg.norm(np.hstack([replayed.q[-1] - sol.q[-1], replayed.v[-1] - sol.v[-1]]))
    assert end_gap < 0.01
    # literal angles: the heading turns the long way, down from 4 pi/3 (never up through 2 pi)
    assert sol.q[:, 2].max() < 4 * np.pi / 3 + 0.01 and sol.q[-1, 2] < 1.0


@pytest.mark.solve
def test_halving_h_converges_at_second_order():
    """Reference figures (docs/theory.md §5): 42.3535, 42.3497, 42.3487 for N = 100, 200, 400."""
    costs = [nht.solve(sleigh_problem(steps=n), 'variational').cost for n in (50, 100, 200)]
    d1, d2 = costs[0] - costs[1], costs[1] - costs[2]
    assert abs(costs[1] - 42.3535) < 2e-3 and abs(costs[2] - 42.3497) < 2e-3
    assert 3.0 < d1 / d2 < 5.0  # ratio 4 for a second-order method


def _discrete_euler_lagrange_residual(problem, sol):
    """Stationarity of the extended discrete action sum (§5) at the interior knots.

    Derived here from the paper's formulas, with the solver's multipliers lambda^k.
    """
    system, h, eps = problem.system, problem.h, problem.epsilon
    n, k = system.n, system.k
    qa, qb, qr = ca.SX.sym('qa', n), ca.SX.sym('qb', n), ca.SX.sym('qr', n)
    va, vb, vr = ca.SX.sym('va', k), ca.SX.sym('vb', k), ca.SX.sym('vr', k)
    qm, vm, vd = (qa + qb) / 2, (va + vb) / 2, (vb - va) / h
    _, f0 = system.dynamics_fn(qm, vm, ca.DM.zeros(k))
    l_d = h * 0.5 * (ca.sumsqr(qm - qr) + ca.sumsqr(vm - vr) + eps * ca.sumsqr(vd - f0))
    psi = (qb - qa) / h - system.rho_fn(qm) @ vm
    lam = ca.SX.sym('lam', n)
    ext = l_d + lam.T @ psi
    grads = ca.Function('g', [qa, va, qb, vb, qr, vr, lam],
                        [ca.gradient(ext, ca.vertcat(qa, va)),
                         ca.gradient(ext, ca.vertcat(qb, vb))])
    q_ref, v_ref = problem.reference_at(problem.grid[:-1] + h / 2)
    multipliers = -h * sol.costates[0]  # the solver reports costates lambda = -lambda^k / h
    worst = 0.0
    for j in range(1, problem.steps):
        _, d34_prev = grads(sol.q[j - 1], sol.v[j - 1], sol.q[j], sol.v[j], q_ref[j - 1],
                            v_ref[j - 1], multipliers[j - 1])
        d12_next, _ = grads(sol.q[j], sol.v[j], sol.q[j + 1], sol.v[j + 1], q_ref[j], v_ref[j],
                            multipliers[j])
        worst = max(worst, float(np.abs(np.array(d12_next + d34_prev)).max()))
    return worst


@pytest.mark.solve
@pytest.mark.parametrize('make', [lambda: sleigh_problem(wrap_angles=False),
                                  lambda: particle_problem(2)])
def test_variational_solution_satisfies_discrete_euler_lagrange(make):
    problem = make()
    sol = nht.solve(problem, 'variational')
    assert _discrete_euler_lagrange_residual(problem, sol) < 1e-8
    assert sol.details['admissibility_residual'] < 1e-10


@pytest.mark.solve
@pytest.mark.parametrize('case, pmp_cost, var_cost', [(1, 14.8598, 14.8594), (2, 5.0484, 5.0482)])
def test_particle_cases_reproduce_pmp_and_variational_costs(case, pmp_cost, var_cost):
    problem = particle_problem(case)
    pmp = nht.solve(problem, 'pmp')
    var = nht.solve(problem, 'variational')
    assert pmp.success and pmp.route == 'zero-costates'  # the paper's own route works here
    assert abs(pmp.cost - pmp_cost) / pmp_cost < 3e-3
    assert abs(var.cost - var_cost) / var_cost < 3e-3
    # the discrete costates approximate the PMP costates (O(h) apart: midpoints vs knots)
    assert np.allclose(var.costates[0][0], pmp.costates[0][0],
                       atol=0.15 * np.abs(pmp.costates[0][0]).max())


def _unicycle_circle_problem():
    uni = nht.models.unicycle(m=2.0, J=0.5)
    ref = nht.simulate(uni, [1.0, 0.0, np.pi / 2], [0.8, 0.8], np.linspace(0, 8, 161))
    return nht.TrackingProblem(uni, ref, q0=[0.0, -0.5, 0.3], v0=[0.0, 0.0], horizon=6.0,
                               steps=60, epsilon=0.5, terminal='cost', omega=5.0)


def _knife_edge_problem():
    knife = inclined_knife_edge()
    ref = nht.simulate(knife, [0, 0, 0], [0.0, 0.6], np.linspace(0, 4, 81))
    return nht.TrackingProblem(knife, ref, q0=[0.3, 0.2, 0.5], v0=[0.2, 0.0], horizon=3.0,
                               steps=40, epsilon=2.0, terminal='cost', omega=2.0)


def _rolling_disk_problem():
    disk = nht.models.rolling_disk()
    ref = nht.simulate(disk, [0, 0, 0, 0], [0.5, 2.0], np.linspace(0, 5, 101))
    return nht.TrackingProblem(disk, ref, q0=[0.2, -0.3, 0.4, 0.0], v0=[0.0, 1.0], horizon=4.0,
                               steps=40, epsilon=1.0, terminal='cost', omega=1.0)


@pytest.mark.solve
@pytest.mark.parametrize('make', [
    lambda: sleigh_problem(wrap_angles=False, terminal='cost'),
    lambda: sleigh_problem(wrap_angles=True, terminal='cost'),
    pytest.param(_unicycle_circle_problem, marks=pytest.mark.slow),
    _knife_edge_problem, _rolling_disk_problem,
], ids=['sleigh', 'sleigh_wrapped', 'unicycle', 'knife_edge', 'rolling_disk'])
def test_methods_agree_on_terminal_cost_problems(make):
    """PMP and the variational method agree within 0.5 %, multiple shooting within 3 %."""
    problem = make()
    var = nht.solve(problem, 'variational')
    pmp = nht.solve(problem, 'pmp')
    ms = nht.solve(problem, 'multiple_shooting')
    assert var.success and pmp.success and ms.success, (pmp.message, ms.message)
    assert abs(pmp.cost - var.cost) / var.cost < 5e-3
    assert abs(ms.cost - var.cost) / var.cost < 3e-2
    assert np.abs(pmp.q - var.q).max() < 0.05 * (1 + np.abs(var.q).max())


@pytest.mark.solve
@pytest.mark.slow
def test_pmp_recovers_where_shooting_from_zero_blows_up():
    problem = sleigh_problem(wrap_angles=False)
    sol = nht.solve(problem, 'pmp')
    assert sol.success
    assert sol.message.startswith('zero-costates -> ')  # plain shooting failed first
    assert sol.route.startswith(('variational-costates', 'multiple-shooting-pmp'))
    assert abs(sol.cost - 42.369) / 42.369 < 5e-3


@pytest.mark.unit
def test_pmp_never_hangs_and_reports_the_deadline():
    from nh_tracking.solvers.pmp import solve_pmp

    sol = solve_pmp(sleigh_problem(wrap_angles=False), max_time=0.3)
    assert not sol.success and 'deadline' in sol.message
    assert sol.solve_time < 5.0  # a bound on the guard, not a performance figure
    assert np.all(np.isfinite(sol.q)) and sol.cost == np.inf


@pytest.mark.solve
def test_wrapping_makes_the_cost_independent_of_whole_turns():
    base = nht.solve(sleigh_problem(wrap_angles=True), 'variational')
    shifted_problem = sleigh_problem(wrap_angles=True)
    shifted_problem = nht.TrackingProblem(
        shifted_problem.system, shifted_problem.reference,
        q0=shifted_problem.q0 + [0, 0, 2 * np.pi], v0=shifted_problem.v0, horizon=5.0,
        steps=50, wrap_angles=True)
    shifted = nht.solve(shifted_problem, 'variational')
    assert abs(shifted.cost - base.cost) < 1e-6 * base.cost
    assert base.cost < 0.5 * 42.369 and abs(base.cost - 17.9) < 0.1
    literal_shifted = nht.TrackingProblem(
        shifted_problem.system, shifted_problem.reference, q0=shifted_problem.q0,
        v0=shifted_problem.v0, horizon=5.0, steps=50, wrap_angles=False)
    assert nht.solve(literal_shifted, 'variational').cost > 100  # 10 pi/3 heading error


@pytest.mark.solve
@pytest.mark.slow
def test_multi_start_finds_the_best_and_several_minima():
    sol = nht.solve(sleigh_problem(wrap_angles=False), 'variational', starts=24, seed=1)
    assert abs(sol.cost - 42.369) / 42.369 < 2e-3
    assert len(sol.minima) > 1 and sol.minima[0][0] == pytest.approx(sol.cost)
    assert all(c2 > c1 for (c1, _), (c2, _) in zip(sol.minima, sol.minima[1:]))


@pytest.mark.solve
def test_warm_start_from_a_previous_plan_converges_faster(sleigh_literal):
    problem, cold = sleigh_literal
    warm = nht.solve(problem, 'variational', initial_guess=cold)
    assert warm.cost == pytest.approx(cold.cost, rel=1e-9)
    assert warm.iterations < cold.iterations


@pytest.mark.unit
@pytest.mark.slow
@pytest.mark.parametrize('kwargs, message', [
    ({'horizon': 0.0}, 'horizon'), ({'steps': 1}, 'steps'), ({'epsilon': -1.0}, 'epsilon'),
    ({'terminal': 'free'}, 'terminal'), ({'q0': [0, np.nan, 0]}, 'finite'),
])
def test_bad_problems_are_rejected(kwargs, message):
    base = {'system': nht.models.chaplygin_sleigh(), 'reference': sleigh_problem().reference,
            'q0': [0, 0, 0], 'v0': [0, 0], 'horizon': 5.0, 'steps': 50}
    base.update(kwargs)
    with pytest.raises(ValueError, match=message):
        nht.TrackingProblem(**base)
    with pytest.raises(ValueError, match='unknown method'):
        nht.solve(sleigh_problem(), 'shooting')


@pytest.mark.solve
@pytest.mark.slow
def test_compiled_real_time_iteration_gives_the_interpreted_step(tmp_path, monkeypatch):
    """compiled=True with iterations: the Gauss-Newton step with its factorisation written out.

    Built in the background (the first steps interpreted), then swapped in; the same plan as
    CasADi's sparse LDL gives, from the same warm guess.
    """
    import shutil

    from nh_tracking.solvers.compiled import wait_for_builds
    from nh_tracking.solvers.inequalities import Shape
    from nh_tracking.solvers.midpoint import transcription
    from nh_tracking.solvers.variational import solve_variational

    if shutil.which('gcc') is None:
        pytest.skip('no C compiler: the interpreted step is used instead')
    monkeypatch.setenv('NH_TRACKING_CACHE', str(tmp_path))
    problem = particle_problem(1, h=0.25)
    converged = solve_variational(problem)
    guess = (converged.q + 0.01, converged.v - 0.02, converged.u)
    step = transcription(problem.system, problem.steps, problem.terminal, False, 'fatrop',
                         True, Shape(), 1).newton
    first = solve_variational(problem, guess, compiled=True, iterations=1)
    assert first.route == 'gauss-newton' and not step.compiled
    wait_for_builds()
    assert step.compiled and len(list(tmp_path.glob('function-*.so'))) == 1
    compiled = solve_variational(problem, guess, compiled=True, iterations=1)
    interpreted = solve_variational(problem, guess, iterations=1)
    assert compiled.route == interpreted.route == 'gauss-newton'
    assert compiled.iterations == interpreted.iterations
    # both factorise the quasi-definite KKT matrix without pivoting, in different orders; its
    # primal block is near singular (regularised by 1e-10), so each step carries ~1e-6 of
    # rounding (dense LU with pivoting is as far from either): the plans agree to about that
    for a, b in ((compiled.q, interpreted.q), (compiled.v, interpreted.v),
                 (compiled.u, interpreted.u)):
        assert np.allclose(a, b, atol=1e-4, rtol=1e-4)
    assert compiled.cost == pytest.approx(interpreted.cost, rel=1e-6)
    assert compiled.cost == pytest.approx(converged.cost, rel=1e-3)  # one step: near optimal


@pytest.mark.solve
def test_compiled_nlp_builds_in_the_background_and_gives_the_same_plan(tmp_path, monkeypatch):
    """compiled=True: the first solve runs interpreted while a child process builds the library.

    Later solves use it, with the same plan; a new process finds it by content at once.
    """
    import shutil
    import subprocess
    import sys

    from nh_tracking.solvers.compiled import wait_for_builds
    from nh_tracking.solvers.midpoint import transcription
    from nh_tracking.solvers.variational import solve_variational

    if shutil.which('gcc') is None:
        pytest.skip('no C compiler: the interpreted NLP is used instead')
    monkeypatch.setenv('NH_TRACKING_CACHE', str(tmp_path))
    problem = particle_problem(2, h=0.4)
    first = solve_variational(problem, compiled=True, newton=False)  # (the NLP's own solver)
    nlp = transcription(problem.system, problem.steps, problem.terminal, compiled=True).nlp
    assert not nlp.compiled and first.success  # solved without waiting for the compiler
    wait_for_builds()
    compiled = solve_variational(problem, compiled=True, newton=False)
    assert nlp.compiled and len(list(tmp_path.glob('nlp-*.so'))) == 1
    interpreted = solve_variational(problem, newton=False)
    assert compiled.route == interpreted.route == 'fatrop'
    assert compiled.success and compiled.cost == pytest.approx(interpreted.cost, rel=1e-12)
    assert np.allclose(compiled.q, interpreted.q, atol=1e-10)
    probe = ('from nh_tracking.examples.experiments import particle_problem as pp\n'
             'from nh_tracking.solvers.midpoint import transcription\n'
             'p = pp(2, h=0.4)\n'
             'print(transcription(p.system, p.steps, p.terminal, compiled=True).nlp.compiled)')
    done = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True,
                          timeout=120)
    assert done.stdout.strip() == 'True', done.stderr


@pytest.mark.solve
@pytest.mark.slow
def test_a_library_is_keyed_by_content_and_no_compiler_means_interpreted(
        monkeypatch, caplog, tmp_path):
    import casadi as ca

    from nh_tracking.solvers import compiled

    monkeypatch.setenv('NH_TRACKING_CACHE', str(tmp_path))
    detect = compiled.compiler
    x, p = ca.SX.sym('x', 2), ca.SX.sym('p')
    nlp = {'x': x, 'p': p, 'f': ca.sumsqr(x - p), 'g': x[0] * x[1]}
    monkeypatch.setattr(compiled, '_BUILDS', {})
    monkeypatch.setattr(compiled, 'compiler', lambda: ('/bin/false', 'cc 1.0'))
    build = compiled.LibraryBuild.of_nlp
    base = build('n', 'ipopt', nlp, {}).path
    keys = {base, build('n', 'ipopt', {**nlp, 'f': ca.sumsqr(x)}, {}).path,
            build('n', 'sqpmethod', nlp, {}).path,
            compiled.LibraryBuild.of_function(ca.Function('n', [x, p], [nlp['f']])).path}
    monkeypatch.setattr(compiled, 'compiler', lambda: ('/bin/false', 'cc 2.0'))
    keys.add(build('n', 'ipopt', nlp, {}).path)
    assert len(keys) == 5 and None not in keys  # expression, solver, kind, compiler: new one
    monkeypatch.setattr(compiled, 'compiler', lambda: ('/bin/false', 'cc 1.0'))
    assert build('n', 'ipopt', nlp, {'ipopt.tol': 1e-3}).path == base
    compiled.wait_for_builds(60.0)
    assert build('n', 'ipopt', nlp, {}).library() is None  # /bin/false failed
    monkeypatch.setattr(compiled, 'compiler', detect)
    monkeypatch.setenv('CC', 'no-such-compiler')
    caplog.set_level('INFO', logger='nh_tracking.solvers.compiled')
    detect.cache_clear()
    try:
        for _ in range(2):
            assert build('n', 'ipopt', nlp, {}).library() is None
    finally:
        detect.cache_clear()  # the next test finds the real compiler again
    assert sum('no C compiler' in r.message for r in caplog.records) == 1


@pytest.mark.solve
def test_methods_are_objects_with_their_own_options(sleigh_literal):
    """By name or as an object, the same method gives the same plan.

    An option a method does not take is an error naming the methods that do; backends agree.
    """
    from nh_tracking.planning.receding_horizon import PlannerSettings
    from nh_tracking.solvers import make_method, METHODS, Variational

    problem, reference = sleigh_literal
    assert set(METHODS) == {'variational', 'pmp', 'multiple_shooting'}
    # by default a cold solve is Newton's (line search); a backend asked for by name solves it
    assert reference.route == 'newton (line search)'
    by_object = nht.solve(problem, Variational(backend='ipopt'))
    assert by_object.route == 'ipopt' and by_object.success
    assert by_object.cost == pytest.approx(reference.cost, rel=1e-6)
    with pytest.raises(ValueError, match="takes no option compiled.*taken by \\['variational'"):
        nht.solve(problem, 'pmp', compiled=True)
    with pytest.raises(ValueError, match='takes no option budget'):
        make_method('multiple_shooting', budget=3.0)
    with pytest.raises(ValueError, match="unknown method 'magic'"):
        make_method('magic')
    with pytest.raises(ValueError, match='backend must be one of'):
        Variational(backend='snopt')
    with pytest.raises(ValueError, match='give options to the method object'):
        make_method(Variational(), compiled=True)
    with pytest.raises(ValueError, match='takes no option compiled'):
        PlannerSettings(method='multiple_shooting', compiled=True)
    assert make_method('pmp', budget=5.0).budget == 5.0


def _knife_reference() -> nht.Trajectory:
    return nht.simulate(inclined_knife_edge(), [0.0, 0.0, 0.0], [0.5, 0.3],
                        np.linspace(0.0, 6.0, 61))


@pytest.mark.solve
@pytest.mark.parametrize('make', [lambda: sleigh_problem(wrap_angles=True, terminal='cost'),
                                  lambda: nht.TrackingProblem(
                                      inclined_knife_edge(), _knife_reference(), [0.0, 0.4, 0.3],
                                      [0.2, 0.0], 3.0, 30, terminal='equality')])
def test_gauss_newton_real_time_iterations_converge_to_the_nlp_solution(make):
    """Repeated real-time iterations (one Gauss-Newton KKT step each) reach fatrop's optimum.

    At the optimum a step stays put and its multipliers are the NLP's: the step solves the
    KKT conditions, whatever Hessian it uses.
    """
    from nh_tracking.solvers.variational import solve_variational

    problem = make()
    exact = nht.solve(problem, second_look=False)
    rng = np.random.default_rng(3)  # a plan near the optimum, as a shifted previous plan is
    q = exact.q + 0.01 * rng.standard_normal(exact.q.shape)
    v = exact.v + 0.01 * rng.standard_normal(exact.v.shape)
    costs = []
    for _ in range(30):  # Gauss-Newton: linear convergence, the rate set by the curvature
        step = solve_variational(problem, (q, v, None), iterations=1)
        assert step.route == 'gauss-newton' and step.message == 'real-time iteration'
        q, v, costs = step.q, step.v, costs + [step.cost]
    assert abs(costs[-1] - exact.cost) <= 1e-8 * max(1.0, exact.cost)
    assert np.abs(step.q - exact.q).max() < 1e-6 and step.details['admissibility_residual'] < 1e-9
    still = solve_variational(problem, (exact.q, exact.v, exact.u), iterations=1)
    assert np.abs(still.q - exact.q).max() < 1e-7
    for mine, theirs in zip(still.costates, exact.costates):
        assert np.abs(mine - theirs).max() < 1e-5 * max(1.0, np.abs(theirs).max())
