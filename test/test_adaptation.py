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

"""The planner learns the robot's masses while tracking it (parameter ``adapt``), through ROS.

The simulated robot has J 30 % above the planner's model and m 20 % below. The
estimates run in a worker process on the planner's odometry and the controls it sent.
"""
import threading
import uuid

import numpy as np
import pytest

from nh_tracking.estimation.adaptation import combined_estimate, mean_control, SentControls
from nh_tracking.estimation.output_error import ParameterEstimate
from nh_tracking.estimation.worker import EstimationWorker
from nh_tracking.examples.adapting import run_adaptation_demo
from nh_tracking.ros import PlannerNode
from nh_tracking.ros.graph import parameters

pytestmark = pytest.mark.timeout(240)
TRUTH = {'m': 0.8, 'J': 5.2}


def _near(values: dict) -> bool:
    return all(abs(values[n] / TRUTH[n] - 1) < 0.05 for n in TRUTH)


@pytest.mark.ros
@pytest.mark.slow
def test_adapting_predicts_5x_better_and_tracks_no_worse_than_the_model_as_typed(tmp_path):
    """The demo (``nh-tracking demo --adapt``): the same ROS loop with and without adaptation.

    The planner's model takes the estimates (new numbers in its NLPs) and /diagnostics shows
    them; the model as typed stays as typed.
    """
    summary = run_adaptation_demo(tmp_path, duration=32.0, log=lambda line: None)
    adapted, fixed = summary['adapted'], summary['fixed']
    assert summary['prediction_error_ratio'] >= 5.0, summary
    assert adapted['cross_track_error_max_after_20s'] <= \
        fixed['cross_track_error_max_after_20s'] + 1e-4 < 0.05
    assert _near(adapted['values_in_use']), adapted
    assert fixed['values_in_use'] == {'m': 1.0, 'J': 4.0} and fixed['diagnostics'] == {
        'excitation reported': []}
    reported = adapted['diagnostics']
    assert _near({n: float(reported[f'estimate/{n}']) for n in TRUTH}), reported
    assert all(float(reported[f'estimate/{n}/std']) > 0 for n in TRUTH), reported  # last fit's
    assert 'excited' in reported['excitation reported'], reported
    assert (tmp_path / 'adapt.png').stat().st_size > 10_000


@pytest.mark.ros
def test_parameters_that_cannot_be_estimated_stop_the_configure_with_a_reason(graph):
    with pytest.raises(ValueError, match='parameters to leave symbolic must be distinct'):
        graph.add(PlannerNode, namespace=f'/t{uuid.uuid4().hex[:8]}',
                  parameter_overrides=parameters(adapt=['mass']))


@pytest.mark.unit
def test_the_controls_sent_are_averaged_over_each_interval_as_they_were_in_force():
    t, u = np.array([0.0, 0.1, 0.2]), np.array([[1.0], [3.0]])
    assert mean_control(t, u, 0.05, 0.15)[0] == pytest.approx(2.0)
    assert mean_control(t, u, -0.1, 0.1)[0] == pytest.approx(1.0)  # before: the first in force
    assert mean_control(t, u, 0.1, 0.1)[0] == 3.0
    assert mean_control(t, u, 0.15, 0.25) is None  # past the plan: not known
    sent = SentControls()
    assert sent.readings(0.0, 0.1) is None  # nothing sent yet
    sent.sent(0.0, t, u)
    sent.sent(0.05, t, u)  # a replan that agrees
    assert [r[0] for r in sent.readings(0.04, 0.08)] == pytest.approx([1.0, 1.0])
    sent.sent(0.12, np.array([0.12, 0.3]), np.array([[5.0]]))  # one that does not
    # 4 if it reached the robot at once, 3 if one interval late
    assert [r[0] for r in sent.readings(0.1, 0.14)] == pytest.approx([4.0, 3.0])
    assert [r[0] for r in sent.readings(0.25, 0.28)] == pytest.approx([5.0, 5.0])


@pytest.mark.unit
def test_fits_under_both_readings_of_the_controls_are_used_only_when_they_agree():
    def fit(m: float, std: float = 0.001, excited: bool = True) -> ParameterEstimate:
        return ParameterEstimate({'m': m}, {'m': std}, excited, {}, 0, 'excited')

    start = {'m': 1.0}
    both = combined_estimate([fit(0.800), fit(0.804)], 0.01, start)
    assert both.excited and both.values['m'] == pytest.approx(0.802)
    assert both.std['m'] == pytest.approx(0.002)  # half the spread, over each fit's own
    apart = combined_estimate([fit(0.78), fit(0.82)], 0.01, start)
    assert not apart.excited and apart.values == start and 'when the controls' in apart.message
    assert not combined_estimate([fit(0.8), fit(0.8, excited=False)], 0.01, start).excited


@pytest.mark.solve
def test_the_worker_process_answers_says_what_failed_and_stays_closed():
    worker = EstimationWorker()
    answers: list = []
    done = threading.Event()

    def ask(request: list) -> object:
        done.clear()
        worker.submit(request, lambda answer: (answers.append(answer), done.set()))
        assert done.wait(60.0)
        return answers[-1]

    t = np.linspace(0.0, 1.0, 51)
    q = np.column_stack([np.zeros(51), 0.5 + t, np.zeros(51)])  # sliding straight on
    u = np.zeros((50, 2))
    log = {'model': 'chaplygin_sleigh', 't': t, 'q': q, 'u': u, 'names': ['m', 'J']}
    (estimate,) = ask([log])
    assert isinstance(estimate, ParameterEstimate) and not estimate.excited
    failed = ask([{**log, 'names': ['mass']}])
    assert isinstance(failed, ValueError) and 'mass' in str(failed)
    worker.close()
    assert 'closed' in str(ask([log]))
