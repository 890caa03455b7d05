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

"""Every ``change_state`` request answered, none fatal.

rclpy 7.1 looks a transition given by label up in the current state (refusing one it lacks), but
one given by id goes straight to the state machine, whose ``RCLError`` escapes the executor and
ends the process — ``configure`` (id 1) to an autostarted node among them. Here a request is
checked against the transitions the current state offers first, the way rclcpp answers it.
"""
from __future__ import annotations

from collections.abc import Callable

from lifecycle_msgs.srv import ChangeState
from rclpy.lifecycle import LifecycleNode

from nh_tracking.ros.rclpy_private import (available_transitions, current_state_label,
                                           replace_change_state_callback, ServiceCallback)


def refusal(node: LifecycleNode, request: ChangeState.Request) -> str:
    """Return why ``request`` cannot be carried out now ('' if it can).

    A label, when given, names the transition (rclpy's own rule); otherwise the id does.
    """
    transitions = available_transitions(node)
    wanted = request.transition
    if wanted.label:
        if wanted.label in transitions.values():
            return ''
        asked = f"'{wanted.label}'"
    else:
        if wanted.id in transitions:
            return ''
        asked = f'id {wanted.id}'
    state = current_state_label(node)
    choices = ', '.join(f'{label} ({i})' for i, label in sorted(transitions.items()))
    return f'transition {asked} is not one the {state} state offers ({choices or "none"})'


def answer_every_transition(node: LifecycleNode, reject: Callable[[str, str], None]) -> None:
    """Make ``node``'s change_state service refuse, with ``reject``, what it cannot carry out."""
    def checked(carry_out: ServiceCallback) -> ServiceCallback:
        def on_change_state(request: ChangeState.Request, response: ChangeState.Response
                            ) -> ChangeState.Response:
            reason = refusal(node, request)
            if reason:
                reject('lifecycle request', reason)
                response.success = False
                return response
            return carry_out(request, response)
        return on_change_state

    replace_change_state_callback(node, checked)
