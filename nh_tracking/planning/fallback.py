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

"""A classical tracking law for when the optimiser cannot deliver: Kanayama on quasi-velocities.

For systems with a heading (a yaw axis), the desired forward speed and yaw rate come from
Kanayama's law on the body-frame pose error (Kanayama et al., ICRA 1990); for others, from
the reference velocity plus the pose error projected onto D (which corrects only the part of
the error lying in D: a fallback that keeps such a system near the reference, no more).
Either desired motion is turned into quasi-velocities v_d by the pose map, and a
computed-torque loop on the quasi-velocities, u = -f(q, v, 0) + k_v (v_d - v), makes v
follow it (for an underactuated system, as nearly as its inputs B u allow: least squares).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from nh_tracking.core.poses import PoseMap, wrap_angle
from nh_tracking.core.simulate import held_rk4
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.problem.limits import Limits, plan_path, plan_times
from nh_tracking.problem.tracking_problem import Solution, terminal_error, TrackingProblem
from nh_tracking.solvers.cache import PerSystemCache


@dataclass(frozen=True)
class KanayamaGains:
    k_x: float = 1.0  # 1/s, along-track
    k_y: float = 4.0  # 1/m^2, cross-track
    k_theta: float = 3.0  # 1/m, heading
    k_v: float = 4.0  # 1/s, quasi-velocity loop


class TrackingLaw:
    """u(t, q, v) that tracks a problem's reference without optimisation."""

    def __init__(self, problem: TrackingProblem, gains: KanayamaGains = KanayamaGains()):
        self.problem, self.gains = problem, gains
        self.pose_map = PoseMap(problem.system)

    def desired_velocity(self, t: float, q: np.ndarray) -> np.ndarray:
        q_r, v_r = self.problem.reference_point(t)
        pm, g = self.pose_map, self.gains
        world_r = pm.system.rho(q_r) @ v_r
        rates_r = np.array([world_r[pm.rows[a]] if a in pm.rows else 0.0
                            for a in ('x', 'y', 'z', 'yaw')])
        if not pm.has_yaw:
            error = pm.pose(q_r) - pm.pose(q)
            return pm.velocity_from_world(q, rates_r + g.k_x * error)
        x, y, _, yaw = pm.pose(q)
        xr, yr, _, yaw_r = pm.pose(q_r)
        c, s = np.cos(yaw), np.sin(yaw)
        e_x = c * (xr - x) + s * (yr - y)
        e_y = -s * (xr - x) + c * (yr - y)
        e_th = wrap_angle(yaw_r - yaw)
        speed_r = np.cos(yaw_r) * rates_r[0] + np.sin(yaw_r) * rates_r[1]
        speed = speed_r * np.cos(e_th) + g.k_x * e_x
        yaw_rate = rates_r[3] + speed_r * (g.k_y * e_y + g.k_theta * np.sin(e_th))
        return pm.velocity_from_world(q, np.array([c * speed, s * speed, rates_r[2], yaw_rate]))

    def __call__(self, t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        return self._effort(q, v, self.gains.k_v * (self.desired_velocity(t, q) - v))

    def _effort(self, q: np.ndarray, v: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """Return the controls that give v the rate ``accel`` at (q, v), within their limits."""
        system = self.problem.system
        _, drift = system.dynamics(q, v)
        wanted = -drift + accel
        if not system.fully_actuated:  # the controls whose effect B u comes closest to it
            wanted = np.linalg.lstsq(system.input_matrix(q), wanted, rcond=None)[0]
        return np.clip(wanted, *self.problem.limits.controls)  # the actuators' limits


HELD_SUBSTEPS = 4  # RK4 steps per interval of a held rollout
_HELD_STEPS: PerSystemCache[ca.Function] = PerSystemCache()
_REPLAYS: PerSystemCache[ca.Function] = PerSystemCache()  # by number of intervals


def held_rollout(problem: TrackingProblem, control: TrackingLaw) -> Trajectory:
    """Roll ``control`` out the way a plan is applied: its value at each knot, held.

    What the robot given the plan's controls does (a continuous feedback rollout would predict
    a motion the robot never makes). Each interval is one call of fixed RK4 steps, not an
    adaptive integration. A state outside the model's domain is refused.
    """
    system, grid = problem.system, problem.grid
    step = held_step(system)
    q, v, u = [problem.q0], [problem.v0], []
    for a, b in zip(grid[:-1], grid[1:]):
        u.append(np.asarray(control(a, q[-1], v[-1]), dtype=float))
        x = np.array(step(np.concatenate([q[-1], v[-1]]), u[-1], b - a)).ravel()
        q.append(system.check_configuration(x[:system.n]))
        v.append(x[system.n:])
    return Trajectory(t=grid, q=np.array(q), v=np.array(v), u=np.array(u))


def held_step(system: NonholonomicSystem, intervals: int = 0) -> ca.Function:
    """(x, u, h) -> x after ``h`` with ``u`` held, :data:`HELD_SUBSTEPS` RK4 steps; cached.

    ``intervals`` > 0: (x0, U (r, N), H (1, N)) -> the states after each of N intervals in turn.
    """
    def build() -> ca.Function:
        x, u, h = ca.SX.sym('x', system.n + system.k), ca.SX.sym('u', system.r), ca.SX.sym('h')
        return ca.Function('held_step', [x, u, h], [held_rk4(system, x, u, h, HELD_SUBSTEPS)])
    step = _HELD_STEPS.get(system, 'held', build)
    return step if not intervals else _REPLAYS.get(system, intervals,
                                                   lambda: step.mapaccum(intervals))


def fallback_plan(problem: TrackingProblem, law: TrackingLaw | None = None) -> Solution:
    """Return a law (the tracking law) rolled out on the model over the horizon, as a plan."""
    traj = held_rollout(problem, TrackingLaw(problem) if law is None else law)
    return Solution(
        t=traj.t, q=traj.q, v=traj.v, u=traj.u, cost=float('nan'), success=False,
        iterations=0, solve_time=0.0,
        terminal_error=terminal_error(problem, traj.q[-1], traj.v[-1]), method='fallback',
        message='not optimal: the Kanayama tracking law rolled out', route='kanayama',
    )


class BrakingLaw(TrackingLaw):
    """The same computed-torque loop, to rest: for when tracking would hit an obstacle.

    With ``decel`` [m/s^2]: the start's velocity scaled down along itself until rest, its
    translational speed falling at ``decel`` (at once if it has none; harder if the horizon is
    shorter than the stop), each held control aimed at the next knot's velocity; at rest at the
    ramp's end, to the model's accuracy.
    """

    def __init__(self, problem: TrackingProblem, gains: KanayamaGains = KanayamaGains(),
                 decel: float | None = None) -> None:
        super().__init__(problem, gains)
        self.decel = decel
        twist = self.pose_map.twist_matrix(problem.q0) @ problem.v0
        span = float(problem.grid[-1] - problem.grid[0])  # harder if need be: at rest in it
        self.stop_time = 0.0 if decel is None else min(
            float(np.hypot(twist[0], twist[1])) / decel, span)

    def desired_velocity(self, t: float, q: np.ndarray) -> np.ndarray:
        if self.stop_time <= 0.0:
            return np.zeros(self.problem.system.k)
        return self.problem.v0 * max(0.0, 1.0 - (t - self.problem.grid[0]) / self.stop_time)

    def __call__(self, t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        if self.decel is None:
            return super().__call__(t, q, v)
        h = self.problem.h
        return self._effort(q, v, (self.desired_velocity(t + h, q) - v) / h)


def fallback(problem: TrackingProblem, clear_of: Limits) -> tuple[Solution, str]:
    """Return the plan to use when no optimal one exists, and what it is.

    The tracking law, rolled out, unless it passes closer to an obstacle of ``clear_of``
    (grown by the robot's radius) than braking to rest (as hard as the actuators allow) does;
    at equal closest approach, the one that ends farther clear. If neither gives finite
    values: holding still.
    """
    try:
        plan, what = _finite(fallback_plan(problem)), 'tracking law fallback'
        tracking = _closest(plan, clear_of, problem.h) if len(clear_of.obstacles) else (0.0, 0.0)
        if tracking[0] < 0.0:
            brake = braking_plan(problem)
            if _closest(brake, clear_of, problem.h) > tracking:
                plan, what = brake, 'braking: the tracking law would come closer to an obstacle'
        return plan, what
    except (ArithmeticError, RuntimeError, ValueError) as exc:
        return stop_plan(problem, str(exc)), f'stopping, tracking law failed: {exc}'


def _closest(plan: Solution, clear_of: Limits, h: float) -> tuple[float, float]:
    """(closest approach after the start at knots and midpoints, clearance at the end), mm.

    Knots ``h`` apart. A path through a disc between its points comes as close as it cuts in
    (negative).
    """
    path, t = plan_path(plan.q), plan_times(len(plan.q) - 1, h)
    closest = min(float(clear_of.clearance(path[1:], t[1:]).min()), -clear_of.swept(path, t))
    return round(closest, 3), round(float(clear_of.clearance(path[-1:], t[-1:]).min()), 3)


def _finite(plan: Solution) -> Solution:
    if not all(np.all(np.isfinite(a)) for a in (plan.q, plan.v, plan.u)):
        raise ValueError('the fallback law gave non-finite values')
    return plan


def braking_plan(problem: TrackingProblem, decel: float | None = None) -> Solution:
    """Return braking to rest from the problem's start.

    At ``decel`` [m/s^2] (see :class:`BrakingLaw`), or (None) as hard as the actuators allow.
    """
    brake = _finite(fallback_plan(problem, BrakingLaw(problem, decel=decel)))
    brake.message, brake.route = 'not optimal: braking to rest', 'brake'
    return brake


def stop_plan(problem: TrackingProblem, reason: str) -> Solution:
    """Hold the current configuration at rest: the last resort.

    For when even the tracking law cannot be rolled out (e.g. the dynamics give NaN here).
    Always finite for a finite state.
    """
    steps, k = problem.steps, problem.system.k
    q = np.tile(problem.q0, (steps + 1, 1))
    return Solution(
        t=problem.grid, q=q, v=np.zeros((steps + 1, k)), u=np.zeros((steps, problem.system.r)),
        cost=float('nan'), success=False, iterations=0, solve_time=0.0,
        terminal_error=terminal_error(problem, q[-1], np.zeros(k)), method='fallback',
        message=f'not optimal: holding still ({reason})', route='stop',
    )
