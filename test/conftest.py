"""Shared test set-up: ROS traffic stays on this machine; test helpers importable."""
import os
import sys

import pytest

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("MPLBACKEND", "Agg")
sys.path.insert(0, os.path.dirname(__file__))


@pytest.fixture
def graph():
    """Nodes in one Context of their own, spun on a background thread; torn down after."""
    from nh_tracking.ros.graph import InProcessGraph

    g = InProcessGraph()
    yield g
    g.close()
