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

"""The paper's experiments (§4 particle cases, §5 sleigh), as problems and as a reproduction.

The set-ups live here once, so the ``reproduce`` command, the tests and the benchmarks all use
the same numbers.
"""
from __future__ import annotations

from collections.abc import Callable
import json
from pathlib import Path
import time

import numpy as np

from nh_tracking import models
from nh_tracking.core.simulate import simulate
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.examples.plotting import plot_energy, plot_tracking
from nh_tracking.problem.tracking_problem import running_cost_profile, Terminal, TrackingProblem
from nh_tracking.solvers import solve

SLEIGH_START = ([0.0, 0.0, 4 * np.pi / 3], [0.25, 1.0])  # gamma(0) of §5
SLEIGH_REFERENCE_START = ([0.0, 0.5, 0.0], [1 / 3, 1.0])  # the uncontrolled reference's start


def sleigh_reference(duration: float = 6.0, dt: float = 0.025) -> Trajectory:
    """Return the paper's reference: the uncontrolled sleigh (m = 1, J = 4, a = 0.2)."""
    sleigh = models.chaplygin_sleigh()
    t = np.linspace(0.0, duration, int(round(duration / dt)) + 1)
    return simulate(sleigh, *SLEIGH_REFERENCE_START, t)


def sleigh_problem(wrap_angles: bool = False, terminal: Terminal = 'equality',
                   steps: int = 50) -> TrackingProblem:
    """§5: h = 0.1, N = 50, T = 5, eps = 1.

    ``wrap_angles=False`` is the paper's literal formulation (heading error 4 pi/3, so the sleigh
    backs up and turns the long way).
    """
    q0, v0 = (np.asarray(x) for x in SLEIGH_START)
    return TrackingProblem(models.chaplygin_sleigh(), sleigh_reference(), q0, v0,
                           horizon=5.0, steps=steps, epsilon=1.0, terminal=terminal,
                           wrap_angles=wrap_angles)


def _constant_velocity_reference(q_of_t: Callable[[np.ndarray], np.ndarray],
                                 v: tuple[float, float]):
    def reference(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        return q_of_t(t), np.tile(v, (len(t), 1))
    return reference


PARTICLE_CASES = {
    # gamma(0) = (q; v), reference (x, y, z)(t) with v_r = (0, 1), T, eps (omega = 1)
    1: ([2.0, 3.0, 2.0], [0.5, 0.4], lambda t: np.stack([-t, np.ones_like(t), t], 1), 5.0, 9.0),
    2: ([0.5, 0.2, 0.7], [0.5, 0.4],
        lambda t: np.stack([np.ones_like(t), np.zeros_like(t), t + 1], 1), 4.0, 7.0),
}


def particle_problem(case: int, h: float = 0.1) -> TrackingProblem:
    """§4 particle, cases 1 and 2: terminal cost omega Phi with omega = 1."""
    q0, v0, q_ref, horizon, eps = PARTICLE_CASES[case]
    return TrackingProblem(models.nonholonomic_particle(),
                           _constant_velocity_reference(q_ref, (0.0, 1.0)), np.asarray(q0),
                           np.asarray(v0),
                           horizon=horizon, steps=int(round(horizon / h)), epsilon=eps,
                           terminal='cost', omega=1.0)


def replay(problem: TrackingProblem, controls: np.ndarray, samples_per_step: int = 1,
           method: str = 'DOP853') -> Trajectory:
    """Replay the plan's controls, held per interval, on the continuous dynamics."""
    fine = problem.start + np.linspace(0.0, problem.horizon,
                                       problem.steps * samples_per_step + 1)
    return simulate(problem.system, problem.q0, problem.v0, fine,
                    np.repeat(controls, samples_per_step, axis=0), method=method)


def _sleigh_metrics(problem: TrackingProblem, out: Path, name: str, log) -> dict:
    sol = solve(problem, 'variational')
    log(f'  variational: cost {sol.cost:.4f}, {sol.iterations} iterations, '
        f'{sol.solve_time * 1e3:.0f} ms')
    replayed = replay(problem, sol.u)
    fine = replay(problem, sol.u, samples_per_step=20, method='RK45')
    others = {m: solve(problem, m) for m in ('multiple_shooting', 'pmp')}
    for m, s in others.items():
        log(f"  {m}: cost {s.cost:.4f} ({'ok' if s.success else 'FAILED'}"
            f"{', route ' + s.message if m == 'pmp' else ''})")
    search = solve(problem, 'variational', starts=40)
    log(f'  40 starts: distinct minima {[round(c, 2) for c, _ in search.minima]}')
    plot_tracking(problem, sol, running_cost_profile(problem, sol), out / f'{name}.png', name)
    plot_energy(problem.system, sol, fine, out / f'{name}_energy.png')
    return {
        'cost': sol.cost, 'terminal_error': sol.terminal_error,
        'admissibility_residual': sol.details['admissibility_residual'],
        'replay_end_error': float(np.linalg.norm(
            np.hstack([replayed.q[-1] - sol.q[-1], replayed.v[-1] - sol.v[-1]]))),
        'iterations': sol.iterations, 'solve_time': sol.solve_time,
        'multiple_shooting_cost': others['multiple_shooting'].cost,
        'pmp_cost': others['pmp'].cost, 'pmp_route': others['pmp'].message,
        'local_minima': [c for c, _ in search.minima],
        'minima_counts': [n for _, n in search.minima],
    }


def _particle_metrics(case: int, out: Path, log) -> dict:
    problem = particle_problem(case)
    pmp = solve(problem, 'pmp')
    log(f'  pmp: cost {pmp.cost:.5f} via {pmp.message} ({pmp.solve_time:.2f} s)')
    var = solve(problem, 'variational')
    log(f'  variational: cost {var.cost:.5f} ({var.solve_time * 1e3:.0f} ms)')
    name = f'particle_case{case}'
    plot_tracking(problem, var, running_cost_profile(problem, var), out / f'{name}.png', name,
                  compare=pmp)
    return {
        'pmp_cost': pmp.cost, 'pmp_success': pmp.success, 'pmp_route': pmp.message,
        'variational_cost': var.cost, 'variational_terminal_error': var.terminal_error,
        'relative_difference': abs(pmp.cost - var.cost) / var.cost,
    }


def reproduce(out: Path, log: Callable[[str], None] = print) -> dict:
    """Re-run the paper's experiments, write figures and ``metrics.json`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    metrics: dict[str, dict] = {}
    steps = [
        ('particle_case1', lambda: _particle_metrics(1, out, log)),
        ('particle_case2', lambda: _particle_metrics(2, out, log)),
        ('sleigh', lambda: _sleigh_metrics(sleigh_problem(False), out, 'sleigh', log)),
        ('sleigh_wrapped', lambda: _sleigh_metrics(sleigh_problem(True), out,
                                                   'sleigh_wrapped', log)),
    ]
    for i, (name, run) in enumerate(steps, 1):
        log(f'[{i}/{len(steps)}] {name}')
        start = time.perf_counter()
        metrics[name] = run()
        log(f'  done in {time.perf_counter() - start:.1f} s')
    (out / 'metrics.json').write_text(json.dumps(metrics, indent=2, default=float))
    return metrics
