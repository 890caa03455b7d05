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

"""Parameters as data: one table per node gives the declarations and their descriptors.

The same table gives the ranges, descriptions, start-up checks, ``--help`` and the installed
parameter file.

Start-up values are checked before they are declared, so a bad ``-p`` or params file ends the
process with one line naming the parameter instead of a traceback; an integer given for a
floating-point parameter (``horizon:=3``) is that number, as every ROS user expects.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any
import weakref

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter
import yaml

from nh_tracking import models
from nh_tracking.core.settings import check, described, markdown_table, Setting
from nh_tracking.ros.rclpy_private import parameter_overrides


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: default (its type is the parameter's type), meaning and limits."""

    name: str
    default: object
    meta: Setting
    read_only: bool = False

    @classmethod
    def of(cls, settings: type, read_only: bool = False) -> tuple[ParameterSpec, ...]:
        """Return the parameters of a settings dataclass, one per described field."""
        return tuple(cls(name, default, meta, read_only)
                     for name, default, meta in described(settings))

    @property
    def description(self) -> str:
        meta = self.meta
        return meta.description + (f' [{meta.unit}]' if meta.unit else '')

    def descriptor(self) -> ParameterDescriptor:
        choices = self.meta.choices
        text = self.description + (f" (one of {', '.join(choices)})" if choices else '')
        descriptor = ParameterDescriptor(description=text, read_only=self.read_only)
        bounds = self.meta.bounds
        if bounds is not None and isinstance(self.default, int) \
                and not isinstance(self.default, bool):
            descriptor.integer_range = [IntegerRange(from_value=int(bounds[0]),
                                                     to_value=int(bounds[1]), step=1)]
        elif bounds is not None:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(bounds[0]), to_value=float(bounds[1]), step=0.0)]
        return descriptor

    def check(self, value: object) -> object:
        """``value`` as this parameter's type, or ValueError naming the parameter."""
        if isinstance(self.default, (list, tuple)) and isinstance(value, (list, tuple)):
            value = [float(v) if isinstance(v, int) and not isinstance(v, bool) else v
                     for v in value]
        return check(value, f'parameter {self.name}', self.default, self.meta)


def plain(name: str, default: object, description: str, unit: str = '',
          bounds: tuple[float, float] | None = None, read_only: bool = False,
          choices: tuple[str, ...] = ()) -> ParameterSpec:
    """Return a parameter of the ROS layer alone (frames, message types, start-up)."""
    return ParameterSpec(name, default, Setting(description, unit, bounds, choices), read_only)


ARRAYS: dict[type, Parameter.Type] = {tuple: Parameter.Type.DOUBLE_ARRAY,
                                      list: Parameter.Type.STRING_ARRAY}
_FLOATS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # node -> float names


def declare(node: Node, spec: ParameterSpec) -> Any:
    """Declare ``spec`` on ``node``, checking (and coercing) a start-up override first.

    At run time too, an integer set on a floating-point parameter (``ros2 param set ... horizon
    3``) is taken as that number instead of refused.
    """
    overrides = parameter_overrides(node)
    if spec.name in overrides:
        value = spec.check(overrides[spec.name].value)
        if type(spec.default) in ARRAYS and not value:
            del overrides[spec.name]  # rclpy re-infers [] as a byte array: declare it empty
        else:
            overrides[spec.name] = Parameter(spec.name, value=list(value) if isinstance(
                value, tuple) else value)
    if isinstance(spec.default, float):
        if node not in _FLOATS:  # one callback per node: rclpy concatenates their results
            names = _FLOATS[node] = set()
            node.add_pre_set_parameters_callback(
                lambda params: [Parameter(p.name, value=float(p.value))
                                if p.name in names and p.type_ == Parameter.Type.INTEGER
                                else p for p in params])
        _FLOATS[node].add(spec.name)
    array = ARRAYS.get(type(spec.default))
    if array is not None:  # possibly empty: typed explicitly
        value = node.declare_parameter(spec.name, array, spec.descriptor()).value
        if value is None:
            default: list = list(spec.default)  # type: ignore[call-overload]
            node.set_parameters([Parameter(spec.name, array, default)])
            value = default
        return list(value)
    return node.declare_parameter(spec.name, spec.default, spec.descriptor()).value


def declare_all(node: Node, specs: tuple[ParameterSpec, ...]) -> dict[str, Any]:
    return {spec.name: declare(node, spec) for spec in specs}


