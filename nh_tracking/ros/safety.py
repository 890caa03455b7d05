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

"""Callbacks that never let an exception reach the executor, and rejection bookkeeping."""
from __future__ import annotations

import functools
import threading

from rclpy.node import Node

from nh_tracking.ros.conversions import InputRejected


class SafeNode(Node):
    """A node that rejects bad input with one log line and counts what went wrong."""

    def __init__(self, name: str, **kwargs) -> None:
        super().__init__(name, **kwargs)
        self._problem_lock = threading.Lock()
        self._reporting = threading.local()
        self.rejected_inputs = 0
        self.errors = 0
        self.last_problem = ''

    def reject(self, what: str, reason: str) -> None:
        """One clear log line for a message that cannot be used; the node carries on."""
        self.get_logger().warn(f'rejected {what}: {reason}')
        with self._problem_lock:
            self.rejected_inputs += 1
            self.last_problem = f'rejected {what}: {reason}'
        self._report()

    def fail(self, what: str, exc: BaseException) -> None:
        if not self.context.ok():  # shutting down: publishing fails, nothing is wrong
            return
        self.get_logger().error(f'{what} failed: {type(exc).__name__}: {exc}')
        with self._problem_lock:
            self.errors += 1
            self.last_problem = f'{what} failed: {type(exc).__name__}: {exc}'
        self._report()

    def _report(self) -> None:
        """``on_problem`` once: a problem met while reporting one is not reported again."""
        if getattr(self._reporting, 'active', False):
            return
        self._reporting.active = True
        try:
            self.on_problem()
        finally:
            self._reporting.active = False

    def take_problem(self) -> str:
        """Return the last problem since the previous call (for diagnostics)."""
        with self._problem_lock:
            problem, self.last_problem = self.last_problem, ''
        return problem

    def on_problem(self) -> None:
        """Report a problem at once (the planner publishes a diagnostic)."""


def guarded(what: str):
    """Decorate a SafeNode callback: InputRejected -> reject(), anything else -> fail()."""
    def wrap(fn):
        @functools.wraps(fn)
        def inner(self: SafeNode, *args, **kwargs):
            try:
                return fn(self, *args, **kwargs)
            except InputRejected as exc:
                self.reject(what, str(exc))
            except Exception as exc:  # noqa: BLE001 - the executor must never see it
                self.fail(what, exc)
            return None
        return inner
    return wrap
