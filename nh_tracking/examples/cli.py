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

"""``nh-tracking``: the command line (simulate a model, and later reproduce, demo, bench)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys

import numpy as np

from nh_tracking import models
from nh_tracking.core.simulate import simulate
from nh_tracking.examples.plotting import plot_simulation


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.replace(',', ' ').split()]


def _param(text: str) -> tuple[str, float]:
    name, _, value = text.partition('=')
    if not _ or not name:
        raise argparse.ArgumentTypeError(f'expected NAME=VALUE, got {text!r}')
    return name, float(value)


def cmd_simulate(args: argparse.Namespace) -> int:
    """Free (or constant-control) motion of a model; writes a PNG and a JSON summary."""
    spec = models.spec(args.model)
    system = spec.create(**dict(args.param))
    start = spec.start or ((0.0,) * system.n, (1.0,) * system.k)
    q0 = args.q0 if args.q0 is not None else start[0]
    v0 = args.v0 if args.v0 is not None else start[1]
    t = np.linspace(0.0, args.duration, args.steps + 1)
    u = np.tile(args.u, (args.steps, 1)) if args.u is not None else None
    traj = simulate(system, q0, v0, t, u)
    energy = np.array([system.energy(q, v) for q, v in zip(traj.q, traj.v)])
    residual = max(np.abs(system.constraints(q) @ system.dynamics(q, v)[0]).max(initial=0.0)
                   for q, v in zip(traj.q, traj.v))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    figure = plot_simulation(system, traj, out / 'simulation.png')
    summary = {
        'model': system.name, 'parameters': system.parameters, 'duration': args.duration,
        'q_final': traj.q[-1].tolist(), 'v_final': traj.v[-1].tolist(),
        'energy_initial': float(energy[0]),
        'energy_drift_max': float(np.abs(energy - energy[0]).max()),
        'constraint_residual_max': float(residual),
    }
    (out / 'simulation.json').write_text(json.dumps(summary, indent=2))
    print(f'{system.name}: simulated {args.duration:g} s; final q = '
          f'{np.array2string(traj.q[-1], precision=4)}; energy drift '
          f"{summary['energy_drift_max']:.2e}; constraint residual {residual:.1e}")
    print(f"wrote {figure} and {out / 'simulation.json'}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Re-run the paper's experiments (particle cases 1-2, the sleigh literal and wrapped)."""
    from nh_tracking.examples.experiments import reproduce

    out = Path(args.out)
    metrics = reproduce(out, log=lambda line: print(line, flush=True))
    s, w = metrics['sleigh'], metrics['sleigh_wrapped']
    print(f"sleigh cost {s['cost']:.4f} (paper prototype 42.369), wrapped {w['cost']:.4f}; "
          f"particle PMP {metrics['particle_case1']['pmp_cost']:.4f} / "
          f"{metrics['particle_case2']['pmp_cost']:.4f}")
    print(f"wrote {out / 'metrics.json'} and figures in {out}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the closed loop through ROS.

    Scenario sleigh: planner + simulator (10 % heavier) on the paper's sleigh. Scenario
    obstacles: a differential-drive robot on a line through two obstacles, torques limited.
    Scenario nav2: a differential-drive robot given a follow_path goal as Nav2 sends it.
    Scenario crossing: a differential-drive robot on a line that ten moving discs cross.
    With --adapt: the sleigh learns its robot's m and J while tracking it.
    """
    def log(line: str) -> None:
        print(line, flush=True)

    if args.scenario == 'nav2':
        from nh_tracking.examples.nav2 import run_nav2_demo

        result = run_nav2_demo(Path(args.out), log=log)
        return 0 if result['error_code'] == 0 else 1
    if args.scenario == 'crossing':
        from nh_tracking.examples.crossing import run_crossing_demo

        result = run_crossing_demo(Path(args.out), log=log)
        return 0 if result['arrived'] and result['collisions'] == 0 else 1
    if args.scenario == 'obstacles':
        from nh_tracking.examples.obstacles import run_obstacle_demo

        result = run_obstacle_demo(Path(args.out), duration=args.duration or 25.0,
                                   kind=args.obstacles, log=log)
        return 0 if result['collisions'] == 0 and result['cross_track_error_last_3s'] < 0.05 \
            else 1
    if args.adapt:
        from nh_tracking.examples.adapting import run_adaptation_demo

        outcome = run_adaptation_demo(Path(args.out), duration=args.duration or 40.0,
                                      log=log)
        return 0 if outcome['prediction_error_ratio'] >= 5 else 1
    from nh_tracking.examples.demo import run_demo

    summary = run_demo(Path(args.out), duration=args.duration or 15.0,
                       reference_kind=args.reference, time_scale=args.time_scale, log=log)
    return 0 if summary['final_cross_track_error'] < 0.05 else 1


def cmd_bench(args: argparse.Namespace) -> int:
    """Solve times side by side with do-mpc; warm replanning; scaling; PMP; ROS latency."""
    from nh_tracking.examples.bench import run_bench

    run_bench(Path(args.out), log=lambda line: print(line, flush=True), ros=not args.no_ros)
    print(f"wrote {Path(args.out) / 'bench.json'} and {Path(args.out) / 'bench.png'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='nh-tracking',
        description='Optimal trajectory tracking for nonholonomic mechanical systems.')
    sub = parser.add_subparsers(dest='command', required=True)
    sim = sub.add_parser('simulate', help='simulate a built-in model and plot it',
                         description=cmd_simulate.__doc__)
    sim.add_argument('--model', default='chaplygin_sleigh',
                     help=f"built-in ({', '.join(models.MODELS)}) or package.module:attribute")
    sim.add_argument('--param', type=_param, action='append', default=[],
                     metavar='NAME=VALUE', help='a physical parameter of the model (repeatable)')
    sim.add_argument('--q0', type=_floats, help="initial configuration (default: paper's sleigh)")
    sim.add_argument('--v0', type=_floats, help='initial quasi-velocities')
    sim.add_argument('--u', type=_floats, help='constant control (default: none)')
    sim.add_argument('--duration', type=float, default=10.0)
    sim.add_argument('--steps', type=int, default=400)
    sim.add_argument('--out', default='results/simulate')
    sim.set_defaults(func=cmd_simulate)
    rep = sub.add_parser('reproduce', help="re-run the paper's experiments",
                         description=cmd_reproduce.__doc__)
    rep.add_argument('--out', default='results/reproduce')
    rep.set_defaults(func=cmd_reproduce)
    demo = sub.add_parser('demo', help='closed-loop tracking through ROS (the main job)',
                          description=cmd_demo.__doc__)
    demo.add_argument('--out', default='results/demo')
    demo.add_argument('--scenario', choices=('sleigh', 'obstacles', 'nav2', 'crossing'),
                      default='sleigh',
                      help="the paper's sleigh, a line through two obstacles with torque "
                           'limits, a follow_path goal with an untimed route, or discs '
                           'crossing a line')
    demo.add_argument('--obstacles', choices=('markers', 'costmap'), default='markers',
                      help='obstacles scenario: send them as MarkerArray or OccupancyGrid')
    demo.add_argument('--adapt', action='store_true',
                      help="sleigh: the robot's J 30 %% above the model's, m 20 %% below, with "
                           'and without online estimates of them (adapt.png)')
    demo.add_argument('--duration', type=float, default=None,
                      help='simulated seconds (default 15, obstacles 25)')
    demo.add_argument('--reference', choices=('path', 'trajectory'), default='path',
                      help='send the reference as nav_msgs/Path or MultiDOFJointTrajectory')
    demo.add_argument('--time-scale', type=float, default=4.0,
                      help='simulated seconds per wall second')
    demo.set_defaults(func=cmd_demo)
    bench = sub.add_parser('bench', help="benchmark the solvers (do-mpc: pip install '.[bench]')",
                           description=cmd_bench.__doc__)
    bench.add_argument('--out', default='results/bench')
    bench.add_argument('--no-ros', action='store_true', help='skip the ROS latency section')
    bench.set_defaults(func=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, RuntimeError) as exc:
        print(f'nh-tracking {args.command}: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
