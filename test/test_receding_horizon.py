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

"""Replanning without ROS: poses and twists, the closed loop, deadlines and fallbacks."""
import dataclasses

import numpy as np
import pytest

from faults import Faulty
import nh_tracking as nht
from nh_tracking.core.poses import PoseMap, wrap_angle
from nh_tracking.examples.experiments import SLEIGH_REFERENCE_START, SLEIGH_START
from nh_tracking.planning.fallback import fallback_plan, TrackingLaw
import nh_tracking.planning.receding_horizon as rh
from systems import ALL_SYSTEMS, random_state


@pytest.mark.unit
@pytest.mark.parametrize('name', ['chaplygin_sleigh', 'nonholonomic_particle', 'unicycle',
                                  'rolling_disk', 'inclined_knife_edge'])
def test_pose_and_twist_round_trips(name):
    system = ALL_SYSTEMS[name]()
    pm = PoseMap(system)  # every one declares its pose axes; the knife edge's heading is phi
    rng = np.random.default_rng(7)
    for _ in range(10):
        q, v, _ = random_state(system, rng)
        pose = pm.pose(q)
        back = pm.configuration(pose, hidden=q)
        assert np.allclose(wrap_angle(back - q), 0.0, atol=1e-12)
        assert np.allclose(pm.velocity(q, pm.body_twist(q, v)), v, atol=1e-10)


@pytest.mark.unit
def test_wheeled_body_twist_has_no_lateral_slip_and_slip_is_projected_out():
    sleigh = nht.models.chaplygin_sleigh()
    pm = PoseMap(sleigh)
    q, v = np.array([1.0, 2.0, 0.7]), np.array([0.3, -0.8])
    twist = pm.body_twist(q, v)
    assert abs(twist[1]) < 1e-12 and twist[0] == pytest.approx(-0.8)  # m = 1
    slipping = twist + np.array([0.0, 0.5, 0.0, 0.0])
    assert np.allclose(pm.velocity(q, slipping), v)


@pytest.mark.unit
def test_reference_from_poses_recovers_velocities_and_hidden_angles():
    disk = nht.models.rolling_disk(R=0.4)
    truth = nht.simulate(disk, [0, 0, 0.2, 0], [0.5, 2.0], np.linspace(0, 4, 81))
    pm = PoseMap(disk)
    poses = np.array([pm.pose(q) for q in truth.q])  # yaw wrapped, rolling angle hidden
    ref = pm.reference(truth.t, poses)
    assert np.abs(ref.v[2:-2] - truth.v[2:-2]).max() < 1e-4
    assert np.abs(ref.q[:, 3] - truth.q[:, 3]).max() < 1e-3  # phi integrated back
    twists = np.array([pm.body_twist(q, v) for q, v in zip(truth.q, truth.v)])
    exact = pm.reference(truth.t, poses, twists)
    assert np.allclose(exact.v, truth.v, atol=1e-12)


def _closed_loop(planner, real, duration, dt=0.1):
    q, v = np.array(SLEIGH_START[0]), np.array(SLEIGH_START[1])
    t, states = 0.0, []
    while t < duration - 1e-9:
        out = planner.plan(t, q, v)
        plan = out.plan
        per = int(round(dt / (plan.t[1] - plan.t[0])))
        tr = nht.simulate(real, q, v, plan.t[:per + 1], plan.u[:per], rtol=1e-8, atol=1e-10)
        q, v, t = tr.q[-1], tr.v[-1], t + dt
        states.append((t, q.copy(), out.status))
    return states


@pytest.mark.solve
def test_closed_loop_tracks_with_inertia_mismatch():
    model = nht.models.chaplygin_sleigh()
    ref = nht.simulate(model, *SLEIGH_REFERENCE_START, np.linspace(0, 20, 801))
    planner = rh.RecedingHorizonPlanner(model)
    planner.set_reference(ref)
    states = _closed_loop(planner, nht.models.chaplygin_sleigh(J=4.4), 14.0)
    cross = [np.hypot(*(ref.q[:, :2] - q[:2]).T).min() for t, q, _ in states if t >= 12.0]
    assert max(cross) < 0.05
    assert planner.stats.optimal == planner.stats.plans == len(states)


@pytest.mark.solve
def test_missed_deadline_falls_back_then_keeps_the_shifted_plan():
    model = nht.models.chaplygin_sleigh()
    ref = nht.simulate(model, *SLEIGH_REFERENCE_START, np.linspace(0, 20, 801))
    planner = rh.RecedingHorizonPlanner(model, rh.PlannerSettings(max_solve_time=1e-5))
    planner.set_reference(ref)
    first = planner.plan(0.0, *SLEIGH_START)
    assert first.status == 'fallback' and 'tracking law' in first.message
    assert not first.plan.success and first.plan.route == 'kanayama'
    second = planner.plan(0.1, *SLEIGH_START)
    assert second.status == 'shifted' and second.plan.t[0] == pytest.approx(0.1)
    assert np.allclose(second.plan.q[0], first.plan.trajectory().sample(0.1)[0][0], atol=1e-9)
    planner.update(max_solve_time=1.0)  # settings change keeps the warm start
    third = planner.plan(0.2, *SLEIGH_START)
    assert third.status == 'optimal' and planner.stats.fallbacks == 1


