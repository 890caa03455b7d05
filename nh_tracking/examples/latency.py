"""ROS latency for the benchmark: odometry receipt to control_sequence publish, in process."""
from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from nav_msgs.msg import Odometry

from nh_tracking.metrics import percentiles_ms
from nh_tracking.ros import conversions as cv
from nh_tracking.examples.demo import ClosedLoop, sleigh_reference
from nh_tracking.ros.graph import InProcessGraph, wait_until
from nh_tracking.ros.runner import responsive_threads


def ros_latency(log: Callable[[str], None], duration: float = 6.0, rate: float = 100.0) -> dict:
    """A planner replanning on every odometry message (``replan_on_odom``) of a robot
    driving the reference, replayed at ``rate`` Hz on the wall clock: latency from receipt to
    the control sequence's publication, and how much of it is not the solve.

    The odometry is replayed rather than simulated in the same process, so the figure is the
    planner's own pipeline, not its competition for the interpreter with a simulator."""
    reference = sleigh_reference(duration + 30.0)
    responsive_threads()
    with InProcessGraph() as graph:
        loop = ClosedLoop(graph, namespace="/bench", planner_overrides={
            "use_sim_time": False, "replan_on_odom": True, "replan_period": 60.0})
        planner = loop.planner
        loop.send_reference(reference, "path")
        replay = graph.plain_node("odometry_replay", "/bench")
        pub = replay.create_publisher(Odometry, "odom", 10)
        t0 = time.monotonic()

        def publish() -> None:
            q, v = reference.at(time.monotonic() - t0)
            pose_map = planner.pose_map
            pub.publish(cv.odometry_msg("odom", "base_link", planner.get_clock().now().nanoseconds,
                                        pose_map.pose(q), pose_map.body_twist(q, v)))

        replay.create_timer(1.0 / rate, publish)
        wait_until(lambda: len(planner.latencies) > 50, 20.0)
        planner.latencies.clear()
        time.sleep(duration)
        samples = np.array(list(planner.latencies))
    latency, planning, solve = samples[:, 0], samples[:, 1], samples[:, 2]
    result = {"plans": int(len(samples)), "odometry_rate_hz": rate,
              "latency_ms": percentiles_ms(latency), "planner_ms": percentiles_ms(planning),
              "solve_ms": percentiles_ms(solve),
              "overhead_ms": percentiles_ms(latency - planning),
              "not_in_nlp_solver_ms": percentiles_ms(latency - solve)}
    log(f"  {len(samples)} plans: latency p50 {result['latency_ms']['p50']:.2f} ms, p99 "
        f"{result['latency_ms']['p99']:.2f} ms; numerical planner p50 "
        f"{result['planner_ms']['p50']:.2f} ms (NLP solver {result['solve_ms']['p50']:.2f} ms);"
        f" ROS layer p50 {result['overhead_ms']['p50']:.2f} ms")
    return result
