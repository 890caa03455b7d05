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
from nh_tracking.examples.cold import interleaved


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
