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

"""``nh-tracking bench``: how fast and how predictably the planner solves, side by side.

Every figure is measured in the same run on the same machine, against a peer where there is
one (do-mpc for the cold solve, IPOPT for the structure-exploiting fatrop), and written to
``bench.json`` with a plot. Nothing here asserts speed: the acceptance bars are reported.
"""
from __future__ import annotations

from collections.abc import Callable
from functools import partial
import json
from pathlib import Path
import time
from typing import Any, TypeVar

import numpy as np

from nh_tracking import models
from nh_tracking.core.metrics import cross_track_error, percentiles_ms
from nh_tracking.core.simulate import simulate
from nh_tracking.examples.cold import cold_past_a_disc, cold_solve, interleaved
from nh_tracking.examples.experiments import (particle_problem, sleigh_problem,
                                              SLEIGH_REFERENCE_START, SLEIGH_START)
from nh_tracking.planning.receding_horizon import PlannerSettings, RecedingHorizonPlanner
from nh_tracking.problem.tracking_problem import TrackingProblem
from nh_tracking.solvers.compiled import wait_for_builds
from nh_tracking.solvers.midpoint import transcription
from nh_tracking.solvers.pmp import solve_pmp
from nh_tracking.solvers.variational import solve_variational

REPEATS = 9
T = TypeVar('T')


def _median_time(run: Callable[[], T], repeats: int = REPEATS) -> tuple[float, T]:
    """Time ``run`` alone: the median wall time [s] and its last result."""
    times, last = interleaved({'run': run}, repeats)
    return float(np.median(times['run'])), last['run']


# the planner's settings for each mode of the warm replanning row
WARM_MODES: dict[str, dict[str, Any]] = {
    'converged': {},
    'converged, compiled': {'compiled': True},
    'real-time iteration': {'iterations': 1},  # Gauss-Newton steps, factorised by CasADi
    'real-time iteration, compiled': {'iterations': 1, 'compiled': True},  # ... written out, C
}


def warm_replanning(log: Callable[[str], None], rate: float = 100.0, duration: float = 20.0
                    ) -> dict:
    """Run a 20 s closed loop replanned at ``rate`` Hz (deadline one period) in each mode.

    The measured state is that of a robot 10 % heavier than the model; each mode's tracking
    error says what a faster mode costs.
    """
    return {mode: _closed_loop(log, mode, PlannerSettings(max_solve_time=1.0 / rate, **options),
                               rate, duration) for mode, options in WARM_MODES.items()}


