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

"""Plans a real robot can fly: control and velocity bounds, and obstacles, in every method."""
import dataclasses

import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.examples.experiments import sleigh_problem

TOL = 1e-6


@pytest.fixture(scope='module')
def saturated():
    """Bound the paper's sleigh (wrapped, omega = 10) to |u| <= half its unbounded peak."""
    free_problem = dataclasses.replace(sleigh_problem(wrap_angles=True, terminal='cost'),
                                       omega=10.0)
    free = nht.solve(free_problem, second_look=False)
    u_max = 0.5 * np.abs(free.u).max()
    problem = dataclasses.replace(free_problem, control_bounds=(-u_max, u_max))
    plans = {m: nht.solve(problem, m, second_look=False)
             for m in ('variational', 'multiple_shooting', 'pmp')}
    return free, u_max, plans


@pytest.mark.solve
@pytest.mark.slow
def test_control_bounds_hold_in_every_method_and_they_agree(saturated):
    free, u_max, plans = saturated
    for method, plan in plans.items():
        slack = 1e-5 if method == 'pmp' else TOL
        assert plan.success, (method, plan.message)
        assert np.abs(plan.u).max() <= u_max + slack, method
        assert plan.details['violation'] <= slack, method
    var = plans['variational']
    assert np.mean(np.abs(np.abs(var.u) - u_max) < 1e-5) > 0.05  # the bound is active
    assert var.cost > free.cost * 1.01  # and it costs something
    assert abs(plans['pmp'].cost - var.cost) / var.cost < 0.01
    assert abs(plans['multiple_shooting'].cost - var.cost) / var.cost < 0.03
    law = plans['pmp'].control_law  # the continuous law saturates too
    assert max(np.abs(law(t)).max() for t in np.linspace(0.0, 5.0, 101)) <= u_max + 1e-9


@pytest.fixture(scope='module')
def disc():
    """Ask a unicycle to drive along y = 0 at 1 m/s, a disc lying (almost) on the line."""
    unicycle = nht.models.unicycle(m=2.0, J=0.3)
    t = np.linspace(0.0, 8.0, 81)
    line = nht.Trajectory(t=t, q=np.c_[t, 0 * t, 0 * t], v=np.c_[np.ones_like(t), 0 * t],
                          u=np.zeros((80, 2)))
    return nht.TrackingProblem(unicycle, line, [0, 0, 0], [1, 0], 6.0, 60, terminal='cost',
                               omega=10.0, obstacles=[(3.0, 0.05, 0.5)], robot_radius=0.2)


@pytest.mark.solve
@pytest.mark.parametrize('method', ['variational', 'multiple_shooting'])
def test_the_plan_keeps_clear_of_a_disc_and_gets_past_it(disc, method):
    plan = nht.solve(disc, method)
    assert plan.success, plan.message
    clearance = disc.limits.clearance(plan.q)
    assert clearance.min() >= -TOL  # |p - c| >= r + robot radius at every knot
    if method == 'variational':  # ... and midpoint, where the Lagrangian is evaluated
        assert disc.limits.clearance(0.5 * (plan.q[1:] + plan.q[:-1])).min() >= -TOL
    assert plan.q[-1, 0] > 3.0 + 0.7 and abs(plan.q[-1, 1]) < 0.1  # past it, back on line
    unbounded = nht.solve(dataclasses.replace(disc, obstacles=()), method)
    assert disc.limits.clearance(unbounded.q).min() < -0.5  # the line goes through it


@pytest.mark.solve
def test_velocity_bounds_hold_at_every_knot():
    problem = dataclasses.replace(sleigh_problem(wrap_angles=True, terminal='cost'),
                                  velocity_bounds=([-0.5, -0.3], [0.5, 1.0]))
    for method in ('variational', 'multiple_shooting'):
        plan = nht.solve(problem, method, second_look=False)
        assert plan.success, (method, plan.message)
        assert np.all(plan.v[1:] >= [-0.5 - TOL, -0.3 - TOL])
        assert np.all(plan.v[1:] <= [0.5 + TOL, 1.0 + TOL])
        assert plan.v[1:, 1].min() < -0.3 + 1e-4 or plan.v[1:, 0].max() > 0.5 - 1e-4  # active


