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

"""Nonholonomic mechanical systems (G, V, D) in an adapted basis, built from Lagrangian data.

The user (or a built-in model) gives the metric G(q), the Pfaffian constraints mu(q) with
mu(q) qdot = 0, the potential V(q) and optionally a basis of D. Everything the solvers need —
the adapted basis rho, the metric on D, the Christoffel symbols of the nonholonomic connection
and the controlled dynamics

    qdot = rho(q) v,    vdot = -Gamma(v, v) - G_D^{-1} rho^T dV/dq + u

— is derived here by automatic differentiation and compiled into CasADi Functions (for the
solvers, which call them on symbols) with numpy wrappers (for users).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from nh_tracking import geometry

SymbolicMap = Callable[[ca.SX], Any]

POSE_AXES = ('x', 'y', 'z', 'yaw')  # of a ROS pose: position and heading
_SAMPLES = 64  # configurations at which data is checked and a default basis is chosen


class NonholonomicSystem:
    """A fully actuated nonholonomic mechanical system in an adapted basis of its distribution.

    Build one with :meth:`from_constraints` or take a model from :mod:`nh_tracking.models`.
    ``n`` is dim Q, ``m`` the number of constraints, ``k = n - m`` the rank of D, which is also
    the number of controls (one per basis field, acting as ``vdot = ... + u``).
    """

    def __init__(
        self,
        *,
        name: str,
        coordinates: Sequence[str],
        q: ca.SX,
        metric: ca.SX,
        constraints: ca.SX,
        potential: ca.SX,
        rho: ca.SX,
        angles: Sequence[str] = (),
        controls: Sequence[str] | None = None,
        velocities: Sequence[str] | None = None,
        parameters: dict[str, float] | None = None,
        basis_condition: float = 1.0,
        pose: Mapping[str, str] | None = None,
    ) -> None:
        self.name = name
        self.coordinates = tuple(coordinates)
        self.angles = tuple(angles)
        self.n = q.shape[0]
        self.k = rho.shape[1]
        self.m = constraints.shape[0]
        self.angle_mask = np.array([c in self.angles for c in self.coordinates])
        self.control_names = tuple(controls or (f'u{a + 1}' for a in range(self.k)))
        self.velocity_names = tuple(velocities or (f'v{a + 1}' for a in range(self.k)))
        self.parameters = dict(parameters or {})
        self.basis_condition = basis_condition
        self.pose = _pose_axes(name, self.coordinates, pose)
        if len(self.control_names) != self.k or len(self.velocity_names) != self.k:
            raise ValueError(f'{name}: need {self.k} control and velocity names')

        v = ca.SX.sym('v', self.k)
        u = ca.SX.sym('u', self.k)
        g_d = geometry.metric_on_distribution(metric, rho)
        gamma = geometry.christoffel(metric, rho, q)
        qdot = rho @ v
        vdot = (
            -geometry.quadratic_christoffel(gamma, v)
            - geometry.potential_force(metric, rho, potential, q)
            + u
        )
        x = ca.vertcat(q, v)
        self.rho_fn = ca.Function('rho', [q], [rho], ['q'], ['rho'])
        self.metric_fn = ca.Function('metric', [q], [metric], ['q'], ['G'])
        self.constraints_fn = ca.Function('constraints', [q], [constraints], ['q'], ['mu'])
        self.potential_fn = ca.Function('potential', [q], [potential], ['q'], ['V'])
        self.metric_D_fn = ca.Function('metric_D', [q], [g_d], ['q'], ['G_D'])
        self.christoffel_fn = ca.Function('christoffel', [q], [gamma], ['q'], ['Gamma'])
        self.dynamics_fn = ca.Function(
            'dynamics', [q, v, u], [qdot, vdot], ['q', 'v', 'u'], ['qdot', 'vdot']
        )
        self.ode_fn = ca.Function('ode', [x, u], [ca.vertcat(qdot, vdot)], ['x', 'u'], ['xdot'])
        self.energy_fn = ca.Function(
            'energy', [q, v], [0.5 * v.T @ g_d @ v + potential], ['q', 'v'], ['E']
        )

    @classmethod
    def from_constraints(
        cls,
        coordinates: Sequence[str],
        metric: SymbolicMap,
        constraints: SymbolicMap | None = None,
        potential: SymbolicMap | None = None,
        *,
        basis: SymbolicMap | None = None,
        angles: Sequence[str] = (),
        controls: Sequence[str] | None = None,
        velocities: Sequence[str] | None = None,
        name: str = 'custom',
        parameters: dict[str, float] | None = None,
        pose: Mapping[str, str] | None = None,
    ) -> NonholonomicSystem:
        """Build a system from its Lagrangian data; each argument maps a CasADi SX column q.

        ``metric(q)``: (n, n) kinetic-energy metric; ``constraints(q)``: (m, n) Pfaffian
        constraints mu(q) qdot = 0 (None: holonomic); ``potential(q)``: scalar V (None: 0);
        ``basis(q)``: (n, n - m) basis of D. Without a basis, a G-orthonormal one is built from
        smooth kernel fields of mu, chosen to stay well conditioned over sampled configurations,
        so costs written in v do not depend on an arbitrary choice of basis. Candidate fields are
        the smooth kernel fields of mu and the projected coordinate fields; the k that stay
        farthest from dependent over sampled configurations are kept (``basis_condition``).
        Such a basis can still degenerate somewhere unsampled: pass ``basis`` for global use.
        ``pose`` says which coordinates a ROS pose shows, e.g. ``{"x1": "x", "x2": "y",
        "theta": "yaw"}`` (axes x, y, z, yaw); the others are hidden from it.
        """
        coordinates = tuple(coordinates)
        n = len(coordinates)
        if n == 0 or len(set(coordinates)) != n:
            raise ValueError(f'coordinates must be unique names, got {coordinates}')
        unknown = set(angles) - set(coordinates)
        if unknown:
            raise ValueError(f'angles {sorted(unknown)} are not coordinates {coordinates}')
        q = ca.SX.sym('q', n)
        g = _as_sx(metric(q), (n, n), 'metric')
        mu = _as_sx(constraints(q), None, 'constraints') if constraints else ca.SX(0, n)
        if mu.shape[1] != n or mu.shape[0] >= n:
            raise ValueError(f'constraints must be (m, {n}) with m < {n}, got {mu.shape}')
        pot = _as_sx(potential(q), (1, 1), 'potential') if potential else ca.SX(0)
        samples = _sample_configurations(coordinates, angles)
        _check_metric(ca.Function('G', [q], [g]), samples)
        k = n - mu.shape[0]
        if basis is not None:
            rho = _as_sx(basis(q), (n, k), 'basis')
            condition = _check_basis(ca.Function('check', [q], [rho, mu, g]), samples)
        else:
            rho, condition = _orthonormal_basis(q, g, mu, k, samples)
        return cls(
            name=name, coordinates=coordinates, q=q, metric=g, constraints=mu, potential=pot,
            rho=rho, angles=angles, controls=controls, velocities=velocities,
            parameters=parameters, basis_condition=condition, pose=pose,
        )

    # numpy interface -------------------------------------------------------------------------
    def rho(self, q: ArrayLike) -> np.ndarray:
        """(n, k) adapted basis at q: column A holds the components rho^i_A of e_A."""
        return np.array(self.rho_fn(self.as_configuration(q)))

    def metric(self, q: ArrayLike) -> np.ndarray:
        """(n, n) kinetic-energy metric G(q)."""
        return np.array(self.metric_fn(self.as_configuration(q)))

    def constraints(self, q: ArrayLike) -> np.ndarray:
        """(m, n) Pfaffian constraint matrix mu(q)."""
        return np.array(self.constraints_fn(self.as_configuration(q))).reshape(self.m, self.n)

    def metric_D(self, q: ArrayLike) -> np.ndarray:
        """(k, k) metric on D in the basis, G_D = rho^T G rho."""
        return np.array(self.metric_D_fn(self.as_configuration(q)))

    def christoffel(self, q: ArrayLike) -> np.ndarray:
        """Christoffel symbols as an array Gamma[C, A, B] (nabla_{e_A} e_B = Gamma^C_AB e_C)."""
        gamma = np.array(self.christoffel_fn(self.as_configuration(q)))
        return gamma.reshape(self.k, self.k, self.k)

    def dynamics(
        self, q: ArrayLike, v: ArrayLike, u: ArrayLike | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(qdot, vdot) of the controlled nonholonomic equations; u = None means no control."""
        qdot, vdot = self.dynamics_fn(self.as_configuration(q), self.as_velocity(v),
                                      self.as_control(u))
        return np.array(qdot).ravel(), np.array(vdot).ravel()

    def energy(self, q: ArrayLike, v: ArrayLike) -> float:
        """Kinetic plus potential energy, 1/2 v^T G_D v + V(q)."""
        return float(self.energy_fn(self.as_configuration(q), self.as_velocity(v)))

    def generalized_force(self, q: ArrayLike, u: ArrayLike) -> np.ndarray:
        """Return the force in full coordinates, G rho u, that the control u stands for."""
        return self.metric(q) @ self.rho(q) @ self.as_control(u)

    def velocity_coordinates(self, q: ArrayLike, qdot: ArrayLike) -> np.ndarray:
        """V with rho v = P qdot: the quasi-velocities of qdot's G-orthogonal projection on D."""
        rho, g = self.rho(q), self.metric(q)
        return np.linalg.solve(rho.T @ g @ rho, rho.T @ g @ _vector(qdot, self.n, 'qdot'))

    def __repr__(self) -> str:
        return (
            f'NonholonomicSystem({self.name!r}, q={self.coordinates}, n={self.n}, k={self.k}, '
            f'parameters={self.parameters})'
        )

    def as_configuration(self, q: ArrayLike) -> np.ndarray:
        return _vector(q, self.n, 'q')

    def as_velocity(self, v: ArrayLike) -> np.ndarray:
        return _vector(v, self.k, 'v')

    def as_control(self, u: ArrayLike | None) -> np.ndarray:
        return np.zeros(self.k) if u is None else _vector(u, self.k, 'u')


