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

"""The ROS 2 layer: message conversions and the planner and simulator nodes.

The only part of nh_tracking that imports rclpy; it holds no numerics beyond unit conversion.
"""
import functools
import sys

from nh_tracking.ros import planner_node, simulator_node
from nh_tracking.ros.parameters import usage
from nh_tracking.ros.planner_node import PlannerNode
from nh_tracking.ros.runner import run, settle_heap
from nh_tracking.ros.simulator_node import SimulatorNode

__all__ = ['PlannerNode', 'SimulatorNode', 'planner_main', 'sim_main']


def planner_main(args=None) -> None:
    """``planner`` executable: the process's heap is frozen as the planner starts commanding."""
    make = functools.partial(PlannerNode, on_commanding=settle_heap,
                             on_released=functools.partial(settle_heap, release=True))
    sys.exit(run(make, lambda argv: usage('planner', 'nh_tracking_planner',
                                          planner_node.PARAMETERS, argv), args))


def sim_main(args=None) -> None:
    """``sim`` executable."""
    sys.exit(run(SimulatorNode, lambda argv: usage(
        'sim', 'nh_tracking_sim', simulator_node.PARAMETERS,
        argv, state_layout=True), args))