@pytest.mark.solve
def test_solver_exception_is_contained():
    model = nht.models.unicycle()
    ref = nht.simulate(model, [0, 0, 0], [1.0, 0.2], np.linspace(0, 10, 101))
    planner = rh.RecedingHorizonPlanner(model)
    planner.set_reference(ref)
    planner.method = Faulty('raise')
    out = planner.plan(0.0, [0.2, 0.1, 0.0], [0.0, 0.0])
    assert out.status == 'fallback' and 'injected solver fault' in out.message
    assert np.all(np.isfinite(out.plan.u))


@pytest.mark.unit
def test_fallback_law_tracks_a_unicycle():
    uni = nht.models.unicycle()
    ref = nht.simulate(uni, [0, 0, 0], [1.0, 0.3], np.linspace(0, 25, 501))
    prob = nht.TrackingProblem(uni, ref, [0.5, -0.5, 1.0], [0, 0], horizon=15, steps=150)
    tr = nht.simulate(nht.models.unicycle(m=1.1), prob.q0, prob.v0, prob.grid, TrackingLaw(prob),
                      rtol=1e-7, atol=1e-9)
    q_ref, _ = prob.reference_at(prob.grid)
    assert np.linalg.norm(tr.q[-1, :2] - q_ref[-1, :2]) < 1e-3


@pytest.mark.unit
@pytest.mark.parametrize('name', ['unicycle', 'chaplygin_sleigh', 'rolling_disk'])
def test_the_fallback_plan_is_what_its_controls_do_held(name):
    """The fallback plan's motion is its controls held per interval (as a robot applies them).

    Checked against the tight adaptive integration of those held controls.
    """
    model = nht.models.create(name)
    ref = nht.simulate(model, np.zeros(model.n), np.full(model.k, 0.4), np.linspace(0, 8, 81))
    q0 = ref.q[0] + np.r_[0.3, -0.2, np.zeros(model.n - 2)]
    prob = nht.TrackingProblem(model, ref, q0, np.zeros(model.k), horizon=3.0, steps=30)
    plan = fallback_plan(prob)
    held = nht.simulate(model, prob.q0, prob.v0, prob.grid, plan.u)
    assert np.abs(plan.q - held.q).max() < 1e-5 and np.abs(plan.v - held.v).max() < 1e-5
    assert np.abs(plan.u).max() > 0.1  # the law did act