def _vector(x: ArrayLike, size: int, what: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float).reshape(-1)
    if arr.size != size:
        raise ValueError(f'{what} must have {size} entries, got {arr.size}')
    return arr


def _as_sx(value: Any, shape: tuple[int, int] | None, what: str) -> ca.SX:
    sx = value if isinstance(value, ca.SX) else ca.SX(value)
    if shape is not None and sx.shape != shape:
        raise ValueError(f'{what}(q) must have shape {shape}, got {sx.shape}')
    return sx


def _sample_configurations(coordinates: Sequence[str], angles: Sequence[str]) -> np.ndarray:
    """Deterministic spread of configurations: angles over the whole circle, others ~ N(0, 1)."""
    rng = np.random.default_rng(0)
    samples = rng.normal(size=(_SAMPLES, len(coordinates)))
    for i, c in enumerate(coordinates):
        if c in angles:
            samples[:, i] = rng.uniform(-np.pi, np.pi, _SAMPLES)
    return samples


def _check_metric(metric_fn: ca.Function, samples: np.ndarray) -> None:
    for q in samples:
        g = np.array(metric_fn(q))
        if not np.allclose(g, g.T) or np.linalg.eigvalsh(0.5 * (g + g.T))[0] <= 0:
            raise ValueError(f'metric(q) is not symmetric positive definite at q = {q}')


