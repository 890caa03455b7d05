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

"""Cold solves side by side: ours and the peers, timed in the same interleaved rounds."""
from __future__ import annotations

from collections.abc import Callable, Mapping
import dataclasses
from functools import partial
import time
from typing import Any, TypeVar

import numpy as np

from nh_tracking import models
from nh_tracking.core.simulate import simulate
from nh_tracking.examples import peers
from nh_tracking.examples.experiments import sleigh_problem
from nh_tracking.problem.tracking_problem import TrackingProblem
from nh_tracking.solvers import solve
from nh_tracking.solvers.compiled import wait_for_builds
from nh_tracking.solvers.midpoint import transcription
from nh_tracking.solvers.variational import solve_variational

COLD_ROUNDS = 21  # each round times every tool once
WARM_OFFSET = 1e-2  # a warm re-solve's start, moved from the last plan's
T = TypeVar('T')


def interleaved(solves: Mapping[str, Callable[[], T]], rounds: int
                ) -> tuple[dict[str, list[float]], dict[str, T]]:
    """Time every solve once per round, in an order that rotates from round to round.

    This machine's speed drifts by +-30 % within a minute: timed one tool after the other, a
    ratio of two medians moved between 8.6x and 15.4x from run to run with neither tool changed.
    Within a round the tools share the machine's state, so the round's ratio is the fair one.
    Returns each one's times [s] and its last result.
    """
    names = list(solves)
    times: dict[str, list[float]] = {name: [] for name in names}
    results: dict[str, T] = {}
    for r in range(rounds):
        for name in names[r % len(names):] + names[:r % len(names)]:
            start = time.perf_counter()
            results[name] = solves[name]()
            times[name].append(time.perf_counter() - start)
    return times, results


def _ours(problem: TrackingProblem, solver: str, compiled: bool, newton: bool
          ) -> tuple[float, int | None]:
    """Run one NLP route of ours alone: its cost and iterations (a peer says its objective)."""
    solution = solve_variational(problem, solver=solver, compiled=compiled, newton=newton)
    return solution.cost, solution.iterations


def _public(problem: TrackingProblem) -> tuple[float, int | None]:
    """Run ``nht.solve`` as a user calls it, with its default settings."""
    solution = solve(problem)
    return solution.cost, solution.iterations


def _theirs(solve: Callable[[], float]) -> tuple[float, int | None]:
    """Run a peer's cold solve: its objective (it does not say its iterations)."""
    return solve(), None


def cold_solve(log: Callable[[str], None]) -> dict:
    """Time the paper's sleigh (literal angles, N = 50) from each tool's default guess.

    Ours as users call it (``nht.solve`` with default settings), each of its routes alone
    (Newton steps with a line search) and the NLP solvers alone:
    fatrop interpreted and compiled, IPOPT; the peers as their users write them
    (:mod:`.peers`). Solvers are built once beforehand (set-up reported apart); then
    all of them are timed in the same rounds (:func:`interleaved`) and a peer's speed-up is the
    median of its per-round ratios to ours, with their spread.
    """
    problem = sleigh_problem(wrap_angles=False)
    solves: dict[str, Callable[[], tuple[float, int | None]]] = {}  # -> cost, iterations
    built: dict[str, float] = {}
    solves['variational'] = partial(_public, problem)  # ours: the public call, defaults
    start = time.perf_counter()
    solves['variational']()  # (builds what the first call builds)
    built['variational'] = time.perf_counter() - start
    for name, solver, compiled, newton in (
            ('variational_newton', 'fatrop', False, True),
            ('variational_fatrop', 'fatrop', False, False),
            ('variational_fatrop_compiled', 'fatrop', True, False),
            ('variational_ipopt', 'ipopt', False, False)):
        start = time.perf_counter()
        transcription(problem.system, problem.steps, problem.terminal, False, solver, compiled)
        wait_for_builds()
        solves[name] = partial(_ours, problem, solver, compiled, newton)
        solves[name]()  # (builds what the first solve builds: the Newton step)
        built[name] = time.perf_counter() - start
    contenders = _peers(problem, log)
    for name, contender in contenders.items():
        solves[name] = partial(_theirs, contender.solve)
        built[name] = contender.build_s
    out = _compared(solves, built, list(contenders), log)
    out['warm'] = _warm_resolve(problem, contenders, log)
    return out


DISC = (1.5, 0.0, 0.3)  # x, y, r [m]: centred on the unicycle's line


