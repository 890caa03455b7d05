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

"""Obstacles and costmaps taken beside the node, newest first: never where commands are sent.

A companion node's thread takes each message as CDR bytes (:mod:`obstacle_bytes` reads them)
and only hands it on, to a worker of its topic that reads and reduces one message at a time.
A message that arrives while the one before is still being worked on waits in a slot of one; a
newer one takes its place, and the one it replaced is counted as dropped. So work never queues
up behind a burst, and what is used is the newest there is. One worker works at a time, and
rests as long as it worked before any works again: floods of every input take at most half of
the interpreter, whatever their rates, and the commands and plans keep the rest. An input dropping
messages, or used more than :data:`LAG_WARNING` after its receipt, is reported for
:data:`RECENT` seconds.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import math
import threading
import time
from typing import Any

from rclpy.node import Node

from nh_tracking.ros import obstacle_bytes
from nh_tracking.ros.companion import CompanionNode, LEAN, POLL
from nh_tracking.ros.planner_interface import subscribe_latched

LAG_WARNING = 0.5  # [s] from receipt to use
RECENT = 5.0  # [s] how long a drop or a lag goes on being reported


class Newest:
    """A slot of one: :meth:`put` replaces what was not taken yet."""

    def __init__(self) -> None:
        self._ready = threading.Condition()
        self._item: Any = None

    def put(self, item: Any) -> bool:
        """Offer ``item``; True if it replaced one not taken."""
        with self._ready:
            replaced, self._item = self._item is not None, item
            self._ready.notify()
        return replaced

    def take(self, timeout: float) -> Any:
        """Return the item, waiting up to ``timeout`` [s] for one (None if none came)."""
        with self._ready:
            if self._item is None:
                self._ready.wait(timeout)
            item, self._item = self._item, None
        return item


@dataclass
class InputLoad:
    """How one input keeps up: messages used and dropped, and how late the last was used."""

    used: int = 0
    dropped: int = 0
    lag: float = 0.0  # [s] from the receipt of the last message used to its use
    dropped_at: float = -math.inf  # (monotonic)
    lagged_at: float = -math.inf  # (monotonic) when a message was used late

    def problem(self, topic: str, now: float) -> str:
        """Return what was wrong within :data:`RECENT` s ('' if nothing)."""
        said = []
        if now - self.dropped_at <= RECENT:
            said.append(f'messages come faster than they can be read, {self.dropped} dropped '
                        'so far (the newest is used)')
        if now - self.lagged_at <= RECENT:
            said.append(f'used {self.lag:.2f} s after receipt')
        return f"{topic}: {', '.join(said)}" if said else ''


class ObstacleReceiver(CompanionNode):
    """Calls ``use(msg, self)`` for each input topic on a worker of its own, newest first.

    ``inputs``: topic -> (message type, use). ``msg`` is the CDR bytes where
    :mod:`obstacle_bytes` reads them (else the message). Latched and volatile publishers are
    both heard.
    """

    def __init__(self, owner: Node,
                 inputs: dict[str, tuple[type, Callable[[Any, ObstacleReceiver], None]]]
                 ) -> None:
        super().__init__(owner, 'obstacles', **LEAN)
        self._logger = owner.get_logger()
        raw = obstacle_bytes.agrees_with_rmw()
        self.loads = {topic: InputLoad() for topic in inputs}
        self._workers = []
        self._working = threading.Lock()  # one at a time, and its rest
        self.subscriptions: list = []
        for topic, (msg_type, use) in inputs.items():
            slot = Newest()
            self.subscriptions += subscribe_latched(
                self.node, msg_type, owner.resolve_topic_name(topic),
                self._arrival(topic, slot), raw=raw)
            self._workers.append(threading.Thread(
                target=self._work, args=(topic, slot, use), name=f'nh_tracking_{topic}',
                daemon=True))
        for worker in self._workers:
            worker.start()
        self.start()

    def _arrival(self, topic: str, slot: Newest) -> Callable[[Any], None]:
        """Return the callback that puts ``topic``'s messages in its slot, counting drops."""
        load = self.loads[topic]

        def arrived(msg: Any) -> None:
            if slot.put((time.monotonic(), msg)):
                now = time.monotonic()
                if now - load.dropped_at > RECENT:
                    self._logger.warn(f'{topic}: messages come faster than they can be read; '
                                      'the newest is used, the others are dropped')
                load.dropped, load.dropped_at = load.dropped + 1, now
        return arrived

    def _work(self, topic: str, slot: Newest,
              use: Callable[[Any, ObstacleReceiver], None]) -> None:
        load = self.loads[topic]
        while not self._stop.is_set():
            item = slot.take(POLL)
            if item is None:
                continue
            received, msg = item
            with self._working:
                began = time.monotonic()
                use(msg, self)
                done = time.monotonic()
                load.used, load.lag = load.used + 1, done - received
                if load.lag > LAG_WARNING:
                    if done - load.lagged_at > RECENT:
                        self._logger.warn(f'{topic}: used {load.lag:.2f} s after receipt')
                    load.lagged_at = done
                self._stop.wait(done - began)  # at most half the interpreter, whatever comes

    def problems(self) -> list[str]:
        """Return each input's recent problem (none: an empty list)."""
        now = time.monotonic()
        return [said for topic, load in self.loads.items() if (said := load.problem(topic, now))]

    def values(self) -> dict[str, object]:
        """Return counts and lags for diagnostics."""
        values: dict[str, object] = {}
        for topic, load in self.loads.items():
            values[f'{topic}_used'] = load.used
            values[f'{topic}_dropped'] = load.dropped
            values[f'{topic}_lag_ms'] = f'{load.lag * 1e3:.1f}'
        return values

    def close(self) -> None:
        """Stop the workers, then the node's thread."""
        self._stop.set()
        for worker in self._workers:
            if worker is not threading.current_thread():
                worker.join(timeout=5.0)
        super().close()
