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

"""The geometric core: a nonholonomic system (G, V, D) in an adapted basis, and its motion.

The derived geometry and dynamics (``NonholonomicSystem``), their regularity checks, integration
(``simulate``), timed trajectories, poses and joints as a configuration shows in the world, and
settings declared once. Imports nothing else from nh_tracking.
"""
