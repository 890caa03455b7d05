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

"""Tracking quality figures used by the demo, the benchmarks and the tests."""
from __future__ import annotations

import numpy as np


def cross_track_error(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distance of each point (M, d) to the polyline ``path`` (P, d), P >= 2."""
    points, path = np.atleast_2d(points), np.atleast_2d(path)
    a, b = path[:-1], path[1:]
    ab = b - a
    length2 = np.maximum(np.einsum('sd,sd->s', ab, ab), 1e-300)
    rel = points[:, None, :] - a[None, :, :]
    s = np.clip(np.einsum('msd,sd->ms', rel, ab) / length2, 0.0, 1.0)
    nearest = a[None] + s[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - nearest, axis=2).min(axis=1)


def percentiles_ms(seconds: list[float] | np.ndarray, qs=(50, 99)) -> dict[str, float]:
    """{"p50": ..., "p99": ...} in milliseconds (NaN for no samples)."""
    values = np.asarray(seconds, dtype=float)
    return {f'p{q}': float(np.percentile(values, q) * 1e3) if values.size else float('nan')
            for q in qs}