def _check_basis(fn: ca.Function, samples: np.ndarray) -> float:
    """Reject a basis that leaves D or loses rank at sampled configurations."""
    worst = np.inf
    for q in samples:
        rho, mu, g = (np.array(a) for a in fn(q))
        if mu.size and np.abs(mu @ rho).max() > 1e-9 * max(1.0, np.abs(mu).max()):
            raise ValueError(f'basis(q) is not in the constraint distribution at q = {q}')
        gram = rho.T @ g @ rho
        d = np.sqrt(np.diag(gram))
        if d.min() <= 0:
            raise ValueError(f'basis(q) has a zero field at q = {q}')
        worst = min(worst, np.linalg.eigvalsh(gram / np.outer(d, d))[0])
    if worst < 1e-9:
        raise ValueError('basis(q) loses rank at a sampled configuration')
    return float(worst)


def _orthonormal_basis(
    q: ca.SX, g: ca.SX, mu: ca.SX, k: int, samples: np.ndarray
) -> tuple[ca.SX, float]:
    candidates = (geometry.constraint_kernel_candidates(mu)
                  + geometry.projected_coordinate_fields(g, mu))
    w = ca.horzcat(*candidates)
    gram_fn = ca.Function('gram', [q], [w.T @ g @ w])
    gram = np.stack([np.array(gram_fn(s)) for s in samples])
    chosen, condition = geometry.select_best_conditioned(gram, k)
    if condition < 1e-6:
        raise ValueError(
            'no smooth basis of D found from the constraints at the sampled configurations; '
            'pass basis= explicitly'
        )
    return geometry.gram_schmidt(g, [candidates[i] for i in chosen]), condition


def _pose_axes(name: str, coordinates: tuple[str, ...],
               pose: Mapping[str, str] | None) -> dict[str, str] | None:
    if pose is None:
        return None
    pose = dict(pose)
    if not set(pose) <= set(coordinates):
        raise ValueError(f'{name}: pose names {sorted(set(pose) - set(coordinates))}, which '
                         f'are not coordinates {coordinates}')
    axes = list(pose.values())
    if not set(axes) <= set(POSE_AXES) or len(set(axes)) != len(axes):
        raise ValueError(f'{name}: pose axes must be distinct members of {POSE_AXES}, '
                         f'got {pose}')
    return pose
