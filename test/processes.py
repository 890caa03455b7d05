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

"""The installed executables as separate processes, the way users deploy them.

Each test on a ROS_DOMAIN_ID of its own, this process talking to them over DDS through its own
Context.
"""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
import itertools
import multiprocessing
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

import numpy as np

from nh_tracking.ros.graph import InProcessGraph

BIN = Path(sys.executable).parent
# the domains ROS recommends (1-101), from a place of this run's own: a test suite, a demo or
# another suite on this machine never hears this one's nodes (a second /clock made a sim-time
# loop's clock jump back and forth)
_domains = itertools.cycle(np.roll(np.arange(1, 102), -(os.getpid() % 101)).tolist())


def rss_bytes() -> int:
    """Return this process's resident memory [bytes]."""
    with open('/proc/self/status') as status:
        return next(int(line.split()[1]) for line in status if line.startswith('VmRSS')) * 1024


def cpu_seconds(pid: int) -> float:
    """Return the CPU time [s] process ``pid`` has used (user and system)."""
    with open(f'/proc/{pid}/stat') as stat:
        fields = stat.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def next_domain() -> int:
    """Return a ROS_DOMAIN_ID for the next test."""
    return next(_domains)


def domain_env() -> dict[str, str]:
    """Return an environment on a fresh domain: tests never hear each other's nodes."""
    return dict(os.environ, ROS_DOMAIN_ID=str(next_domain()),
                ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')


class Process:
    """One executable; its output collected line by line on a thread."""

    def __init__(self, executable: str, args: list[str], env: dict[str, str]) -> None:
        path = Path(executable) if os.sep in executable else BIN / executable
        self.executable, self.args, self.env = executable, args, env
        self.proc = subprocess.Popen([str(path), *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, env=env)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)

    @property
    def output(self) -> str:
        return ''.join(self.lines)

    def wait_for(self, text: str, timeout: float = 60.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.output:
                return True
            if self.proc.poll() is not None:
                self._reader.join(timeout=5.0)
                return text in self.output
            time.sleep(0.05)
        return False

    def interrupt(self, timeout: float = 30.0) -> int:
        """Ctrl-C, and the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        return self.finish(timeout)

    def kill(self) -> None:
        """Kill -9: no chance to clean up, as in a crash."""
        self.proc.kill()
        self.finish()

    def finish(self, timeout: float = 30.0) -> int:
        try:
            code = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        self._reader.join(timeout=5.0)
        return code


def starts_and_stops(process: Process, ready: str) -> str:
    """Check it started (its ready line logged).

    And Ctrl-C ends it with code 0 and no traceback; its output.
    """
    assert process.wait_for(ready), process.output
    assert process.interrupt() == 0, process.output
    assert 'Traceback' not in process.output, process.output
    return process.output


def run(executable: str, args: list[str], env: dict[str, str], timeout: float = 60.0
        ) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / executable), *args], capture_output=True, text=True,
                          env=env, timeout=timeout)


class Peer:
    """This test's own ROS participant on the processes' domain, spun on a thread."""

    def __init__(self, env: dict[str, str], name: str = 'test_peer') -> None:
        self.graph = InProcessGraph(domain_id=int(env['ROS_DOMAIN_ID']))
        self.node = self.graph.plain_node(name)

    def close(self) -> None:
        self.graph.close()


def _spin_forever(stop) -> None:  # a busy core
    while not stop.is_set():
        sum(range(10_000))


@contextmanager
def busy_cores(count: int) -> Iterator[None]:
    """Keep ``count`` cores busy in other processes for the duration of the block."""
    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=_spin_forever, args=(stop,), daemon=True)
            for _ in range(count)]
    for hog in hogs:
        hog.start()
    try:
        yield
    finally:
        stop.set()
        for hog in hogs:
            hog.join(timeout=5.0)
