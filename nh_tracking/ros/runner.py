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

"""``main()`` plumbing shared by the executables: ``--help``.

Start-up errors as one line and exit code 2, spin, and a clean exit (code 0) on Ctrl-C or SIGTERM.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
import signal
import sys

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from nh_tracking.session import settle_heap

HELP = ('-h', '--help')
SWITCH_INTERVAL = 5e-4  # s


def responsive_threads() -> None:
    """Let the solver, builder and executor threads hand the interpreter over every 0.5 ms.

    CPython's default (5 ms) would add up to 5 ms to a replan's latency. Process-wide, so only
    entry points (executables, the demo's graph) call it, never the library.
    """
    sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL))


def _wants_help(args: Sequence[str]) -> bool:
    """``--help`` before any ``--ros-args`` section (what follows that belongs to ROS)."""
    ours = list(args)[:list(args).index('--ros-args')] if '--ros-args' in args else list(args)
    return any(a in HELP for a in ours)


def run(make_node: Callable[[], Node], usage: Callable[[], str],
        args: Sequence[str] | None = None) -> int:
    """Create the node and spin it until Ctrl-C, SIGTERM or an external shutdown; exit code 0.

    Or 2 when the node cannot start (bad parameters), with the reason on stderr.
    """
    argv = list(sys.argv if args is None else args)
    if _wants_help(argv[1:]):
        print(usage())
        return 0
    try:
        rclpy.init(args=argv)
    except Exception as exc:  # noqa: BLE001 - malformed --ros-args: say so, in one line
        print(f'cannot start: bad command line: {str(exc).splitlines()[0]}', file=sys.stderr)
        return 2
    # SIGTERM (what process managers and `kill` send) ends as cleanly as Ctrl-C, also while
    # the node is still starting (building, maybe compiling, its solver)
    signal.signal(signal.SIGTERM, lambda *_: rclpy.try_shutdown())
    try:
        node = make_node()
    except KeyboardInterrupt:
        rclpy.try_shutdown()
        return 0
    except Exception as exc:  # noqa: BLE001 - start-up problems are one line, not a traceback
        if not rclpy.ok():  # stopped while starting
            return 0
        rclpy.try_shutdown()
        if not isinstance(exc, (ValueError, TypeError, ParameterException)):
            raise
        print(f'cannot start: {str(exc).splitlines()[0]}', file=sys.stderr)
        return 2
    responsive_threads()
    # Single-threaded on purpose: the solver runs in the planner's own worker thread, and
    # rclpy's MultiThreadedExecutor (7.1, Jazzy) starves timers when another node subscribes
    # to what they publish (ros2/rclpy#1223, #1452).
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        settle_heap(2)  # the node as built lives as long as the process (inside the try: a
        # Ctrl-C during the collection ends cleanly too)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:  # (RCLError) SIGTERM shut down while the executor made its wait set
        if rclpy.ok():
            raise
    finally:
        executor.shutdown(timeout_sec=5.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
