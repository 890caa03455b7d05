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

"""Guesses that go round the obstacles a reference runs through, one per way round.

A cold solve started from a reference that runs through a disc sits on the disc's symmetry
line: the interior point then spends its iteration limit there or slides round the side the
start leans to, which need not be the cheaper one. The reference pushed round each blocking
disc on a chosen side, onto the circle of its clearance, is a guess near one local minimum per
side: solved from each, the cheaper plan is kept (:meth:`.solvers.base.Method.solve`). A moving
disc is gone round in its own frame: relative to it the reference runs past a disc at rest.
"""
from __future__ import annotations

from itertools import product

import numpy as np

from nh_tracking.problem.tracking_problem import TrackingProblem

MARGIN = 0.1  # of a disc's (grown) radius: how far outside it a detour guess passes
MAX_COMBINATIONS = 8  # sides tried for the blocking discs: every combination of up to three
PASSES = 4  # pushes round the discs a pushed guess runs into, at most
SAME_DIRECTION = 1e-9  # a reference slower than this along a disc has no direction there


def joined(problem: TrackingProblem) -> tuple[np.ndarray, np.ndarray]:
    """Return knots and velocities from the start onto the reference, its offset fading out.

    q_i = r_i + (1 - i / N) (q0 - r_0): the reference where the robot is on it; where the
    reference has run ahead (a robot held up, a route ended), the way from the robot to it,
    which a plan takes and which meets the discs in between.
    """
    q, v = (a.copy() for a in problem.reference_samples[:2])
    q += np.linspace(1.0, 0.0, len(q))[:, None] * (problem.q0 - q[0])
    v[0] = problem.v0
    return q, v


def blocking_discs(problem: TrackingProblem, q: np.ndarray) -> np.ndarray:
    """Return the indices of the discs the knots ``q`` (N+1, n) pass inside, in passing order."""
    clearance = problem.limits.clearance(q, problem.grid - problem.grid[0])
    inside = clearance < 0.0
    if not inside.any():
        return np.zeros(0, dtype=int)
    hit = np.flatnonzero(inside.any(axis=0))
    first = np.argmax(inside[:, hit], axis=0)
    return hit[np.argsort(first, kind='stable')]


def detour_guesses(problem: TrackingProblem, q: np.ndarray
                   ) -> list[tuple[np.ndarray, tuple[int, ...]]]:
    """Return ``q`` pushed round the discs it runs through: (knots, side per disc) per way round.

    Side +1 passes a disc on the left of the direction of travel, -1 on the right. Every
    combination of sides for up to three blocking discs; past that, each on the side ``q``
    leans to, all on the left and all on the right. None where ``q`` runs through no disc (or
    the model has no plane).
    """
    limits = problem.limits
    if limits.plane is None or not len(limits.obstacles):
        return []
    blocking = blocking_discs(problem, q)
    if not len(blocking):
        return []
    if 2 ** len(blocking) <= MAX_COMBINATIONS:
        sides = list(product((1, -1), repeat=len(blocking)))
    else:
        sides = list(dict.fromkeys([_leaning(problem, q, blocking), (1,) * len(blocking),
                                    (-1,) * len(blocking)]))
    return [(_pushed(problem, q, blocking, choice), choice) for choice in sides]


def stops_short_of_disc(problem: TrackingProblem, q: np.ndarray, plan: np.ndarray) -> bool:
    """Whether a plan's knots stop short of a disc that the knots ``q`` run through and pass.

    Short: its last knot not past the disc's centre in the direction ``q`` passes it, where
    the last of ``q`` is past it (a plan pressed against the disc's near side, where a warm
    start keeps it; not one whose horizon ends before the disc).
    """
    for disc in blocking_discs(problem, q):
        position = _relative(problem, q, disc)
        along = _direction_past(position)
        if _relative(problem, plan, disc)[-1] @ along < 0.0 < position[-1] @ along:
            return True
    return False