def cold_past_a_disc(log: Callable[[str], None]) -> dict:
    """Time cold solves whose reference runs through a disc; which way round each tool goes.

    A unicycle on a straight line at 0.5 m/s through a 0.3 m disc centred on it (robot radius
    0.2 m, 6 s, N = 60, terminal cost): ours as users call it (``nht.solve``, defaults), the
    peers from their default guesses, timed in the same rounds.
    """
    unicycle = models.unicycle()
    line = simulate(unicycle, np.zeros(3), [0.5, 0.0], np.linspace(0.0, 10.0, 101))
    problem = TrackingProblem(unicycle, line, np.zeros(3), np.array([0.5, 0.0]), 6.0, 60,
                              terminal='cost', omega=10.0, obstacles=[DISC], robot_radius=0.2)
    plans = [solve(problem)]  # (builds what the first call builds)

    def ours() -> tuple[float, int | None]:
        plans[0] = solve(problem)
        return plans[0].cost, plans[0].iterations

    contenders = _peers(problem, log)
    solves: dict[str, Callable[[], tuple[float, int | None]]] = {'variational': ours}
    solves.update({name: partial(_theirs, c.solve) for name, c in contenders.items()})
    out = _compared(solves, {'variational': 0.0, **{n: c.build_s for n, c in contenders.items()}},
                    list(contenders), log)
    paths = {'variational': lambda: plans[0].q[:, :2],
             **{n: c.positions for n, c in contenders.items() if c.positions is not None}}
    for name, path in paths.items():
        out[name]['side'] = _side(path())
        log(f"  {name} {out[name]['side']}")
    return out


def _side(positions: np.ndarray) -> str:
    """Say on which side of the direction of travel (+x) a plan passes DISC, if it does."""
    if positions[:, 0].max() < DISC[0]:
        return 'stops short of it'
    beside = positions[np.argmin(np.abs(positions[:, 0] - DISC[0])), 1] - DISC[1]
    return 'passes it on the ' + ('left' if beside > 0 else 'right')


def _peers(problem: TrackingProblem, log: Callable[[str], None]) -> dict[str, peers.Contender]:
    """Return the peers installed, set up for ``problem``."""
    contenders = {}
    for name, peer in (('do_mpc', peers.dompc), ('opti_ipopt_ms', peers.opti_multiple_shooting),
                       ('rockit_fatrop', peers.rockit_fatrop)):
        try:
            contenders[name] = peer(problem)
        except ImportError:
            log(f'  {name} not installed (scripts/bench.sh installs it): comparison skipped')
    return contenders


def _compared(solves: dict[str, Callable[[], tuple[float, int | None]]],
              built: dict[str, float], peer_names: list[str], log: Callable[[str], None]
              ) -> dict[str, Any]:
    """Time ``solves`` in interleaved rounds; each peer's speed-up against 'variational'."""
    times, results = interleaved(solves, COLD_ROUNDS)
    out: dict[str, Any] = {'rounds': COLD_ROUNDS, 'do_mpc': None, 'opti_ipopt_ms': None,
                           'rockit_fatrop': None}
    for name, (cost, iterations) in results.items():
        out[name] = {'median_s': float(np.median(times[name])), 'cost': cost,
                     'iterations': iterations, 'build_s': built[name]}
        log(f"  {name}: {out[name]['median_s'] * 1e3:.2f} ms, cost {cost:.4f} "
            f'(set up in {built[name]:.1f} s)')
    ours = np.array(times['variational'])
    for name in peer_names:
        ratios = np.array(times[name]) / ours
        out[name].update(speedup=float(np.median(ratios)),
                         speedup_quartiles=np.percentile(ratios, [25, 75]).tolist())
        log(f"  {name}: ours (default settings) is {out[name]['speedup']:.1f}x faster "
            f"(median of {COLD_ROUNDS} rounds' ratios; quartiles "
            f"{out[name]['speedup_quartiles'][0]:.1f}-{out[name]['speedup_quartiles'][1]:.1f}x)")
    return out


def _warm_resolve(problem: TrackingProblem, contenders: dict[str, peers.Contender],
                  log: Callable[[str], None]) -> dict[str, Any]:
    """Re-solve from each tool's last plan, the start moved by +-1e-2 in turn.

    Ours: ``nht.solve(moved, initial_guess=last)``, default settings.
    """
    log('  warm re-solve (start moved by +-1e-2 from the last plan, in turn):')
    n, last = problem.system.n, [solve(problem)]

    def ours(offset: np.ndarray) -> float:
        moved = dataclasses.replace(problem, q0=problem.q0 + offset[:n],
                                    v0=problem.v0 + offset[n:])
        last[0] = solve(moved, initial_guess=last[0])
        return last[0].cost

    warm = {'variational': ours, **{name: c.warm for name, c in contenders.items()
                                    if c.warm is not None}}
    solves = {name: _alternating(run, n + problem.system.k) for name, run in warm.items()}
    for run in solves.values():
        run()  # each from its own last solution from here on
    return _compared(solves, dict.fromkeys(solves, 0.0), list(solves)[1:], log)


def _alternating(warm: Callable[[np.ndarray], float], size: int
                 ) -> Callable[[], tuple[float, int | None]]:
    """Call ``warm`` with the start moved by +WARM_OFFSET, then -WARM_OFFSET, and so on."""
    sign = [1.0]

    def run() -> tuple[float, int | None]:
        sign[0] = -sign[0]
        return warm(np.full(size, WARM_OFFSET * sign[0])), None
    return run