@pytest.mark.solve
@pytest.mark.parametrize('method', ['variational', 'multiple_shooting'])
def test_a_start_that_breaks_a_limit_gets_the_least_violating_plan(disc, method):
    inside = dataclasses.replace(disc, q0=np.array([3.0, 0.2, 0.0]))  # in the disc
    plan = nht.solve(inside, method, second_look=False)
    assert not plan.success and 'least-violating' in plan.message
    assert 0 < plan.details['violation'] < 0.7 and np.all(np.isfinite(plan.q))
    assert plan.q[-1, 0] > 4.0  # it still leaves the disc and carries on
    fast = dataclasses.replace(disc, obstacles=(), v0=np.array([2.0, 0.0]),
                               velocity_bounds=(-1.2, 1.2))
    plan = nht.solve(fast, method, second_look=False)
    assert not plan.success and plan.details['violation'] > 0.1
    assert np.abs(plan.v[-1]).max() <= 1.2 + TOL


@pytest.mark.solve
def test_pmp_refuses_what_it_cannot_do(disc):
    with pytest.raises(ValueError, match='pmp takes control bounds only.*variational'):
        nht.solve(disc, 'pmp')


@pytest.mark.unit
@pytest.mark.parametrize('change, message', [
    ({'control_bounds': (1.0, -1.0)}, 'control_bounds has lo > hi'),
    ({'control_bounds': ([0, 0, 0], 1.0)}, 'control_bounds must be a'),
    ({'velocity_bounds': (np.nan, 1.0)}, 'velocity_bounds has NaN'),
    ({'obstacles': [(1.0, 2.0, -0.1)]}, 'obstacles radii must be >= 0'),
    ({'obstacles': [(np.inf, 2.0, 0.1)]}, 'obstacles must have finite'),
    ({'obstacles': [(1.0, 2.0)]}, r'obstacles must be a list of \(x, y, r\)'),
    ({'robot_radius': -0.2}, 'robot_radius must be'),
])
def test_inconsistent_limits_are_refused_naming_the_argument(disc, change, message):
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(disc, **change)


@pytest.mark.unit
def test_only_obstacles_that_can_bend_the_plan_enter_its_nlp():
    """Discs far from the path stay out of the NLP (small and fast); the nearest come first."""
    from nh_tracking.solvers.obstacles import relevant_discs

    path = np.c_[np.linspace(0.0, 5.0, 51), np.zeros(51)]
    discs = np.array([[3.0, 0.3, 0.2],     # on the path
                      [1.0, -1.0, 0.1],    # 0.9 m beside it: within 0.5 + 2 * 0.4 of it
                      [2.0, 4.0, 0.5],     # far beside it
                      [-6.0, 0.0, 0.5],    # far behind the robot
                      [0.5, 0.9, 0.3]])    # near the robot, off the path
    chosen = relevant_discs(discs, np.array([0.0, 0.0]), path, 0.2, 8)
    assert chosen.tolist() == [[0.5, 0.9, 0.3], [1.0, -1.0, 0.1], [3.0, 0.3, 0.2]]
    assert relevant_discs(discs, np.array([0.0, 0.0]), path, 0.2, 1).tolist() == [
        [0.5, 0.9, 0.3]]
    offset = relevant_discs(discs, np.array([2.0, 3.0]), path, 0.2, 8)  # 3 m off the path
    assert [2.0, 4.0, 0.5] in offset.tolist()  # the way back to it passes the far one
    assert len(relevant_discs(np.zeros((0, 3)), np.zeros(2), path, 0.2, 8)) == 0


