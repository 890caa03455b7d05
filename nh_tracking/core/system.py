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

    qdot = rho(q) v,    vdot = -Gamma(v, v) - G_D^{-1} rho^T dV/dq + B(q) u

with the input matrix B = G_D^{-1} rho^T F of the actuators' force directions F (n, r) projected
onto D (fully actuated, the default: F = G rho, B = identity, r = k) — is derived here by
automatic differentiation and compiled into CasADi Functions (for the solvers, which call them
on symbols) with numpy wrappers (for users). The data is checked for regularity first
(:mod:`nh_tracking.core.regularity`).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
import copy
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from nh_tracking.core import geometry, lean, regularity
from nh_tracking.core.family import DynamicsFamily, finite, sample_states
from nh_tracking.core.lagrangian_data import (as_sx, check_name, LagrangianData, pose_axes,
                                              SymbolicMap)
from nh_tracking.core.numeric import NumericFunction
from nh_tracking.core.regularity import Domain


class NonholonomicSystem:
    """A nonholonomic mechanical system in an adapted basis of its distribution.

    Build one with :meth:`from_constraints` or take a model from :mod:`nh_tracking.models`.
    ``n`` is dim Q, ``m`` the number of constraints, ``k = n - m`` the rank of D and ``r`` the
    number of controls: ``r = k`` when fully actuated (one control per basis field, acting as
    ``vdot = ... + u``), fewer for a system driven by ``actuators`` (e.g. shape torques).
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
        actuators: ca.SX | None = None,
        domain: Domain | None = None,
        symbolic: Sequence[str] = (),
        p: ca.SX | None = None,
    ) -> None:
        self.name = check_name(name)
        self.coordinates = tuple(coordinates)
        self.angles = tuple(angles)
        self.n = q.shape[0]
        self.k = rho.shape[1]
        self.m = constraints.shape[0]
        self.r = self.k if actuators is None else actuators.shape[1]
        self.fully_actuated = actuators is None
        self.domain = domain or Domain.of(self.coordinates, None)
        self.angle_mask = np.array([c in self.angles for c in self.coordinates])
        self.control_names = tuple(controls or (f'u{a + 1}' for a in range(self.r)))
        self.velocity_names = tuple(velocities or (f'v{a + 1}' for a in range(self.k)))
        self.parameters = dict(parameters or {})
        self.basis_condition = basis_condition
        self.pose = pose_axes(name, self.coordinates, pose)
        if len(self.control_names) != self.r or len(self.velocity_names) != self.k:
            raise ValueError(f'{name}: need {self.r} control and {self.k} velocity names')

        v, u = ca.SX.sym('v', self.k), ca.SX.sym('u', self.r)
        p = ca.SX.sym('p', 0) if p is None else p
        if p.shape[0] != len(symbolic):
            raise ValueError(f'{name}: {len(symbolic)} symbolic parameters, {p.shape[0]} symbols')
        g_d = geometry.metric_on_distribution(metric, rho)
        gamma = geometry.christoffel(metric, rho, q)
        inputs = geometry.input_matrix(metric, rho, actuators)
        qdot = rho @ v
        vdot = geometry.acceleration(gamma, inputs, metric, rho, potential, q, v, u)
        self._symbols = (q, v, u, p)
        self._expressions = {
            'actuators': metric @ rho if actuators is None else actuators, 'rho': rho,
            'metric': metric, 'constraints': constraints, 'potential': potential,
            'input_matrix': inputs, 'metric_D': g_d, 'christoffel': gamma, 'qdot': qdot,
            'vdot': vdot, 'energy': 0.5 * v.T @ g_d @ v + potential}
        values = np.array([self.parameters[name] for name in symbolic], dtype=float)
        self._bind(values)
        w = ca.SX.sym('qdot', self.n)
        if symbolic:
            projected = geometry.basis_coefficients(metric, rho, w)
        else:  # the numeric functions, lean already, with an empty p
            qdot, vdot = self.dynamics_fn(q, v, u)
            rho, inputs = self.rho_fn(q), self.input_matrix_fn(q)
            projected = self.velocity_fn(q, w)
        lean = self._lean if symbolic else lambda function, p: function
        self.family = DynamicsFamily(
            tuple(symbolic),
            lean(ca.Function('dynamics', [q, v, u, p], [qdot, vdot], ['q', 'v', 'u', 'p'],
                             ['qdot', 'vdot']), values),
            ca.Function('rho', [q, p], [rho], ['q', 'p'], ['rho']),
            lean(ca.Function('input_matrix', [q, p], [inputs], ['q', 'p'], ['B']), values),
            ca.Function('velocity', [q, w, p], [projected], ['q', 'qdot', 'p'], ['v']))

    def _bind(self, values: np.ndarray) -> None:
        """Build the numeric functions at the symbolic parameters' ``values``."""
        q, v, u, p = self._symbols
        e = {key: ca.substitute(expr, p, values) for key, expr in self._expressions.items()}
        self.actuators_fn = ca.Function('actuators', [q], [e['actuators']], ['q'], ['F'])
        self.rho_fn = ca.Function('rho', [q], [e['rho']], ['q'], ['rho'])
        self._rho = NumericFunction(self.rho_fn)  # every odometry message and command needs it
        self.metric_fn = ca.Function('metric', [q], [e['metric']], ['q'], ['G'])
        self.constraints_fn = ca.Function('constraints', [q], [e['constraints']], ['q'], ['mu'])
        self.potential_fn = ca.Function('potential', [q], [e['potential']], ['q'], ['V'])
        # The derived functions, without what the derivation leaves symbolic but is constant.
        self.input_matrix_fn = self._lean(
            ca.Function('input_matrix', [q], [e['input_matrix']], ['q'], ['B']))
        self.metric_D_fn = ca.Function('metric_D', [q], [e['metric_D']], ['q'], ['G_D'])
        self.christoffel_fn = ca.Function('christoffel', [q], [e['christoffel']], ['q'],
                                          ['Gamma'])
        self.dynamics_fn = self._lean(ca.Function(
            'dynamics', [q, v, u], [e['qdot'], e['vdot']], ['q', 'v', 'u'], ['qdot', 'vdot']))
        self.energy_fn = self._lean(ca.Function('energy', [q, v], [e['energy']], ['q', 'v'],
                                                ['E']))
        x = ca.SX.sym('x', self.n + self.k)
        self.ode_fn = ca.Function('ode', [x, u], [ca.vertcat(*self.dynamics_fn(
            x[:self.n], x[self.n:], u))], ['x', 'u'], ['xdot'])
        qdot = ca.SX.sym('qdot', self.n)
        self.velocity_fn = ca.Function(
            'velocity', [q, qdot], [geometry.basis_coefficients(e['metric'], e['rho'], qdot)],
            ['q', 'qdot'], ['v'])

    @property
    def family_values(self) -> np.ndarray:
        """Return the values of the family's symbolic parameters, in order (the NLPs' numbers)."""
        return np.array([self.parameters[name] for name in self.family.names], dtype=float)

    def with_values(self, **values: float) -> NonholonomicSystem:
        """Return this system with new values of symbolic parameters: same family, same NLPs.

        No derivation and no NLP is built again. A ValueError names a parameter that is not
        symbolic here (its change needs the model built anew), a value that is not a finite
        number, or values that make the model singular (a zero mass); the model's ranges are
        checked by :func:`nh_tracking.models.with_parameters`.
        """
        fixed = set(values) - set(self.family.names)
        if fixed:
            raise ValueError(f'{self.name}: parameters {sorted(fixed)} are not symbolic in '
                             f'this system ({list(self.family.names)} are)')
        given = {k: finite(x, f'{self.name}: parameter {k}') for k, x in values.items()}
        if all(self.parameters.get(k) == x for k, x in given.items()):
            return self
        parameters = {**self.parameters, **given}
        singular = self.family.singular_at(
            [parameters[name] for name in self.family.names],
            regularity.sample_configurations(self.coordinates, self.angles, self.domain))
        if singular is not None:
            raise ValueError(f'{self.name}: {given} make the model singular (not finite at '
                             f'q = {np.round(singular, 3).tolist()})')
        changed = copy.copy(self)
        changed.parameters = parameters
        changed._bind(changed.family_values)
        return changed

    @classmethod
    def from_constraints(
        cls,
        coordinates: Sequence[str],
        metric: SymbolicMap,
        constraints: SymbolicMap | None = None,
        potential: SymbolicMap | None = None,
        *,
        basis: SymbolicMap | None = None,
        actuators: SymbolicMap | None = None,
        domain: Mapping[str, tuple[float, float]] | None = None,
        angles: Sequence[str] = (),
        controls: Sequence[str] | None = None,
        velocities: Sequence[str] | None = None,
        name: str = 'custom',
        parameters: dict[str, float] | None = None,
        pose: Mapping[str, str] | None = None,
    ) -> NonholonomicSystem:
        """Build a system from its Lagrangian data; each argument maps a CasADi SX column q.

        ``metric(q)``: (n, n) kinetic-energy metric; ``constraints(q)``: (m, n) Pfaffian
        constraints mu(q) qdot = 0 with independent rows (None: holonomic); ``potential(q)``:
        scalar V (None: 0); ``basis(q)``: (n, n - m) basis of D. Without a basis, a G-orthonormal
        one is built from the smooth kernel fields of mu and the projected coordinate fields:
        the k that stay farthest from dependent over sampled configurations are kept
        (``basis_condition``), so costs written in v do not depend on an arbitrary choice.
        ``actuators(q)``: (n, r) generalised force directions (joint torques, wheel forces) —
        None means one control per basis field. ``domain``: open intervals of the coordinates
        where the model is valid, e.g. ``{"phi": (-pi/2, pi/2)}``; states outside are refused.
        ``pose`` says which coordinates a ROS pose shows, e.g. ``{"x1": "x", "x2": "y",
        "theta": "yaw"}`` (axes x, y, z, yaw); the others are hidden from it. Irregular data
        (non-finite, dependent constraint rows, a degenerate basis) is refused with the
        coordinates near the trouble named.
        """
        coordinates = tuple(coordinates)
        n = len(coordinates)
        if n == 0 or len(set(coordinates)) != n:
            raise ValueError(f'coordinates must be unique names, got {coordinates}')
        unknown = set(angles) - set(coordinates)
        if unknown:
            raise ValueError(f'angles {sorted(unknown)} are not coordinates {coordinates}')
        check_name(name)
        box = Domain.of(coordinates, domain)
        q = ca.SX.sym('q', n)
        g = as_sx(metric(q), (n, n), 'metric')
        mu = as_sx(constraints(q), None, 'constraints') if constraints else ca.SX(0, n)
        if mu.shape[1] != n or mu.shape[0] >= n:
            raise ValueError(f'constraints must be (m, {n}) with m < {n}, got {mu.shape}')
        pot = as_sx(potential(q), (1, 1), 'potential') if potential else ca.SX(0)
        samples = regularity.sample_configurations(coordinates, angles, box)
        data = regularity.numeric_map(q, g, mu, pot, ca.gradient(pot, q))
        regularity.check_finite('metric(q)', lambda x: data(x)[:1], samples, coordinates)
        regularity.check_finite('constraints(q)', lambda x: data(x)[1:2], samples, coordinates)
        regularity.check_finite('potential(q) or its gradient', lambda x: data(x)[2:], samples,
                                coordinates)
        regularity.check_metric(lambda x: data(x)[0], samples, coordinates)
        regularity.check_constraint_rank(lambda x: data(x)[1].reshape(-1, n), samples,
                                         coordinates)
        k = n - mu.shape[0]
        if basis is not None:
            rho = as_sx(basis(q), (n, k), 'basis')
            regularity.check_in_distribution(regularity.numeric_map(q, rho, mu), samples,
                                             coordinates)
            condition = regularity.basis_condition(
                regularity.numeric_map(q, rho, g), samples, coordinates, 'basis(q)')
        else:
            rho, condition = geometry.orthonormal_basis(q, g, mu, k, samples, coordinates)
        forces = None
        if actuators is not None:
            forces = as_sx(actuators(q), None, 'actuators')
            regularity.check_actuators(q, g, rho, forces, samples, coordinates)
        return cls(
            name=name, coordinates=coordinates, q=q, metric=g, constraints=mu, potential=pot,
            rho=rho, angles=angles, controls=controls, velocities=velocities,
            parameters=parameters, basis_condition=condition, pose=pose, actuators=forces,
            domain=box,
        )

    @classmethod
    def from_data(cls, data: LagrangianData, **names: Any) -> NonholonomicSystem:
        """Build a system from a model's :class:`LagrangianData`.

        ``names`` as in :meth:`from_constraints`: domain, controls, velocities, name,
        parameters, pose.
        """
        return cls.from_constraints(
            data.coordinates, data.metric, data.constraints, data.potential, basis=data.basis,
            actuators=data.actuators, angles=data.angles, **names)

    def parametrised(self, lagrangian: Callable[..., LagrangianData], names: Sequence[str]
                     ) -> NonholonomicSystem:
        """Return this system with the physical parameters ``names`` symbolic in its data.

        ``lagrangian``: the model's data as a function of its physical parameters (keyword
        arguments; the others at this system's ``parameters``); it must give this system
        (same basis and dynamics, checked at sampled states; else a ValueError). Every other
        choice (names, pose, domain) is kept. Its :meth:`with_values` then changes those values
        without a rebuild.
        """
        names = tuple(names)
        p = ca.SX.sym('p', len(names))
        data = lagrangian(**{**self.parameters, **{name: p[i] for i, name in enumerate(names)}})
        q = ca.SX.sym('q', self.n)
        metric, constraints, potential, rho, actuators = data.expressions(q)
        family = type(self)(
            name=self.name, coordinates=self.coordinates, q=q, metric=metric,
            constraints=constraints, potential=potential, rho=rho, angles=self.angles,
            controls=self.control_names, velocities=self.velocity_names,
            parameters=self.parameters, basis_condition=self.basis_condition, pose=self.pose,
            actuators=actuators, domain=self.domain,
            symbolic=names, p=p)
        for x, v, u in sample_states(regularity.sample_configurations(
                self.coordinates, self.angles, self.domain), self.k, self.r):
            ours, theirs = (np.concatenate([s.rho(x).ravel(), *s.dynamics(x, v, u)])
                            for s in (self, family))
            if not np.allclose(ours, theirs, rtol=1e-9, atol=1e-12):
                raise ValueError(f'{self.name}: its Lagrangian data is not this model (basis '
                                 f'or dynamics differ at q = {np.round(x, 3).tolist()})')
        return family

    def _lean(self, function: ca.Function, p: np.ndarray | None = None) -> ca.Function:
        """Drop what is constant or repeated in ``function``, checked over the domain.

        ``p``: the values its input ``p`` (physical parameters) is drawn around.
        """
        return lean.lean(function, lean.draw_states(
            function, self.coordinates, self.angles, self.domain, {'v': self.k, 'u': self.r},
            None if p is None else {'p': p}))

    # numpy interface -------------------------------------------------------------------------
    def rho(self, q: ArrayLike) -> np.ndarray:
        """(n, k) adapted basis at q: column A holds the components rho^i_A of e_A."""
        return self._rho(self.as_configuration(q))[0].reshape(self.n, self.k)

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
        """Return the force in full coordinates, F u (G rho u when fully actuated)."""
        return np.array(self.actuators_fn(self.as_configuration(q))) @ self.as_control(u)

    def input_matrix(self, q: ArrayLike) -> np.ndarray:
        """(k, r) B(q): how the controls move the quasi-velocities, vdot = ... + B u."""
        return np.array(self.input_matrix_fn(self.as_configuration(q))).reshape(self.k, self.r)

    def velocity_coordinates(self, q: ArrayLike, qdot: ArrayLike) -> np.ndarray:
        """V with rho v = P qdot: the quasi-velocities of qdot's G-orthogonal projection on D."""
        q, qdot = self.as_configuration(q), _vector(qdot, self.n, 'qdot')
        return np.array(self.velocity_fn(q, qdot)).ravel()

    def __repr__(self) -> str:
        return (
            f'NonholonomicSystem({self.name!r}, q={self.coordinates}, n={self.n}, k={self.k}, '
            f'r={self.r}, parameters={self.parameters})'
        )

    def as_configuration(self, q: ArrayLike, what: str = 'q') -> np.ndarray:
        return _vector(q, self.n, what)

    def as_velocity(self, v: ArrayLike, what: str = 'v') -> np.ndarray:
        return _vector(v, self.k, what)

    def as_control(self, u: ArrayLike | None) -> np.ndarray:
        return np.zeros(self.r) if u is None else _vector(u, self.r, 'u')

    def check_configuration(self, q: ArrayLike, what: str = 'q') -> np.ndarray:
        """``q`` as an array, or a ValueError if it is not finite or outside the domain."""
        q = self.as_configuration(q, what)
        self.domain.check(q, what)
        return q


def _vector(x: ArrayLike, size: int, what: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float).reshape(-1)
    if arr.size != size:
        raise ValueError(f'{what} must have {size} entries, got {arr.size}')
    return arr
