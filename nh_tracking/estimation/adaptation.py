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
seconds the last ``window`` seconds are fitted (:func:`~nh_tracking.estimation.output_error.
estimate_parameters`) from the values in use, and only an excited fit moves them — by at most
``step`` (relative) per update, so one bad window cannot throw the model out.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
import threading
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from nh_tracking import models
from nh_tracking.estimation.output_error import estimate_parameters, ParameterEstimate
from nh_tracking.estimation.worker import EstimationWorker
from nh_tracking.models.spec import ModelSpec


@dataclass(frozen=True)
class AdaptationSettings:
    """How the estimates follow the motion.

    ``window``: seconds of motion fitted; ``period``: seconds between fits; ``step``: the
    largest relative change of a value per fit; ``rate``: samples kept per second at most;
    ``agree``: how close (relative) the fits under each reading of when the controls took
    effect must come for the estimate to be used.
    """

    window: float = 10.0
    period: float = 2.0
    step: float = 0.3
    rate: float = 50.0
    agree: float = 0.01


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

    @property
    def last_time(self) -> float | None:
        return self._samples[-1][0] if self._samples else None

    def add(self, t: float, q: ArrayLike, u: ArrayLike, u_late: ArrayLike | None = None) -> None:
        """Take the configuration at ``t`` and the mean control since the last sample.

        ``u_late``: the mean control had the robot applied each new sequence one sample late,
        when that may have been so. The first sample's controls are not used. Samples closer
        than 1 / rate to the last one, or not after it, are dropped.
        """
        if not self.takes(t):
            return
        readings = np.array([u, u if u_late is None else u_late], dtype=float)
        self._samples.append((float(t), np.array(q, dtype=float), readings))
        while self._samples[0][0] < t - self.settings.window:
            self._samples.popleft()

    def takes(self, t: float) -> bool:
        """Say whether a sample at ``t`` would be kept: 1 / rate or more after the last one."""
        return not self._samples or t - self._samples[-1][0] >= 0.999 / self.settings.rate

    def clear(self) -> None:
        """Drop the samples: a gap in what is known of the controls."""
        self._samples.clear()

    def due(self, t: float) -> bool:
        """Say whether a fit is due: ``period`` since the last one, and a full window."""
        return (t - self._fitted_at >= self.settings.period and len(self._samples) > 2
                and self._samples[-1][0] - self._samples[0][0]
                >= 0.9 * self.settings.window)

    def requests(self) -> list[dict[str, Any]]:
        """Return the fits of the window, one per reading of the controls.

        Each as ``estimate_parameters``' arguments after the model.
        """
        t, q, u = zip(*self._samples)
        self._fitted_at = t[-1]
        readings = np.array(u[1:])
        count = 1 if np.array_equal(readings[:, 0], readings[:, 1]) else 2
        return [{'t': np.array(t), 'q': np.array(q), 'u': readings[:, i], 'names': self.names,
                 'fixed': self.fixed, 'start': dict(self.values)} for i in range(count)]

    def accept(self, estimates: Sequence[ParameterEstimate]) -> ParameterEstimate:
        """Move the values in use toward the fits' estimate, if it holds, by ``step`` at most."""
        estimate = combined_estimate(estimates, self.settings.agree, self.values)
        if estimate.excited:
            step = self.settings.step
            self.values = {n: float(np.clip(estimate.values[n], v - step * max(abs(v), 1e-3),
                                            v + step * max(abs(v), 1e-3)))
                           for n, v in self.values.items()}
        self.last = estimate
        return estimate

    def update(self) -> ParameterEstimate:
        """Fit the window from the values in use, here and now, and accept the estimate."""
        return self.accept([estimate_parameters(self.spec, **r) for r in self.requests()])


def combined_estimate(estimates: Sequence[ParameterEstimate], agree: float,
                      start: Mapping[str, float]) -> ParameterEstimate:
    """Return the estimate the fits under each reading of the controls support together.

    Their mean, each std widened to half their spread; excited only when every fit is and the
    spread is within ``agree`` (relative): otherwise the controls' timing is what the data
    cannot tell, and the values are ``start``.
    """
    first = estimates[0]
    unexcited = [e for e in estimates if not e.excited]
    if len(estimates) == 1 or unexcited:
        return unexcited[0] if unexcited else first
    names = list(first.values)
    values = {n: float(np.mean([e.values[n] for e in estimates])) for n in names}
    spread = {n: float(np.ptp([e.values[n] for e in estimates]) / 2) for n in names}
    loose = [f'{n} ±{spread[n] / max(abs(values[n]), 1e-9):.1%}' for n in names
             if spread[n] > agree * abs(values[n])]
    std = {n: max(max(e.std[n] for e in estimates), spread[n]) for n in names}
    if loose:
        return replace(first, values=dict(start), std=std, excited=False,
                       message=f'not excited: when the controls took effect leaves '
                               f"{', '.join(loose)} (over {agree:.0%}); starting values kept")
    return replace(first, values=values, std=std)


