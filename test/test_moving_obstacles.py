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

"""Moving discs (x, y, r, vx, vy): plans keep clear of where each disc is when they get there.

Checked independently of the planner's own clearance rows: the plan's controls replayed on
the continuous dynamics (a fine integrator) against the disc moved on by its velocity, at
every millisecond of the horizon.
"""
import dataclasses

import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.planning.receding_horizon import PlannerSettings, RecedingHorizonPlanner
from nh_tracking.problem.limits import obstacle_discs

ROBOT_RADIUS = 0.1
REPLAY_TOL = 0.01  # [m] a replay may come this much closer than the knots and midpoints


def _replayed_clearance(problem: nht.TrackingProblem, plan: nht.Solution) -> float:
    """Least distance from the robot to a disc's edge (grown) on a fine replay of the plan."""
    fine = np.linspace(plan.t[0], plan.t[-1], int((plan.t[-1] - plan.t[0]) * 1000) + 1)
    law = plan.control_law if plan.control_law is not None else plan.u
    replay = nht.simulate(problem.system, problem.q0, problem.v0, plan.t, law)
    q = np.vstack([np.interp(fine, replay.t, replay.q[:, i]) for i in range(problem.system.n)]).T
    if not np.allclose(replay.q[-1], plan.q[-1], atol=0.05):
        raise AssertionError(f'the replay ends at {replay.q[-1]}, the plan at {plan.q[-1]}')
    axes = list(problem.limits.plane)
    discs = obstacle_discs(problem.obstacles)
    t = (fine - fine[0])[:, None]
    centres = discs[None, :, :2] + t[..., None] * discs[None, :, 3:5]
    gaps = np.linalg.norm(q[:, None, axes] - centres, axis=2)
    return float((gaps - discs[None, :, 2] - problem.robot_radius).min())


def _crossing(system: nht.NonholonomicSystem, v0: list[float]) -> nht.TrackingProblem:
    """Return a straight reference along +x at 0.5 m/s (velocities ``v0``) and a disc crossing it.

    At 0.3 m/s, timed to be on the line when the reference is there (after 2 s, at x = 1).
    """
    reference = nht.simulate(system, np.zeros(system.n), v0, np.linspace(0, 10.0, 101))
    disc = (1.0, -0.6, 0.2, 0.0, 0.3)
    return nht.TrackingProblem(system, reference, np.zeros(system.n), np.array(v0, float),
                               4.0, 40, terminal='cost', omega=10.0, obstacles=[disc],
                               robot_radius=ROBOT_RADIUS)


SYSTEMS = {'unicycle': (nht.models.unicycle(m=2.0, J=0.3), [0.5, 0.0]),
           'sleigh': (nht.models.chaplygin_sleigh(), [0.0, 0.5])}  # coasting straight


@pytest.mark.solve
@pytest.mark.parametrize('name', SYSTEMS)
def test_a_plan_keeps_clear_of_a_disc_crossing_its_way_where_the_disc_will_be(name):
    problem = _crossing(*SYSTEMS[name])
    plan = nht.solve(problem)
    assert plan.success, plan.message
    clearance = _replayed_clearance(problem, plan)
    print(f'\n{name}: a disc crossing at 0.3 m/s, cost {plan.cost:.4f}, route {plan.route}, '
          f'closest replayed approach {clearance:+.4f} m, end {plan.q[-1, :2].round(3)}')
    assert clearance >= -REPLAY_TOL
    assert problem.limits.moving
    # frozen where it starts, or where it will be, it is another problem: each plan hits it
    for frozen_at in (0.0, 2.0):
        still = dataclasses.replace(problem, obstacles=[
            (1.0, -0.6 + 0.3 * frozen_at, 0.2)])
        other = nht.solve(still)
        assert other.success, other.message
        assert _replayed_clearance(problem, other) < -0.05, frozen_at


@pytest.mark.solve
def test_a_disc_at_rest_given_five_numbers_is_the_disc_given_three():
    problem = _crossing(*SYSTEMS['unicycle'])
    three = dataclasses.replace(problem, obstacles=[(1.0, 0.02, 0.2)])
    five = dataclasses.replace(problem, obstacles=[(1.0, 0.02, 0.2, 0.0, 0.0)])
    a, b = nht.solve(three), nht.solve(five)
    assert a.success and b.success and not five.limits.moving
    assert np.array_equal(a.q, b.q) and a.cost == b.cost


@pytest.mark.unit
def test_a_path_through_a_moving_disc_between_its_points_is_caught():
    """Relative to the disc the segment is straight: swept() judges it there."""
    limits = dataclasses.replace(_crossing(*SYSTEMS['unicycle']),
                                 obstacles=[(0.5, -1.0, 0.2, 0.0, 2.0)]).limits
    path = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    # at t = 0 and t = 1 the disc is 1 m off the line on either side; at 0.5 s it is on it
    assert limits.clearance(path, [0.0, 1.0]).min() > 0.7
    assert limits.swept(path, [0.0, 1.0]) > 0.1
    assert limits.swept(path, [0.0, 0.1]) == 0.0  # past it before it arrives
    with pytest.raises(ValueError, match='times'):
        limits.clearance(path)


@pytest.mark.unit
@pytest.mark.parametrize('bad, message', [
    ([(0, 0, 0.2, np.nan, 0)], 'finite'),
    ([(0, 0, 0.2, 1.0)], 'rows of'),
    ([(0, 0, -0.2, 0, 0)], 'radii'),
    ([(0, 0, 0.2), (1, 1, 0.2, 0, 0, 0)], 'rows of'),
    (None, 'list of'),
])
def test_malformed_moving_discs_are_refused_naming_the_argument(bad, message):
    with pytest.raises(ValueError, match=message):
        obstacle_discs(bad)


