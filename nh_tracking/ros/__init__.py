"""The ROS 2 layer: message conversions and the planner and simulator nodes.

The only part of nh_tracking that imports rclpy; it holds no numerics beyond unit conversion.
"""
import sys

from nh_tracking.ros import planner_node, simulator_node
from nh_tracking.ros.parameters import usage
from nh_tracking.ros.planner_node import PlannerNode
from nh_tracking.ros.runner import run
from nh_tracking.ros.simulator_node import SimulatorNode

__all__ = ["PlannerNode", "SimulatorNode", "planner_main", "sim_main"]


def planner_main(args=None) -> None:
    """``planner`` executable."""
    sys.exit(run(PlannerNode, lambda: usage("planner", "nh_tracking_planner",
                                            planner_node.PARAMETERS), args))


def sim_main(args=None) -> None:
    """``sim`` executable."""
    sys.exit(run(SimulatorNode, lambda: usage("sim", "nh_tracking_sim",
                                              simulator_node.PARAMETERS), args))