@pytest.mark.unit
@pytest.mark.parametrize('bad', [{'horizon': -1.0}, {'steps': 1}, {'epsilon': 0.0},
                                 {'method': 'magic'}, {'terminal': 'free'},
                                 {'max_solve_time': float('nan')}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError, match='invalid PlannerSettings'):
        rh.PlannerSettings(**bad)


@pytest.mark.unit
def test_bounds_as_the_parameter_services_send_them():
    """A double array set at run time arrives as array('d'); NaN is refused by name."""
    from array import array
    assert rh.PlannerSettings(u_max=array('d', [5.0]), v_min=array('d')).u_max == (5.0,)
    with pytest.raises(ValueError, match=r'u_max must not contain NaN .*got \[nan\]'):
        rh.PlannerSettings(u_max=array('d', [float('nan')]))
    with pytest.raises(ValueError, match='u_min must be a list of numbers'):
        rh.PlannerSettings(u_min=['fast'])


@pytest.mark.unit
@pytest.mark.parametrize('v_min, v_max', [
    ((-0.7, -3.0), (-0.5, 3.0)), ((0.1,), (1.0,)), ((), (-0.2, 1.0))])
def test_velocity_bounds_that_leave_out_standing_still_are_refused(v_min, v_max):
    settings = rh.PlannerSettings(v_min=v_min, v_max=v_max)
    with pytest.raises(ValueError, match='must allow standing still'):
        settings.limits(nht.models.unicycle())
    assert rh.PlannerSettings(v_min=(0.0,), v_max=(0.0, 1.0)).limits(nht.models.unicycle())


@pytest.mark.solve
def test_nan_from_the_dynamics_gives_a_finite_stop_plan():
    """A knife edge whose potential is NaN for x < -50 (sqrt), far from where it was checked.

    From x = -51 the solver and the tracking law both meet NaN; the planner still returns a
    finite plan (stop) and says so.
    """
    import casadi as ca

    knife = nht.NonholonomicSystem.from_constraints(
        ['x', 'y', 'theta'], lambda q: ca.SX.eye(3),
        lambda q: ca.horzcat(ca.sin(q[2]), -ca.cos(q[2]), 0),
        potential=lambda q: -ca.sqrt(q[0] + 50), angles=['theta'], name='nan_knife')
    ref = nht.Trajectory(t=[0.0, 10.0], q=[[1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
                         v=[[0.1, 0.0], [0.1, 0.0]], u=[[0.0, 0.0]])
    planner = rh.RecedingHorizonPlanner(knife, rh.PlannerSettings(steps=10, horizon=1.0))
    planner.set_reference(ref)
    out = planner.plan(0.0, [-51.0, 0.0, 0.0], [0.2, 0.0])
    assert out.status == rh.PlanStatus.STOP and out.message.startswith('stopping')
    assert not out.plan.success  # a stop plan is no solution, and says so
    assert np.all(np.isfinite(out.plan.q)) and np.all(out.plan.v == 0) and np.all(out.plan.u == 0)
    again = planner.plan(0.1, [-51.0, 0.0, 0.0], [0.2, 0.0])  # still failing: shifted stop plan
    assert again.status == 'shifted' and np.all(np.isfinite(again.plan.u))


@pytest.mark.solve
def test_real_time_iterations_track_like_converged_plans():
    """One Newton step per replan on the warm-started previous plan (iterations=1).

    The sleigh closed loop (model 10 % lighter than the robot) ends as close to the path as
    with converged plans, every plan after the first is a real-time iteration, and its first
    control stays near the converged plan's from the same state.
    """
    model = nht.models.chaplygin_sleigh()
    ref = nht.simulate(model, *SLEIGH_REFERENCE_START, np.linspace(0, 20, 801))
    real = nht.models.chaplygin_sleigh(J=4.4)
    errors = {}
    for iterations in (0, 1):
        planner = rh.RecedingHorizonPlanner(model, rh.PlannerSettings(iterations=iterations))
        planner.prepare()  # (else the first plan builds its NLP within its 0.25 s: on a loaded
        planner.set_reference(ref)  # machine it ran out, and the plan count below failed)
        states = _closed_loop(planner, real, 10.0)
        errors[iterations] = max(np.hypot(*(ref.q[:, :2] - q[:2]).T).min()
                                 for t, q, _ in states if t >= 8.0)
        assert planner.stats.optimal == planner.stats.plans == len(states)
    assert errors[1] < 0.05 and abs(errors[1] - errors[0]) < 0.01, errors
    assert planner.previous is not None and planner.previous.message == 'real-time iteration'


@pytest.mark.solve
def test_a_real_time_iteration_is_close_to_the_converged_plan_on_a_knife_edge():
    """A system beyond the built-in set (a knife edge on a slope, gravity pulling it off its path).

    Replanned every 0.05 s, each real-time iteration's first control is within 1 per cent
    of the converged plan's from the same state and time.
    """
    from systems import inclined_knife_edge

    knife = inclined_knife_edge()
    ref = nht.simulate(knife, [0.0, 0.0, 0.3], [0.5, 0.2], np.linspace(0, 10, 201),
                       np.tile([0.1, -0.3], (200, 1)))
    settings = rh.PlannerSettings(horizon=2.0, steps=20)
    rti = rh.RecedingHorizonPlanner(knife, dataclasses.replace(settings, iterations=1))
    rti.set_reference(ref)
    converged = rh.RecedingHorizonPlanner(knife, settings)
    converged.set_reference(ref)
    q, v, gaps = np.array([0.1, -0.1, 0.35]), np.array([0.5, 0.2]), []
    for step in range(40):
        t = 0.05 * step
        plan = rti.plan(t, q, v).plan
        best = converged.preview(t, q, v)
        gaps.append(np.abs(plan.u[0] - best.u[0]).max() / np.abs(best.u).max())
        tr = nht.simulate(knife, q, v, [t, t + 0.05], plan.u[:1])
        q, v = tr.q[-1], tr.v[-1]
    assert rti.stats.optimal == 40 and max(gaps[1:]) < 0.01, gaps


@pytest.mark.solve
def test_a_real_time_iteration_far_from_admissible_is_converged_instead():
    """After the reference jumps, one Newton step leaves the plan off the model's dynamics.

    Such a step does not count: the solve converges within the same deadline, so every plan
    in force is a trajectory of the model (admissibility residual <= 1e-3).
    """
    unicycle = nht.models.unicycle()
    t = np.linspace(0.0, 20.0, 201)
    line = nht.Trajectory(t=t, q=np.c_[0.5 * t, 0 * t, 0 * t],
                          v=np.c_[0.5 * np.ones_like(t), 0 * t], u=np.zeros((200, 2)))
    jumped = nht.Trajectory(t=t, q=line.q + [1.5, -2.0, 0.0], v=line.v, u=line.u)
    planner = rh.RecedingHorizonPlanner(unicycle, rh.PlannerSettings(iterations=1))
    planner.set_reference(line)
    q, v, residuals, messages = np.zeros(3), np.array([0.5, 0.0]), [], set()
    for step in range(40):
        if step == 20:
            planner.set_reference(jumped)
        out = planner.plan(0.1 * step, q, v)
        residuals.append(out.plan.details['admissibility_residual'])
        messages.add(out.plan.message)
        tr = nht.simulate(unicycle, q, v, out.plan.t[:2], out.plan.u[:1])
        q, v = tr.q[-1], tr.v[-1]
    assert planner.stats.optimal == 40 and max(residuals) <= 1e-3, max(residuals)
    assert {'real-time iteration', 'converged'} <= messages
