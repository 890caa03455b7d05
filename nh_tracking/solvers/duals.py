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

"""A previous plan's multipliers on a new problem's rows: the curvature of a warm first step.

A warm replan's Newton steps take the Lagrangian's Hessian, which needs multipliers. Started
from zero, the first step is Gauss-Newton's: it leaves out the curvature of the admissibility
constraint (a turning robot) and of the obstacles' clearance, and replans that turn or slide
along a disc take a step more to converge. The previous plan's multipliers, moved by the time
the plan itself moved (linear between stages, the last held, as the plan is shifted), estimate
them well. Only rows that may curve are carried — admissibility, an underactuated system's
dynamics, control bounds (a fully actuated system's u is eliminated: u = dv/dt - f(q, v)),
clearance while the discs are the same; linear rows (the explicit dynamics, the start,
velocity bounds) add nothing to the Hessian and start from zero.
"""
from __future__ import annotations

from collections.abc import Hashable

import numpy as np

from nh_tracking.problem.tracking_problem import Multipliers, TrackingProblem
from nh_tracking.solvers.base import Guess
from nh_tracking.solvers.midpoint import Transcription

SAME_DISC = 1e-9  # [m] a point's disc as carried, to rounding (a moving one's centre is computed)


def _layout(tr: Transcription, problem: TrackingProblem) -> Hashable:
    """Return what fixes the rows of g and their order: equal layouts, the same rows.

    (Two systems alike in these have the same rows: their multipliers are then only a worse
    estimate of the curvature, never misplaced.)
    """
    sys = problem.system
    return (sys.name, sys.n, sys.k, sys.r, sys.fully_actuated, tr.steps, tr.terminal,
            tr.limits.shape, tr.rows, tr.unknowns)


def multipliers_at(tr: Transcription, problem: TrackingProblem, values: np.ndarray,
                   p: np.ndarray) -> Multipliers | None:
    """Return a plan's multipliers ``values`` (one per row of g) with where they belong.

    ``p``: the parameters of the solve, whose discs the clearance rows had.
    """
    if len(values) != tr.rows or not np.isfinite(values).all():
        return None
    return Multipliers(values, float(problem.grid[0]), problem.h, _layout(tr, problem),
                       tr.limits.assigned_discs(p))


def carried_multipliers(tr: Transcription, problem: TrackingProblem, guess: Guess | None,
                        p: np.ndarray) -> np.ndarray | None:
    """Return the guess's multipliers placed on this problem's rows, or None if none fit.

    They fit from a plan of the same NLP with the same interval h that started earlier within
    the horizon. A clearance point's rows keep theirs only if its discs (in ``p``, this solve's
    parameters) are those the rows carried from had.
    """
    old = getattr(guess, 'multipliers', None)  # (a plain (q, v, u) tuple has none)
    if not isinstance(old, Multipliers) or old.layout != _layout(tr, problem) or \
            len(old.values) != tr.rows or not np.isfinite(old.values).all() or \
            abs(old.h - problem.h) > 1e-9 * problem.h:
        return None
    stages = (float(problem.grid[0]) - old.t0) / problem.h
    if abs(stages - round(stages)) <= 1e-9:  # a whole number of intervals, but for rounding:
        stages = round(stages)  # no block blended in at 1e-15, whose discs would then count
    if not 0.0 <= stages < tr.steps:
        return None
    carried = np.zeros(tr.rows)
    interval, clearance = tr.curved_rows
    _shift(carried, old.values, interval, stages)
    if clearance.size:  # blocks half an interval apart
        _shift(carried, old.values, clearance, 2 * stages)
        discs = tr.limits.assigned_discs(p)
        other = np.zeros(len(discs), dtype=bool)
        for moved in _moved(old.obstacles, 2 * stages):  # (moving discs: to rounding)
            other |= ~np.all(np.isclose(moved, discs, rtol=0.0, atol=SAME_DISC), axis=1)
        carried[clearance[other]] = 0.0
    return carried


def _moved(blocks: np.ndarray, by: float) -> list[np.ndarray]:
    """Return the blocks that :func:`_shift` by ``by`` blends into each (one, or two)."""
    whole = int(by)
    low = np.concatenate([blocks[whole:], np.repeat(blocks[-1:], whole, axis=0)])
    return [low] if by == whole else [low, np.concatenate([low[1:], low[-1:]])]


def _shift(out: np.ndarray, values: np.ndarray, blocks: np.ndarray, by: float) -> None:
    """Set out's rows ``blocks`` (one block a row) to ``values``' blocks ``by`` further on."""
    fraction = by - int(by)
    low, *high = _moved(values[blocks], by)  # the last held
    out[blocks] = low if not high else (1.0 - fraction) * low + fraction * high[0]