@pytest.mark.solve
@pytest.mark.slow
def test_a_replanning_robot_crosses_behind_a_disc_crossing_its_way():
    """A RecedingHorizonPlanner replanning every 0.1 s on the continuous dynamics.

    Told where the disc is at each replan, as a tracker would (told nothing newer, the
    planner holds a disc where it would be :data:`.limits.PREDICTION` seconds on).
    """
    system, v0 = SYSTEMS['unicycle']
    problem = _crossing(system, v0)
    planner = RecedingHorizonPlanner(system, PlannerSettings(
        horizon=3.0, steps=30, omega=10.0, terminal='cost', robot_radius=ROBOT_RADIUS))
    planner.set_reference(problem.reference)
    q, v, closest = problem.q0, problem.v0, np.inf
    disc = obstacle_discs(problem.obstacles)[0]
    for k in range(80):
        t = 0.1 * k
        planner.obstacles = np.r_[disc[:2] + t * disc[3:5], disc[2:]][None]
        planner.obstacles_time = t
        outcome = planner.plan(t, q, v)
        step = nht.simulate(system, q, v, [t, t + 0.1], outcome.plan.u[:1])
        for s in np.linspace(0.0, 0.1, 11)[1:]:
            qs = nht.simulate(system, q, v, [t, t + s], outcome.plan.u[:1]).q[-1]
            centre = disc[:2] + (t + s) * disc[3:5]
            closest = min(closest, float(np.hypot(*(qs[:2] - centre)) - disc[2] - ROBOT_RADIUS))
        q, v = step.q[-1], step.v[-1]
    print(f'\nreplanning past a crossing disc: closest {closest:+.4f} m, end {q[:2].round(3)}, '
          f'{planner.stats.fallbacks} fallbacks')
    assert closest >= -REPLAY_TOL
    assert q[0] > 3.5 and abs(q[1]) < 0.05  # past it and back on the line


@pytest.mark.unit
def test_a_disc_seen_moving_gets_its_velocity_and_loses_it_where_it_jumps_or_time_goes_back():
    from nh_tracking.problem.disc_tracks import DiscTracks, MAX_SPEED
    from nh_tracking.problem.limits import PREDICTION

    rng = np.random.default_rng(3)
    tracks, velocity = DiscTracks(), np.array([0.3, -0.2])
    for t in np.arange(0.0, 2.0, 0.1):  # 10 Hz, 1 cm of noise
        tracks.seen('person', 100.0 + t, *(velocity * t + rng.normal(0, 0.01, 2)), 0.3)
    tracks.seen('crate', None, 2.0, 1.0, 0.5)  # no time: at rest
    person, crate = tracks.discs(101.9 + 0.5)  # half a second after it was last seen
    assert np.allclose(person[3:5], velocity, atol=0.05)
    assert np.allclose(person[:2], velocity * 2.4, atol=0.05) and person[2] == 0.3
    assert crate.tolist() == [2.0, 1.0, 0.5, 0.0, 0.0]
    before = tracks.copy()
    tracks.seen('person', 102.0, 5.0, 5.0, 0.3)  # 7 m in 0.1 s: a jump, not a speed
    assert tracks.discs(103.0)[0].tolist() == [5.0, 5.0, 0.3, 0.0, 0.0]
    assert np.allclose(before.discs(101.9)[0, 3:5], velocity, atol=0.05)  # the copy kept
    tracks.seen('person', 102.1, 5.1, 5.0, 0.3)  # 1 m/s along x
    held = tracks.discs(102.1 + PREDICTION + 1.0)[0]  # not seen again: held, at rest
    assert held == pytest.approx([5.1 + PREDICTION, 5.0, 0.3, 0.0, 0.0])
    tracks.seen('person', 50.0, 0.0, 0.0, 0.3)  # time went back: a new history
    assert tracks.discs(51.0)[0].tolist() == [0.0, 0.0, 0.3, 0.0, 0.0]
    tracks.seen('person', 50.0, 0.1, 0.0, 0.3)  # the same moment told again
    tracks.seen('fast', 0.0, 0.0, 0.0, 0.1)
    tracks.seen('fast', 0.1, 0.9, 0.0, 0.1)  # 9 m/s: no jump, but faster than believed
    fast = tracks.discs(0.1)[2]
    assert np.hypot(*fast[3:5]) == pytest.approx(MAX_SPEED) and fast[3] > 0
    assert tracks.discs(50.0)[0, 0] == 0.1
    tracks.forget('person')
    assert len(tracks.discs()) == 2
    tracks.forget()
    assert tracks.discs().shape == (0, 5)


@pytest.mark.unit
def test_discs_move_on_from_when_each_was_seen_never_back_and_at_most_the_prediction():
    from nh_tracking.problem.limits import moved, PREDICTION

    discs = np.tile([0.0, 0.0, 0.2, 1.0, 0.5], (3, 1))
    out = moved(discs, [-5.0, 1.0, 10.0])  # stamped ahead of the clock, 1 s ago, long ago
    assert out[:, :2].tolist() == [[0.0, 0.0], [1.0, 0.5], [PREDICTION, PREDICTION / 2]]
    assert out[:, 3:].tolist() == [[1.0, 0.5], [1.0, 0.5], [0.0, 0.0]]  # held, at rest
    assert np.array_equal(discs[:, 3:], np.tile([1.0, 0.5], (3, 1)))  # (a copy)
