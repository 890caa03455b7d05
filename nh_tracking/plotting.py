"""PNG figures of trajectories, for people to look at (matplotlib, no display needed)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nh_tracking.system import NonholonomicSystem  # noqa: E402
from nh_tracking.trajectory import Trajectory  # noqa: E402


def plot_simulation(system: NonholonomicSystem, traj: Trajectory, path: Path) -> Path:
    """Path in the plane of the first two coordinates, quasi-velocities, and energy drift."""
    energy = np.array([system.energy(q, v) for q, v in zip(traj.q, traj.v)])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    ax = axes[0]
    ax.plot(traj.q[:, 0], traj.q[:, 1], lw=2)
    ax.plot(*traj.q[0, :2], "go", label="start")
    ax.plot(*traj.q[-1, :2], "rs", label="end")
    ax.set(xlabel=system.coordinates[0], ylabel=system.coordinates[1], aspect="equal",
           title=f"{system.name}: path")
    ax.legend()
    for a, name in enumerate(system.velocity_names):
        axes[1].plot(traj.t, traj.v[:, a], label=name)
    axes[1].set(xlabel="t [s]", ylabel="v (adapted basis)", title="quasi-velocities")
    axes[1].legend()
    axes[2].plot(traj.t, energy - energy[0])
    axes[2].set(xlabel="t [s]", ylabel="E(t) - E(0)", title=f"energy drift (E0 = {energy[0]:.4g})")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
