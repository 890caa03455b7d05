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

"""What a solve ran, in order: each backend's try, typed (``Solution.attempts``).

A solve may run several backends: Newton steps that hand over to the interior point, a retry
with IPOPT, soft limits, the domain as bounds, another disc set, a second look. Each run is one
:class:`Attempt`; code reads these, not the words of ``Solution.route`` or ``message``.
"""
from __future__ import annotations

from dataclasses import dataclass
import enum


class Backend(enum.Enum):
    """What solved (or tried to): a numerical backend of a transcription."""

    GAUSS_NEWTON = 'gauss-newton'  # real-time iterations: Gauss-Newton steps, a fixed number
    WORKING_SET = 'newton (working set)'  # Newton steps, limit rows on a working set (warm)
    LINE_SEARCH = 'newton (line search)'  # Newton steps with a filter line search (cold)
    FATROP = 'fatrop'  # the structure-exploiting interior point
    IPOPT = 'ipopt'  # the general interior point


class Status(enum.Enum):
    """How one backend's try ended."""

    CONVERGED = 'converged'
    ITERATED = 'iterated'  # a real-time iteration: the steps asked (and more while inadmissible)
    HANDED_OVER = 'handed over'  # steps that did not settle (or an inadmissible real-time
    # iteration): the next backend runs
    PAUSED = 'paused'  # not tried: it kept failing on the plans before (see Guess)
    FAILED = 'failed'
    DEADLINE = 'deadline reached'
    NOT_FINITE = 'not finite'  # the NLP gives NaN or Inf at the guess (not started), or after


@dataclass(frozen=True)
class Attempt:
    """One backend's try: how it ended, its iterations (factorisations) and wall time [s]."""

    backend: Backend
    status: Status
    iterations: int
    time: float
