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

"""The planner's services, taken at once on a thread of their own and answered by a worker.

A service that solves (``plan``) or waits for a solve (``replan``) must not hold the executor
that publishes ``cmd_vel``, so — like Nav2's controller server, which spins a dedicated executor
on its own thread — the services live on a companion node (``<planner>_services``, same
namespace, so the service names are the planner's). Its executor only takes requests; a worker
thread answers them in turn. A burst beyond :data:`BACKLOG` waiting requests is answered at once
as busy (an empty plan; ``success=false``, "busy"): every request gets a response.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import queue
import threading
from typing import Any

from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
import numpy as np
from rclpy.exceptions import InvalidHandle
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from nh_tracking.ros import conversions as cv
from nh_tracking.ros import messages as msgs
from nh_tracking.ros.companion import CompanionNode
from nh_tracking.ros.planner_host import PlannerHost
from nh_tracking.ros.rclpy_private import ClaimingExecutor

BACKLOG = 64  # requests waiting for the worker (~2 s of solves); more are answered busy at once
SERVICE_QUEUE = 1000  # requests DDS keeps until the executor takes them (a take is quick)


@dataclass
class Answerer:
    """A service callback answered later: ``take`` queues, ``answer`` fills, ``busy`` refuses."""

    answer: Callable[[Any, Any], Any]  # (request, response) -> response
    busy: Callable[[Any], Any]  # (response) -> response
    take: Callable[[_Request], None]


@dataclass
class _Request:
    service: Any  # an rclpy Service whose callback is an Answerer
    answerer: Answerer
    request: Any
    header: Any

    def respond(self, fill: Callable[..., Any], *args: Any) -> None:
        """Send ``fill(*args, response)``; a service destroyed meanwhile answers nobody."""
        response = fill(*args, self.service.srv_type.Response())
        try:
            self.service.send_response(response, self.header)
        except InvalidHandle:  # the planner is closing
            pass


class TakingExecutor(ClaimingExecutor):
    """An executor that hands an :class:`Answerer` service its request with the header.

    rclpy's executor sends a response when the callback returns, and resumes an async callback
    without pause while it waits (a busy loop): neither lets a slow service take a burst.
    """

    def claim(self, service: Any) -> bool:
        answerer: Any = service.callback
        if not isinstance(answerer, Answerer):
            return False
        try:
            with service.handle:
                request, header = service.handle.service_take_request(service.srv_type.Request)
        except InvalidHandle:  # destroyed meanwhile
            return True
        if header is not None:
            answerer.take(_Request(service, answerer, request, header))
        return True


class PlannerServices:
    """``plan`` (nav_msgs/GetPlan) and ``replan`` (std_srvs/Trigger) for one planner."""

    def __init__(self, planner: PlannerHost) -> None:
        self.planner = planner
        self._queue: queue.Queue[_Request | None] = queue.Queue(BACKLOG)
        self._worker = threading.Thread(target=self._work, name='nh_tracking_services',
                                        daemon=True)
        self._worker.start()
        self.companion = CompanionNode(planner, 'services', executor=TakingExecutor,
                                       start_parameter_services=False)
        requests = QoSProfile(depth=SERVICE_QUEUE, reliability=ReliabilityPolicy.RELIABLE)
        node = self.companion.node
        plan: Any = Answerer(self.on_plan, self._busy_plan, self._take)
        replan: Any = Answerer(self.on_replan, self._busy_replan, self._take)
        node.create_service(GetPlan, 'plan', plan, qos_profile=requests)
        node.create_service(Trigger, 'replan', replan, qos_profile=requests)
        self.companion.start()

    def close(self) -> None:
        """Stop taking requests, answer the waiting ones as busy, stop the worker."""
        self.companion.close()
        while True:
            try:
                waiting = self._queue.get_nowait()
            except queue.Empty:
                break
            if waiting is not None:
                waiting.respond(waiting.answerer.busy)
        self._queue.put(None)
        self._worker.join(timeout=10.0)

    def _take(self, request: _Request) -> None:
        try:
            self._queue.put_nowait(request)
        except queue.Full:
            self.planner.problems.reject(f'{request.service.srv_name} request',
                                         f'busy: {BACKLOG} requests are waiting')
            request.respond(request.answerer.busy)

    def _work(self) -> None:
        while (request := self._queue.get()) is not None:
            try:
                request.respond(request.answerer.answer, request.request)
            except Exception as exc:  # noqa: BLE001 - the worker must answer the next one
                self.planner.problems.fail(f'{request.service.srv_name} service', exc)
                request.respond(request.answerer.busy)

    def _busy_plan(self, response: GetPlan.Response) -> GetPlan.Response:
        response.plan = Path()
        response.plan.header.frame_id = self.planner.frame
        return response

    @staticmethod
    def _busy_replan(response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = False, 'busy: too many requests are waiting'
        return response

    def on_plan(self, request: GetPlan.Request, response: GetPlan.Response
                ) -> GetPlan.Response:
        """Answer with a plan tracking the active reference, from ``start`` (at rest).

        From the latest odometry when start's frame is empty; an empty path when there is none
        to give.
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
                node.problems.reject('plan request', 'the planner is not configured')
                return response
            solution, reason = session.preview(pose)
        except cv.InputRejected as exc:
            node.problems.reject('plan request', str(exc))
            return response
        except Exception as exc:  # noqa: BLE001 - a service must always answer
            node.problems.fail('plan service', exc)
            return response
        if solution is None:
            node.problems.reject('plan request', reason)
            return response
        stamps = [session.ns(t) for t in solution.t]
        response.plan = msgs.path_msg(node.frame, stamps,
                                      np.array([session.pose_map.pose(q) for q in solution.q]))
        return response

    def on_replan(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        """Replan now; ``message`` says what happened (optimal / shifted / fallback / why not)."""
        session = self.planner.session
        try:
            result = session.replan() if session is not None else None
        except Exception as exc:  # noqa: BLE001 - a service must always answer
            self.planner.problems.fail('replan service', exc)
            response.success, response.message = False, f'replanning failed: {exc}'
            return response
        if result is None:
            response.success, response.message = False, 'the planner is not configured'
        else:
            response.success, response.message = result.outcome is not None, result.reason
        return response
