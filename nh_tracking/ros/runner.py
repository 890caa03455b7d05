"""``main()`` plumbing shared by the executables: spin, and shut down cleanly on Ctrl-C."""
from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node


def run(make_node: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Create the node and spin it until Ctrl-C or an external shutdown; exit code 0, or 2
    when the node cannot start (bad parameters), with the reason on stderr."""
    rclpy.init(args=args)
    try:
        node = make_node()
    except ValueError as exc:
        print(f"cannot start: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    # Single-threaded on purpose: the solver runs in the planner's own worker thread, and
    # rclpy's MultiThreadedExecutor (7.1, Jazzy) starves timers when another node subscribes
    # to what they publish (ros2/rclpy#1223, #1452).
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown(timeout_sec=5.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