def _leaning(problem: TrackingProblem, q: np.ndarray, blocking: np.ndarray
             ) -> tuple[int, ...]:
    """Return the side of each blocking disc that the knots ``q`` pass nearer (left if on it)."""
    sides = []
    for disc in blocking:
        position = _relative(problem, q, disc)
        along = _direction_past(position)
        nearest = position[np.argmin(np.linalg.norm(position, axis=1))]
        sides.append(-1 if nearest @ np.array([-along[1], along[0]]) < 0.0 else 1)
    return tuple(sides)


def _pushed(problem: TrackingProblem, q: np.ndarray, blocking: np.ndarray,
            sides: tuple[int, ...]) -> np.ndarray:
    """Return ``q`` with its positions moved sideways out of each blocking disc, on its side.

    A disc the pushed guess then runs into (a neighbour too close to pass between) is gone
    round on the side of the nearest disc already pushed round: a cluster on one side.
    """
    side_of = {int(d): s for d, s in zip(blocking, sides)}
    centres = problem.limits.centres(problem.grid - problem.grid[0])  # (knots or 1, M, 2)
    for _ in range(PASSES):
        order = sorted(side_of, key=lambda d: _passing_knot(problem, q, d))
        guess = _pushed_once(problem, q, [(d, side_of[d]) for d in order])
        more = [int(d) for d in blocking_discs(problem, guess) if int(d) not in side_of]
        if not more:
            break
        for disc in more:  # (where the discs are when the guess passes the new one)
            at = centres[min(_passing_knot(problem, guess, disc), len(centres) - 1)]
            known = np.array(list(side_of))
            nearest = known[np.argmin(np.linalg.norm(at[known] - at[disc], axis=1))]
            side_of[disc] = side_of[int(nearest)]
    return guess


def _passing_knot(problem: TrackingProblem, q: np.ndarray, disc: int) -> int:
    """Return the knot of ``q`` nearest a disc: the order in which a path passes discs."""
    return int(np.argmin(np.linalg.norm(_relative(problem, q, disc), axis=1)))


def _pushed_once(problem: TrackingProblem, q: np.ndarray,
                 sides: list[tuple[int, int]]) -> np.ndarray:
    """Return ``q`` pushed out of each disc on its side, (disc, side) in the order given."""
    axes = list(problem.limits.plane or ())
    guess = q.copy()
    for disc, side in sides:
        radius = problem.limits.obstacles[disc, 2]
        offset = _relative(problem, guess, disc)
        along = _direction_past(offset)
        normal = side * np.array([-along[1], along[0]])
        a, b = offset @ along, offset @ normal
        reach = radius * (1.0 + MARGIN)
        need = np.sqrt(np.maximum(reach**2 - a**2, 0.0))
        lift = np.where(np.abs(a) < reach, np.maximum(need - b, 0.0), 0.0)
        guess[:, axes] += lift[:, None] * normal
    guess[0] = q[0]  # the start is the robot's
    return guess


def _relative(problem: TrackingProblem, q: np.ndarray, disc: int) -> np.ndarray:
    """Return the positions of knots ``q`` relative to a disc's centre at their times."""
    limits = problem.limits
    centres = limits.centres(problem.grid - problem.grid[0])[:, disc]
    return q[:, list(limits.plane or ())] - centres


def _direction_past(position: np.ndarray) -> np.ndarray:
    """Return the unit direction in which a path (relative to a centre) passes it.

    The chord at its point nearest the centre.
    """
    nearest = int(np.argmin(np.linalg.norm(position, axis=1)))
    before, after = position[max(nearest - 1, 0)], position[min(nearest + 1, len(position) - 1)]
    chord = after - before
    if np.linalg.norm(chord) <= SAME_DIRECTION:  # at rest there: the whole path's direction
        chord = position[-1] - position[0]
    length = float(np.linalg.norm(chord))
    return chord / length if length > SAME_DIRECTION else np.array([1.0, 0.0])
