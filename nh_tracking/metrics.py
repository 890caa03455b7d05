"""Tracking quality figures used by the demo, the benchmarks and the tests."""
from __future__ import annotations

import numpy as np


def cross_track_error(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distance of each point (M, d) to the polyline ``path`` (P, d), P >= 2."""
    points, path = np.atleast_2d(points), np.atleast_2d(path)
    a, b = path[:-1], path[1:]
    ab = b - a
    length2 = np.maximum(np.einsum("sd,sd->s", ab, ab), 1e-300)
    rel = points[:, None, :] - a[None, :, :]
    s = np.clip(np.einsum("msd,sd->ms", rel, ab) / length2, 0.0, 1.0)
    nearest = a[None] + s[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - nearest, axis=2).min(axis=1)


def percentiles_ms(seconds: list[float] | np.ndarray, qs=(50, 99)) -> dict[str, float]:
    """{"p50": ..., "p99": ...} in milliseconds (NaN for no samples)."""
    values = np.asarray(seconds, dtype=float)
    return {f"p{q}": float(np.percentile(values, q) * 1e3) if values.size else float("nan")
            for q in qs}
