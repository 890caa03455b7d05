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

"""Physical parameters learnt while tracking: estimates over a sliding window of the motion.

The robot's configurations and the controls in force come in as they happen; every ``period``
seconds the last ``window`` seconds are fitted (:func:`~nh_tracking.estimation.
estimate_parameters`) from the values in use, and only an excited fit moves them — by at most
``step`` (relative) per update, so one bad window cannot throw the model out.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from nh_tracking.estimation import estimate_parameters, ParameterEstimate
from nh_tracking.models.spec import ModelSpec


@dataclass(frozen=True)
class AdaptationSettings:
    """How the estimates follow the motion.

    ``window``: seconds of motion fitted; ``period``: seconds between fits; ``step``: the
    largest relative change of a value per fit; ``rate``: samples kept per second at most.
    """

    window: float = 10.0
    period: float = 2.0
    step: float = 0.2
    rate: float = 50.0


class OnlineEstimator:
    """Estimates of ``names`` of ``spec``, from a stream of (t, q, u), starting at ``values``."""

    def __init__(self, spec: ModelSpec, names: Sequence[str], values: Mapping[str, float],
                 settings: AdaptationSettings = AdaptationSettings()) -> None:
        self.spec = spec
        self.names = tuple(names)
        self.values = {n: float(values[n]) for n in self.names}  # in use; checked by the fit
        self.fixed = {n: float(v) for n, v in values.items() if n not in self.names}
        self.settings = settings
        self.last: ParameterEstimate | None = None
        self._samples: deque[tuple[float, np.ndarray, np.ndarray]] = deque()
        self._fitted_at = -np.inf

    def add(self, t: float, q: ArrayLike, u: ArrayLike) -> None:
        """Take the configuration at ``t`` and the control in force from ``t`` on.

        Samples closer than 1 / rate to the last one, or not after it, are dropped.
        """
        if self._samples and t - self._samples[-1][0] < 1.0 / self.settings.rate * 0.999:
            return
        self._samples.append((float(t), np.array(q, dtype=float), np.array(u, dtype=float)))
        while self._samples[0][0] < t - self.settings.window:
            self._samples.popleft()

    def due(self, t: float) -> bool:
        """Say whether a fit is due: ``period`` since the last one, and a full window."""
        return (t - self._fitted_at >= self.settings.period and len(self._samples) > 2
                and self._samples[-1][0] - self._samples[0][0]
                >= 0.9 * self.settings.window)

    def update(self) -> ParameterEstimate:
        """Fit the window from the values in use; move them toward an excited estimate."""
        t, q, u = zip(*self._samples)
        self._fitted_at = t[-1]
        estimate = estimate_parameters(self.spec, np.array(t), np.array(q), np.array(u[:-1]),
                                       self.names, fixed=self.fixed, start=self.values)
        if estimate.excited:
            step = self.settings.step
            self.values = {n: float(np.clip(estimate.values[n], v - step * max(abs(v), 1e-3),
                                            v + step * max(abs(v), 1e-3)))
                           for n, v in self.values.items()}
        self.last = estimate
        return estimate
