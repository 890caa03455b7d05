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

"""Models: built-in ones by name, and user models with no edit to the package.

Each built-in model is one module holding its Lagrangian data (metric, constraints, basis —
the dynamics are derived) and a :class:`ModelSpec`; adding one is a new module and one line in
:data:`MODELS`. A user model is named ``package.module:attribute`` (a ModelSpec, or a factory
function whose numeric keyword defaults are its physical parameters) or registered by an entry
point in the group ``nh_tracking.models``.
"""
from __future__ import annotations

from collections.abc import Mapping
import importlib
from importlib.metadata import entry_points

from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.models import chaplygin_sleigh as _sleigh
from nh_tracking.models import nonholonomic_particle as _particle
from nh_tracking.models import rolling_disk as _disk
from nh_tracking.models import snakeboard as _snakeboard
from nh_tracking.models import unicycle as _unicycle
from nh_tracking.models.chaplygin_sleigh import chaplygin_sleigh
from nh_tracking.models.nonholonomic_particle import nonholonomic_particle
from nh_tracking.models.rolling_disk import rolling_disk
from nh_tracking.models.snakeboard import snakeboard
from nh_tracking.models.spec import ModelSpec, PhysicalParameter
from nh_tracking.models.unicycle import unicycle

__all__ = ['MODELS', 'ModelSpec', 'PhysicalParameter', 'chaplygin_sleigh', 'create',
           'create_parametrised', 'model_parameters', 'nonholonomic_particle', 'rolling_disk',
           'snakeboard', 'spec', 'unicycle', 'with_parameters']

MODELS: dict[str, ModelSpec] = {m.SPEC.name: m.SPEC for m in (_sleigh, _particle, _unicycle,
                                                              _disk, _snakeboard)}
ENTRY_POINTS = 'nh_tracking.models'


def spec(name: str) -> ModelSpec:
    """Return the model called ``name``: built-in, an entry point or ``package.module:attr``."""
    if name in MODELS:
        return MODELS[name]
    plugins = {ep.name: ep for ep in entry_points(group=ENTRY_POINTS)}
    if name in plugins:
        return _as_spec(name, plugins[name].load())
    if ':' in name:
        module, _, attribute = name.partition(':')
        try:
            target = getattr(importlib.import_module(module), attribute)
        except Exception as exc:  # noqa: BLE001 - a user's module may fail in any way
            raise ValueError(f'cannot load model {name!r}: {type(exc).__name__}: {exc}') from None
        return _as_spec(name, target)
    raise ValueError(f'unknown model {name!r}; built-in: {sorted(MODELS)}, from entry points: '
                     f'{sorted(plugins)}, or give package.module:attribute')


def _as_spec(name: str, target: object) -> ModelSpec:
    if isinstance(target, ModelSpec):
        return target
    if callable(target):
        return ModelSpec.from_factory(name, target)
    raise ValueError(f'model {name!r} is neither a ModelSpec nor a factory function')


def model_parameters(name: str) -> dict[str, float]:
    """Return the physical parameters a model takes, with their defaults."""
    return spec(name).defaults


def create(name: str, **parameters: float) -> NonholonomicSystem:
    """Return a model by name (as the ROS parameter ``model`` names it), its parameters checked."""
    return spec(name).create(**parameters)


def create_parametrised(name: str, **parameters: float) -> NonholonomicSystem:
    """As :func:`create`, with the physical parameters symbolic: see ``with_values``."""
    return spec(name).create_parametrised(**parameters)


def with_parameters(system: NonholonomicSystem, name: str,
                    parameters: Mapping[str, float]) -> NonholonomicSystem:
    """Return model ``name`` (now ``system``) with ``parameters``, rebuilt only if need be.

    ``system`` itself if nothing changes; new values in its family (the same NLPs) if every
    change is symbolic in it; else the model built anew, as :func:`create_parametrised`. Values
    out of the model's ranges are a ValueError.
    """
    spec(name).check(**parameters)  # the ranges, as create checks them
    changed = {k: x for k, x in parameters.items() if system.parameters.get(k) != x}
    if not changed:
        return system
    if set(changed) <= set(system.family.names):
        return system.with_values(**changed)
    return create_parametrised(name, **{**system.parameters, **parameters})