def _closed_loop(log: Callable[[str], None], mode: str, settings: PlannerSettings, rate: float,
                 duration: float) -> dict:
    model = models.chaplygin_sleigh()
    real = models.chaplygin_sleigh(J=4.4)
    reference = simulate(model, *SLEIGH_REFERENCE_START, np.linspace(0, duration + 10, 601))
    period = 1.0 / rate
    planner = RecedingHorizonPlanner(model, settings)
    planner.prepare()
    wait_for_builds()  # compiled modes: measured compiled
    planner.set_reference(reference)
    q, v = np.array(SLEIGH_START[0]), np.array(SLEIGH_START[1])
    t, positions = 0.0, []
    while t < duration - 1e-9:
        plan = planner.plan(t, q, v).plan
        i = min(int((t - plan.t[0]) // (plan.t[1] - plan.t[0])), len(plan.u) - 1)
        step = simulate(real, q, v, [t, t + period], plan.u[i][None], rtol=1e-8, atol=1e-10)
        q, v, t = step.q[-1], step.v[-1], t + period
        positions.append(q[:2])
    times = np.array(planner.stats.solve_times)
    planning = np.array(planner.stats.plan_durations)
    error = cross_track_error(np.array(positions), reference.q[:, :2])
    result: dict[str, Any] = {
        'rate_hz': rate, 'solves': int(times.size), **percentiles_ms(times),
        'plan_call_ms': {**percentiles_ms(planning), 'max': float(planning.max() * 1e3)},
        'max_ms': float(times.max() * 1e3), 'deadline_misses': int((planning > period).sum()),
        'fallbacks': planner.stats.fallbacks, 'shifted': planner.stats.shifted,
        'mean_cross_track_error': float(error.mean()),
        'final_cross_track_error': float(error[-100:].max()),
    }
    log(f"  {mode}: {times.size} solves at {rate:g} Hz: p50 {result['p50']:.2f} ms, p99 "
        f"{result['p99']:.2f} ms, max {result['max_ms']:.2f} ms, "
        f"{result['deadline_misses']} deadline misses (whole plan() call: p50 "
        f"{result['plan_call_ms']['p50']:.2f} ms); cross-track error mean "
        f"{result['mean_cross_track_error']:.4f} m, last second "
        f"{result['final_cross_track_error']:.4f} m")
    return result


def scaling(log: Callable[[str], None], sizes=(50, 100, 200, 400, 800)) -> dict:
    """Cold solve time of the paper's sleigh as the horizon is cut finer (T = 5 s)."""
    out: dict[str, Any] = {}
    for n in sizes:
        problem = sleigh_problem(wrap_angles=False, steps=n)
        start = time.perf_counter()
        transcription(problem.system, n, problem.terminal)
        build = time.perf_counter() - start
        median, sol = _median_time(partial(solve_variational, problem), repeats=3)
        out[str(n)] = {'median_s': median, 'build_s': build, 'cost': sol.cost,
                       'iterations': sol.iterations}
        log(f'  N = {n}: {median * 1e3:.1f} ms ({sol.iterations} iterations, built in '
            f'{build:.1f} s), cost {sol.cost:.4f}')
    out['ratio_800_50'] = out[str(sizes[-1])]['median_s'] / out[str(sizes[0])]['median_s']
    return out


def pmp_shooting(log: Callable[[str], None]) -> dict:
    out: dict[str, Any] = {}
    for case in (1, 2):
        problem = particle_problem(case)
        solve_pmp(problem)  # builds the flow once
        median, sol = _median_time(partial(solve_pmp, problem), repeats=3)
        out[f'particle_case{case}'] = {'median_s': median, 'cost': sol.cost, 'route': sol.message}
        log(f'  particle case {case}: {median:.2f} s via {sol.message}, cost {sol.cost:.5f}')
    return out


def limits_cost(log: Callable[[str], None]) -> dict:
    """Cold solve time with limits against the same problem without them (same run)."""
    import dataclasses

    from nh_tracking import solve
    from nh_tracking.examples.obstacles import line_reference

    sleigh = dataclasses.replace(sleigh_problem(wrap_angles=True, terminal='cost'), omega=10.0)
    u_max = 0.5 * np.abs(solve(sleigh, second_look=False).u).max()
    unicycle = TrackingProblem(models.unicycle(), line_reference(10.0),  # 0.3 m off the line
                               np.array([0.0, 0.3, 0.0]), np.array([0.5, 0.0]), 6.0, 60,
                               terminal='cost', omega=10.0)
    cases: dict[str, tuple[TrackingProblem, dict[str, Any]]] = {
        'sleigh |u| <= half its peak': (sleigh, {'control_bounds': (-u_max, u_max)}),
        'unicycle line through a disc': (unicycle, {'obstacles': [(1.5, 0.05, 0.3)],
                                                    'robot_radius': 0.2})}
    out: dict[str, Any] = {}
    for name, (free, limits) in cases.items():
        solves = {label: partial(solve, problem, second_look=False) for label, problem in
                  (('free', free), ('limited', dataclasses.replace(free, **limits)))}
        for run in solves.values():
            run()  # builds its NLP
        times = interleaved(solves, REPEATS)[0]
        out[name] = {label: float(np.median(t)) for label, t in times.items()}
        out[name]['ratio'] = float(np.median(np.divide(times['limited'], times['free'])))
        log(f"  {name}: {out[name]['limited'] * 1e3:.1f} ms vs {out[name]['free'] * 1e3:.1f} "
            f"ms without ({out[name]['ratio']:.2f}x, median of per-round ratios)")
    out['worst_ratio'] = max(v['ratio'] for v in out.values())
    out['replanning'] = _replanning_with_limits(log)
    return out


def _replanning_with_limits(log: Callable[[str], None]) -> dict:
    """Median warm solve in a 16 s closed loop (unicycle, line, 10 Hz) with and without limits."""
    from nh_tracking.examples.obstacles import line_reference

    model, reference = models.unicycle(), line_reference(30.0)
    cases: dict[str, tuple[dict[str, Any], tuple]] = {
        'free': ({}, ()), '|u| <= 0.15': ({'u_min': (-0.15,), 'u_max': (0.15,)}, ()),
        'two discs on the line': ({'robot_radius': 0.2}, ((3.0, 0.05, 0.3), (6.0, -0.05, 0.3))),
        # a corridor, as a costmap's walls come: eight discs beside the line, 0.25 m off it
        'eight discs beside the line': ({'robot_radius': 0.2}, tuple(
            (x, side * 0.75, 0.3) for x in (1.0, 2.5, 4.0, 5.5) for side in (1, -1)))}
    out: dict[str, Any] = {}
    for name, (settings, discs) in cases.items():
        planner = RecedingHorizonPlanner(model, PlannerSettings(horizon=5.0, steps=50,
                                                                **settings))
        planner.obstacles = np.array(discs).reshape(-1, 3)  # known at the start: prepared for
        planner.prepare()
        planner.set_reference(reference)
        q, v, t = np.array([0.0, 0.3, 0.0]), np.array([0.5, 0.0]), 0.0
        while t < 16.0:
            plan = planner.plan(t, q, v).plan
            step = simulate(model, q, v, plan.t[:2], plan.u[:1])
            q, v, t = step.q[-1], step.v[-1], t + 0.1
        out[name] = {**percentiles_ms(np.array(planner.stats.solve_times)),
                     'optimal': planner.stats.optimal, 'plans': planner.stats.plans}
    for name in list(out)[1:]:
        out[name]['ratio'] = out[name]['p50'] / out['free']['p50']
        log(f"  replanning, {name}: p50 {out[name]['p50']:.2f} ms vs {out['free']['p50']:.2f} "
            f"ms without ({out[name]['ratio']:.2f}x)")
    return out


def command_guard_cost(log: Callable[[str], None], calls: int = 500) -> dict:
    """Time the command guard per command [us]: a unicycle with diff_drive.yaml's bounds.

    A ``cmd_vel`` near a costmap wall (600 occupied cells) and 10 marker discs, and a 30-step
    control sequence that keeps to its limits (the replay and its checks), each the median
    over rounds of ``calls`` calls.
    """
    from nh_tracking.planning.command_guard import Clearance, CommandGuard, OccupiedCells
    from nh_tracking.planning.guarded_plan import guard_controls
    from nh_tracking.core.poses import PoseMap

    pose_map = PoseMap(models.unicycle())
    guard = CommandGuard(np.array([[-0.7, -3.0], [0.7, 3.0]]), 0.5, 1.0, 0.2)
    wall = np.c_[np.linspace(-1.0, 5.0, 600), np.full(600, 0.6)]
    rng = np.random.default_rng(0)
    discs = np.c_[rng.uniform(-3, 3, (10, 2)) + [0, 3], np.full(10, 0.2)]
    clearance = Clearance(discs, OccupiedCells(wall, 0.05))
    q, v = np.array([0.0, 0.0, 0.2]), np.array([0.5, 0.4])

    def commands() -> None:
        for _ in range(calls):
            guard.velocity(v, pose_map.twist_matrix(q), v, 0.05, pose_map.pose(q), clearance,
                           0.06)

    sequence = np.zeros((30, 2))  # v held: inside the bounds

    def sequences() -> None:
        for _ in range(calls // 10):
            guard_controls(guard, pose_map, q, v, sequence, np.full(30, 0.1), 0.1, clearance)

    per_command = _median_time(commands)[0] / calls * 1e6
    per_sequence = _median_time(sequences)[0] / (calls // 10) * 1e6
    log(f'  command guard: {per_command:.0f} us a cmd_vel, {per_sequence:.0f} us a control '
        'sequence (30 steps) that keeps to its limits')
    return {'cmd_vel_us': per_command, 'control_sequence_us': per_sequence}


def run_bench(out: Path, log: Callable[[str], None] = print, ros: bool = True) -> dict:
    """All sections, in one run; writes bench.json and bench.png."""
    from nh_tracking.examples.plotting import plot_bench

    out.mkdir(parents=True, exist_ok=True)
    sections: list[tuple[str, Callable[[], dict]]] = [
        ('cold_solve', lambda: cold_solve(log)),
        ('warm_replanning', lambda: warm_replanning(log)),
        ('scaling', lambda: scaling(log)),
        ('pmp_shooting', lambda: pmp_shooting(log)),
        ('limits', lambda: limits_cost(log)),
        ('cold_disc', lambda: cold_past_a_disc(log)),
        ('command_guard', lambda: command_guard_cost(log)),
    ]
    if ros:
        from nh_tracking.examples.crossing import obstacle_scenes
        from nh_tracking.examples.fleet import fleet
        from nh_tracking.examples.latency import deployed_latency, ros_latency
        sections += [('ros_latency', lambda: ros_latency(log)),
                     ('ros_latency_deployed', lambda: deployed_latency(log)),
                     ('fleet', lambda: fleet(log)),
                     ('obstacle_scenes', lambda: obstacle_scenes(log))]
    results: dict[str, dict] = {}
    for i, (name, run) in enumerate(sections, 1):
        log(f'[{i}/{len(sections)}] {name}')
        results[name] = run()
    results['acceptance'] = acceptance(results)
    (out / 'bench.json').write_text(json.dumps(results, indent=2, default=float))
    plot_bench(results, out / 'bench.png')
    for name, verdict in results['acceptance'].items():
        log(f"  {'PASS' if verdict['pass'] else 'FAIL'} {name}: {verdict['value']}")
    return results


def acceptance(results: dict) -> dict:
    """Return the project's performance targets, each judged on this run's figures."""
    verdicts = {}
    cold = results.get('cold_solve', {})
    if cold.get('do_mpc'):
        ratio = cold['do_mpc']['speedup']
        low, high = cold['do_mpc']['speedup_quartiles']
        verdicts['cold solve >= 10x faster than do-mpc (default settings)'] = {
            'value': f'{ratio:.1f}x (median of per-round ratios; quartiles {low:.1f}-{high:.1f}x)',
            'pass': ratio >= 10}
    for section, peer, bar in (('cold', 'rockit_fatrop', 3), ('warm', 'do_mpc', 20),
                               ('warm', 'rockit_fatrop', 3)):
        measured = (cold if section == 'cold' else cold.get('warm', {})).get(peer)
        if measured:
            verdicts[f'{section} solve >= {bar}x faster than {peer} (public API, defaults)'] = {
                'value': f"{measured['speedup']:.1f}x", 'pass': measured['speedup'] >= bar}
    for mode, warm in results.get('warm_replanning', {}).items():
        call = warm['plan_call_ms']  # the planner call's wall clock, not the solver's own
        verdicts[f'warm plan() p50 <= 0.5 ms, p99 <= 2 ms, no misses at 100 Hz ({mode})'] = {
            'value': f"p50 {call['p50']:.2f} ms, p99 {call['p99']:.2f} ms, "
                     f"{warm['deadline_misses']} misses",
            'pass': call['p50'] <= 0.5 and call['p99'] <= 2 and warm['deadline_misses'] == 0}
    disc = results.get('cold_disc', {}).get('rockit_fatrop')
    if disc:
        verdicts['cold solve past a disc on the reference <= 0.1x rockit + fatrop'] = {
            'value': f"{1 / disc['speedup']:.2f}x its time ({disc['speedup']:.1f}x faster)",
            'pass': disc['speedup'] >= 10}
    scale = results.get('scaling')
    if scale:
        verdicts['t(N=800)/t(N=50) <= 16'] = {'value': f"{scale['ratio_800_50']:.1f}",
                                              'pass': scale['ratio_800_50'] <= 16}
    limits = results.get('limits')
    if limits:
        warm = limits['replanning']
        worst_warm = max(v['ratio'] for k, v in warm.items() if k != 'free')
        verdicts['solve time with limits <= 2x without'] = {
            'value': f"cold {limits['worst_ratio']:.2f}x, replanning {worst_warm:.2f}x "
                     f"(bounds {warm['|u| <= 0.15']['ratio']:.2f}x)",
            'pass': limits['worst_ratio'] <= 2 and worst_warm <= 2}
    ros, deployed = results.get('ros_latency'), results.get('ros_latency_deployed')
    if ros and deployed:
        verdicts['ROS odom -> control_sequence p50 <= 1.5 ms'] = {
            'value': f"deployed {deployed['latency_ms']['p50']:.2f} ms; in one process with "
                     f"the odometry's source {ros['latency_ms']['p50']:.2f} ms, of which "
                     f"{ros['overhead_ms']['p50']:.2f} ms beyond the numerical planner",
            'pass': deployed['latency_ms']['p50'] <= 1.5}
    scenes = results.get('obstacle_scenes')
    if scenes:
        free, centred = scenes['free'], scenes['centred']
        verdicts['a disc centred on the route: at the end in <= 1.5x the time without'] = {
            'value': f"{centred['took_s']:.1f} s vs {free['took_s']:.1f} s, "
                     f"{centred['collisions']} collisions",
            'pass': free['arrived'] and centred['arrived'] and centred['collisions'] == 0
            and centred['took_s'] <= 1.5 * free['took_s']}
        arrived = sum(scene['arrived'] for scene in scenes['scenes'])
        hits = sum(scene['collisions'] for scene in scenes['scenes'])
        verdicts['random scenes of 3-6 discs: >= 90 % arrive, 0 collisions'] = {
            'value': f"{arrived} of {len(scenes['scenes'])} arrived, {hits} collisions",
            'pass': arrived >= 0.9 * len(scenes['scenes']) and hits == 0}
        crossing = scenes['crossing']
        verdicts['discs crossing the route: 0 collisions, the robot arrives'] = {
            'value': f"arrived {crossing['late_s']:+.1f} s after the reference, closest "
                     f"{crossing['closest_m']:.3f} m, {crossing['collisions']} collisions",
            'pass': crossing['arrived'] and crossing['collisions'] == 0}
    crowd = results.get('fleet')
    if crowd:
        verdicts['fleet figure (reported, no bar)'] = {
            'value': f"{crowd['largest_without_misses']} robots at 10 Hz without a miss on "
                     f"{crowd['cores']} cores", 'pass': True}
    return verdicts
