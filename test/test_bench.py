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

"""The benchmark's timing discipline (its figures are measured by ``nh-tracking bench``)."""
import pytest

from nh_tracking.examples.cold import interleaved

pytestmark = pytest.mark.unit


def test_interleaved_rounds_run_every_tool_once_per_round_in_a_rotating_order():
    """A drift in the machine's speed must hit every tool alike, and none always go first."""
    calls: list[str] = []

    def tool(name: str) -> int:
        calls.append(name)
        return len(calls)

    solves = {name: (lambda name=name: tool(name)) for name in ('ours', 'peer', 'other')}
    times, last = interleaved(solves, 4)
    assert calls == ['ours', 'peer', 'other', 'peer', 'other', 'ours',
                     'other', 'ours', 'peer', 'ours', 'peer', 'other']
    assert {name: len(t) for name, t in times.items()} == {'ours': 4, 'peer': 4, 'other': 4}
    assert all(s >= 0 for t in times.values() for s in t)
    assert last == {'ours': 10, 'peer': 11, 'other': 12}


def test_the_peers_write_out_the_dynamics_this_package_derives():
    """The peers solve the same problem: their hand-written equations are the derived ones."""
    import casadi as ca
    import numpy as np

    import nh_tracking as nht
    from nh_tracking.examples.experiments import sleigh_problem
    from nh_tracking.examples.peers import written_rhs

    unicycle = nht.models.unicycle(m=2.0, J=0.3)
    line = nht.simulate(unicycle, np.zeros(3), [0.5, 0.0], np.linspace(0, 5, 51))
    rng = np.random.default_rng(1)
    for problem in (sleigh_problem(), nht.TrackingProblem(unicycle, line, np.zeros(3),
                                                          np.zeros(2), 2.0, 20)):
        system = problem.system
        for _ in range(5):
            q, v, u = rng.normal(size=system.n), rng.normal(size=system.k), rng.normal(
                size=system.r)
            written = np.array(ca.evalf(written_rhs(problem)(ca.DM(np.r_[q, v]), ca.DM(u))))
            assert np.allclose(written.ravel(), np.r_[system.dynamics(q, v, u)], atol=1e-12)
