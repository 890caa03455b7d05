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

"""``main()`` plumbing shared by the executables: ``--help`` for the model asked for.

Start-up errors as one line and exit code 2, spin, and a clean exit (code 0) on Ctrl-C or SIGTERM
at any moment, start-up included; the node is destroyed while its context is still up, so a
planner that was commanding sends its zero ``cmd_vel``.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
import gc
import signal
import sys

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions


HELP = ('-h', '--help')
SWITCH_INTERVAL = 5e-4  # s
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
STOP_POLL = 0.1  # [s] the longest an executor wait lasts before a stop request is looked at


def settle_heap(release: bool = False) -> None:
    """Collect, then exempt every object alive from later collections. Process-wide.

    A full collection holds the interpreter while it walks every tracked object (in a planner
    process: imports, models, NLPs), stopping ``cmd_vel`` and the solver alike. The ``planner``
    executable has its node call it as it starts commanding; ``release``: when its session is
    dropped (a lifecycle cleanup), the exempt objects are collected first, so that it goes with
    them. Process-wide, so only entry points pass it, never the library.
    """
    if release:
        gc.unfreeze()
    gc.collect()
    gc.freeze()


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


def autostart(node: LifecycleNode, why_not: Callable[[], str]) -> None:
    """Configure and activate ``node``; ValueError saying why configuring failed.

    What the transitions built (companion nodes' and solver threads) must not outlive the
    interpreter: a thread left in an rclpy wait aborts the process at exit. So a failure
    destroys the node before it goes on.
    """
    try:
        if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            raise ValueError(f'configuring failed: {why_not()}')
        node.trigger_activate()
    except BaseException:
        node.destroy_node()
        raise


class StopRequest:
    """Ctrl-C and SIGTERM recorded as a request, never raised as an exception.

    Python's own SIGINT handler raises KeyboardInterrupt at whatever line the main thread is on:
    inside a ``with lock`` before its ``try`` (the lock stays held and every thread that needs it
    hangs), inside rclpy's ``Task.__init__`` (a traceback from its ``__del__``), or during
    start-up, where it can abort the process (``terminate called``) or leave it running. rclpy's
    own handlers are not installed: they shut the context down at once, before the node could
    send a last command. The main loop looks at the request between waits of at most
    :data:`STOP_POLL`. A second request is the user insisting and is not absorbed: it raises
    KeyboardInterrupt or, once the interpreter is exiting (it restores the default handlers),
    ends the process by the signal itself.
    """

    def __init__(self) -> None:
        self.requested = False
        for number in STOP_SIGNALS:
            signal.signal(number, self._record)

    def _record(self, number: int, frame: object) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True


def _shut_down() -> None:
    """Shut the default context down if still up."""
    try:
        rclpy.try_shutdown()
    except RuntimeError:
        if rclpy.ok():
            raise


def run(make_node: Callable[[], Node], usage: Callable[[Sequence[str]], str],
        args: Sequence[str] | None = None) -> int:
    """Create the node and spin it until Ctrl-C, SIGTERM or an external shutdown.

    Returns the exit code: 0, or 2 when the node cannot start (bad parameters), with the
    reason on stderr.
    """
    argv = list(sys.argv if args is None else args)
    if _wants_help(argv[1:]):
        print(usage(argv[1:]))  # (the model asked for decides what it lists)
        return 0
    stop = StopRequest()
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # noqa: BLE001 - malformed --ros-args: say so, in one line
        print(f'cannot start: bad command line: {str(exc).splitlines()[0]}', file=sys.stderr)
        return 2
    node = executor = None
    try:
        # Single-threaded on purpose: the solver runs in the planner's own worker thread, and
        # rclpy's MultiThreadedExecutor (7.1, Jazzy) starves timers when another node
        # subscribes to what they publish (github.com/ros2/rclpy/issues/1223 and 1452).
        executor = SingleThreadedExecutor()
        try:
            node = make_node()  # a stop meanwhile is looked at once it is built
        except Exception as exc:  # noqa: BLE001 - start-up problems are one line
            if not isinstance(exc, (ValueError, TypeError, ParameterException)):
                raise
            print(f'cannot start: {str(exc).splitlines()[0]}', file=sys.stderr)
            return 2
        responsive_threads()
        executor.add_node(node)
        while not stop.requested and rclpy.ok():
            executor.spin_once(timeout_sec=STOP_POLL)
    except ExternalShutdownException:
        pass
    except RuntimeError:  # (RCLError) the context shut down while a wait set was made
        if rclpy.ok():
            raise
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=5.0)
        if node is not None:
            node.destroy_node()  # (the context is up: a commanding planner says stop)
        _shut_down()
    return 0
