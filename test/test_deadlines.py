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

"""``max_time`` bounds the whole call: NLP builds, every route, the second look.

Seeded random problems on five kinds of systems no other test draws from (single input,
polar chart, Euler angles, a potential, a coupled metric), each solved by a random method under
a random deadline. Run as a script, it measures how far past its deadline each call returns.
"""
from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np
import pytest

import nh_tracking as nht
from nh_tracking.solvers.cache import await_builds
from systems import coupled_system, euler_ball, inclined_knife_edge, polar_knife, rotor_sleigh

pytestmark = [pytest.mark.solve, pytest.mark.slow]

KINDS = {'rotor_sleigh': rotor_sleigh, 'polar_knife': polar_knife, 'euler_ball': euler_ball,
         'inclined_knife_edge': inclined_knife_edge, 'coupled': coupled_system}


@pytest.fixture(autouse=True)
def builds_done_after_each_test():
    """End the builds a test leaves in the background with it, not in later tests."""
    yield
    assert await_builds(timeout=300.0)


def start_inside(system: nht.NonholonomicSystem, rng: np.random.Generator) -> np.ndarray:
    lo, hi = system.domain.interior(range(system.n), 0.2)
    return np.clip(rng.normal(size=system.n) * np.where(system.angle_mask, 2.0, 1.0), lo, hi)


def random_problem(system: nht.NonholonomicSystem, rng: np.random.Generator
                   ) -> tuple[nht.TrackingProblem, str]:
    """Return a problem whose reference stays in the domain, and a method that takes it."""
    horizon = float(rng.uniform(2.0, 8.0))
    t = np.linspace(0.0, 1.5 * horizon, 151)
    while True:
        q0, v0 = start_inside(system, rng), rng.normal(scale=0.4, size=system.k)
        amplitude, rate = rng.normal(scale=0.5, size=system.r), rng.uniform(0.3, 2.0)
        try:
            reference = nht.simulate(system, q0, v0, t,
                                     lambda s, q, v: amplitude * np.sin(rate * s))
            break
        except (RuntimeError, ValueError):  # left the domain: draw again
            continue
    bounded = rng.random() < 0.4
    speed = np.abs(reference.v).max(axis=0) + 0.1
    offset = system.domain.inside(q0 + rng.normal(scale=0.05, size=system.n), range(system.n))
    problem = nht.TrackingProblem(
        system, reference, offset, v0, horizon=horizon, steps=int(rng.integers(20, 200)),
        terminal='cost', velocity_bounds=(-1.2 * speed, 1.2 * speed) if bounded else None)
    methods = ['variational'] * 3 + ['multiple_shooting'] + ([] if bounded else ['pmp'])
    return problem, str(rng.choice(methods))


def sweep(count: int, seed: int, longest: float, built: bool = False
          ) -> list[tuple[str, str, float, float, bool, str]]:
    """Solve ``count`` random problems; (kind, method, max_time, wall time, success, message).

    ``built``: each problem is solved once first, with a deadline it does not reach, so that the
    measured call finds its NLPs (those built to be stopped) built and spends its time in the
    solve, its routes and the second look.
    """
    rng = np.random.default_rng(seed)
    names = list(KINDS)
    systems = {name: KINDS[name]() for name in names}
    rows = []
    for i in range(count):
        name = names[i % len(names)]
        problem, method = random_problem(systems[name], rng)
        max_time = float(np.exp(rng.uniform(np.log(0.02), np.log(longest))))
        if built:
            nht.solve(problem, method=method, max_time=600.0)
        started = time.perf_counter()
        solution = nht.solve(problem, method=method, max_time=max_time)
        elapsed = time.perf_counter() - started
        if solution.success:
            assert np.isfinite(solution.q).all() and np.isfinite(solution.u).all()
            assert problem.system.domain.contains(solution.q), (name, method)
        else:
            assert solution.message, (name, method)
        rows.append((name, method, max_time, elapsed, solution.success, solution.message))
    return rows


def test_random_problems_on_five_kinds_of_system_return_with_a_verdict():
    rows = sweep(20, seed=3, longest=2.0)
    worst = max(rows, key=lambda row: row[3] / row[2])
    print(f'\n{sum(row[4] for row in rows)} of {len(rows)} solved; latest return '
          f'{worst[3]:.3f} s for max_time {worst[2]:.3f} s ({worst[0]}, {worst[1]})')
    assert len({row[0] for row in rows}) == 5 and len({row[1] for row in rows}) == 3


@pytest.mark.parametrize('method', ['variational', 'multiple_shooting', 'pmp'])
def test_a_call_out_of_time_says_so_even_while_its_nlp_is_being_built(method):
    """A system made for this test has no NLP yet: the build cannot finish in 1 ms."""
    problem, _ = random_problem(rotor_sleigh(J=2.5), np.random.default_rng(7))
    problem = dataclasses.replace(problem, velocity_bounds=None)
    solution = nht.solve(problem, method=method, max_time=1e-3)
    assert not solution.success
    assert 'deadline reached' in solution.message, solution.message


if __name__ == '__main__':
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 100
    for built in (False, True):
        print('NLPs built first' if built else 'NLPs built within the deadline')
        table = sweep(count, seed=11, longest=5.0, built=built)
        for kind, method, limit, took, ok, message in table:
            print(f'{kind:20s} {method:18s} max_time {limit:7.3f} s  returned {took:7.3f} s '
                  f'({took / limit:5.2f}x)  {"solved" if ok else message[:70]}')
        late = np.array([row[3] - row[2] for row in table])
        ratios = np.array([row[3] / row[2] for row in table])
        print(f'worst {ratios.max():.3f}x, latest {1e3 * late.max():.1f} ms past; over +10 %: '
              f'{(ratios > 1.1).sum()} of {len(table)}; solved {sum(r[4] for r in table)}')
