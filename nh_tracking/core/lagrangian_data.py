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

"""The user's Lagrangian data as CasADi matrices, and the names a system is given, checked.

Metric, constraints, potential, basis and actuators come as callables of a CasADi SX column q;
what they return is taken as an SX matrix of the shape the system needs (a list of rows of
expressions too), or refused with the argument named. A model's data may close over physical
parameters that are numbers (to build the system) or CasADi symbols (to estimate them).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import re
from typing import Any

import casadi as ca

SymbolicMap = Callable[[ca.SX], Any]

POSE_AXES = ('x', 'y', 'z', 'yaw')  # of a ROS pose: position and heading
NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*')  # a system's name names its CasADi functions


@dataclass(frozen=True)
class LagrangianData:
    """A model's coordinates and the maps of q that define its dynamics.

    As :meth:`NonholonomicSystem.from_constraints` takes them: ``metric`` (n, n),
    ``constraints`` (m, n) or None, ``potential`` scalar or None, ``basis`` (n, k) of D or None
    (then a G-orthonormal one is sampled, which needs numeric parameters), ``actuators`` (n, r)
    or None (one control per basis field).
    """

    coordinates: Sequence[str]
    metric: SymbolicMap
    constraints: SymbolicMap | None = None
    potential: SymbolicMap | None = None
    basis: SymbolicMap | None = None
    actuators: SymbolicMap | None = None
    angles: Sequence[str] = ()

    def expressions(self, q: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX, ca.SX | None]:
        """(metric, constraints, potential, basis, actuators) at the symbol ``q``.

        A ValueError if the data gives no basis (a sampled one needs numeric parameters).
        """
        n = len(self.coordinates)
        if self.basis is None:
            raise ValueError('Lagrangian data with symbolic parameters must give a basis of D')
        metric = as_sx(self.metric(q), (n, n), 'metric')
        constraints = (as_sx(self.constraints(q), None, 'constraints') if self.constraints
                       else ca.SX(0, n))
        potential = as_sx(self.potential(q), (1, 1), 'potential') if self.potential else ca.SX(0)
        actuators = as_sx(self.actuators(q), None, 'actuators') if self.actuators else None
        return metric, constraints, potential, as_sx(self.basis(q), None, 'basis'), actuators


def as_sx(value: Any, shape: tuple[int, int] | None, what: str) -> ca.SX:
    if isinstance(value, (list, tuple)):  # rows of expressions, as users write them
        try:
            value = ca.vertcat(*[ca.horzcat(*row) if isinstance(row, (list, tuple)) else row
                                 for row in value])
        except Exception as exc:  # noqa: BLE001 - CasADi's own message names no argument
            raise ValueError(f'{what}(q) must be a CasADi SX matrix (or a list of rows of '
                             f'expressions), got {type(value).__name__}: {exc}') from None
    try:
        sx = value if isinstance(value, ca.SX) else ca.SX(value)
    except Exception:  # noqa: BLE001
        raise ValueError(f'{what}(q) must be a CasADi SX matrix, got '
                         f'{type(value).__name__}') from None
    if shape is not None and sx.shape != shape:
        raise ValueError(f'{what}(q) must have shape {shape}, got {sx.shape}')
    return sx


def check_name(name: object) -> str:
    """Refuse names CasADi cannot take as a function name (they fail deep inside it)."""
    if not isinstance(name, str) or not NAME.fullmatch(name) or '__' in name:
        raise ValueError(f'system name must be letters, digits and single underscores, '
                         f'starting with a letter; got {name!r}')
    return name


def pose_axes(name: str, coordinates: tuple[str, ...],
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
