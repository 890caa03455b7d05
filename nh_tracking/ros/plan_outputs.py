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

"""What the planner node publishes of its plans: control sequences, the display, ``cmd_vel``."""
from __future__ import annotations

from collections.abc import Callable

from geometry_msgs.msg import TwistStamped
import numpy as np
from rclpy.publisher import Publisher

from nh_tracking.ros import cdr, messages as msgs
from nh_tracking.ros.guarded import guarded, GuardedNode
from nh_tracking.ros.markers import obstacle_markers, plan_markers
from nh_tracking.ros.twin_watch import TwinWatch
from nh_tracking.session.tracking_session import PlanResult, TrackingSession


class PlanOutputs(GuardedNode):
    """The planner node's publishers of plans; it creates them on configure."""

    frame: str
    session: TrackingSession | None
    pub_controls: Publisher
    pub_path: Publisher
    pub_markers: Publisher
    pub_cmd: Publisher
    _displayed: object  # the outcome last shown on planned_path
    now_ns: Callable[[], int]
    twins: TwinWatch  # a node of the same name: commands only if this one keeps the robot

    @property
    def live(self) -> TrackingSession:
        """Return the session; callbacks run only while the node is configured."""
        if self.session is None:
            raise RuntimeError('the planner is not configured')
        return self.session

    @guarded('publishing the plan')
    def _publish_plan(self, result: PlanResult) -> None:
        """Publish a new plan's control sequence, on the solver thread (as bytes: :mod:`cdr`)."""
        if result.outcome is not None and not self.twins.yields:
            plan, session = result.outcome.plan, self.live
            fields = (self.frame, session.ns(plan.t[0]), plan.t[:-1] - plan.t[0],
                      session.system.control_names, plan.u)
            self.pub_controls.publish(cdr.control_sequence(*fields) if cdr.agrees_with_rmw()
                                      else msgs.control_sequence_msg(*fields))

    @guarded('publishing the plan display')
    def publish_display(self) -> None:
        """Publish the newest plan (path; markers if listened to) at display_rate."""
        session = self.live
        outcome = session.outcome
        if outcome is None or outcome is self._displayed:
            return
        self._displayed = outcome
        plan, pose = outcome.plan, session.pose_map.pose
        stamps = [session.ns(t) for t in plan.t]
        poses = np.array([pose(q) for q in plan.q])
        self.pub_path.publish(msgs.path_msg(self.frame, stamps, poses))
        if self.pub_markers.get_subscription_count() > 0:
            reference = np.array([pose(q) for q in outcome.reference])
            markers = plan_markers(self.frame, stamps[0], poses[:, :3], reference[:, :3])
            markers.markers += obstacle_markers(self.frame, stamps[0],
                                                session.obstacles_at(plan.t[0]))
            self.pub_markers.publish(markers)

    @guarded('cmd_vel')
    def publish_cmd_vel(self) -> None:
        """Publish the plan's velocity now, as a body twist (slowing to rest without a plan)."""
        twist = self.live.command(self.now_ns())
        if twist is not None and not self.twins.yields:
            self._publish_twist(twist)

    def _publish_stop(self) -> None:
        """Publish a zero ``cmd_vel`` and record it: a later halt ramps from rest."""
        if self.session is not None:
            self.session.commands.stopped(self.session.seconds(self.now_ns()))
        self._publish_twist(np.zeros(4))

    def _publish_twist(self, twist: np.ndarray) -> None:
        if self.pub_cmd.msg_type is TwistStamped:
            self.pub_cmd.publish(msgs.twist_stamped_msg(self.frame, self.now_ns(), twist))
        else:
            self.pub_cmd.publish(msgs.twist_msg(twist))

    def on_clock_stopped(self) -> None:
        if self.live.active:
            self._publish_stop()
