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

"""How a tracking session is doing, in words and figures.

What a diagnostics front end (the ROS planner's /diagnostics) reports. ROS-free, so the figures are
computed once, here.
"""
from __future__ import annotations

from dataclasses import dataclass
import enum

import numpy as np

from nh_tracking.estimation.adaptation import BackgroundEstimates
from nh_tracking.navigation.goal_checking import GoalState
from nh_tracking.planning.command_guard import GuardAction
from nh_tracking.planning.receding_horizon import PlanStatus
from nh_tracking.session.tracking_session import TrackingSession

RECENT = 200  # solves the solve-time percentiles are taken over


class HealthLevel(enum.IntEnum):
    """Worse is larger (a report gives the worst of the last second)."""

    OK = 0
    WARN = 1
    STALE = 2


@dataclass(frozen=True)
class Health:
    level: HealthLevel
    message: str
    values: dict[str, object]


def session_health(session: TrackingSession, problem: str, counts: dict[str, int]) -> Health:
    """Return the session's state: the worst of the last second.

    ``problem`` is the last input or callback problem ('' if none), ``counts`` the front end's own
    counters (rejected inputs, errors).
    """
    outcome, stats = session.outcome, session.planner.stats
    stale = session.staleness.fraction()
    goal = session.following.status
    level, message = HealthLevel.OK, 'planning'
    if not session.active:
        level, message = HealthLevel.WARN, 'inactive: not commanding'
    elif session.planner.reference is None or session.state is None:
        missing = [what for what, absent in (
            ('a reference (reference_path, reference_trajectory or a follow_path goal)',
             session.planner.reference is None), ('odometry', session.state is None)) if absent]
        level, message = HealthLevel.WARN, f"waiting for {' and '.join(missing)}"
    elif session.staleness.now or stale > 0.0:
        level, message = HealthLevel.STALE, (
            f'odometry {"is" if session.staleness.now else "was"} stale ({stale:.0%} of the '
            'last second): not commanding')
    elif (ahead := session.planner.reference.t[0] - session.seconds(session.clock())
          ) > session.planner.settings.horizon:
        level, message = HealthLevel.WARN, (f'the reference starts {ahead:.1f} s from now '
                                            '(a clock that jumped back?)')
    elif goal.state is GoalState.BLOCKED:
        level, message = HealthLevel.WARN, (
            f'blocked: {session.following.goal_settings.stuck()}, {goal.remaining:.2f} m '
            'before the goal')
    elif session.robot.joints_lost:
        level, message = HealthLevel.WARN, f'hidden coordinates: {session.robot.hidden_status}'
    elif outcome is not None and outcome.status is not PlanStatus.OPTIMAL:
        level, message = HealthLevel.WARN, f'{outcome.status}: {outcome.message}'
    guarded = session.commands.notes(session.now())
    if guarded and level is HealthLevel.OK:
        # a speed zone is the robot doing as told; a bound, a ramp or an obstacle is news
        level = HealthLevel.OK if all(note.action is GuardAction.SPEED_LIMIT
                                      for note in guarded) else HealthLevel.WARN
        message = f"guard: {'; '.join(note.text for note in guarded)}"
    if problem and level is HealthLevel.OK:
        level, message = HealthLevel.WARN, problem
    times = np.array(stats.solve_times)[-RECENT:] if stats.solve_times else np.zeros(1)
    recent = list(session.latencies)[-RECENT:]
    latency = np.array([row[0] for row in recent]) if recent else np.zeros(1)
    values: dict[str, object] = {
        'status': str(outcome.status) if outcome else 'none', 'plans': stats.plans,
        'optimal': stats.optimal, 'shifted': stats.shifted, 'fallbacks': stats.fallbacks,
        'deadline_misses': stats.deadline_misses, **counts, 'last_problem': problem,
        'reconfiguring': session.reconfiguring, 'stale_fraction': f'{stale:.2f}',
        'hidden_coordinates': session.robot.hidden_status or 'none', 'goal': str(goal.state),
        'distance_to_goal_m': f'{goal.remaining:.2f}',
        'speed_limit': str(session.commands.speed_limit),
        'guard': '; '.join(note.text for note in guarded) or 'none',
        'solve_time_last_ms': f'{(outcome.solve_time if outcome else 0.0) * 1e3:.2f}',
        'solve_time_p50_ms': f'{np.percentile(times, 50) * 1e3:.2f}',
        'solve_time_p99_ms': f'{np.percentile(times, 99) * 1e3:.2f}',
        # odometry receipt -> control_sequence published: how old the state is that a plan
        # starts from when the robot gets it
        'latency_p50_ms': f'{np.percentile(latency, 50) * 1e3:.2f}',
        'latency_p99_ms': f'{np.percentile(latency, 99) * 1e3:.2f}',
    }
    if session.adaptation is not None:
        values.update(estimate_values(session.adaptation))
    return Health(level, message, values)


def estimate_values(adaptation: BackgroundEstimates) -> dict[str, object]:
    """Return the values in use of what is estimated online, its spread and the excitation."""
    last = adaptation.last
    values: dict[str, object] = {}
    for name, value in adaptation.values.items():
        values[f'estimate/{name}'] = f'{value:.6g}'
        values[f'estimate/{name}/std'] = f'{last.std[name]:.3g}' if last else 'none'
    values['estimate/excitation'] = (
        adaptation.failure or (last.message if last else 'waiting for a full window'))
    return values
