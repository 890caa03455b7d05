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

"""A plan to start a solve from, with what a warm start takes from the plan that made it."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from nh_tracking.problem.tracking_problem import Multipliers


class Guess(NamedTuple):
    """A plan to start a solve from: q (N+1, n), v (N+1, k), u (N, r) or None.

    With the ``multipliers`` of the NLP that made it, if any (a warm start's Newton steps
    take them; a plain (q, v, u) tuple serves as a guess without them), and its
    ``working_set_misses``: warm solves in a row, up to the plan, whose working set did not
    settle (past a few, it is tried only now and then: each miss costs up to 24
    factorisations). The count rides with the plans, not with the shared NLPs.
    """

    q: np.ndarray
    v: np.ndarray
    u: np.ndarray | None
    multipliers: Multipliers | None = None
    working_set_misses: int = 0
