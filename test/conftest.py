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

"""Shared test set-up: ROS traffic stays on this machine; test helpers importable; tiers.

Every test is in one tier, marked ``unit``, ``solve`` or ``ros`` (on the test or on its module);
``slow`` marks those ``scripts/test.sh --fast`` leaves out.
"""
import os
import sys

import pytest

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('MPLBACKEND', 'Agg')
sys.path.insert(0, os.path.dirname(__file__))
TIERS = ('unit', 'solve', 'ros')


def pytest_collection_modifyitems(config, items):
    """Refuse a test that is in no tier or in more than one."""
    wrong = [item.nodeid for item in items
             if sum(1 for mark in item.iter_markers() if mark.name in TIERS) != 1]
    if wrong:
        raise pytest.UsageError(f'tests without exactly one tier marker {TIERS}: {wrong}')


@pytest.fixture(autouse=True)
def own_domain(monkeypatch):
    """Nodes a test makes without naming a domain (the demos') are on one of its own."""
    from processes import next_domain

    monkeypatch.setenv('ROS_DOMAIN_ID', str(next_domain()))


@pytest.fixture
def graph():
    """Nodes in one Context and ROS domain of their own, spun on a thread; torn down after."""
    from nh_tracking.ros.graph import InProcessGraph
    from processes import next_domain

    g = InProcessGraph(domain_id=next_domain())
    yield g
    g.close()
