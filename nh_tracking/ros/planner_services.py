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

"""The planner's services, answered on a thread of their own.

A service that solves (``plan``) or waits for a solve (``replan``) must not hold the executor
that publishes ``cmd_vel``. rclpy cannot hand one node's callback group to a second executor,
and its MultiThreadedExecutor starves timers (ros2/rclpy#1223), so — like Nav2's controller
server, which spins a dedicated callback-group executor on its own thread — the services live
on a companion node (``<planner>_services``, same namespace, so the service names are the
planner's) spun by a single-threaded executor of its own.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
import numpy as np
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from nh_tracking.ros import conversions as cv
from nh_tracking.ros.companion import CompanionNode

if TYPE_CHECKING:
    from nh_tracking.ros.planner_node import PlannerNode

SERVICE_QUEUE = 100  # requests: a burst is queued, not dropped (the default keeps 10)


class PlannerServices:
    """``plan`` (nav_msgs/GetPlan) and ``replan`` (std_srvs/Trigger) for one planner."""

    def __init__(self, planner: PlannerNode) -> None:
        self.planner = planner
        self.companion = CompanionNode(planner, 'services', start_parameter_services=False)
        requests = QoSProfile(depth=SERVICE_QUEUE, reliability=ReliabilityPolicy.RELIABLE)
        self.companion.node.create_service(GetPlan, 'plan', self.on_plan, qos_profile=requests)
        self.companion.node.create_service(Trigger, 'replan', self.on_replan,
                                           qos_profile=requests)
        self.companion.start()

    def close(self) -> None:
        self.companion.close()

    def on_plan(self, request: GetPlan.Request, response: GetPlan.Response
                ) -> GetPlan.Response:
        """Answer with a plan from ``start`` (at rest).

        Or from the latest odometry when start's frame is empty, tracking the active reference; an
        empty path when there is none to give.
        """
        node = self.planner
        response.plan = Path()
        response.plan.header.frame_id = node.frame
        try:
            pose = None
            if request.start.header.frame_id:
                cv.check_frame(request.start.header.frame_id, node.frame, 'plan start')
                pose = cv.pose_array(request.start.pose, 'plan start')
            session = node.session
            if session is None:
                node.get_logger().warn('plan request: the planner is not configured')
                return response
            solution, reason = session.preview(pose)
        except cv.InputRejected as exc:
            node.reject('plan request', str(exc))
            return response
        except Exception as exc:  # noqa: BLE001 - a service must always answer
            node.fail('plan service', exc)
            return response
        if solution is None:
            node.get_logger().warn(f'plan request: {reason}')
            return response
        stamps = [session.ns(t) for t in solution.t]
        response.plan = cv.path_msg(node.frame, stamps,
                                    np.array([session.pose_map.pose(q) for q in solution.q]))
        return response

    def on_replan(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        """Replan now; ``message`` says what happened (optimal / shifted / fallback / why not)."""
        session = self.planner.session
        try:
            result = session.replan() if session is not None else None
        except Exception as exc:  # noqa: BLE001 - a service must always answer
            self.planner.fail('replan service', exc)
            response.success, response.message = False, f'replanning failed: {exc}'
            return response
        if result is None:
            response.success, response.message = False, 'the planner is not configured'
        else:
            response.success, response.message = result.outcome is not None, result.reason
        return response
