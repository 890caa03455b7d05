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

"""Timed trajectories on D: what ``simulate`` returns and what a reference is."""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline


@dataclass(frozen=True)
class Trajectory:
    """Samples (t, q, v) of a curve on D, with the controls u held on each interval.

    ``t`` (N+1,) strictly increasing, ``q`` (N+1, n), ``v`` (N+1, k), ``u`` (N, r). Angles are
    kept continuous (unwrapped) along the curve so that interpolation is meaningful.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    _coefficients: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float).reshape(-1)
        q = np.atleast_2d(np.asarray(self.q, dtype=float))
        v = np.atleast_2d(np.asarray(self.v, dtype=float))
        u = np.asarray(self.u, dtype=float)
        u = u.reshape(max(len(t) - 1, 0), -1) if u.ndim < 2 and u.size else np.atleast_2d(u)
        if len(t) < 2 or np.any(np.diff(t) <= 0):
            raise ValueError('trajectory times must be strictly increasing, at least two')
        if q.shape[0] != len(t) or v.shape[0] != len(t) or u.shape[0] != len(t) - 1:
            raise ValueError(f'q {q.shape} and v {v.shape} must have {len(t)} rows like t, '
                             f'u {u.shape} {len(t) - 1}')
        for name, arr in (('t', t), ('q', q), ('v', v), ('u', u)):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f'trajectory {name} has non-finite values')
        for name, arr in (('t', t), ('q', q), ('v', v), ('u', u)):
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        spline = CubicSpline(t, np.hstack([q, v]), axis=0)
        object.__setattr__(self, '_coefficients', spline.c)  # (4, N, n + k), local powers

    def at(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) at one time: the scalar fast path of :meth:`sample` for ODE right-hand sides."""
        t = self.t
        time = min(max(time, t[0]), t[-1])
        i = min(bisect.bisect_right(t, time) - 1, len(t) - 2)
        c, dt = self._coefficients[:, i], time - t[i]
        value = ((c[0] * dt + c[1]) * dt + c[2]) * dt + c[3]
        n = self.q.shape[1]
        return value[:n], value[n:]

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def sample(self, times: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) at ``times`` (arrays (len, n), (len, k)), held constant outside [t0, tN]."""
        t = self.t  # (ufuncs and methods: np.clip's own overhead is several times theirs)
        times = np.minimum(np.maximum(np.asarray(times, dtype=float).reshape(-1), t[0]), t[-1])
        i = np.minimum(t.searchsorted(times, 'right') - 1, len(t) - 2)  # times >= t[0]: i >= 0
        c, dt = self._coefficients[:, i], (times - t[i])[:, None]
        value = ((c[0] * dt + c[1]) * dt + c[2]) * dt + c[3]
        n = self.q.shape[1]
        return value[:, :n], value[:, n:]
