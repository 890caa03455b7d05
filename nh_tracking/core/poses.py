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

"""Where a configuration sits in the world of ROS messages: poses, body twists, references.

A ROS pose gives (x, y, z, yaw); a system's coordinates map onto some of these axes (the
sleigh's x1, x2, theta onto x, y, yaw) and the rest are *hidden* (the rolling disk's rolling
angle phi), not observable from a pose. Velocities given in full coordinates are projected
onto D by least squares on the pose rows of rho — the lateral slip of a path, which no wheeled
robot can follow, is dropped.
"""
from __future__ import annotations

from collections.abc import Mapping

import casadi as ca
import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.interpolate import CubicSpline

from nh_tracking.core.implied_shape import ImpliedShape
from nh_tracking.core.lagrangian_data import POSE_AXES
from nh_tracking.core.numeric import NumericFunction
from nh_tracking.core.regularity import random_configurations
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.core.trajectory import Trajectory

AXES = POSE_AXES
MAX_CONDITION = 1e4  # of the pose rows of rho, for the normal equations (their square: 1e8)
_AXIS_BY_NAME = {'x': 'x', 'x1': 'x', 'y': 'y', 'x2': 'y', 'z': 'z', 'theta': 'yaw',
                 'yaw': 'yaw'}


def _by_name(system: NonholonomicSystem) -> dict[str, str]:
    """Return pose axes from unambiguous coordinate names, for systems that declare none.

    An angle that could be the heading but is not named so is an error, never silently hidden.
    """
    mapping = {c: _AXIS_BY_NAME[c] for c in system.coordinates if c in _AXIS_BY_NAME}
    unnamed_angles = [a for a in system.angles if a not in mapping]
    if 'x' not in mapping.values() or ('yaw' not in mapping.values() and unnamed_angles):
        raise ValueError(f"{system.name}: which coordinates are the pose's x, y and heading "
                         f'is not clear from {system.coordinates}; give pose={{...}} to '
                         'NonholonomicSystem.from_constraints (or axes to PoseMap)')
    return mapping


def bases(system: NonholonomicSystem, qs: np.ndarray) -> np.ndarray:
    """(N, n, k) adapted bases rho at N configurations, in one CasADi call.

    A reference has thousands of poses: one call for all of them, not one per pose.
    """
    qs = np.asarray(qs, dtype=float).reshape(-1, system.n)
    blocks = np.array(system.rho_fn.map(len(qs))(qs.T)).reshape(system.n, len(qs), system.k)
    return blocks.transpose(1, 0, 2)


def carried(old: NonholonomicSystem, new: NonholonomicSystem, qs: np.ndarray,
            vs: np.ndarray) -> np.ndarray:
    """Return (N, k) quasi-velocities in ``new``'s basis of the motions ``vs`` give in ``old``'s.

    For a model with other physical parameters, whose basis may scale with them: qdot = rho v
    is kept, projected G-orthogonally onto ``new``'s D where that moves too.
    """
    qs = np.asarray(qs, dtype=float).reshape(-1, old.n)
    qdot = np.einsum('nik,nk->ni', bases(old, qs), np.reshape(vs, (len(qs), old.k)))
    return np.array(new.velocity_fn.map(len(qs))(qs.T, qdot.T)).T


def reexpressed(reference: Trajectory, old: NonholonomicSystem,
                new: NonholonomicSystem) -> Trajectory:
    """Return ``reference`` (in ``old``'s basis of D) as the same motion in ``new``'s.

    The velocities are :func:`carried`; the controls, the old model's, are dropped (zero).
    """
    v = carried(old, new, reference.q, reference.v)
    return Trajectory(reference.t, reference.q, v, np.zeros((len(reference.t) - 1, new.r)))


def wrap_angle(angle: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) in (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(angle), 2 * np.pi)


