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

"""What the package knows about a model beyond its equations: its physical parameters.

Their ranges, units and meanings, so every front end — ROS parameters, the command line,
documentation — reads them from one place instead of knowing each robot.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import functools
import inspect
import math

import casadi as ca

from nh_tracking.core.lagrangian_data import LagrangianData
from nh_tracking.core.system import NonholonomicSystem

POSITIVE = (1e-6, 1e6)
Scalar = float | ca.SX  # a physical parameter: a number to build with, a symbol to estimate


def positive(**values: float) -> None:
    """Factories check their own arguments too: they can be called without a spec."""
    for name, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f'model parameter {name} must be a finite number > 0, got {value!r}')


@dataclass(frozen=True)
class PhysicalParameter:
    """One physical parameter of a model."""

    name: str
    default: float
    unit: str
    description: str
    bounds: tuple[float, float] = POSITIVE

    def check(self, value: object) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                math.isfinite(value) and self.bounds[0] <= value <= self.bounds[1]):
            raise ValueError(f'model parameter {self.name} must be a number in '
                             f'[{self.bounds[0]:g}, {self.bounds[1]:g}], got {value!r}')
        return float(value)


@dataclass(frozen=True)
class ModelSpec:
    """A model: its factory (keyword arguments = the physical parameters) and their specs.

    ``start`` is a typical initial state (q, v) for demonstrations. ``lagrangian`` (keyword
    arguments = the physical parameters, numbers or CasADi symbols) gives the model's data with
    its parameters left symbolic, which estimating them needs; without it they are fixed.
    """

    name: str
    factory: Callable[..., NonholonomicSystem]
    parameters: tuple[PhysicalParameter, ...] = ()
    summary: str = ''
    start: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    lagrangian: Callable[..., LagrangianData] | None = None

    def __post_init__(self) -> None:
        arguments = inspect.signature(self.factory).parameters
        required = {n for n, a in arguments.items() if a.default is inspect.Parameter.empty}
        declared = {p.name for p in self.parameters}
        if not required <= declared <= set(arguments):
            raise ValueError(f'model {self.name}: parameters {sorted(declared)} do not match '
                             f"the factory's arguments {sorted(arguments)}")

    @property
    def defaults(self) -> dict[str, float]:
        return {p.name: p.default for p in self.parameters}

    def check(self, **values: object) -> dict[str, float]:
        """``values`` checked against the ranges, completed with defaults; no model is built."""
        known = {p.name: p for p in self.parameters}
        unknown = set(values) - set(known)
        if unknown:
            raise ValueError(f'model {self.name} takes {sorted(known)}, not {sorted(unknown)}')
        return {**self.defaults, **{k: known[k].check(v) for k, v in values.items()}}

    def create(self, **values: object) -> NonholonomicSystem:
        """Build the model, its parameters checked; any failure is a ValueError naming it."""
        checked = self.check(**values)
        try:
            system = self.factory(**checked)
        except ValueError:
            raise
        except Exception as exc:  # noqa: BLE001 - a user's factory may fail in any way
            raise ValueError(f'model {self.name}: its factory raised '
                             f'{type(exc).__name__}: {exc}') from None
        if not isinstance(system, NonholonomicSystem):
            raise ValueError(f'model {self.name}: its factory returned '
                             f'{type(system).__name__}, not a NonholonomicSystem')
        return system

    def create_parametrised(self, **values: object) -> NonholonomicSystem:
        """Build the model with its physical parameters symbolic in its dynamics.

        Its :meth:`~NonholonomicSystem.with_values` changes them without a rebuild (the NLPs
        take them as parameters). The plain model when the spec has no symbolic Lagrangian data,
        its data no basis of D, or data that is not the factory's model.
        """
        system = self.create(**values)
        if self.lagrangian is None:
            return system
        try:
            return system.parametrised(self.lagrangian, [p.name for p in self.parameters])
        except Exception:  # noqa: BLE001 - no basis given (a sampled one needs numbers), another
            return system  # model, or data a user wrote for numbers only (if m > 0: ...)

    def parametrised(self, names: Sequence[str], **values: object) -> NonholonomicSystem:
        """Build the model with the physical parameters ``names`` symbolic in its dynamics.

        The others are at ``values`` or their defaults; ``names`` start at theirs. Its
        ``family`` (:class:`~nh_tracking.core.family.DynamicsFamily`) takes ``names``' values
        as its input ``p``; the family is derived once per spec, names and other values.
        A ValueError names what is missing: symbolic Lagrangian data, a basis of D, or
        parameters the model does not have.
        """
        names = tuple(names)
        known = [p.name for p in self.parameters]
        if not names or len(set(names)) != len(names) or not set(names) <= set(known):
            raise ValueError(f'model {self.name}: parameters to leave symbolic must be distinct '
                             f'names among {known}, got {list(names)}')
        if self.lagrangian is None:
            raise ValueError(f'model {self.name} gives no Lagrangian data with symbolic '
                             'parameters (ModelSpec.lagrangian); its parameters can only be fixed')
        checked = self.check(**values)
        family = _family(self, names, tuple((k, x) for k, x in checked.items() if k not in names))
        return family.with_values(**{name: checked[name] for name in names})

    @classmethod
    def from_factory(cls, name: str, factory: Callable[..., NonholonomicSystem]) -> ModelSpec:
        """Return a spec for a plain factory function: its keyword defaults are the parameters.

        Each a positive number (write a ModelSpec to say more).
        """
        parameters = []
        for p in inspect.signature(factory).parameters.values():
            if isinstance(p.default, bool) or not isinstance(p.default, (int, float)):
                raise ValueError(f'model {name}: argument {p.name} needs a numeric default '
                                 'to be a physical parameter')
            parameters.append(PhysicalParameter(p.name, float(p.default), '', p.name))
        return cls(name, factory, tuple(parameters), (factory.__doc__ or '').strip())


@functools.lru_cache(maxsize=8)
def _family(spec: ModelSpec, names: tuple[str, ...],
            fixed: tuple[tuple[str, float], ...]) -> NonholonomicSystem:
    """Return the model with ``names`` symbolic (at their defaults), the others ``fixed``."""
    try:
        system = spec.create(**dict(fixed))
        return system.parametrised(spec.lagrangian, names)  # type: ignore[arg-type]
    except ValueError as exc:
        raise ValueError(f'model {spec.name}: {exc}') from None
