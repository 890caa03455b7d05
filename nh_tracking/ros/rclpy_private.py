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

"""Every use of rclpy's private attributes, one small function each, in this module alone.

Each says which public API is missing. All are checked against rclpy 7.1.5 (Jazzy); a newer
rclpy that renames what they read fails here, in one place (``test/test_architecture.py`` keeps
the rest of the package off rclpy's private attributes).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.service import Service

ServiceCallback = Callable[[Any, Any], Any]  # (request, response) -> response


def available_transitions(node: LifecycleNode) -> dict[int, str]:
    """Return the transitions (id: label) ``node``'s current state offers.

    rclpy's LifecycleNode answers this only as its ``get_available_transitions`` service; it has
    no method for it, so the state machine is read. Checked against rclpy 7.1.5 (Jazzy).
    """
    return {row[0]: row[1] for row in node._state_machine.available_transitions}


def current_state_label(node: LifecycleNode) -> str:
    """Return the label of ``node``'s current lifecycle state ('unconfigured', 'active', ...).

    rclpy's LifecycleNode answers this only as its ``get_state`` service; it has no method for
    it, so the state machine is read. Checked against rclpy 7.1.5 (Jazzy).
    """
    return str(node._state_machine.current_state[1])


def replace_change_state_callback(
        node: LifecycleNode, replace: Callable[[ServiceCallback], ServiceCallback]) -> None:
    """Make ``node``'s ``change_state`` service answer with ``replace(its own callback)``.

    rclpy's LifecycleNode offers no hook before a requested transition is carried out (and one
    given by id goes to the state machine unchecked), so the service's callback is swapped.
    Checked against rclpy 7.1.5 (Jazzy).
    """
    service = node._service_change_state
    service.callback = replace(service.callback)


def parameter_overrides(node: Node) -> dict[str, Parameter]:
    """Return ``node``'s start-up parameter values (``-p``, params files), to check or change.

    rclpy's Node keeps them in a private dict and applies one, unchecked, as its parameter is
    declared; no public API reads or amends them first. The dict itself is returned: what is
    changed there is what the declaration takes. Checked against rclpy 7.1.5 (Jazzy).
    """
    overrides: dict[str, Parameter] = node._parameter_overrides
    return overrides


class ClaimingExecutor(SingleThreadedExecutor):
    """A single-threaded executor that offers each service request to :meth:`claim` first.

    rclpy's executor runs a service's callback and sends its response when it returns; it has no
    public hook to take a request and answer it later (from a worker), so its private
    ``_take_service`` is overridden. Checked against rclpy 7.1.5 (Jazzy).
    """

    def claim(self, service: Service) -> bool:
        """Take ``service``'s waiting request and answer it in time; False: the executor does."""
        return False

    def _take_service(self, srv: Service) -> Any:
        if self.claim(srv):
            return None  # nothing for the executor to run
        return super()._take_service(srv)
