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

"""Discs on and across the route through ROS (:mod:`nh_tracking.examples.crossing`)."""
import pytest

pytestmark = [pytest.mark.timeout(240), pytest.mark.ros, pytest.mark.slow]
SCENES = 3  # of test_detours' ten, in its order


def test_a_disc_centred_on_the_route_is_got_past_in_at_most_half_again_the_time(graph):
    from nh_tracking.examples.crossing import drive, Standing
    from test_ros import unique_namespace

    free = drive(graph, lambda start: Standing([]), 6.0, unique_namespace())
    run = drive(graph, lambda start: Standing([(3.0, 0.0, 0.3)]), 6.0, unique_namespace())
    print(f'\na disc centred on the route: arrived after {run.took:.1f} s ({free.took:.1f} s '
          f'without it), closest approach {run.closest[0]:.3f} m, {run.sim.collisions} '
          'collisions counted')
    assert free.arrived and run.arrived and run.took <= 1.5 * free.took
    assert run.closest[0] >= 0.0 and run.sim.collisions == 0 and run.planner.problems.errors == 0


def test_discs_crossing_the_route_are_passed_without_collision_and_the_demo_draws_it(tmp_path):
    """The crossing demo: ten discs crossing the route, each timed to meet the robot."""
    from nh_tracking.examples.crossing import run_crossing_demo

    summary = run_crossing_demo(tmp_path, log=print)
    closest = summary['closest_approach_per_disc']
    assert summary['arrived'] and summary['errors'] == 0
    assert min(closest) >= 0.0 and summary['collisions'] == 0
    assert max(closest) < 1.0  # each crossing met the robot: the test tests something
    assert (tmp_path / 'crossing.png').stat().st_size > 10_000


def test_random_scenes_of_discs_on_and_near_the_route_through_ros(graph):
    """The first three of ``test_detours``' seeded scenes, through the nodes: each arrives.

    3-6 discs within 0.5 m of a 6 m route; no collision in any. The session loop there drives
    all ten (at least 9 arrive); here the nodes' part is checked: obstacles in, detours out.
    """
    import numpy as np

    from nh_tracking.examples.crossing import drive, random_scene
    from test_ros import unique_namespace

    rng, arrived, collisions, closest, took = np.random.default_rng(0), 0, 0, np.inf, []
    for _ in range(SCENES):
        scene = random_scene(rng)
        run = drive(graph, lambda start: scene, 6.0, unique_namespace(), patience=10.0)
        arrived += run.arrived
        collisions += run.sim.collisions
        closest = min(closest, float(run.closest.min()))
        took.append(run.took)
        assert run.planner.problems.errors == 0 and run.sim.problems.errors == 0
        graph.remove(run.planner, run.sim, run.probe)
    print(f'\n{SCENES} scenes of 3-6 discs through ROS: {arrived} arrived '
          f'(in {np.round(took, 1)} s), '
          f'closest approach {closest:+.3f} m, {collisions} collision steps')
    assert arrived == SCENES and collisions == 0 and closest >= 0.0
