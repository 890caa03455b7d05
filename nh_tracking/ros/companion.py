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

"""A companion node: beside another, in its namespace, spun by an executor on its own thread.

rclpy cannot hand one node's callbacks to a second executor, so work that must not wait for the
owner's executor (or hold it up) gets a node of its own — the pattern of Nav2's controller
server, which spins a dedicated executor on its own thread.
"""
from __future__ import annotations

import threading
from typing import Any, Protocol

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

POLL = 0.1  # [s] how long a wait may last before the thread looks whether it is to stop
# a receiver's node: no arguments of its own (its owner resolves the topic names), no rosout,
# no parameter or type description services
LEAN: dict[str, Any] = {
    'use_global_arguments': False, 'enable_rosout': False, 'start_parameter_services': False,
    'parameter_overrides': [Parameter('start_type_description_service', value=False)]}


class Owner(Protocol):
    """What a companion takes of the node it stands beside."""

    @property
    def context(self) -> Any:
        """Return the node's rclpy context."""

    def get_name(self) -> str:
        """Return the node's name."""

    def get_namespace(self) -> str:
        """Return the node's namespace."""


class CompanionNode:
    """``<owner>_<suffix>``: create its entities on :attr:`node`, then :meth:`start`."""

    def __init__(self, owner: Owner, suffix: str, *,
                 executor: type[SingleThreadedExecutor] = SingleThreadedExecutor,
                 **node_options: object) -> None:
        self.node = Node(f'{owner.get_name()}_{suffix}', namespace=owner.get_namespace(),
                         context=owner.context, **node_options)  # type: ignore[arg-type]
        self._executor = executor(context=owner.context)
        self._executor.add_node(self.node)
        self.owned: list[Any] = []  # entities destroyed with the node, before it
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name=f'nh_tracking_{suffix}',
                                        daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _spin(self) -> None:
        try:
            while not self._stop.is_set():
                self._executor.spin_once(timeout_sec=POLL)
        except ExternalShutdownException:
            pass
        except RuntimeError:  # the context shut down while the executor made its wait set
            if self.node.context.ok():
                raise

    def close(self) -> None:
        """Stop the thread, then the executor, then free the node.

        In that order: rclpy's ``Executor.shutdown`` does not wait for a spinning thread and
        destroys the guard conditions it may be using (an occasional traceback on close).
        """
        self._stop.set()
        self._executor.wake()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self._executor.shutdown(timeout_sec=0.0)
        for entity in self.owned:  # (an action server: destroy_node leaves it)
            entity.destroy()
        self.node.destroy_node()