class PoseMap:
    """Maps a system's (q, v) to and from world poses (x, y, z, yaw) and body twists.

    ``axes`` maps coordinate names to pose axes (default: the system's own ``pose``, which every
    built-in model declares; failing that, the unambiguous names x/x1, y/x2, z, theta/yaw);
    coordinates without an axis are hidden from a pose.
    """

    def __init__(self, system: NonholonomicSystem,
                 axes: Mapping[str, str] | None = None) -> None:
        mapping = dict(axes) if axes is not None else system.pose or _by_name(system)
        if not set(mapping.values()) <= set(AXES) or len(set(mapping.values())) != len(mapping):
            raise ValueError(f'pose axes must be distinct members of {AXES}, got {mapping}')
        if 'x' not in mapping.values():
            raise ValueError(f"{system.name}: no coordinate maps onto the pose's x axis")
        self.system = system
        self.rows = {axis: system.coordinates.index(c) for c, axis in mapping.items()}
        self.hidden = [i for i, c in enumerate(system.coordinates) if c not in mapping]
        self.pose_rows = [self.rows[a] for a in AXES if a in self.rows]
        self._axes = [AXES.index(a) for a in AXES if a in self.rows]  # their index in a pose
        self._projection = self._normal_equations()
        self.implied = ImpliedShape(system, self.pose_rows, self.hidden, [
            i for i, a in enumerate(a for a in AXES if a in self.rows) if a != 'yaw'])

    @property
    def has_yaw(self) -> bool:
        return 'yaw' in self.rows

    def pose(self, q: np.ndarray) -> np.ndarray:
        """(x, y, z, yaw) of a configuration; absent axes are 0, yaw in (-pi, pi]."""
        out = np.array([q[self.rows[a]] if a in self.rows else 0.0 for a in AXES])
        out[3] = wrap_angle(out[3])
        return out

    def configuration(self, pose: np.ndarray, hidden: np.ndarray | None = None) -> np.ndarray:
        """Q from a pose; hidden coordinates from ``hidden`` (default 0)."""
        q = np.zeros(self.system.n)
        if hidden is not None and self.hidden:
            q[self.hidden] = np.asarray(hidden, dtype=float)[self.hidden]
        q[self.pose_rows] = np.asarray(pose, dtype=float)[self._axes]
        return q

    def _normal_equations(self) -> NumericFunction | None:
        """(q, body twist) -> v in one call, where the pose rows of rho keep full rank.

        The least-squares solution is then that of the normal equations, written out: one call
        on every odometry message instead of rho, rotation and ``lstsq`` one by one. None where a
        basis direction moves hidden coordinates alone (the snakeboard's
        shape): there the minimum-norm solution is wanted, from ``lstsq``.
        """
        system = self.system
        samples = random_configurations(system.coordinates, system.angles, system.domain,
                                        np.random.default_rng(0), 32)
        if np.linalg.cond(bases(system, samples)[:, self.pose_rows, :]).max() > MAX_CONDITION:
            return None
        q, twist = ca.SX.sym('q', system.n), ca.SX.sym('twist', 4)
        yaw = q[self.rows['yaw']] if self.has_yaw else 0.0
        c, s = ca.cos(yaw), ca.sin(yaw)
        world = ca.vertcat(c * twist[0] - s * twist[1], s * twist[0] + c * twist[1], twist[2],
                           twist[3])[self._axes]
        rows = system.rho_fn(q)[self.pose_rows, :]
        return NumericFunction(ca.Function('velocity', [q, twist], [
            ca.solve(rows.T @ rows, rows.T @ world)]))

    def velocity(self, q: np.ndarray, body_twist: np.ndarray, rows: list[int] | None = None,
                 rates: np.ndarray | None = None) -> np.ndarray:
        """V from a body-frame twist (vx, vy, vz, wz), projected onto D (least squares).

        ``rows``: hidden coordinates whose ``rates`` are measured too (a steering joint's).
        """
        if not rows and self._projection is not None:
            v = self._projection(q, body_twist)[0]
            if np.isfinite(v).all():  # (else a singular configuration: lstsq's answer)
                return v
        return self.velocity_from_world(q, self.world_rates(q, body_twist), rows, rates)

    def world_rates(self, q: np.ndarray, body_twist: np.ndarray) -> np.ndarray:
        """(xdot, ydot, zdot, yaw rate) of a body-frame twist at q."""
        yaw = q[self.rows['yaw']] if self.has_yaw else 0.0
        c, s = np.cos(yaw), np.sin(yaw)
        vx, vy, vz, wz = body_twist
        return np.array([c * vx - s * vy, s * vx + c * vy, vz, wz])

    def velocity_from_world(self, q: np.ndarray, world: np.ndarray,
                            rows: list[int] | None = None,
                            rates: np.ndarray | None = None) -> np.ndarray:
        """V from world-frame rates (xdot, ydot, zdot, yaw rate), projected onto D.

        With the ``rates`` of hidden coordinates ``rows`` too. One least-squares solve (the
        tracking law's, and odometry's where the pose rows of rho lose rank or joints are
        measured), not a batched pseudo-inverse.
        """
        matrix = self.system.rho(q)[self.pose_rows + list(rows or ()), :]
        measured = np.concatenate([np.asarray(world, dtype=float)[self._axes],
                                   [] if rates is None else rates])
        return np.linalg.lstsq(matrix, measured, rcond=None)[0]

    @staticmethod
    def _project(rho: np.ndarray, rows: list[int], rates: np.ndarray) -> np.ndarray:
        """(N, k) least-squares velocities from (N, n, k) bases and (N, len(rows)) q rates."""
        matrices = rho[:, rows, :]
        cutoff = np.finfo(float).eps * max(matrices.shape[1:])  # lstsq's default (rcond=None)
        return (np.linalg.pinv(matrices, rcond=cutoff) @ rates[:, :, None])[:, :, 0]

    def hidden_rates(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Rates of the hidden coordinates in the motion (q, v): (rho(q) v) at those rows."""
        return self.system.rho(q)[self.hidden] @ v

    def body_twist(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Body-frame twist (vx, vy, vz, wz) of the motion (q, v)."""
        return self.twist_matrix(q) @ v

    def twist_matrix(self, q: np.ndarray) -> np.ndarray:
        """(4, k) M(q): the body-frame twist (vx, vy, vz, wz) of quasi-velocities v is M v."""
        return self._body_frame(self.system.rho(q)[None], np.asarray(q)[None])[0]

    def twist_matrices(self, qs: np.ndarray) -> np.ndarray:
        """(N, 4, k) M(q) at N configurations, in one CasADi call."""
        return self._body_frame(bases(self.system, qs), np.asarray(qs).reshape(-1, self.system.n))

    def _body_frame(self, rho: np.ndarray, qs: np.ndarray) -> np.ndarray:
        """(N, 4, k) body-frame twist matrices from bases rho (N, n, k) at ``qs`` (N, n)."""
        zero = np.zeros(rho.shape[::2])
        world = [rho[:, self.rows[a]] if a in self.rows else zero for a in AXES]
        yaw = qs[:, self.rows['yaw']] if self.has_yaw else np.zeros(len(qs))
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        return np.stack([c * world[0] + s * world[1], -s * world[0] + c * world[1],
                         world[2], world[3]], axis=1)

    def reference(self, times: np.ndarray, poses: np.ndarray,
                  body_twists: np.ndarray | None = None,
                  hidden0: np.ndarray | None = None) -> Trajectory:
        """Return a reference Trajectory from timed poses (N, 4) and body twists (N, 4) or None.

        Without twists, velocities are the derivatives of a C2 spline through the poses (yaw
        unwrapped first). Either way they are projected onto D. Hidden coordinates the motion
        implies (a steering angle: :mod:`implied_shape`) are solved for, the others integrated
        from ``hidden0`` along the projected motion.
        """
        times = np.asarray(times, dtype=float)
        poses = np.array(poses, dtype=float)
        poses[:, 3] = np.unwrap(poses[:, 3])
        if body_twists is None:
            world = _derivative(times, poses)
        else:
            yaw, tw = poses[:, 3], np.asarray(body_twists, dtype=float)
            c, s = np.cos(yaw), np.sin(yaw)
            world = np.stack([c * tw[:, 0] - s * tw[:, 1], s * tw[:, 0] + c * tw[:, 1],
                              tw[:, 2], tw[:, 3]], axis=1)
        q = np.array([self.configuration(p, hidden0) for p in poses])
        rho = bases(self.system, q)
        rates = world[:, self._axes]
        v = self._project(rho, self.pose_rows, rates)
        implied = self.implied.indices
        if implied:
            q[:, implied] = self.implied.solve(q, v, rates)
            rho = bases(self.system, q)
            v = self._project(rho, self.pose_rows + implied,
                              np.hstack([rates, _derivative(times, q[:, implied])]))
        integrated = [h for h in self.hidden if h not in implied]
        if integrated:
            hidden_rates = np.einsum('nik,nk->ni', rho[:, integrated, :], v)
            q[:, integrated] += cumulative_trapezoid(hidden_rates, times, axis=0, initial=0.0)
        return Trajectory(t=times, q=q, v=v, u=np.zeros((len(times) - 1, self.system.r)))


def _derivative(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Rates of ``values`` (N, d) at ``times``: a C2 spline's derivative (a chord for N = 2)."""
    if len(times) > 2:
        return CubicSpline(times, values, axis=0).derivative()(times)
    return np.tile((values[-1] - values[0]) / (times[-1] - times[0]), (len(times), 1))
