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

"""``nh-tracking demo --adapt``: the sleigh whose real J is 30 % above the model's, m 20 % below.

The same closed loop twice, with and without ``adapt: [m, J]``: the values the planner uses
over time against the truth, and how far each plan's position one second ahead is from where
the robot then was.
"""
from __future__ import annotations

from collections.abc import Callable
import json
from pathlib import Path
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np

from nh_tracking.core.metrics import cross_track_error
from nh_tracking.examples.demo import ClosedLoop, sleigh_reference, START
from nh_tracking.ros.graph import InProcessGraph
from nh_tracking.ros.runner import responsive_threads

TRUTH = {'m': 0.8, 'J': 5.2}
AHEAD = 1.0  # s: how far ahead a plan's prediction is judged


def run_adaptation_demo(out: Path, duration: float = 40.0, time_scale: float = 2.0,
                        log: Callable[[str], None] = print) -> dict:
    """Run both loops for ``duration`` simulated seconds; write adapt.png and adapt.json."""
    from nh_tracking.examples.plotting import plot_adaptation

    out.mkdir(parents=True, exist_ok=True)
    responsive_threads()
    reference = sleigh_reference(duration + 10.0)
    runs = {adapt: _run(adapt, reference, duration, time_scale, log) for adapt in (True, False)}
    summary: dict = {'truth': TRUTH, 'duration': duration}
    for adapt, run in runs.items():
        key = 'adapted' if adapt else 'fixed'
        late = run['prediction_t'] >= 20.0
        summary[key] = {
            'prediction_error_median_after_20s': float(np.median(run['prediction_error'][late])),
            'cross_track_error_max_after_20s': float(run['cross_track'][run['t'] >= 20.0].max()),
            'values_in_use': run['values'][-1][1] if run['values'] else None,
            'diagnostics': run['diagnostics'],
        }
    summary['prediction_error_ratio'] = (
        summary['fixed']['prediction_error_median_after_20s']
        / summary['adapted']['prediction_error_median_after_20s'])
    within = [t for t, values in runs[True]['values']
              if all(abs(values[n] / TRUTH[n] - 1) < 0.05 for n in TRUTH)]
    summary['in_use_within_5_percent_from_s'] = within[0] if within else None
    figure = plot_adaptation(runs, TRUTH, out / 'adapt.png')
    (out / 'adapt.json').write_text(json.dumps(summary, indent=2))
    fixed, adapted = (summary[k]['prediction_error_median_after_20s'] for k in ('fixed',
                                                                                'adapted'))
    log(f'1-s prediction error after 20 s: {fixed:.4f} m fixed, {adapted:.4f} m adapted '
        f"({summary['prediction_error_ratio']:.1f}x); values in use within 5 % from "
        f"t = {summary['in_use_within_5_percent_from_s']} s; wrote {figure}")
    return summary


def _run(adapt: bool, reference, duration: float, time_scale: float,
         log: Callable[[str], None]) -> dict:
    predictions: list[tuple[float, np.ndarray]] = []  # (time predicted for, xy predicted)
    values: list[tuple[float, dict]] = []  # (time, the planner's model's values)
    reported: dict[str, str] = {}  # the planner's last estimate/* diagnostics
    excitation: set[str] = set()  # every excitation it reported

    with InProcessGraph() as graph:
        loop = ClosedLoop(graph, namespace='/adapted' if adapt else '/fixed',
                          planner_overrides={'adapt': list(TRUTH)} if adapt else None,
                          robot=TRUTH)

        def on_diagnostics(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if 'planner' in status.name and status.hardware_id.startswith(loop.namespace):
                    found = {kv.key: kv.value for kv in status.values
                             if kv.key.startswith('estimate/')}
                    reported.update(found)
                    excitation.update(v for k, v in found.items() if k == 'estimate/excitation')

        loop.feeder.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 100)
        loop.start(reference, 'path', time_scale)
        last = None
        wall_limit = time.monotonic() + 60.0 + 4.0 * duration / time_scale
        while loop.sim_time() < START + duration and time.monotonic() < wall_limit:
            time.sleep(0.02)
            session = loop.planner.session
            outcome = session.outcome if session is not None else None
            if session is None or outcome is None or outcome is last:
                continue
            last, plan = outcome, outcome.plan
            times = plan.t + session.epoch_ns * 1e-9  # on the clock odometry is stamped with
            when = times[0] + AHEAD
            if times[-1] >= when:
                predictions.append((when - START, np.array(
                    [np.interp(when, times, plan.q[:, i]) for i in (0, 1)])))
            used = session.system.parameters
            if not values or values[-1][1] != {n: used[n] for n in TRUTH}:
                values.append((loop.sim_time() - START, {n: used[n] for n in TRUTH}))
                log(f"{'adapted' if adapt else 'fixed'}: t = {values[-1][0]:.1f} s, model "
                    f'{values[-1][1]}')
        t, xy = loop.track()
    t = t - START
    when = np.array([w for w, _ in predictions])
    where = np.array([np.interp(when, t, xy[:, i]) for i in (0, 1)]).T
    error = np.linalg.norm(np.array([p for _, p in predictions]) - where, axis=1)
    kept = when <= t[-1]
    return {'t': t, 'cross_track': cross_track_error(xy, reference.q[:, :2]),
            'prediction_t': when[kept], 'prediction_error': error[kept], 'values': values,
            'diagnostics': {**reported, 'excitation reported': sorted(excitation)}}