class BackgroundEstimates:
    """An :class:`OnlineEstimator` whose fits run in a worker process (:mod:`.worker`).

    ``on_values()`` is called (on the thread that waits for the worker) when a fit moved a
    value in use by more than ``agree`` (relative): :attr:`values` are then the new ones.
    """

    def __init__(self, model: str, names: Sequence[str], values: Mapping[str, float],
                 on_values: Callable[[], None],
                 settings: AdaptationSettings = AdaptationSettings()) -> None:
        spec = models.spec(model)
        spec.parametrised(names, **values)  # a ValueError now, not in the worker
        self.model = model
        self.estimator = OnlineEstimator(spec, names, values, settings)
        self.failure = ''  # the last fit's exception, if it raised
        self._on_values = on_values
        self._lock = threading.Lock()
        self._worker = EstimationWorker()
        self._busy = False

    @property
    def values(self) -> dict[str, float]:
        with self._lock:
            return dict(self.estimator.values)

    @property
    def last(self) -> ParameterEstimate | None:
        return self.estimator.last

    def sample(self, t: float, q: ArrayLike, controls: Callable[
            [float, float], tuple[np.ndarray, np.ndarray] | None]) -> None:
        """Take the configuration at ``t``; start the fits when they are due.

        ``controls(t0, t1)``: the mean control applied over [t0, t1], had each sequence been
        applied at once and one sample late (:meth:`SentControls.readings`), or None when it
        is not known (the window then starts again).
        """
        with self._lock:
            if not self.estimator.takes(t):
                return
            since = self.estimator.last_time
            readings = controls(t if since is None else since, t)
            if readings is None:
                self.estimator.clear()
                return
            self.estimator.add(t, q, *readings)
            if self._busy or not self.estimator.due(t):
                return
            requests = self.estimator.requests()
            self._busy = True
        self._worker.submit([{'model': self.model, **r} for r in requests], self._done)

    def _done(self, answer: list[ParameterEstimate] | Exception) -> None:
        moved = False
        with self._lock:
            try:
                if isinstance(answer, Exception):  # reported; the values in use are kept
                    raise answer
                before = dict(self.estimator.values)
                self.estimator.accept(answer)
                moved = any(abs(v - before[n]) > self.estimator.settings.agree * max(
                    abs(before[n]), 1e-9) for n, v in self.estimator.values.items())
                self.failure = ''
            except Exception as exc:  # noqa: BLE001 - one bad fit must not end the estimates
                self.failure = f'{type(exc).__name__}: {exc}'
            finally:
                self._busy = False
        if moved:
            self._on_values()

    def close(self) -> None:
        self._worker.close()


def mean_control(t: np.ndarray, u: np.ndarray, t0: float, t1: float) -> np.ndarray | None:
    """Return the mean over [t0, t1] of controls ``u`` (N, r) held on the intervals of ``t``.

    Before ``t[0]`` the first control is taken as in force; None when [t0, t1] reaches past
    ``t[-1]`` or ends before ``t[0]``. ``t0 == t1``: the control in force then.
    """
    if t1 > t[-1] or t1 < t[0] or t1 < t0:
        return None
    if t1 == t0:
        return u[min(int(np.searchsorted(t, t0, side='right')) - 1, len(u) - 1)]
    edges = np.clip(t, t0, t1)
    weights = np.diff(edges)
    weights[0] += max(t[0] - t0, 0.0)
    return weights @ u / (t1 - t0)


class SentControls:
    """The control sequences sent (each from its start, or once it was sent) until the next one.

    What the robot applied, as far as the planner knows; ``keep`` seconds of them are kept.
    """

    def __init__(self, keep: float = 5.0) -> None:
        self.keep = keep
        self._sent: deque[tuple[float, np.ndarray, np.ndarray]] = deque()
        self._lock = threading.Lock()

    def clear(self) -> None:
        """Forget what was sent: the robot was not commanded since."""
        with self._lock:
            self._sent.clear()

    def sent(self, when: float, t: np.ndarray, u: np.ndarray) -> None:
        with self._lock:
            self._sent.append((when, t, u))
            while len(self._sent) > 1 and self._sent[1][0] < when - self.keep:
                self._sent.popleft()

    def readings(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Return the mean control applied over [t0, t1], read two ways; None if not known.

        A sequence may have reached the robot at once or only after the solve that made it and
        one more interval: the mean had each been applied from its start, and from ``t1 - t0``
        after it was sent (where the later reading runs past what was sent, the first is given
        twice).
        """
        with self._lock:
            sent = list(self._sent)
        if not sent or sent[0][0] > t0:
            return None
        prompt = self._mean(sent, t0, t1, None)
        late = prompt if t1 == t0 else self._mean(sent, t0, t1, t1 - t0)
        if prompt is None:
            return None
        return prompt, prompt if late is None else late

    @staticmethod
    def _mean(sent: list, t0: float, t1: float, lag: float | None) -> np.ndarray | None:
        """Return the mean with each sequence but the first in force ``lag`` after it was sent.

        ``lag`` None: each from its own start instead (as if it reached the robot at once).
        """
        starts = [sent[0][0]] + [t[0] if lag is None else max(when, t[0]) + lag
                                 for when, t, _ in sent[1:]]
        ends = starts[1:] + [np.inf]
        if t1 == t0:
            j = max(i for i, start in enumerate(starts) if start <= t0)
            return mean_control(sent[j][1], sent[j][2], t0, t0)
        total = np.zeros(sent[0][2].shape[1])
        for (_, t, u), start, end in zip(sent, starts, ends):
            a, b = max(start, t0), min(end, t1)
            if b <= a:
                continue
            piece = mean_control(t, u, a, b)
            if piece is None:
                return None
            total += piece * (b - a)
        return total / (t1 - t0)
