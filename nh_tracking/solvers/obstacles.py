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

"""The obstacle policy: which discs a plan keeps clear of, at which points, and what then.

- **Which discs** (a replan): at most :data:`MAX_OBSTACLES`, those that can bend a plan from the
  robot along the reference (:func:`relevant_discs`), each shrunk where the robot is already
  inside its clearance (:func:`clear_of_start`).
- **At which points** (an NLP): each knot and midpoint has :func:`obstacle_slots` slots, filled
  with the discs nearest it on the guess (:func:`nearest_per_point`).
- **What a plan calls for** (:func:`limit_check`): another solve where it met a disc its points
  were not given, or went through one between its points; the least-violating plan where its
  start breaks a limit.
- **The retry loops** that act on it: :func:`clear_of_every_disc` (one NLP's discs, at its
  points) and :func:`clear_of_discs_left_out` (a replan's discs, of which an NLP takes some).

Discs are (x, y, r, vx, vy), or (x, y, r) at rest, at the start (moving ones:
:mod:`nh_tracking.problem.limits`).
"""
from __future__ import annotations

from collections.abc import Callable
import dataclasses

import numpy as np

from nh_tracking.problem.limits import (centres_at, Limits, nearest_discs, obstacle_discs,
                                        plan_path, plan_times, VIOLATION_TOL)
from nh_tracking.problem.tracking_problem import LimitCheck, Solution, TrackingProblem
from nh_tracking.solvers.guess import Guess
from nh_tracking.solvers.nlp import before

MAX_OBSTACLES = 8  # nearest obstacles a plan avoids: a bounded NLP
MIN_SLOTS = 2  # obstacle slots of an NLP with obstacles (then 4, 8: one NLP per size)
POINT_SLOTS = 4  # discs a knot or midpoint keeps clear of at most (those nearest it)


def relevant_discs(discs: np.ndarray, robot: np.ndarray, path: np.ndarray,
                   robot_radius: float, count: int, horizon: float = 0.0) -> np.ndarray:
    """Return at most ``count`` discs, nearest the robot first, that can bend a plan on ``path``.

    ``discs``: (x, y, r) or (x, y, r, vx, vy) at the start; ``robot``: the robot's (x, y);
    ``path``: (., 2) the reference's positions, evenly over the ``horizon`` (seconds: where
    moving discs are when the reference is there). A plan runs from the robot to the path and
    swerves around the obstacles near it, so a disc farther from the path than the robot's
    offset from it plus 0.5 m, plus twice the largest disc near the path, cannot touch it:
    leaving it out keeps the last-resort NLP (every disc at every point) small. The caller
    checks the plan against every disc all the same.
    """
    if not len(discs):
        return discs
    points = np.vstack([np.asarray(robot, dtype=float)[None, :2], path[:, :2]])
    t = np.r_[0.0, np.linspace(0.0, horizon, len(path))]
    centres = centres_at(discs[:, :2], obstacle_discs(discs)[:, 3:5], t)  # (points, M, 2)
    grown = discs[:, 2] + robot_radius
    to_path = np.linalg.norm(points[:, None, :] - centres, axis=2).min(axis=0) - grown
    margin = 0.5 + float(np.hypot(*(points[0] - points[1])))
    near = to_path < margin
    margin += 2.0 * float(np.max(grown[near], initial=0.0))
    return nearest_discs(discs[to_path < margin], points[0], count)


def clear_of_start(discs: np.ndarray, point: np.ndarray, velocity: np.ndarray,
                   robot_radius: float, interval: float) -> np.ndarray:
    """Shrink the discs whose clearance the robot at ``point`` (moving at ``velocity``) is inside.

    Each such disc is shrunk to leave the robot where it is, less what its approach speed
    carries it in one ``interval`` (so the plan's first midpoint can be clear too): a
    replanning robot that drifted a little inside the margin it keeps (model error, a disc
    redrawn) gets a plan from the NLP it has, instead of no plan; it comes closer by at most
    that one interval's approach per replan, while the plan brakes it. At rest nothing is given
    away, so replans cannot ratchet a stopped robot in. A disc the robot is within its radius of
    is shrunk to a point and still breaks the limit: the least-violating plan's.
    ``discs``: (x, y, r, vx, vy), the approach is the robot's relative to the disc.
    """
    discs = obstacle_discs(discs)
    offset = np.asarray(point, dtype=float)[:2] - discs[:, :2]
    distance = np.hypot(*offset.T)
    closing = np.asarray(velocity, dtype=float)[None, :2] - discs[:, 3:5]
    approach = np.maximum(-np.sum(offset * closing, axis=1) / np.maximum(distance, 1e-12), 0.0)
    allowed = np.maximum(distance - robot_radius - approach * interval, 0.0)
    discs[:, 2] = np.minimum(discs[:, 2], allowed)
    return discs


def obstacle_slots(count: int, every: bool = False) -> int:
    """Return the discs per clearance point of an NLP for ``count`` obstacles.

    Room for all of them (powers of two from 2: a changing count rarely rebuilds), up to
    :data:`POINT_SLOTS`: past that each point has the nearest ones only. ``every``: room for
    all of them past it too, for a crowd where a point's nearest are not enough
    (:func:`clear_of_every_disc`), and for the least-violating plan of a soft NLP
    (whose plan may break a disc it was not given).
    """
    if not count:
        return 0
    room = max(MIN_SLOTS, 1 << (count - 1).bit_length())
    return room if every else min(room, POINT_SLOTS)


