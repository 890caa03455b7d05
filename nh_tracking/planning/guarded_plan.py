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

"""A control sequence through the command guard: replayed on the model, cut back where it must.

The controls are replayed from the robot's state as a driver holds them (each over its
interval). If the replay keeps to the velocity bounds and the speed limit (within
:data:`REPLAY_TOL`) and its first command clears every obstacle, the sequence passes as it is.
Otherwise it is replayed interval by interval: where the next state breaks a limit, the guard
(:class:`CommandGuard`, from the robot's velocity: beyond the bounds it slows at ``max_decel``)
names the state to reach instead, and the interval's control is the one that reaches it on the
model (computed torque, one correction), clipped to the actuators' bounds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nh_tracking.core.poses import PoseMap
from nh_tracking.planning.command_guard import Clearance, CommandGuard, GuardAction, GuardNote
from nh_tracking.planning.fallback import held_step

REPLAY_TOL = 0.005  # of a bound: a replay this little past one passes (the plan's own error)


@dataclass(frozen=True)
class GuardedControls:
    """Controls ``u`` (N, r) the guard let pass, their replay ``q``, ``v`` (N + 1) and notes."""

    u: np.ndarray
    q: np.ndarray
    v: np.ndarray
    notes: tuple[GuardNote, ...] = ()


def replay(pose_map: PoseMap, q0: np.ndarray, v0: np.ndarray, u: np.ndarray,
           steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q, v) at the knots of the controls ``u`` (N, r) held over ``steps`` (N,) from (q0, v0)."""
    system = pose_map.system
    states = np.array(held_step(system, len(u))(np.r_[q0, v0], u.T, steps[None, :])).T
    x = np.vstack([np.r_[q0, v0], states])
    return x[:, :system.n], x[:, system.n:]


def guard_controls(guard: CommandGuard, pose_map: PoseMap, q0: np.ndarray, v0: np.ndarray,
                   u: np.ndarray, steps: np.ndarray, lookahead: float,
                   clearance: Clearance | None = None,
                   u_bounds: np.ndarray | None = None) -> GuardedControls:
    """Return the controls ``u`` held over ``steps`` from (q0, v0), cut back to the limits.

    ``lookahead``: how long the first control is in force before another sequence comes;
    ``u_bounds`` (2, r): the actuators'.
    """
    q, v = replay(pose_map, q0, v0, u, steps)
    if np.isfinite(q).all() and np.isfinite(v).all() and _keeps_to(
            guard, pose_map, q, v, steps, lookahead, clearance):
        return GuardedControls(u, q, v)
    return _cut_back(guard, pose_map, q0, v0, u, steps, lookahead, clearance, u_bounds)


def _keeps_to(guard: CommandGuard, pose_map: PoseMap, q: np.ndarray, v: np.ndarray,
              steps: np.ndarray, lookahead: float, clearance: Clearance | None) -> bool:
    """Whether the replay (q, v) keeps to the bounds and speed limit, its start clear."""
    if guard.bounds is not None:
        lo, hi = guard.bounds
        slack = REPLAY_TOL * np.where(np.isfinite(hi - lo), np.maximum(np.abs(lo), np.abs(hi)),
                                      0.0)
        if ((v < lo - slack) | (v > hi + slack)).any():
            return False
    matrix = pose_map.twist_matrix(q[0])
    cap = guard.speed_limit.cap(guard.max_speed(matrix) if guard.speed_limit.percentage
                                else np.inf)
    if np.isfinite(cap):
        speeds = np.hypot(*np.einsum('nij,nj->in', pose_map.twist_matrices(q)[:, :2], v))
        if (speeds > cap * (1.0 + REPLAY_TOL)).any():
            return False
    if clearance is None or clearance.empty:
        return True
    first = guard.velocity(v[1], matrix, v[1], steps[0], pose_map.pose(q[0]), clearance,
                           lookahead)  # (bounds and speed limit: judged above, with REPLAY_TOL)
    return all(note.action is not GuardAction.OBSTACLE for note in first.notes)


def _cut_back(guard: CommandGuard, pose_map: PoseMap, q0: np.ndarray, v0: np.ndarray,
              u: np.ndarray, steps: np.ndarray, lookahead: float, clearance: Clearance | None,
              u_bounds: np.ndarray | None) -> GuardedControls:
    """Replay interval by interval; where the next state breaks a limit, reach the guard's."""
    system = pose_map.system
    step = held_step(system)
    qs, vs, us = [q0], [v0], []
    notes: dict[GuardAction, GuardNote] = {}
    for k, (control, h) in enumerate(zip(u, steps)):
        q, v = qs[-1], vs[-1]
        x = np.array(step(np.r_[q, v], control, h)).ravel()
        matrix = pose_map.twist_matrix(q)
        guarded = guard.velocity(x[system.n:], matrix, v, h, pose_map.pose(q), clearance,
                                 lookahead if k == 0 else h, from_state=True)
        if guarded.changed or not np.isfinite(x).all():
            control = _reaching(pose_map, q, v, guarded.v, h, u_bounds)
            x = np.array(step(np.r_[q, v], control, h)).ravel()
            for note in guarded.notes:
                notes.setdefault(note.action, note)  # the first of each kind, with its figures
        us.append(control)
        qs.append(x[:system.n])
        vs.append(x[system.n:])
    return GuardedControls(np.array(us), np.array(qs), np.array(vs), tuple(notes.values()))


def _reaching(pose_map: PoseMap, q: np.ndarray, v: np.ndarray, target: np.ndarray, h: float,
              u_bounds: np.ndarray | None) -> np.ndarray:
    """Return the control held over ``h`` from (q, v) that brings v nearest ``target``.

    Computed torque, vdot = drift + B u, then one correction for what the step really did.
    """
    system = pose_map.system
    step = held_step(system)
    matrix = system.input_matrix(q)
    drift = system.dynamics(q, v)[1]
    control = np.linalg.lstsq(matrix, (target - v) / h - drift, rcond=None)[0]
    if u_bounds is not None:
        control = np.clip(control, *u_bounds)
    reached = np.array(step(np.r_[q, v], control, h)).ravel()[system.n:]
    control = control + np.linalg.lstsq(matrix, (target - reached) / h, rcond=None)[0]
    return control if u_bounds is None else np.clip(control, *u_bounds)
