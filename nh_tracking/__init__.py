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

"""nh_tracking: optimal trajectory tracking for nonholonomic mechanical systems.

Layers, one package each and usable without the ones above it: ``core`` (``NonholonomicSystem``,
``simulate``, trajectories), ``models``, ``problem`` and ``estimation``, ``solvers`` (the tracking
methods), ``planning`` and ``navigation`` (receding horizon, routes, goals), ``session`` (the
planner without ROS), ``ros`` (the nodes, the only part that imports rclpy) and ``examples``
(demo, benchmark, experiments).
"""
from importlib.metadata import PackageNotFoundError, version

from nh_tracking import models
from nh_tracking.core.simulate import simulate
from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.estimation.output_error import estimate_parameters, ParameterEstimate
from nh_tracking.problem.tracking_problem import Solution, TrackingProblem
from nh_tracking.solvers import solve

__all__ = ['NonholonomicSystem', 'ParameterEstimate', 'Solution', 'TrackingProblem',
           'Trajectory', 'estimate_parameters', 'models', 'simulate', 'solve']
try:
    __version__ = version('nh_tracking')  # one source: package.xml, read by setup.py
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = 'unknown'