def model_specs(model: str) -> tuple[ParameterSpec, ...]:
    """Return the physical parameters of ``model``, as its spec describes them."""
    try:
        physical = models.spec(model).parameters
    except ValueError as exc:
        raise ValueError(f'parameter model: {exc}') from None
    return tuple(plain(p.name, p.default, p.description, p.unit, p.bounds) for p in physical)


MODEL = plain('model', 'chaplygin_sleigh', "the robot's model: a built-in one "
              f"({', '.join(models.MODELS)}), an entry point of group {models.ENTRY_POINTS}, "
              'or package.module:attribute', read_only=True)


def declare_model(node: Node) -> tuple[str, dict[str, float]]:
    """Declare ``model`` and its physical parameters; returns (model, parameters)."""
    model = declare(node, MODEL)
    values = declare_all(node, model_specs(model))
    return str(model), {k: float(v) for k, v in values.items()}


def model_asked_for(args: Sequence[str], node_name: str) -> str:
    """Return the model a command line gives: ``-p model:=NAME``, else a params file's.

    As rcl ranks them: a ``-p`` over any file, a later file over an earlier one.
    """
    given, from_file = None, None
    for flag, value in zip(args, list(args)[1:]):
        name, _, model = value.partition(':=')
        if flag in ('-p', '--param') and name in ('model', f'{node_name}:model'):
            given = model
        elif flag == '--params-file':
            from_file = _model_in_file(value, node_name) or from_file
    return given or from_file or str(MODEL.default)


def _model_in_file(path: str, node_name: str) -> str | None:
    """``model`` of ``node_name`` (or of a wildcard entry) in a ROS parameter file."""
    try:
        with open(path) as stream:
            content = yaml.safe_load(stream)
    except (OSError, yaml.YAMLError):
        return None  # the node itself says what is wrong with the file

    def search(entry: object, name: str) -> str | None:
        if not isinstance(entry, dict):
            return None
        ours = name.rsplit('/', 1)[-1] in (node_name, '*', '**')
        params = entry.get('ros__parameters')
        if ours and isinstance(params, dict) and 'model' in params:
            return str(params['model'])
        return next((found for key, value in entry.items()
                     if (found := search(value, str(key))) is not None), None)
    return search(content, '')


def usage(executable: str, node_name: str, specs: tuple[ParameterSpec, ...],
          args: Sequence[str] = (), state_layout: bool = False) -> str:
    """``--help`` text: how to start the node, every parameter it takes, and the model's.

    The model is the one ``args`` asks for (``-p model:=...`` or a params file); with
    ``state_layout``, the order of q and v in ``initial_state`` too.
    """
    lines = [f'usage: {executable} [--ros-args -p NAME:=VALUE ... --params-file FILE '
             f'-r __ns:=/NAMESPACE]', '',
             f'Starts the ROS 2 node {node_name}. Parameters (default, range):']
    lines += [_line(spec) for spec in (MODEL, *specs)]
    model = model_asked_for(args, node_name)
    try:
        physical = model_specs(model)
        system = models.create(model) if state_layout else None
    except ValueError as exc:
        return '\n'.join(lines + ['', f'The physical parameters depend on the model: {exc}'])
    lines += ['', f'Physical parameters of {model} (give -p model:=NAME for another model):']
    lines += [_line(spec) for spec in physical]
    if system is not None:
        lines += ['', f'The state of {model}:', _line(plain(
            'initial_state', [0.0] * (system.n + system.k), f'q then v, {system.n} + {system.k}'
            f" numbers: {', '.join(system.coordinates + system.velocity_names)}"))]
    return '\n'.join(lines)


def _line(spec: ParameterSpec) -> str:
    bounds, choices = spec.meta.bounds, spec.meta.choices
    limits = f', [{bounds[0]:g}, {bounds[1]:g}]' if bounds else ''
    fixed = ', read-only' if spec.read_only else ''
    one_of = f" — one of {', '.join(choices)}" if choices else ''
    return f'  {spec.name} ({spec.default!r}{limits}{fixed}): {spec.description}{one_of}'


def parameter_table(specs: tuple[ParameterSpec, ...]) -> str:
    """Return docs/ros.md's table of a node's parameters (``model`` first), from the same specs."""
    rows = [(s.name, s.default, s.meta if not s.read_only else Setting(
        s.meta.description + ' (read-only)', s.meta.unit, s.meta.bounds, s.meta.choices))
        for s in (MODEL, *specs)]
    return markdown_table(rows)
