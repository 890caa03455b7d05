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

"""Whether a timed reference asks for a motion a robot can make, and thinning one too dense.

Finite poses and increasing stamps are not enough: two poses 100 km apart 10 s apart are both,
and a planner tracking them commands thousands of m/s. Speeds are those of the polyline through
the positions; accelerations those of the same polyline thinned to points at least
:data:`ACCEL_WINDOW` apart, so a corner sampled every millimetre is not read as a jolt.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

ACCEL_WINDOW = 0.2  # [s] accelerations are measured over at least this long
BOUND_TOLERANCE = 0.01  # a reference may exceed a velocity bound by 1 % of it (and 1e-5)


class ReferenceRejected(ValueError):
    """A reference whose timing asks for more than the robot may do, with the reason."""


def _thinned(times: np.ndarray, spacing: float) -> np.ndarray:
    """Return the indices of points at least ``spacing`` apart in time (first and last kept)."""
    keep = [0]
    for i in range(1, len(times)):
        if times[i] - times[keep[-1]] >= spacing:
            keep.append(i)
    if keep[-1] != len(times) - 1:
        keep[-1] = len(times) - 1
    return np.array(keep)


def thin(times: np.ndarray, spacing: float) -> np.ndarray:
    """Return the indices of the points kept of a reference denser than ``spacing`` [s].

    The first point in each ``spacing``-long interval from the first point on, and the last: a
    planner reads the reference at its knots, so points closer than a fraction of its step
    only cost memory and time (a 100,000-pose Path).
    """
    times = np.asarray(times, dtype=float)
    bins = np.floor((times - times[0]) / spacing)
    keep = np.r_[True, np.diff(bins) > 0]
    keep[-1] = True
    return np.flatnonzero(keep)


def check_implied_motion(times: np.ndarray, positions: np.ndarray, max_speed: float,
                         max_accel: float) -> None:
    """Raise :class:`ReferenceRejected` where the poses' timing exceeds a bound.

    ``times`` [s] strictly increasing, ``positions`` (N, 2) [m]; a bound of 0 is not checked.
    """
    times, positions = np.asarray(times, dtype=float), np.asarray(positions, dtype=float)
    steps = np.diff(times)
    speeds = np.hypot(*np.diff(positions, axis=0).T) / steps
    if max_speed > 0 and speeds.size and speeds.max() > max_speed:
        i = int(np.argmax(speeds))
        raise ReferenceRejected(
            f'it asks for {speeds[i]:.4g} m/s between points {i} and {i + 1} '
            f'(reference_max_speed is {max_speed:g} m/s)')
    keep = _thinned(times, ACCEL_WINDOW)
    if max_accel <= 0 or len(keep) < 3:
        return
    t, p = times[keep], positions[keep]
    velocity = np.diff(p, axis=0) / np.diff(t)[:, None]
    middles = (t[1:] + t[:-1]) / 2
    accel = np.hypot(*np.diff(velocity, axis=0).T) / np.diff(middles)
    if accel.max() > max_accel:
        i = int(np.argmax(accel))
        raise ReferenceRejected(
            f'it asks for {accel[i]:.4g} m/s^2 near point {keep[i + 1]} '
            f'(reference_max_accel is {max_accel:g} m/s^2)')


def check_velocity_bounds(v: np.ndarray, bounds: tuple | None, names: Sequence[str]) -> None:
    """Raise :class:`ReferenceRejected` where velocities ``v`` (N, k) leave ``bounds`` (lo, hi).

    By more than :data:`BOUND_TOLERANCE` of them: a reference the robot may not follow.
    """
    if bounds is None:
        return
    for side, bound, sign in (('v_min', bounds[0], -1.0), ('v_max', bounds[1], 1.0)):
        bound = np.broadcast_to(np.asarray(bound, dtype=float), v.shape[1])
        excess = sign * (v - bound) - BOUND_TOLERANCE * (np.abs(bound) + 1e-3)
        if np.any(excess > 0):
            i, j = (int(a) for a in np.unravel_index(int(np.argmax(excess)), excess.shape))
            raise ReferenceRejected(f'it asks for {names[j]} = {v[i, j]:.4g} at point {i} '
                                    f'({side} is {bound[j]:g})')


def bound_ratios(v: np.ndarray, bounds: tuple) -> np.ndarray:
    """How many times its velocity bounds each row of ``v`` (N, k) asks for (<= 1: within)."""
    lo, hi = (np.broadcast_to(np.asarray(b, dtype=float), v.shape[1]) for b in bounds)
    with np.errstate(divide='ignore', invalid='ignore'):
        over = np.where(hi > 0, v / hi, np.where(v > 0, np.inf, 0.0))
        under = np.where(lo < 0, v / lo, np.where(v < 0, np.inf, 0.0))
    return np.nan_to_num(np.maximum(over, under), nan=0.0).max(axis=1)
