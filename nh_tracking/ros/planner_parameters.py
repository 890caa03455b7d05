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

"""Runtime parameter changes of the planner node: checked first, then built in the background."""
from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import SetParametersResult

from nh_tracking.navigation.goal_checking import GoalSettings
from nh_tracking.navigation.route import RouteSettings
from nh_tracking.planning.command_guard import GuardSettings
from nh_tracking.planning.receding_horizon import PlannerSettings
from nh_tracking.ros.guarded import guarded, GuardedNode
from nh_tracking.ros.planner_interface import GOAL, GUARD, ROUTE, SETTINGS
from nh_tracking.session.tracking_session import TrackingSession

_SETTING_NAMES = {s.name for s in SETTINGS}


class RuntimeParameters(GuardedNode):
    """The planner node's parameter handling: ``ros2 param set`` never stops the plan in force."""

    session: TrackingSession | None
    params: dict[str, Any]
    physical: dict[str, float]
    _command_timers: list

    def _tune(self, session: TrackingSession) -> None:
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

    def _settings_values(self) -> dict:
        return {s.name: self.get_parameter(s.name).value for s in SETTINGS}

    def _validate_parameters(self, params) -> SetParametersResult:
        changes = {p.name: p.value for p in params}
        try:
            settings = PlannerSettings(**{**self._settings_values(), **{
                k: v for k, v in changes.items() if k in _SETTING_NAMES}})
            if self.session is not None:
                settings.limits(self.session.system)  # bounds sized for the model
            RouteSettings(**self._values(ROUTE, changes))
            GoalSettings(**self._values(GOAL, changes))
            GuardSettings(**self._values(GUARD, changes))
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    @guarded('parameter change')
    def _apply_parameters(self, params) -> None:
        names = {p.name for p in params}
        for p in params:
            if p.name in self.params:
                self.params[p.name] = p.value
            if p.name in self.physical:
                self.physical[p.name] = float(p.value)
        timers = {'replan_period': 0, 'cmd_rate': 1, 'display_rate': 2}
        for name in names & timers.keys():
            if self._command_timers:
                period = self.params[name] if name == 'replan_period' else 1 / self.params[name]
                timer = self._command_timers[timers[name]]
                timer.timer_period_ns = int(period * 1e9)
                timer.reset()  # from now: else the call already due at the old period comes first
        session = self.session
        if session is not None:
            self._tune(session)
            if names & (_SETTING_NAMES | set(self.physical)):
                # built on the session's builder thread; the plan in force keeps going
                session.reconfigure(self.physical, PlannerSettings(**self._settings_values()))
        self.get_logger().info(f'parameters changed: {sorted(names)}')
