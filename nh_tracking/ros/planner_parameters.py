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

"""The planner node's parameters: declared, checked before a change, applied after it."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.timer import Timer

from nh_tracking.navigation.goal_checking import GoalSettings
from nh_tracking.navigation.route import RouteSettings
from nh_tracking.planning.command_guard import GuardSettings
from nh_tracking.planning.receding_horizon import PlannerSettings
from nh_tracking.ros.guarded import guarded, ProblemLog
from nh_tracking.ros.parameters import declare_all, declare_model
from nh_tracking.ros.planner_interface import GOAL, GUARD, PARAMETERS, ROUTE, SETTINGS
from nh_tracking.session.tracking_session import TrackingSession

_SETTING_NAMES = {s.name for s in SETTINGS}
_TIMERS = {'replan_period': 0, 'cmd_rate': 1, 'display_rate': 2}  # index in the command timers


class ParameterHandler:
    """The planner's parameters: ``ros2 param set`` never stops the plan in force.

    Declares the model, its physical parameters and :data:`PARAMETERS` on ``node`` (a bad
    start-up value: ValueError naming it). A change is refused unless the settings it makes are
    consistent; one taken retimes the command timers (``timers()``: replan, cmd_vel, display)
    and hands the session (``session()``, None while unconfigured) what changed.
    """

    def __init__(self, node: Node, problems: ProblemLog,
                 session: Callable[[], TrackingSession | None],
                 timers: Callable[[], Sequence[Timer]]) -> None:
        self.node, self.problems = node, problems
        self._session, self._timers = session, timers
        self.model, self.physical = declare_model(node)
        self.params: dict[str, Any] = declare_all(node, PARAMETERS)  # the values in force
        PlannerSettings(**self.settings_values())  # consistent at start-up, or ValueError
        node.add_on_set_parameters_callback(self.validate)
        node.add_post_set_parameters_callback(self.apply)

    def tune(self, session: TrackingSession) -> None:
        """Hand the session the input checks' parameters (they need no rebuild)."""
        session.robot.odom_timeout = self.params['odom_timeout']
        session.robot.max_clock_skew = self.params['max_clock_skew']
        session.reference_bounds = (self.params['reference_max_speed'],
                                    self.params['reference_max_accel'])
        session.following.configure(RouteSettings(**self._values(ROUTE)),
                                    GoalSettings(**self._values(GOAL)))
        commands = session.commands
        commands.settings = GuardSettings(**self._values(GUARD))
        commands.max_accel = self.params['max_accel']
        commands.command_period = 1.0 / self.params['cmd_rate']
        commands.sequence_period = self.params['replan_period']

    def _values(self, specs, changes: dict | None = None) -> dict:
        return {s.name: (changes or {}).get(s.name, self.params[s.name]) for s in specs}

    def settings_values(self) -> dict:
        """Return the solver's settings as the node's parameters give them now."""
        return {s.name: self.node.get_parameter(s.name).value for s in SETTINGS}

    def validate(self, params) -> SetParametersResult:
        """Refuse a change that makes inconsistent settings, with the reason."""
        changes = {p.name: p.value for p in params}
        try:
            settings = PlannerSettings(**{**self.settings_values(), **{
                k: v for k, v in changes.items() if k in _SETTING_NAMES}})
            if (session := self._session()) is not None:
                settings.limits(session.system)  # bounds sized for the model
            RouteSettings(**self._values(ROUTE, changes))
            GoalSettings(**self._values(GOAL, changes))
            GuardSettings(**self._values(GUARD, changes))
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    @guarded('parameter change')
    def apply(self, params) -> None:
        """Put a change in force; the solver's are built on the session's builder thread."""
        names = {p.name for p in params}
        for p in params:
            if p.name in self.params:
                self.params[p.name] = p.value
            if p.name in self.physical:
                self.physical[p.name] = float(p.value)
        timers = self._timers()
        for name in names & _TIMERS.keys():
            if timers:
                period = self.params[name] if name == 'replan_period' else 1 / self.params[name]
                timer = timers[_TIMERS[name]]
                timer.timer_period_ns = int(period * 1e9)
                timer.reset()  # from now: else the call already due at the old period comes first
        session = self._session()
        if session is not None:
            self.tune(session)
            if names & (_SETTING_NAMES | set(self.physical)):
                # built on the session's builder thread; the plan in force keeps going
                session.reconfigure(self.physical, PlannerSettings(**self.settings_values()))
        self.node.get_logger().info(f'parameters changed: {sorted(names)}')