@pytest.mark.solve
def test_a_plan_that_touches_a_left_out_obstacle_is_replanned_with_it(monkeypatch):
    """Re-solve with the nearest obstacles if the selection ever misses one the plan hits.

    No plan in force goes through an obstacle the planner knows of.
    """
    import nh_tracking.planning.avoidance as avoidance
    import nh_tracking.planning.receding_horizon as rh

    unicycle = nht.models.unicycle()
    t = np.linspace(0.0, 20.0, 201)
    line = nht.Trajectory(t=t, q=np.c_[0.5 * t, 0 * t, 0 * t],
                          v=np.c_[0.5 * np.ones_like(t), 0 * t], u=np.zeros((200, 2)))
    planner = rh.RecedingHorizonPlanner(unicycle, rh.PlannerSettings(  # (no deadline: a
        horizon=5.0, steps=50, robot_radius=0.2, max_solve_time=60.0))  # loaded CPU is slow)
    planner.set_reference(line)
    planner.obstacles = np.array([[1.5, 0.05, 0.3]])
    monkeypatch.setattr(avoidance, 'relevant_discs', lambda discs, *args: discs[:0])
    outcome = planner.plan(0.0, np.zeros(3), np.array([0.5, 0.0]))
    plan = outcome.plan
    assert outcome.status == 'optimal', outcome.message
    grown = nht.TrackingProblem(unicycle, line, np.zeros(3), [0.5, 0], 5.0, 50,
                                obstacles=planner.obstacles, robot_radius=0.2).limits
    assert grown.clearance(np.vstack([plan.q, 0.5 * (plan.q[1:] + plan.q[:-1])])).min() > -TOL


@pytest.mark.solve
def test_a_plan_that_meets_a_disc_left_out_of_its_nlp_is_solved_again_with_those_nearest_it():
    """The replan's obstacle loop, on real solves, names what it did.

    A plan given only a far disc drives through one on the line; solved again with the discs
    nearest that plan, it keeps clear of both; every solve shows in its attempts, and the
    second is told what the first spent. Left-out discs it does not touch change nothing.
    """
    from nh_tracking.solvers.obstacles import clear_of_discs_left_out, touches_one_left_out
    from nh_tracking.solvers.variational import Variational

    method = Variational()
    problem = nht.TrackingProblem(nht.models.unicycle(), _line(), np.zeros(3), [0.5, 0.0],
                                  5.0, 50, terminal='cost', robot_radius=0.2)
    on_line, far = [1.5, 0.05, 0.3], [4.0, 3.0, 0.2]
    discs = np.array([on_line, far])
    given = dataclasses.replace(problem, obstacles=[far])
    first = method.solve(given)
    assert first.success and touches_one_left_out(given, first, discs)
    spent = []

    def solve(problem, guess, before):
        spent.append(before)
        return method.solve(problem, guess)

    plan = clear_of_discs_left_out(solve, given, None, discs)
    assert plan.success, plan.message
    assert '(it touched one left out)' in plan.route
    assert spent[0] == 0.0 and 0.0 < spent[1] < plan.solve_time  # the second gets what is left
    assert len(plan.attempts) > len(first.attempts)
    every = dataclasses.replace(problem, obstacles=discs).limits
    assert every.clearance(np.vstack([plan.q, 0.5 * (plan.q[1:] + plan.q[:-1])])).min() > -TOL

    aside = np.array([far, [2.0, -3.0, 0.3]])  # none near the line: one solve, as it was
    untouched = clear_of_discs_left_out(lambda p, g, spent: method.solve(p, g), given, None,
                                        aside)
    assert untouched.success and untouched.route == first.route
    assert untouched.cost == pytest.approx(first.cost)


