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

from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Path
import numpy as np
from rclpy.lifecycle import LifecycleNode
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from nh_tracking.ros import cdr, messages as msgs
from nh_tracking.ros.guarded import guarded, ProblemLog
from nh_tracking.ros.markers import obstacle_markers, plan_markers
from nh_tracking.ros.planner_interface import LATCHED
from nh_tracking.ros.twin_watch import TwinWatch
from nh_tracking.session.tracking_session import PlanResult, TrackingSession


class PlanOutputs:
    """The lifecycle publishers of one configured session's plans, until :meth:`close`.

    ``planned_path``, ``control_sequence`` and ``planned_markers`` latched, ``cmd_vel``
    (TwistStamped if ``stamped``); they publish only while the node is active. Neither
    ``cmd_vel`` nor ``control_sequence`` is published while a twin keeps the robot.
    """

    def __init__(self, node: LifecycleNode, session: TrackingSession, problems: ProblemLog,
                 twins: TwinWatch, frame: str, stamped: bool) -> None:
        self.node, self.session, self.problems = node, session, problems
        self.twins, self.frame = twins, frame
        self.pub_path = node.create_lifecycle_publisher(Path, 'planned_path', LATCHED)
        self.pub_controls = node.create_lifecycle_publisher(JointTrajectory, 'control_sequence',
                                                            LATCHED)
        self.pub_cmd = node.create_lifecycle_publisher(TwistStamped if stamped else Twist,
                                                       'cmd_vel', 10)
        self.pub_markers = node.create_lifecycle_publisher(MarkerArray, 'planned_markers',
                                                           LATCHED)
        self._displayed: object = None  # the outcome last shown on planned_path

    def close(self) -> None:
        """Destroy the publishers."""
        for publisher in (self.pub_path, self.pub_controls, self.pub_cmd, self.pub_markers):
            self.node.destroy_lifecycle_publisher(publisher)

    def _now_ns(self) -> int:
        return self.node.get_clock().now().nanoseconds

    @guarded('publishing the plan')
    def publish_plan(self, result: PlanResult) -> None:
        """Publish a new plan's control sequence, on the solver thread (as bytes: :mod:`cdr`)."""
        if result.outcome is not None and not self.twins.yields:
            plan, session = result.outcome.plan, self.session
            fields = (self.frame, session.ns(plan.t[0]), plan.t[:-1] - plan.t[0],
                      session.system.control_names, plan.u)
            self.pub_controls.publish(cdr.control_sequence(*fields) if cdr.agrees_with_rmw()
                                      else msgs.control_sequence_msg(*fields))

    @guarded('publishing the plan display')
    def publish_display(self) -> None:
        """Publish the newest plan (path; markers if listened to) at display_rate."""
        session = self.session
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
        twist = self.session.command(self._now_ns())
        if twist is not None and not self.twins.yields:
            self._publish_twist(twist)

    def publish_stop(self) -> None:
        """Publish a zero ``cmd_vel`` and record it: a later halt ramps from rest."""
        self.session.commands.stopped(self.session.seconds(self._now_ns()))
        self._publish_twist(np.zeros(4))

    def _publish_twist(self, twist: np.ndarray) -> None:
        if self.pub_cmd.msg_type is TwistStamped:
            self.pub_cmd.publish(msgs.twist_stamped_msg(self.frame, self._now_ns(), twist))
        else:
            self.pub_cmd.publish(msgs.twist_msg(twist))
