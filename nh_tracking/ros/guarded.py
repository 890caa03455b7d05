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

"""Callbacks that never let an exception reach the executor, and the problem bookkeeping."""
from __future__ import annotations

from collections.abc import Callable
import functools
import math
import re
import threading
import time
from typing import Protocol

from rclpy.node import Node

from nh_tracking.ros.conversions import InputRejected


LOG_PERIOD = 5.0  # [s] a problem of a kind already said within it is counted, not said again
SHOWN_FOR = 10.0  # [s] how long diagnostics go on showing the last problem
_FIGURES = re.compile(r'[-+]?\d+(\.\d+)?(e[-+]?\d+)?')


class RepeatCounter:
    """Says a problem once per kind per period; the next line counts those held back."""

    def __init__(self, period: float = LOG_PERIOD) -> None:
        self.period = period
        self._kinds: dict[str, tuple[float, int]] = {}  # kind -> (said at, held back since)

    def __call__(self, problem: str, now: float) -> str | None:
        """Return the line to log for ``problem`` now, or None to hold it back."""
        kind = _FIGURES.sub('#', problem)  # the same problem with other figures is one kind
        said, held = self._kinds.get(kind, (-math.inf, 0))
        if now - said < self.period:
            self._kinds[kind] = (said, held + 1)
            return None
        if len(self._kinds) > 100:  # kinds not said for a period are forgotten
            self._kinds = {k: v for k, v in self._kinds.items() if now - v[0] < self.period}
        self._kinds[kind] = (now, 0)
        return problem + (f' ({held} more like it held back)' if held else '')


class ProblemLog:
    """What went wrong in one node's callbacks: counted, logged once a period, shown a while.

    A rejected input is one WARN line, anything else one ERROR line; a problem repeated is
    logged (and reported at once, through ``on_problem``) once per :data:`LOG_PERIOD`, with a
    count of those held back. Every one is counted, and the newest is the diagnostics'
    ``last_problem`` for :data:`SHOWN_FOR` seconds. Safe to use from any thread.
    """

    def __init__(self, node: Node, on_problem: Callable[[], None] | None = None) -> None:
        self._logger = node.get_logger()
        self._context = node.context
        self._on_problem = on_problem
        self._lock = threading.Lock()
        self._reporting = threading.local()
        self.rejected_inputs = 0
        self.errors = 0
        self.last_problem = ''
        self._noted_at = -math.inf  # (monotonic) when last_problem was noted
        self._repeats = RepeatCounter()

    def reject(self, what: str, reason: str) -> None:
        """One clear log line for a message that cannot be used; the node carries on."""
        with self._lock:
            self.rejected_inputs += 1
            line = self._note(f'rejected {what}: {reason}')
        if line is not None:
            self._logger.warn(line)
            self.report()

    def fail(self, what: str, exc: BaseException) -> None:
        """One ERROR line for a failure in a callback, which goes on (none when shutting down)."""
        if not self._context.ok():  # shutting down: publishing fails, nothing is wrong
            return
        with self._lock:
            self.errors += 1
            line = self._note(f'{what} failed: {type(exc).__name__}: {exc}')
        if line is not None:
            self._logger.error(line)
            self.report()

    def _note(self, problem: str) -> str | None:
        self.last_problem, self._noted_at = problem, time.monotonic()
        return self._repeats(problem, self._noted_at)

    def report(self) -> None:
        """Call ``on_problem`` once: a problem met while reporting one is not reported again."""
        if self._on_problem is None or getattr(self._reporting, 'active', False):
            return
        self._reporting.active = True
        try:
            self._on_problem()
        finally:
            self._reporting.active = False

    def recent(self) -> str:
        """Return the last problem if noted within :data:`SHOWN_FOR` s ('' if none)."""
        with self._lock:
            recent = time.monotonic() - self._noted_at <= SHOWN_FOR
            return self.last_problem if recent else ''


class HasProblems(Protocol):
    """An object whose callbacks are guarded: a node or one of its parts."""

    problems: ProblemLog  # the node's log, shared by all its parts


def guarded(what: str):
    """Decorate a callback method of a :class:`HasProblems`: it never raises.

    :class:`InputRejected` -> ``problems.reject``, anything else -> ``problems.fail``; the
    callback then returns None.
    """
    def wrap(fn):
        @functools.wraps(fn)
        def inner(self: HasProblems, *args, **kwargs):
            try:
                return fn(self, *args, **kwargs)
            except InputRejected as exc:
                self.problems.reject(what, str(exc))
            except Exception as exc:  # noqa: BLE001 - the executor must never see it
                self.problems.fail(what, exc)
            return None
        return inner
    return wrap
