"""Parameter declarations with descriptors (ranges, descriptions), shared by both nodes."""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from nh_tracking import models

MODEL_PARAMETER_RANGE = (1e-6, 1e6)
MODEL_PARAMETER_HELP = {
    "m": "mass [kg]", "J": "moment of inertia about the centre of mass [kg m^2]",
    "a": "distance from the blade's contact point to the centre of mass [m]",
    "R": "wheel radius [m]", "I_spin": "inertia about the wheel axle [kg m^2]",
    "I_turn": "inertia about the vertical axis [kg m^2]",
}


def declare(node: Node, name: str, default, description: str,
            bounds: tuple[float, float] | None = None, read_only: bool = False):
    """Declare a parameter with a descriptor; numeric ``bounds`` become an enforced range."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if bounds is not None and isinstance(default, bool):
        raise TypeError("booleans take no range")
    if bounds is not None and isinstance(default, int):
        descriptor.integer_range = [IntegerRange(from_value=int(bounds[0]),
                                                 to_value=int(bounds[1]), step=1)]
    elif bounds is not None:
        descriptor.floating_point_range = [FloatingPointRange(
            from_value=float(bounds[0]), to_value=float(bounds[1]), step=0.0)]
    return node.declare_parameter(name, default, descriptor).value


def declare_model(node: Node, default_model: str = "chaplygin_sleigh") -> tuple[str, dict]:
    """Declare ``model`` (read-only: a node drives one kind of robot) and its physical
    parameters by name, with the model's defaults; returns (model, parameters)."""
    model = declare(node, "model", default_model,
                    f"built-in model: one of {sorted(models.MODELS)}", read_only=True)
    try:
        defaults = models.model_parameters(model)
    except ValueError as exc:
        raise ValueError(f"parameter model: {exc}") from None
    params = {}
    for name, default in defaults.items():
        lo = -1e6 if name == "a" else MODEL_PARAMETER_RANGE[0]
        params[name] = declare(node, name, float(default), MODEL_PARAMETER_HELP.get(name, name),
                               (lo, MODEL_PARAMETER_RANGE[1]))
    return model, params
