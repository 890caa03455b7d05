"""Parameters as data: one table per node gives the declarations, their descriptors (ranges,
descriptions), the start-up checks, ``--help`` and the installed parameter file.

Start-up values are checked before they are declared, so a bad ``-p`` or params file ends the
process with one line naming the parameter instead of a traceback; an integer given for a
floating-point parameter (``horizon:=3``) is that number, as every ROS user expects.
"""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from nh_tracking import models

MODEL_PARAMETER_RANGE = (1e-6, 1e6)
MODEL_PARAMETER_HELP = {
    "m": "mass [kg]", "J": "moment of inertia about the centre of mass [kg m^2]",
    "a": "distance from the blade's contact point to the centre of mass [m]",
    "R": "wheel radius [m]", "I_spin": "inertia about the wheel axle [kg m^2]",
    "I_turn": "inertia about the vertical axis [kg m^2]",
}


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: default (its type is the parameter's type), meaning and limits."""

    name: str
    default: object
    description: str
    bounds: tuple[float, float] | None = None
    read_only: bool = False
    choices: tuple[str, ...] = ()

    def descriptor(self) -> ParameterDescriptor:
        text = self.description + (f" (one of {', '.join(self.choices)})" if self.choices else "")
        descriptor = ParameterDescriptor(description=text, read_only=self.read_only)
        if self.bounds is not None and isinstance(self.default, int) \
                and not isinstance(self.default, bool):
            descriptor.integer_range = [IntegerRange(from_value=int(self.bounds[0]),
                                                     to_value=int(self.bounds[1]), step=1)]
        elif self.bounds is not None:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(self.bounds[0]), to_value=float(self.bounds[1]), step=0.0)]
        return descriptor

    def check(self, value: object) -> object:
        """``value`` as this parameter's type, or ValueError naming the parameter."""
        value = _coerce(self.default, value)
        kind = type(self.default)
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise ValueError(f"parameter {self.name} must be {_type_name(self.default)}, "
                             f"got {value!r}")
        if self.bounds is not None and isinstance(value, (int, float)) and not (
                math.isfinite(value) and self.bounds[0] <= value <= self.bounds[1]):
            raise ValueError(f"parameter {self.name} must be in [{self.bounds[0]:g}, "
                             f"{self.bounds[1]:g}], got {value!r}")
        if self.choices and value not in self.choices:
            raise ValueError(f"parameter {self.name} must be one of {list(self.choices)}, "
                             f"got {value!r}")
        return value


def _coerce(default: object, value: object) -> object:
    """Integers where floats are expected are those floats (also inside arrays)."""
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, list) and isinstance(value, (list, tuple)):
        return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v
                for v in value]
    return value


def _type_name(default: object) -> str:
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string",
            list: "a list of numbers"}[type(default)]


_FLOATS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # node -> float names


def declare(node: Node, spec: ParameterSpec):
    """Declare ``spec`` on ``node``, checking (and coercing) a start-up override first. At run
    time too, an integer set on a floating-point parameter (``ros2 param set ... horizon 3``)
    is taken as that number instead of refused."""
    overrides = node._parameter_overrides  # rclpy keeps -p / params-file values here
    if spec.name in overrides:
        value = spec.check(overrides[spec.name].value)
        overrides[spec.name] = Parameter(spec.name, value=value)
    if isinstance(spec.default, float):
        if node not in _FLOATS:  # one callback per node: rclpy concatenates their results
            names = _FLOATS[node] = set()
            node.add_pre_set_parameters_callback(
                lambda params: [Parameter(p.name, value=float(p.value))
                                if p.name in names and p.type_ == Parameter.Type.INTEGER
                                else p for p in params])
        _FLOATS[node].add(spec.name)
    return node.declare_parameter(spec.name, spec.default, spec.descriptor()).value


def declare_all(node: Node, specs: tuple[ParameterSpec, ...]) -> dict[str, object]:
    return {spec.name: declare(node, spec) for spec in specs}


def model_specs(model: str) -> tuple[ParameterSpec, ...]:
    """The physical parameters of a built-in model, with its defaults."""
    try:
        defaults = models.model_parameters(model)
    except ValueError as exc:
        raise ValueError(f"parameter model: {exc}") from None
    return tuple(ParameterSpec(
        name, float(default), MODEL_PARAMETER_HELP.get(name, name),
        (-MODEL_PARAMETER_RANGE[1] if name == "a" else MODEL_PARAMETER_RANGE[0],
         MODEL_PARAMETER_RANGE[1])) for name, default in defaults.items())


MODEL = ParameterSpec("model", "chaplygin_sleigh", "built-in model (a node drives one kind of "
                      "robot)", read_only=True, choices=tuple(sorted(models.MODELS)))


def declare_model(node: Node) -> tuple[str, dict[str, float]]:
    """Declare ``model`` and its physical parameters; returns (model, parameters)."""
    model = declare(node, MODEL)
    return model, {k: float(v) for k, v in declare_all(node, model_specs(model)).items()}


def usage(executable: str, node_name: str, specs: tuple[ParameterSpec, ...]) -> str:
    """``--help`` text: how to start the node and every parameter it takes."""
    lines = [f"usage: {executable} [--ros-args -p NAME:=VALUE ... --params-file FILE "
             f"-r __ns:=/NAMESPACE]", "",
             f"Starts the ROS 2 node {node_name}. Parameters (default, range):"]
    for spec in (MODEL, *specs):
        limits = f", [{spec.bounds[0]:g}, {spec.bounds[1]:g}]" if spec.bounds else ""
        fixed = ", read-only" if spec.read_only else ""
        choices = f" — one of {', '.join(spec.choices)}" if spec.choices else ""
        lines.append(f"  {spec.name} ({spec.default!r}{limits}{fixed}): {spec.description}"
                     f"{choices}")
    lines.append("  and the model's physical parameters, e.g. for chaplygin_sleigh: " + ", ".join(
        f"{s.name} ({s.default!r}): {s.description}" for s in model_specs("chaplygin_sleigh")))
    return "\n".join(lines)
