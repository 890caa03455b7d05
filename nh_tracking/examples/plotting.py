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

"""PNG figures of trajectories, for people to look at.

Figures are matplotlib ``Figure`` objects drawn straight to PNG: no pyplot, so importing this
module neither picks a GUI backend nor changes the one a user's program has chosen.
"""
from __future__ import annotations

from pathlib import Path
from typing import Protocol

from matplotlib.figure import Figure
import numpy as np

from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.core.trajectory import Trajectory


def _subplots(*grid: int, figsize: tuple[float, float]):
    """(figure, axes) like pyplot.subplots, without pyplot's global state."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*grid)


def _finish(fig, path: Path, dpi: int = 100) -> Path:
    """Grid on every 2-D axis, tight layout, write the PNG, free the figure."""
    for ax in fig.axes:
        if ax.name != '3d':
            ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return path


def plot_simulation(system: NonholonomicSystem, traj: Trajectory, path: Path) -> Path:
    """Path in the plane of the first two coordinates, quasi-velocities, and energy drift."""
    energy = np.array([system.energy(q, v) for q, v in zip(traj.q, traj.v)])
    fig, axes = _subplots(1, 3, figsize=(15, 4.5))
    ax = axes[0]
    ax.plot(traj.q[:, 0], traj.q[:, 1], lw=2)
    ax.plot(*traj.q[0, :2], 'go', label='start')
    ax.plot(*traj.q[-1, :2], 'rs', label='end')
    ax.set(xlabel=system.coordinates[0], ylabel=system.coordinates[1], aspect='equal',
           title=f'{system.name}: path')
    ax.legend()
    for a, name in enumerate(system.velocity_names):
        axes[1].plot(traj.t, traj.v[:, a], label=name)
    axes[1].set(xlabel='t [s]', ylabel='v (adapted basis)', title='quasi-velocities')
    axes[1].legend()
    axes[2].plot(traj.t, energy - energy[0])
    axes[2].set(xlabel='t [s]', ylabel='E(t) - E(0)', title=f'energy drift (E0 = {energy[0]:.4g})')
    return _finish(fig, path, dpi=110)


def plot_tracking(problem, solution, running: np.ndarray, path: Path, title: str,
                  compare=None) -> Path:
    """Plot a plan against its reference.

    The path in 2-D and with the third coordinate as height, the controls, and the running action h
    L per interval with the accumulated cost.
    """
    system = problem.system
    t_fine = np.linspace(problem.grid[0], problem.grid[-1], 400)
    q_ref, _ = problem.reference_at(t_fine)
    names = system.coordinates
    fig = Figure(figsize=(15, 9))
    ax = fig.add_subplot(2, 2, 1)
    ax.plot(q_ref[:, 0], q_ref[:, 1], 'k--', label='reference')
    ax.plot(solution.q[:, 0], solution.q[:, 1], 'o-', ms=3, label=solution.method)
    if compare is not None:
        ax.plot(compare.q[:, 0], compare.q[:, 1], '-', alpha=0.7, label=compare.method)
    ax.plot(*problem.q0[:2], 'gs', label='start')
    ax.set(xlabel=names[0], ylabel=names[1], title=f'{title}: path', aspect='equal')
    ax.legend()
    ax3 = fig.add_subplot(2, 2, 2, projection='3d')
    ax3.plot(*q_ref[:, :3].T, 'k--', label='reference')
    ax3.plot(*solution.q[:, :3].T, 'o-', ms=2, label=solution.method)
    ax3.set(xlabel=names[0], ylabel=names[1], zlabel=names[2], title='with ' + names[2])
    ax = fig.add_subplot(2, 2, 3)
    for a, name in enumerate(system.control_names):
        ax.step(solution.t[:-1], solution.u[:, a], where='post', label=name)
    ax.set(xlabel='t [s]', ylabel='u', title='controls (held per interval)')
    ax.legend()
    ax = fig.add_subplot(2, 2, 4)
    mids = solution.t[:-1] + 0.5 * problem.h
    ax.bar(mids, running, width=problem.h * 0.9, alpha=0.5, label='h L per interval')
    ax.set(xlabel='t [s]', ylabel='h L', title=f'running action; cost {solution.cost:.4f}')
    twin = ax.twinx()
    twin.plot(solution.t[1:], np.cumsum(running), 'r-', label='accumulated')
    twin.set_ylabel('accumulated running cost')
    ax.legend(loc='upper left')
    twin.legend(loc='upper right')
    return _finish(fig, path)


def plot_energy(system: NonholonomicSystem, solution, fine: Trajectory, path: Path) -> Path:
    """Plot the energy along the plan's knots and along a fine integration of its controls.

    The paper's Fig. 8 comparison.
    """
    e_plan = [system.energy(q, v) for q, v in zip(solution.q, solution.v)]
    e_fine = [system.energy(q, v) for q, v in zip(fine.q, fine.v)]
    fig, ax = _subplots(figsize=(8, 4.5))
    ax.plot(fine.t, e_fine, 'b-', label="fine RK45 integration of the plan's controls")
    ax.plot(solution.t, e_plan, 'ro', ms=4,
            label=f'{solution.method} plan ({len(solution.t)} knots)')
    ax.set(xlabel='t [s]', ylabel='energy', title='controlled energy')
    ax.legend()
    return _finish(fig, path)


def plot_closed_loop(reference: Trajectory, t: np.ndarray, xy: np.ndarray, error: np.ndarray,
                     solve_t: np.ndarray, solve_s: np.ndarray, path: Path) -> Path:
    """Plot the closed loop: reference vs driven path, cross-track error, solve times.

    All times are from the start of the run.
    """
    fig, axes = _subplots(1, 3, figsize=(16, 4.8))
    ax = axes[0]
    shown = reference.t <= t[-1] + 1.0
    ax.plot(reference.q[shown, 0], reference.q[shown, 1], 'k--', label='reference')
    ax.plot(xy[:, 0], xy[:, 1], '-', lw=2, label='closed loop (robot 10 % heavier)')
    ax.plot(*xy[0], 'gs', label='start')
    ax.set(xlabel='x [m]', ylabel='y [m]', aspect='equal', title='sleigh tracking through ROS')
    ax.legend(loc='upper left', fontsize=8)
    axes[1].semilogy(t, np.maximum(error, 1e-5))
    axes[1].axhline(0.05, color='r', ls=':', label='0.05 m')
    axes[1].set(xlabel='t [s]', ylabel='cross-track error [m]', title='tracking error')
    axes[1].legend()
    axes[2].plot(solve_t, solve_s * 1e3, '.', ms=3)
    axes[2].set(xlabel='t [s]', ylabel='solve time [ms]', title='replanning solve time')
    return _finish(fig, path)


def plot_bench(results: dict, path: Path) -> Path:
    """Cold solve vs do-mpc, warm replanning solve times, scaling in N, ROS latency split."""
    fig, axes = _subplots(1, 5, figsize=(24, 4.5))
    cold = results.get('cold_solve', {})
    names = [k for k in ('variational', 'variational_fatrop', 'variational_fatrop_compiled',
                         'variational_ipopt', 'do_mpc', 'opti_ipopt_ms') if cold.get(k)]
    axes[0].bar([k.replace('variational_', '').replace('variational', 'ours\n(default)')
                 .replace('_', '\n') for k in names],
                [cold[k]['median_s'] * 1e3 for k in names],
                color=['C5', 'C1', 'C2', 'C0', 'C3', 'C4'][:len(names)])
    axes[0].set(ylabel='median solve [ms]', title="cold solve, paper's sleigh (N = 50)")
    axes[0].tick_params(axis='x', labelrotation=15)
    warm = results.get('warm_replanning', {})
    for j, (mode, row) in enumerate(warm.items()):
        axes[1].bar(np.arange(3) + 0.27 * (j - 1), [row['p50'], row['p99'], row['max_ms']],
                    width=0.27, label=f"{mode} ({row['deadline_misses']} misses)")
    if warm:
        axes[1].set_xticks(range(3), ['p50', 'p99', 'max'])
        axes[1].axhline(10.0, color='r', ls=':', label='deadline (100 Hz)')
        axes[1].set(ylabel='solve time [ms]', title='warm replanning at 100 Hz')
        axes[1].legend(fontsize=7)
    scale = results.get('scaling')
    if scale:
        sizes = [int(k) for k in scale if k.isdigit()]
        times = [scale[str(n)]['median_s'] * 1e3 for n in sizes]
        axes[2].loglog(sizes, times, 'o-', label='measured')
        axes[2].loglog(sizes, [times[0] * n / sizes[0] for n in sizes], 'k:', label='linear')
        axes[2].set(xlabel='N', ylabel='cold solve [ms]', title='scaling in N')
        axes[2].legend()
    ros = results.get('ros_latency')
    if ros:
        keys = ['p50', 'p99']
        solve = np.array([ros['solve_ms'][k] for k in keys])
        planner = np.array([ros['planner_ms'][k] for k in keys])
        ros_layer = np.array([ros['overhead_ms'][k] for k in keys])
        axes[3].bar(keys, solve, label='NLP solver')
        axes[3].bar(keys, planner - solve, bottom=solve, label='rest of the planner')
        axes[3].bar(keys, ros_layer, bottom=planner, label='ROS layer')
        deployed = results.get('ros_latency_deployed')
        if deployed:
            axes[3].plot(keys, [deployed['latency_ms'][k] for k in keys], 'kD', ms=8,
                         label='deployed (planner process)')
        axes[3].set(ylabel='odom -> control_sequence [ms]',
                    title='ROS latency (bars: in one process)')
        axes[3].legend()
    crowd = results.get('fleet')
    if crowd:
        sizes = [r['robots'] for r in crowd['sizes']]
        axes[4].plot(sizes, [r['cpu_percent_per_robot'] for r in crowd['sizes']], 'o-',
                     label='CPU per robot [% of a core]')
        axes[4].plot(sizes, [r['misses'] for r in crowd['sizes']], 'rs--',
                     label='late or failed plans')
        axes[4].set(xlabel='robots (planner + simulator processes each)',
                    title=f"fleet at 10 Hz on {crowd['cores']} cores")
        axes[4].legend(fontsize=8)
    return _finish(fig, path)


def plot_obstacles(reference: Trajectory, obstacles: np.ndarray, robot_radius: float,
                   xy: np.ndarray, tu: np.ndarray, u: np.ndarray, limit: float,
                   path: Path) -> Path:
    """Plot obstacles, reference and driven path, and the controls against their limit."""
    from matplotlib.patches import Circle

    fig, axes = _subplots(2, 1, figsize=(11, 6.5))
    ax = axes[0]
    for i, (x, y, r) in enumerate(obstacles):
        ax.add_patch(Circle((x, y), r, color='tab:red', alpha=0.5,
                            label='obstacle' if i == 0 else None))
        ax.add_patch(Circle((x, y), r + robot_radius, fill=False, ls=':', color='tab:red',
                            label='clearance needed' if i == 0 else None))
    shown = reference.q[:, 0] <= xy[:, 0].max() + 0.5
    ax.plot(reference.q[shown, 0], reference.q[shown, 1], 'k--', label='reference')
    ax.plot(xy[:, 0], xy[:, 1], '-', lw=2, label='robot (closed loop through ROS)')
    ax.set(xlabel='x [m]', ylabel='y [m]', aspect='equal', title='tracking past obstacles')
    ax.legend(loc='upper right', fontsize=8)
    ax = axes[1]
    for j, name in enumerate(('linear', 'angular')):
        ax.step(tu, u[:, j], where='post', label=f'{name} acceleration')
    for bound in (-limit, limit):
        ax.axhline(bound, color='r', ls=':')
    ax.set(xlabel='t [s]', ylabel='u (first of each plan)', title='controls and their limit')
    ax.legend(fontsize=8)
    return _finish(fig, path)


class MovingDiscs(Protocol):
    """Discs whose centres are known at any time."""

    radius: np.ndarray

    def at(self, t: float) -> np.ndarray:
        """Return the centres (M, 2) at time t."""


def plot_crossing(track: np.ndarray, discs: MovingDiscs, robot_radius: float,
                  path: Path) -> Path:
    """Plot the robot's path among discs crossing it, and its gap to the nearest over time.

    ``track``: (T, 3) t, x, y.
    """
    from matplotlib.patches import Circle

    fig, axes = _subplots(2, 1, figsize=(11, 6.5))
    centres = np.array([discs.at(t) for t in track[:, 0]])  # (T, M, 2)
    gaps = np.linalg.norm(centres - track[:, None, 1:], axis=2) - discs.radius - robot_radius
    ax = axes[0]
    for j in range(centres.shape[1]):
        nearest = int(np.argmin(gaps[:, j]))
        ax.plot(centres[:, j, 0], centres[:, j, 1], ':', color='tab:red', lw=0.8)
        ax.add_patch(Circle(tuple(centres[nearest, j]), discs.radius[j], color='tab:red',
                            alpha=0.4, label='disc when the robot is nearest' if j == 0 else None))
        ax.add_patch(Circle(tuple(track[nearest, 1:]), robot_radius, fill=False,
                            color='tab:blue', label='robot then' if j == 0 else None))
    ax.plot(track[:, 1], track[:, 2], '-', lw=2, label='robot (closed loop through ROS)')
    ax.set(xlabel='x [m]', ylabel='y [m]', aspect='equal', ylim=(-2.0, 2.0),
           title='discs crossing the route at their own speed')
    ax.legend(loc='upper right', fontsize=8)
    ax = axes[1]
    ax.plot(track[:, 0] - track[0, 0], gaps.min(axis=1), label='gap to the nearest disc')
    ax.axhline(0.0, color='r', ls=':', label='contact')
    ax.set(xlabel='t [s]', ylabel='gap [m]', ylim=(-0.1, 1.5), title='clearance over time')
    ax.legend(fontsize=8)
    return _finish(fig, path)


def plot_route(route: np.ndarray, track: np.ndarray, feedback: np.ndarray,
               block: tuple[float, float, float, float], robot_radius: float,
               path: Path) -> Path:
    """Plot a followed route: path and block, speed, and the action's distance_to_goal.

    ``track`` rows (t, x, y, forward speed), ``feedback`` rows (t, distance_to_goal).
    """
    from matplotlib.patches import Rectangle

    fig, axes = _subplots(1, 3, figsize=(16, 4.8))
    ax = axes[0]
    ax.plot(route[:, 0], route[:, 1], 'k.', ms=2, label='route (a pose every 5 cm, untimed)')
    ax.plot(track[:, 1], track[:, 2], '-', lw=2, label='robot')
    x0, y0, x1, y1 = block
    ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, color='r', label='lethal block'))
    ax.add_patch(Rectangle((x0 - robot_radius, y0 - robot_radius), x1 - x0 + 2 * robot_radius,
                           y1 - y0 + 2 * robot_radius, fill=False, ec='r', ls=':',
                           label='inscribed (99)'))
    ax.set(xlabel='x [m]', ylabel='y [m]', aspect='equal', title='follow_path: a Nav2 route')
    ax.legend(loc='upper left', fontsize=8)
    axes[1].plot(track[:, 0], track[:, 3])
    axes[1].set(xlabel='t [s]', ylabel='forward speed [m/s]', title='speed (reference_speed 0.5)')
    if len(feedback):
        axes[2].plot(feedback[:, 0], feedback[:, 1], '.-', ms=3)
    axes[2].set(xlabel='t [s]', ylabel='distance_to_goal [m]', title='action feedback')
    return _finish(fig, path)


def plot_adaptation(runs: dict, truth: dict[str, float], path: Path) -> Path:
    """Plot the values the planner used over time against the truth, and 1-s predictions."""
    fig, axes = _subplots(1, len(truth) + 1, figsize=(5.2 * (len(truth) + 1), 4.4))
    for ax, name in zip(axes, truth):
        for adapt, run in runs.items():
            times = [t for t, _ in run['values']] + [run['t'][-1]]
            used = [v[name] for _, v in run['values']]
            ax.step(times, used + used[-1:], where='post',
                    label='adapted' if adapt else 'fixed (the model as typed)')
        ax.axhline(truth[name], color='k', ls='--', label='the robot')
        ax.set(xlabel='t [s]', ylabel=name, title=f"{name} in the planner's model")
        ax.legend(fontsize=8)
    ax = axes[-1]
    for adapt, run in runs.items():
        ax.semilogy(run['prediction_t'], np.maximum(run['prediction_error'], 1e-6), '.', ms=3,
                    label='adapted' if adapt else 'fixed')
    ax.set(xlabel='t [s]', ylabel='error [m]', title='plan 1 s ahead vs where the robot was')
    ax.legend(fontsize=8)
    return _finish(fig, path)
