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

"""Several nodes in one process: one Context, a single-threaded executor on its own thread.

What ``nh-tracking demo`` and the integration tests use to compose planner and simulator
without launch files (the pattern of rclpy's own tests).
"""
from __future__ import annotations

from collections.abc import Callable
import threading
import time
from typing import TypeVar

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

N = TypeVar('N', bound=Node)
R = TypeVar('R')


def parameters(**values: object) -> list[Parameter]:
    """Parameter overrides from keyword arguments."""
    return [Parameter(name, value=value) for name, value in values.items()]


def wait_until(predicate: Callable[[], bool], timeout: float, period: float = 0.01) -> bool:
    """Poll ``predicate`` until it holds or ``timeout`` (wall seconds) passes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period)
    return predicate()


class InProcessGraph:
    """Owns a Context and an executor thread; ``close()`` tears everything down."""

    def __init__(self, domain_id: int | None = None) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes: list[Node] = []
        self._thread = threading.Thread(target=self._spin, name='ros_graph', daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - shutdown races end the thread quietly
            pass

    def add(self, make: Callable[..., N], **kwargs: object) -> N:
        """Create a node in this graph's context (``make(context=..., **kwargs)``) and spin it."""
        node = make(context=self.context, **kwargs)
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def plain_node(self, name: str, namespace: str = '') -> Node:
        return self.add(lambda **kw: rclpy.create_node(name, **kw), namespace=namespace)

    def remove(self, *nodes: Node) -> None:
        """Stop spinning ``nodes`` and destroy them (a graph that runs scene after scene).

        On the executor's thread, between two callbacks: a timer of theirs is not cut short.
        """
        def remove_now() -> None:
            for node in nodes:
                self.executor.remove_node(node)
                self.nodes.remove(node)
                node.destroy_node()
        self.call(remove_now)

    def call(self, request: Callable[..., R], *args: object, timeout: float = 10.0,
             **kwargs: object) -> R:
        """Run ``request(*args, **kwargs)`` on the executor's thread; what it returns.

        rclpy's ActionClient files a request's future only after sending it: called from
        another thread while the executor spins, a fast response can arrive first and be
        dropped ("Ignoring unexpected goal response"). Requests made here cannot race it.
        """
        task = self.executor.create_task(request, *args, **kwargs)
        if not wait_until(task.done, timeout):
            raise TimeoutError(f'the executor did not run {request} within {timeout} s')
        return task.result()

    def close(self) -> None:
        """Stop spinning first, so no callback runs while nodes are destroyed."""
        self.executor.shutdown(timeout_sec=5.0)
        self._thread.join(timeout=5.0)
        for node in reversed(self.nodes):
            node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> InProcessGraph:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