def nearest_per_point(points: np.ndarray, centres: np.ndarray, radii: np.ndarray,
                      slots: int) -> np.ndarray:
    """Return the ``slots`` discs nearest each point (by their edges), in the discs' order.

    ``points``: (P, 2) positions; ``centres``: (P, M, 2) where each disc is at each point's time;
    ``radii``: (M,). (P, slots) indices: a disc keeps its slot while it stays among a point's
    nearest, so its multiplier is carried from one replan to the next.
    """
    edge = np.linalg.norm(points[:, None, :] - centres, axis=2) - radii[None, :]
    return np.sort(np.argpartition(edge, slots - 1, axis=1)[:, :slots], axis=1)


def limit_check(soft: bool, converged: bool, at_points: float, swept: float,
                more_discs_than_slots: bool, tolerance: float) -> LimitCheck:
    """Return what a plan's limits call for, from how far it breaks them at and between points.

    A soft NLP's converged plan is the least-violating one (its start breaks a limit); a hard
    NLP's plan that converged into a disc went into one its points were not given
    (``other_disc``: :func:`clear_of_every_disc` solves again), and one clear at its points
    that cuts through a disc between two of them (:meth:`.Limits.swept`) went through it
    (``through_disc``: solved again from rest, which a soft NLP, as blind to it, does not mend).
    """
    return LimitCheck(
        least_violating=soft and converged,
        other_disc=not soft and converged and at_points > tolerance and more_discs_than_slots,
        through_disc=converged and at_points <= tolerance < swept)


def clear_of_every_disc(solve: Callable[[Guess | None, bool], Solution], guess: Guess | None,
                        stop: float | None, problem: TrackingProblem) -> Solution:
    """Solve from ``guess``; again where the plan converged into a disc it was not given.

    ``solve(guess, every)``. Each knot and midpoint keeps clear of the discs nearest it on a
    guess that is a plan (:data:`POINT_SLOTS`); a plan that went far from its
    guess (round an obstacle, into a crowd of them) may meet another. Solved again from that
    plan, its points get the discs nearest them there; if it still meets one (a point among
    more discs), a last solve from ``guess`` gives every point every disc (``every``; started
    from the plan that ran into the crowd, it tends to end infeasible). A
    cold solve (no guess: the reference, which runs through the obstacles and tells little of
    where the plan will pass) has every disc at once. A plan that went through a disc between
    its points (fast: from the reference, a jump over an obstacle lying on it can look cheaper
    than the way round) is solved again from rest at the start (every disc), where the steps
    start slow.
    """
    result = solve(guess, guess is None)
    for every in (False, True):
        if not result.limit_check.other_disc or not before(stop):
            break
        retry = solve(guess if every else Guess(result.q, result.v, result.u), every)
        result = _after(result, retry, 'every disc at every point' if every
                        else 'the discs nearest its plan')
    if result.limit_check.through_disc and before(stop):
        steps, sys = problem.steps, problem.system
        rest = Guess(np.tile(problem.q0, (steps + 1, 1)), np.zeros((steps + 1, sys.k)),
                     np.zeros((steps, sys.r)))
        result = _after(result, solve(rest, True), 'from rest (it went through a disc)')
    return result


def _after(failed: Solution, retry: Solution, how: str) -> Solution:
    retry.follows(failed)
    retry.route = f'{failed.route} -> again, {how}'
    return retry


def clear_of_discs_left_out(
        solve: Callable[[TrackingProblem, Guess | None, float], Solution],
        problem: TrackingProblem, guess: Guess | None, discs: np.ndarray) -> Solution:
    """Solve ``problem`` (some of ``discs``); again where its plan touches one left out.

    ``solve(problem, guess, spent)``: ``spent`` [s] is what the solves before took (the
    replan's budget is one). A replan gives its NLP at most :data:`MAX_OBSTACLES` of the
    discs about it (:func:`relevant_discs`), nearest the robot first; a plan that swerved
    may then touch another. Solved again from that plan with the discs nearest it (those it
    touches first); a plan that still touches one left out (more discs about it than an NLP
    takes) is no success.
    """
    plan = solve(problem, guess, 0.0)
    if not plan.success or not touches_one_left_out(problem, plan, discs):
        return plan
    nearest = dataclasses.replace(problem, obstacles=_nearest_to_plan(problem, plan, discs))
    again = solve(nearest, Guess(plan.q, plan.v, plan.u, plan.multipliers,
                                 plan.working_set_misses), plan.solve_time)
    again = _after(plan, again, f'the discs nearest its plan (it touched one left out): '
                                f'{again.route}')
    if again.success and touches_one_left_out(nearest, again, discs):
        again.success = False
        again.message = f'{again.message}; the plan touches an obstacle left out'
    return again


def touches_one_left_out(problem: TrackingProblem, plan: Solution, discs: np.ndarray) -> bool:
    """Whether ``plan`` of ``problem``, built with some of ``discs``, touches one left out.

    At its knots and midpoints, or between them (:meth:`.Limits.swept`).
    """
    if len(problem.limits.obstacles) == len(discs):
        return False
    every, path, times = _every(problem, discs), plan_path(plan.q), _times(problem)
    return bool(every.clearance(path, times).min() < -VIOLATION_TOL
                or every.swept(path, times) > VIOLATION_TOL)


def _nearest_to_plan(problem: TrackingProblem, plan: Solution, discs: np.ndarray) -> np.ndarray:
    """Return the discs an NLP can take that come nearest ``plan`` (those it touches first).

    (Nearest the robot instead, a plan through a crowd of more could touch a ninth.)
    """
    grown = _every(problem, discs).clearance(plan_path(plan.q), _times(problem)).min(axis=0)
    return discs[np.argsort(grown, kind='stable')[:MAX_OBSTACLES]]


def _every(problem: TrackingProblem, discs: np.ndarray) -> Limits:
    return Limits.of(problem.system, None, None, discs, problem.robot_radius)


def _times(problem: TrackingProblem) -> np.ndarray:
    return plan_times(problem.steps, problem.h)
