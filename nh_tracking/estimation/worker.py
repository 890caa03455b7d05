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

"""Parameter fits in a process of their own, one at a time.

CasADi keeps Python's GIL while it works, so a fit of seconds on a thread would stall a node's
commands. The worker is ``python -m nh_tracking.estimation.worker``: a list of keyword
arguments of :func:`~nh_tracking.estimation.output_error.estimate_parameters` comes pickled on its
stdin, the list of estimates (or the exception) goes back on its stdout. Started with the
interpreter, not ``multiprocessing``, it never runs the caller's main module again.
"""
from __future__ import annotations

from collections.abc import Callable
import os
import pickle
import select
import subprocess
import sys
import threading
from typing import Any

from nh_tracking.estimation.output_error import estimate_parameters, ParameterEstimate

Reply = Callable[[list[ParameterEstimate] | Exception], None]
NICENESS = 10  # the worker yields the cores to the planner and the robot's own software
TIMEOUT = 120.0  # s: a worker that has not answered by then is stopped


class EstimationWorker:
    """A worker process started at the first request; ``close`` ends it for good."""

    def __init__(self) -> None:
        self._process: subprocess.Popen | None = None
        self._closed = False
        self._lock = threading.Lock()

    def submit(self, request: list[dict[str, Any]], reply: Reply) -> None:
        """Send ``request`` (estimate_parameters' keywords, each); ``reply`` gets the answer.

        The caller sends the next request only after the reply (one fit at a time).
        """
        threading.Thread(target=self._exchange, args=(request, reply),
                         name='nh_tracking_estimation', daemon=True).start()

    def _exchange(self, request: list[dict[str, Any]], reply: Reply) -> None:
        process: subprocess.Popen | None = None
        try:
            with self._lock:
                if self._closed:
                    raise RuntimeError('closed')
                process = self._process
                if process is None or process.poll() is not None:
                    process = self._process = subprocess.Popen(
                        [sys.executable, '-m', 'nh_tracking.estimation.worker'],
                        stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            assert process.stdin is not None and process.stdout is not None
            pickle.dump(request, process.stdin)
            process.stdin.flush()
            ready, _, _ = select.select([process.stdout], [], [], TIMEOUT)
            if not ready:
                raise TimeoutError(f'no answer in {TIMEOUT:g} s')
            answer = pickle.load(process.stdout)  # the GIL is free while this waits
        except Exception as exc:  # noqa: BLE001 - a worker that died, hung or was closed
            self._end(process)
            answer = RuntimeError(f'the estimation worker failed: {type(exc).__name__}: {exc}')
        reply(answer)

    def _end(self, process: subprocess.Popen | None) -> None:
        """Stop ``process`` (a stream out of step is never read again)."""
        with self._lock:
            if process is not None and process is self._process:
                self._process = None
        if process is not None:
            if process.poll() is None:
                process.kill()
            process.wait()
            for stream in (process.stdin, process.stdout):
                if stream is not None:
                    stream.close()

    def close(self) -> None:
        with self._lock:
            self._closed = True
            process = self._process
        self._end(process)


def main() -> None:
    """Answer requests until stdin closes, at a low priority: the commands come first."""
    os.nice(NICENESS)
    requests, answers = sys.stdin.buffer, sys.stdout.buffer
    while True:
        try:
            request = pickle.load(requests)
        except EOFError:
            return
        try:
            answer: list[ParameterEstimate] | Exception = [
                estimate_parameters(**keywords) for keywords in request]
        except Exception as exc:  # noqa: BLE001 - sent back to the caller
            answer = exc
        pickle.dump(answer, answers)
        answers.flush()


if __name__ == '__main__':
    main()
