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

"""The ``follow_path`` action (nav2_msgs/action/FollowPath): what Nav2's BT navigator drives.

Served as Nav2's controller_server serves it: a goal's path becomes the reference; a new goal
preempts the running one without stopping the robot; feedback (distance along the path to its
end, speed) at :data:`FEEDBACK_RATE`; the result says arrived (NONE), blocked
(FAILED_TO_MAKE_PROGRESS), a path the input checks refuse (INVALID_PATH, with the reason) or
an unknown plugin id (INVALID_CONTROLLER); a goal without fresh odometry for
:data:`ODOMETRY_PATIENCE` × ``odom_timeout`` fails (FAILED_TO_MAKE_PROGRESS, naming the topic).
Cancel brings the robot to rest. The execute
callback is a coroutine that waits on a timer's futures; the server lives on a companion node
with an executor of its own, so a goal's path is read and timed off the thread that sends
``cmd_vel``.
"""
from __future__ import annotations

import time
from typing import Any

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.task import Future

from nh_tracking.navigation.goal_checking import GoalState
from nh_tracking.ros import conversions as cv
from nh_tracking.ros.companion import CompanionNode, LEAN
from nh_tracking.ros.path_input import take_path
from nh_tracking.ros.planner_host import PlannerHost

try:
    from nav2_msgs.action import FollowPath
except ImportError:  # no nav2_msgs: the planner runs without the action (and says so)
    FollowPath = None

FEEDBACK_RATE = 10.0  # [Hz]
ODOMETRY_PATIENCE = 10.0  # a goal without fresh odometry for this many odom_timeouts fails
# the ids a goal may name besides '': the plugin names of Nav2's default nav2_params.yaml
PLUGIN_IDS = {'controller_id': ('FollowPath',),
              'goal_checker_id': ('general_goal_checker', 'goal_checker'),
              'progress_checker_id': ('progress_checker',)}


def plugin_problem(goal: Any) -> str:
    """Why a goal's plugin ids are not this planner's ('' if they are)."""
    for field, own in PLUGIN_IDS.items():
        value = getattr(goal, field)
        if value and value not in own:
            names = ', '.join(f"'{name}'" for name in own)
            return f"{field} '{value}' is not this planner's (give '' or {names})"
    return ''


class FollowPathServer:
    """The action on ``node``, while it is configured; :meth:`close` ends every goal."""

    def __init__(self, node: PlannerHost) -> None:
        self.node = node
        self._current: Any = None  # the goal handle in force; older ones are preempted
        self._generation = -1  # the path the last goal made the reference (its generation)
        self._ticks: list[Future] = []
        self.companion = CompanionNode(node, 'follow_path', **LEAN)
        self.companion.node.create_timer(1.0 / FEEDBACK_RATE, self._tick)
        server = ActionServer(self.companion.node, FollowPath,
                              node.resolve_topic_name('follow_path'), self._execute,
                              goal_callback=self._on_goal,
                              handle_accepted_callback=self._on_accepted,
                              cancel_callback=lambda handle: CancelResponse.ACCEPT)
        self.companion.owned.append(server)
        self.companion.start()

    @classmethod
    def serve(cls, node: PlannerHost) -> FollowPathServer | None:
        """Serve the action on ``node``; None (and one warning) without nav2_msgs."""
        if FollowPath is None:
            node.get_logger().warn('nav2_msgs is not installed: no follow_path action')
            return None
        return cls(node)

    def close(self) -> None:
        """End every goal (aborted) and free the server."""
        self._current = None
        self._tick()
        self.companion.close()

    def _tick(self) -> None:
        ticks, self._ticks = self._ticks, []
        for future in ticks:
            future.set_result(None)

    def _next_tick(self) -> Future:
        future = Future()
        self._ticks.append(future)
        return future

    def _on_goal(self, request: Any) -> GoalResponse:
        session = self.node.session
        if session is None or not session.active:
            self.node.get_logger().warn('follow_path goal rejected: the planner is not active')
            return GoalResponse.REJECT
        if self.node.twins.yields:
            self.node.get_logger().warn(f'follow_path goal rejected: {self.node.twins.describe()}')
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_accepted(self, handle: Any) -> None:
        self._current = handle  # the goal before it sees that it was preempted
        handle.execute()

    async def _execute(self, handle: Any) -> Any:
        node, result = self.node, FollowPath.Result()
        following = node.live.following
        problem = plugin_problem(handle.request)
        code = FollowPath.Result.INVALID_CONTROLLER
        if not problem:
            try:
                take_path(node, handle.request.path, goal=True)
            except cv.InputRejected as exc:
                node.problems.reject('follow_path goal', str(exc))
                problem, code = str(exc), FollowPath.Result.INVALID_PATH
        if problem:  # the goal it preempted is over too: its robot is brought to rest
            if following.generation == self._generation:
                following.halt()
            return self._end(handle, code, problem)
        generation = self._generation = following.generation
        waiting: float | None = None  # since when (steady clock) no fresh odometry came
        while True:
            await self._next_tick()
            session = node.session
            if self._current is not handle:
                return self._end(handle, FollowPath.Result.NONE, 'preempted by a newer goal',
                                 quiet=True)
            if session is None or not session.active:
                return self._end(handle, FollowPath.Result.UNKNOWN, 'the planner was '
                                 'deactivated')
            if handle.is_cancel_requested:
                following.halt()
                handle.canceled()
                return result
            if following.generation != generation:
                return self._end(handle, FollowPath.Result.NONE, 'replaced by a reference '
                                 'on reference_path or reference_trajectory')
            if session.state is None or session.staleness.now:
                waiting = time.monotonic() if waiting is None else waiting
                patience = ODOMETRY_PATIENCE * session.robot.odom_timeout
                if time.monotonic() - waiting > patience:
                    following.halt()
                    return self._end(handle, FollowPath.Result.FAILED_TO_MAKE_PROGRESS,
                                     f'no fresh odometry on {node.resolve_topic_name("odom")} '
                                     f'for {patience:g} s')
            else:
                waiting = None
            status = session.following.status
            handle.publish_feedback(FollowPath.Feedback(distance_to_goal=status.remaining,
                                                        speed=status.speed))
            if status.state is GoalState.ARRIVED:
                handle.succeed()
                self._current = None
                return result
            if status.state is GoalState.BLOCKED:
                following.halt()
                return self._end(handle, FollowPath.Result.FAILED_TO_MAKE_PROGRESS,
                                 f'no progress: {following.goal_settings.stuck()}')

    def _end(self, handle: Any, code: int, why: str, quiet: bool = False) -> Any:
        """Abort ``handle`` with ``code`` and ``why`` (logged, unless ``quiet``: routine)."""
        if self._current is handle:
            self._current = None
        handle.abort()
        if not quiet:
            self.node.get_logger().info(f'follow_path goal aborted: {why}')
        return FollowPath.Result(error_code=code, error_msg=why)
