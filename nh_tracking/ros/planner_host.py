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

"""What the planner node's companions (services, FollowPath, path input) use of the node.

Typed as a protocol so they need not import the node module, which imports them.
"""
from __future__ import annotations

from typing import Any, Protocol

from nh_tracking.ros.companion import Owner
from nh_tracking.ros.guarded import ProblemLog
from nh_tracking.ros.twin_watch import TwinWatch
from nh_tracking.session.tracking_session import TrackingSession


class PlannerHost(Owner, Protocol):
    """The planner node as its companions see it."""

    frame: str  # the fixed frame plans and references are in
    session: TrackingSession | None  # None while unconfigured
    twins: TwinWatch  # whether a node of the same name keeps the robot instead
    problems: ProblemLog  # refused inputs and failures: logged once, counted, reported

    @property
    def live(self) -> TrackingSession:
        """Return the session (RuntimeError while unconfigured)."""

    def now_ns(self) -> int:
        """Return the node's clock now [ns]."""

    def get_logger(self) -> Any:
        """Return the node's logger."""

    def resolve_topic_name(self, topic: str, *, only_expand: bool = False) -> str:
        """Return a topic name resolved in the node's namespace."""
