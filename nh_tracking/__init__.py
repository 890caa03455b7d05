"""nh_tracking: optimal trajectory tracking for nonholonomic mechanical systems.

Layers, each usable without the ones above it: the geometric core (``NonholonomicSystem``,
``models``), simulation (``simulate``), and — in later modules — the tracking solvers and the
ROS 2 nodes (``nh_tracking.ros``, the only part that imports rclpy).
"""
from nh_tracking import models
from nh_tracking.problem import Solution, TrackingProblem
from nh_tracking.simulate import simulate
from nh_tracking.solvers import solve
from nh_tracking.system import NonholonomicSystem
from nh_tracking.trajectory import Trajectory

__all__ = ["NonholonomicSystem", "Solution", "TrackingProblem", "Trajectory", "models",
           "simulate", "solve"]
__version__ = "0.1.0"