@pytest.mark.unit
def test_each_knot_and_midpoint_keeps_clear_of_the_discs_nearest_it():
    """A clearance point's rows take the discs whose edges are nearest it on the guess.

    Checked against a brute force over the points in g's order (midpoint, then the interval's
    end knot): all of them while they fit (2 or 4 slots), the nearest 4 of more, in the discs'
    own order (a disc keeps its slot); the NLP is the same for 5 discs as for 8 (its size
    does not grow with them).
    """
    from nh_tracking.solvers.inequalities import Shape
    from nh_tracking.solvers.midpoint import transcription

    rng = np.random.default_rng(7)
    base = nht.TrackingProblem(nht.models.unicycle(), _line(), [0, 0.2, 0], [0.5, 0], 3.0, 30,
                               terminal='cost', robot_radius=0.1)
    q = base.reference_samples[0] + rng.normal(scale=0.3, size=(31, 3))
    built = {}
    for count in (1, 3, 5, 8):
        discs = np.c_[rng.uniform(0, 1.5, count), rng.uniform(-1, 1, count),
                      rng.uniform(0.1, 0.4, count)]
        problem = dataclasses.replace(base, obstacles=discs)
        tr = transcription(problem.system, 30, 'cost', shape=Shape.of(problem.limits))
        slots = tr.limits.shape.slots
        built[count] = (id(tr), slots)
        assigned = tr.limits.assigned_discs(tr.parameters(problem, q)).reshape(60, slots, 4)
        for j in range(60):
            point = 0.5 * (q[j // 2] + q[j // 2 + 1]) if j % 2 == 0 else q[j // 2 + 1]
            edge = [np.hypot(*(point[:2] - d[:2])) - d[2] - 0.1 for d in discs]
            order = sorted(sorted(range(count), key=edge.__getitem__)[:slots])  # the given order
            np.testing.assert_allclose(assigned[j, :len(order), :3],
                                       problem.limits.obstacles[order], atol=1e-12)
            assert assigned[j, :, 3].tolist() == [1.0] * len(order) + [0.0] * (slots - len(order))
    assert [s for _, s in built.values()] == [2, 4, 4, 4]
    assert built[5][0] == built[8][0]  # one NLP for any crowd


@pytest.mark.solve
@pytest.mark.parametrize('method, discs', [  # crowds the plan meets where its guess was not
    ('variational', [(1.74, -0.19, 0.1), (2.79, 0.77, 0.2), (1.0, -0.37, 0.19), (1.39, 0.09, 0.15),
                     (2.56, 0.13, 0.16), (1.67, -0.91, 0.11), (2.34, -0.8, 0.16),
                     (1.67, -0.53, 0.23)]),
    ('multiple_shooting', [(1.8, -0.59, 0.16), (2.18, -0.9, 0.2), (2.19, -0.57, 0.22),
                           (0.81, 0.2, 0.24), (0.88, 0.77, 0.16), (1.1, -0.3, 0.21),
                           (1.23, -0.27, 0.15)])])
def test_a_plan_among_many_discs_is_clear_of_every_one(method, discs):
    """Solved again from a plan that ran into a disc it was not given: clear of all of them.

    From the plan without obstacles (through them, on the line), each point has the 4 discs
    nearest it there; the plan goes round them into another. Solved again with the discs
    nearest that plan (and, if it still meets one, every disc at every point), it is clear of
    all of them at its points and between them, and a minimum of the problem with every disc
    at every point (a solve from it stays there).
    """
    from nh_tracking.problem.limits import plan_path
    from nh_tracking.solvers.base import Guess
    from nh_tracking.solvers.routes import Route, solve_route

    free = nht.TrackingProblem(nht.models.unicycle(), _line(), [0, 0.3, 0], [0.5, 0], 6.0, 60,
                               terminal='cost', omega=10.0, robot_radius=0.1)
    problem = dataclasses.replace(free, obstacles=discs)
    plan = nht.solve(problem, method, initial_guess=nht.solve(free, second_look=False),
                     second_look=False)
    assert plan.success, plan.message
    assert 'again' in plan.route
    points = plan.q if method == 'multiple_shooting' else plan_path(plan.q)
    assert problem.limits.clearance(points).min() >= -TOL
    assert problem.limits.swept(points) <= TOL  # nor between them
    if method == 'variational':
        every = solve_route(problem, Guess(plan.q, plan.v, plan.u), None, Route(every=True))
        assert every.success and abs(every.cost - plan.cost) <= 1e-6 * plan.cost


@pytest.mark.unit
def test_a_path_through_a_disc_between_its_points_is_caught():
    """Segments between consecutive points may cut into a disc as a chord does, at most 10 %.

    Points on the disc's edge, close together: within (the sagitta); far apart: a polygon that
    cuts in by 17 % of the radius; a jump across the disc from one side to the other, both
    points clear of it: caught, by nearly the radius.
    """
    from nh_tracking.problem.limits import Limits

    limits = Limits.of(nht.models.unicycle(), None, None, [(0.5, 0.0, 0.1)], 0.05)  # R = 0.15

    def arc(step: float) -> np.ndarray:
        angle = np.arange(0.0, np.pi, step)
        return np.c_[0.5 + 0.15 * np.cos(angle), 0.15 * np.sin(angle), 0 * angle]

    assert limits.clearance(arc(0.1)).min() >= -1e-12
    assert limits.swept(arc(0.1)) <= 1e-12
    assert limits.swept(arc(1.2)) == pytest.approx(0.15 * (1 - np.cos(0.6)) - 0.015, rel=1e-9)
    jump = np.c_[[0.0, 0.1, 0.2, 0.3, 0.7, 0.8], np.zeros(6), np.zeros(6)]
    assert limits.clearance(jump).min() == pytest.approx(0.05)
    assert limits.swept(jump) == pytest.approx(0.15 - 0.015)
    assert limits.swept(jump[:4]) == 0.0  # short segments, all clear


def _line(duration: float = 20.0) -> nht.Trajectory:
    t = np.linspace(0.0, duration, int(duration * 10) + 1)
    return nht.Trajectory(t=t, q=np.c_[0.5 * t, 0 * t, 0 * t],
                          v=np.c_[0.5 * np.ones_like(t), 0 * t], u=np.zeros((len(t) - 1, 2)))


@pytest.mark.unit
def test_costmap_discs_do_not_move_with_the_robot():
    """Each blob of cells is one disc wherever the robot is; a long wall is cut on a fixed grid.

    Discs redrawn about the robot's position put a plan hugging one inside the next one.
    """
    from nh_tracking.navigation.costmap import costmap_discs
    from nh_tracking.problem.limits import nearest_discs

    size = 0.05
    x, y = np.meshgrid(np.arange(-40, 200) * size, np.arange(-40, 40) * size)
    centres = [(3.0, 0.05, 0.3), (6.0, -0.05, 0.25), (8.0, 1.0, 0.1)]
    blob = np.zeros(x.shape, dtype=bool)
    for cx, cy, r in centres:
        blob |= np.hypot(x - cx, y - cy) <= r
    cells = np.c_[x[blob], y[blob]]
    wall = np.c_[np.arange(0, 100) * size, np.full(100, -1.9)]  # 5 m long
    every = costmap_discs(np.vstack([cells, wall]), size, 0.5)
    seen = [nearest_discs(every, np.array(c), 30, 50.0)
            for c in ((0.0, 0.0), (2.6, -0.5), (5.9, 0.6), (9.0, 3.0))]
    for discs in seen:
        assert {tuple(d) for d in np.round(discs, 9)} == {tuple(d) for d in np.round(seen[0], 9)}
        blobs = discs[discs[:, 1] > -1.0]
        assert len(blobs) == 3 and len(discs) >= 10  # the wall in pieces of at most 0.5 m
        for cx, cy, r in centres:  # each blob: one disc about it, a cell's half diagonal more
            d = blobs[np.argmin(np.hypot(blobs[:, 0] - cx, blobs[:, 1] - cy))]
            assert np.hypot(d[0] - cx, d[1] - cy) < 0.02 and r <= d[2] <= r + 0.06
    near = nearest_discs(every, np.array([6.0, 0.5]), 2, 50.0)
    assert len(near) == 2 and np.allclose(near[0, :2], [6.0, -0.05], atol=0.02)  # nearest first
    assert len(nearest_discs(every, np.array([20.0, 0.0]), 8, 1.0)) == 0  # none within reach


@pytest.mark.unit
def test_the_gap_to_costmap_cells_is_to_their_squares_and_to_disc_edges():
    from nh_tracking.navigation.costmap import gap

    cells = np.array([[1.0, 0.0], [1.0, 0.1]])  # 0.1 m squares: x 0.95-1.05, y -0.05-0.15
    discs = np.array([[-2.0, 0.0, 0.5]])
    assert gap(np.array([0.75, 0.1]), discs, cells, 0.1) == pytest.approx(0.2)  # face
    assert gap(np.array([0.95 - 0.3, 0.15 + 0.4]), discs, cells, 0.1) == pytest.approx(0.5)
    assert gap(np.array([1.02, 0.0]), discs, cells, 0.1) == 0.0  # inside
    assert gap(np.array([-1.0, 0.0]), discs, cells, 0.1) == pytest.approx(0.5)  # the disc
    assert gap(np.array([0.0, 0.0]), np.zeros((0, 3)), np.zeros((0, 2)), 0.1) == np.inf


@pytest.mark.solve
def test_a_robot_inside_the_margin_it_keeps_still_gets_an_optimal_plan():
    """0.01 m inside an obstacle's clearance: the prepared NLP plans, keeping its distance."""
    import nh_tracking.planning.receding_horizon as rh

    unicycle = nht.models.unicycle()
    planner = rh.RecedingHorizonPlanner(unicycle, rh.PlannerSettings(
        horizon=5.0, steps=50, robot_radius=0.2, u_min=(-0.3,), u_max=(0.3,)))
    planner.prepare()
    planner.set_reference(_line())
    planner.obstacles = np.array([[0.3, 0.49, 0.3]])  # 0.01 m closer than 0.3 + 0.2 to (0.3, 0)
    outcome = planner.plan(0.0, np.array([0.3, 0.0, 0.0]), np.array([0.5, 0.0]))
    assert outcome.status == 'optimal', outcome.message
    plan = outcome.plan
    points = np.vstack([plan.q, 0.5 * (plan.q[1:] + plan.q[:-1])])
    distance = np.hypot(points[:, 0] - 0.3, points[:, 1] - 0.49)
    assert distance.min() >= 0.49 - 0.05 - TOL  # held what it had, less one interval's travel
    assert distance[-1] > 1.0 and plan.q[-1, 0] > 2.0  # and went on past it
    # at rest in front of a disc on the reference: replans must not ratchet it in
    planner.obstacles = np.array([[1.0, 0.02, 0.25]])
    planner.previous = None  # a new situation
    q, v, t, closest, optimal = np.array([0.56, 0.0, 0.0]), np.zeros(2), 1.12, np.inf, 0
    for _ in range(60):
        outcome = planner.plan(t, q, v)
        optimal += outcome.status == 'optimal'
        step = nht.simulate(unicycle, q, v, outcome.plan.t[:2], outcome.plan.u[:1])
        q, v, t = step.q[-1], step.v[-1], t + 0.1
        closest = min(closest, np.hypot(q[0] - 1.0, q[1] - 0.02))
    assert closest >= 0.44 - 1e-3 and optimal >= 50  # 0.01 inside the 0.45 it keeps


@pytest.mark.unit
def test_an_unprepared_structure_is_built_in_the_background_not_in_the_loop():
    import threading

    from nh_tracking.ros.graph import wait_until
    from nh_tracking.solvers.cache import builds_deferred, NotPrepared, PerSystemCache

    cache, system, calls, release = PerSystemCache(), nht.models.unicycle(), [], threading.Event()

    def build() -> str:
        release.wait(10.0)
        calls.append(threading.current_thread().name)
        return 'built'

    with builds_deferred():
        with pytest.raises(NotPrepared, match='background'):
            cache.get(system, 'key', build)
        with pytest.raises(NotPrepared):  # asked again while building: still one build
            cache.get(system, 'key', build)
    release.set()
    assert wait_until(lambda: cache.get(system, 'key', lambda: 'again') == 'built', 10.0)
    assert calls == ['nh_tracking_nlp_build']
    assert cache.get(system, 'other', lambda: 'in line') == 'in line'  # outside: at once


@pytest.mark.unit
def test_the_cache_keeps_the_horizon_sizes_used_last_and_drops_older_ones_together():
    from nh_tracking.solvers.cache import by_steps, PerSystemCache

    cache, system, builds = PerSystemCache(group=by_steps, groups=2), nht.models.unicycle(), []

    def get(steps: int, variant: str) -> tuple:
        return cache.get(system, (steps, variant), lambda: builds.append((steps, variant)) or (
            steps, variant))

    for steps in (10, 20):
        get(steps, 'fatrop'), get(steps, 'ipopt')
    get(10, 'fatrop')  # 10 used last: 20 is the oldest now
    get(30, 'fatrop')
    assert len(cache) == 3 and len(builds) == 5
    get(10, 'ipopt'), get(30, 'fatrop')  # kept: no build
    assert len(builds) == 5
    get(20, 'fatrop')  # dropped with its group: built again, and 10 goes
    assert len(builds) == 6 and len(cache) == 2
    other = nht.models.unicycle()  # another system has groups of its own
    cache.get(other, (10, 'fatrop'), lambda: 'x')
    assert len(cache) == 3
    del other
    assert len(cache) == 2


@pytest.mark.unit
def test_the_fallback_brakes_where_tracking_would_hit_an_obstacle():
    """No optimal plan and an obstacle on the reference: brake as hard as the limits allow."""
    from nh_tracking.planning.fallback import fallback

    unicycle = nht.models.unicycle()
    problem = nht.TrackingProblem(unicycle, _line(), [0.0, 0.0, 0.0], [0.5, 0.0], 5.0, 50,
                                  control_bounds=(-0.3, 0.3), obstacles=[(1.5, 0.0, 0.3)],
                                  robot_radius=0.2)
    plan, what = fallback(problem, problem.limits)
    assert plan.route == 'brake' and 'braking' in what
    assert problem.limits.clearance(plan.q).min() > 0.0  # stops short of it
    assert np.abs(plan.u).max() <= 0.3 + TOL and abs(plan.v[-1, 0]) < 0.05
    inside = dataclasses.replace(problem, q0=np.array([1.4, 0.0, 0.0]))  # tracking drives out
    plan, what = fallback(inside, inside.limits)
    assert plan.route == 'kanayama' and inside.limits.clearance(plan.q[-1:]).min() > 0.0
    clear = dataclasses.replace(problem, obstacles=[(1.5, 2.0, 0.3)])
    plan, what = fallback(clear, clear.limits)  # nothing in the way: the tracking law
    assert plan.route == 'kanayama' and plan.q[-1, 0] > 2.0


@pytest.mark.solve
def test_a_robot_inside_an_obstacle_is_given_the_way_out():
    """Overlapping an obstacle (a collision): the least-violating plan, once its NLP is built.

    The soft NLP is built in the background on first need, so the first replans keep what they
    have; then the least-violating plan leaves the obstacle. One that would go deeper first
    (through it and out: a smaller summed violation than braking) is not put in force.
    """
    import nh_tracking.planning.receding_horizon as rh
    from nh_tracking.ros.graph import wait_until

    unicycle = nht.models.unicycle()
    planner = rh.RecedingHorizonPlanner(unicycle, rh.PlannerSettings(
        horizon=5.0, steps=50, robot_radius=0.2, u_min=(-0.3,), u_max=(0.3,)))
    planner.prepare()
    planner.set_reference(_line())
    planner.obstacles = np.array([[-0.1, 0.1, 0.3]])  # overlapping the robot, behind it
    start = (0.0, np.zeros(3), np.array([0.5, 0.0]))
    first = planner.plan(*start)
    assert first.status != 'optimal' and np.all(np.isfinite(first.plan.u))
    assert wait_until(lambda: planner.plan(*start).status == 'least-violating', 60.0)
    plan = planner.plan(*start).plan
    grown = nht.TrackingProblem(unicycle, _line(), np.zeros(3), [0.5, 0], 5.0, 50,
                                obstacles=planner.obstacles, robot_radius=0.2).limits
    clearance = grown.clearance(plan.q)[:, 0]
    assert clearance[0] < 0 and clearance[-1] > 0  # it starts inside and gets out
    assert clearance.min() >= clearance[0] - TOL and np.abs(plan.u).max() <= 0.3 + TOL
    planner.obstacles = np.array([[0.25, 0.0, 0.3]])  # ahead: the way out is through it
    ahead = nht.TrackingProblem(unicycle, _line(), np.zeros(3), [0.5, 0], 5.0, 50,
                                obstacles=planner.obstacles, robot_radius=0.2).limits
    outcome = planner.plan(*start)
    if outcome.status == 'least-violating':  # only if it goes no deeper than it is
        clearance = ahead.clearance(outcome.plan.q)
        assert clearance.min() >= clearance[0].min() - TOL


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.parametrize('change', [None, 'an obstacle appears', 'the robot grows',
                                    'u_max tightens'])
def test_a_previous_plan_that_breaks_the_limits_now_in_force_is_not_kept(change):
    """A failed replan keeps the previous plan, shifted, only if it keeps the limits in force.

    The plan was made before the obstacle was known (or for a smaller robot, or looser
    torques): following it on would drive into what the planner now knows. A deployed
    planner did exactly that after robot_radius was raised with the robot already inside the
    new clearance (the soft NLP not yet built, every replan failed): it kept its old plan down
    to the bare disc's edge.
    """
    import nh_tracking.planning.receding_horizon as rh

    unicycle = nht.models.unicycle()
    planner = rh.RecedingHorizonPlanner(unicycle, rh.PlannerSettings(horizon=5.0, steps=50))
    planner.prepare()
    planner.set_reference(_line())
    planner.obstacles = np.array([[1.2, 0.25, 0.2]])  # 0.05 m off the plan: clear at radius 0
    start = (np.array([0.1, 0.0, 0.0]), np.array([0.5, 0.0]))
    assert planner.plan(0.0, *start).status == 'optimal'
    changes: dict = {None: {}, 'an obstacle appears': {}, 'the robot grows': {'robot_radius': 0.3},
                     'u_max tightens': {'u_min': (-0.01,), 'u_max': (0.01,)}}[change]
    planner.update(max_solve_time=1e-6, **changes)  # every replan now misses its deadline
    if change == 'an obstacle appears':
        planner.obstacles = np.vstack([planner.obstacles, [1.5, 0.0, 0.3]])
    outcome = planner.plan(0.1, *start)
    if change is None:  # nothing changed: the plan still holds, and is kept
        assert outcome.status == 'shifted', outcome.message
        return
    assert outcome.status in ('fallback', 'stop'), outcome.message
    assert 'breaks the limits in force' in outcome.message
    if change != 'u_max tightens':
        grown = planner.avoidance(0.1).limits(planner.obstacles)
        assert grown.clearance(outcome.plan.q).min() > 0.0  # it brakes short of the disc
