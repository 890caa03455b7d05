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

"""Fast numeric calls of CasADi Functions from Python hot loops (ODE right-hand sides)."""
from __future__ import annotations

import threading
from typing import Any

import casadi as ca
import numpy as np


class NumericFunction:
    """Calls a CasADi Function through preallocated buffers.

    A plain call converts every argument to a DM and back, which would dominate an ODE
    right-hand side evaluated 10^5 times per shooting solve; the buffers skip the conversions.
    Outputs are densified and returned as fresh numpy arrays of the output shapes (a column
    as 1-D). One call at a time: the buffers are shared, so calls from several threads (a
    planner's odometry, solver and executor threads) take turns.
    """

    def __init__(self, fn: ca.Function) -> None:
        sym = ca.SX.sym if fn.is_a('SXFunction') else ca.MX.sym  # MX: e.g. a linear solve
        inputs: list[Any] = [sym(fn.name_in(i), fn.sparsity_in(i)) for i in range(fn.n_in())]
        outputs = [ca.densify(o) for o in fn.call(inputs)]
        dense = ca.Function(fn.name() + '_dense', inputs, outputs)
        self._buffer, self._trigger = dense.buffer()
        self._args = [np.zeros(dense.nnz_in(i)) for i in range(dense.n_in())]
        self._empty = [not len(a) for a in self._args]  # (skipped: no copy, no ravel)
        self._res = [np.zeros(dense.nnz_out(i)) for i in range(dense.n_out())]
        self._shapes = [dense.size_out(i) for i in range(dense.n_out())]
        self._lock = threading.Lock()
        for i, a in enumerate(self._args):
            self._buffer.set_arg(i, memoryview(a))  # type: ignore[call-arg, arg-type]
        for i, r in enumerate(self._res):
            self._buffer.set_res(i, memoryview(r))  # type: ignore[call-arg, arg-type]

    def __call__(self, *args: np.ndarray | float) -> list[np.ndarray]:
        with self._lock:
            for buf, value, empty in zip(self._args, args, self._empty):
                if not empty:
                    buf[:] = np.ravel(value)
            self._trigger()
            return [r.copy().reshape(shape, order='F') if shape[1] > 1 else r.copy()
                    for r, shape in zip(self._res, self._shapes)]
