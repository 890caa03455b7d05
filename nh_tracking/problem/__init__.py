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

"""The optimal tracking problem as data: cost, limits, obstacles, and what a solve returns.

``TrackingProblem`` and ``Solution`` (paper §3), actuator and velocity bounds, obstacle discs and
their tracks, detour guesses round discs a reference runs through, and the typed record of what a
solve tried. Builds on the core and the models; no solver.
"""
