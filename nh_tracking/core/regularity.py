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

"""Whether a system's data is regular where it will be used, checked before anything is derived.

A basis of D that vanishes, turns NaN or loses rank somewhere, or constraint rows that are
dependent, give wrong dynamics silently. The data is evaluated at sampled configurations — random
ones spread over the model's ``domain`` plus the special points where charts and bases typically
degenerate (coordinates at 0, angles at 0, +-pi/2, pi) — and refused with the coordinates near
the trouble named.

The basis condition is the smallest eigenvalue, over all samples, of the G-Gram matrix of the
basis fields each scaled by *one* constant (its RMS length over the samples): a field that
shrinks to zero somewhere scores near 0 there, which per-sample normalisation would hide.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

SAMPLES = 64  # random configurations, besides the special points
BASIS_CONDITION_MIN = 1e-3  # below this a basis is refused (docs/theory.md, "Regularity")
VANISHING = 1e-6  # a field this much shorter than its RMS length somewhere vanishes there
_IMPLICATED = 10.0  # moving a coordinate improves the condition this much: it is implicated


@dataclass(frozen=True)
class Domain:
    """Open box lower < q < upper where the model is valid (e.g. a steering angle's range)."""

    coordinates: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def of(cls, coordinates: Sequence[str],
           bounds: Mapping[str, tuple[float, float]] | None) -> Domain:
        coordinates = tuple(coordinates)
        lower, upper = np.full(len(coordinates), -np.inf), np.full(len(coordinates), np.inf)
        for name, (lo, hi) in (bounds or {}).items():
            if name not in coordinates:
                raise ValueError(f'domain names {name!r}, which is not a coordinate '
                                 f'{coordinates}')
            if not lo < hi:
                raise ValueError(f'domain of {name} must be an interval lo < hi, got '
                                 f'({lo}, {hi})')
            i = coordinates.index(name)
            lower[i], upper[i] = lo, hi
        return cls(coordinates, lower, upper)

    @property
    def bounded(self) -> bool:
        return bool(np.isfinite(self.lower).any() or np.isfinite(self.upper).any())

    def contains(self, q: np.ndarray) -> bool:
        return bool(np.all(q > self.lower) and np.all(q < self.upper))

    @property
    def bounded_coordinates(self) -> tuple[int, ...]:
        """Indices of the coordinates with a finite end."""
        return tuple(int(i) for i in np.flatnonzero(np.isfinite(self.lower)
                                                    | np.isfinite(self.upper)))

    def interior(self, indices: Sequence[int],
                 margin: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
        """Return closed bounds ``margin`` inside the open box, for the coordinates ``indices``.

        (A fraction ``margin`` of an interval narrower than 1.)
        """
        lo, hi = self.lower[list(indices)], self.upper[list(indices)]
        gap = margin * np.minimum(1.0, hi - lo)
        return lo + gap, hi - gap

    def inside(self, values: np.ndarray, indices: Sequence[int],
               margin: float = 1e-3) -> np.ndarray:
        """``values`` of the coordinates ``indices`` moved ``margin`` inside the domain."""
        return np.clip(values, *self.interior(indices, margin))

    def check(self, q: np.ndarray, what: str = 'q') -> None:
        """Raise a ValueError naming each coordinate of ``q`` outside the domain."""
        if (self.lower < q).all() and (q < self.upper).all():  # (NaN fails both)
            return
        if not np.isfinite(q).all():
            raise ValueError(f'{what} must be finite, got {describe(self.coordinates, q)}')
        out = [f'{c} = {x:.6g} not in ({lo:.6g}, {hi:.6g})'
               for c, x, lo, hi in zip(self.coordinates, q, self.lower, self.upper)
               if not lo < x < hi]
        if out:
            raise ValueError(f"{what} is outside the model's valid domain: {'; '.join(out)}")


def describe(coordinates: Sequence[str], q: np.ndarray) -> str:
    return ', '.join(f'{c} = {x:.4g}' for c, x in zip(coordinates, q))


def random_configurations(coordinates: Sequence[str], angles: Sequence[str], domain: Domain,
                          rng: np.random.Generator, count: int = SAMPLES) -> np.ndarray:
    """Return (count, n) random configurations inside the domain.

    Angles uniform, intervals uniform inside, half lines from their end outwards, others normal.
    """
    samples = rng.normal(size=(count, len(coordinates)))
    for i, c in enumerate(coordinates):
        lo, hi = domain.lower[i], domain.upper[i]
        if c in angles:
            samples[:, i] = rng.uniform(-np.pi, np.pi, count)
        if np.isfinite(lo) and np.isfinite(hi):  # stay a little inside an open interval
            margin = 1e-2 * (hi - lo)
            samples[:, i] = rng.uniform(lo + margin, hi - margin, count)
        elif np.isfinite(lo) or np.isfinite(hi):  # a half line: from its end outwards
            side = 1.0 if np.isfinite(lo) else -1.0
            end = lo if np.isfinite(lo) else hi
            samples[:, i] = end + side * (1e-2 + np.abs(samples[:, i]))
    return samples


def sample_configurations(coordinates: Sequence[str], angles: Sequence[str],
                          domain: Domain) -> np.ndarray:
    """Deterministic configurations: random ones, and the special points, inside the domain."""
    samples = random_configurations(coordinates, angles, domain, np.random.default_rng(0))
    specials: list[list[float]] = []
    for i, c in enumerate(coordinates):
        lo, hi = domain.lower[i], domain.upper[i]
        values = [0.0, np.pi / 2, -np.pi / 2, np.pi] if c in angles else [0.0, 1.0, -1.0]
        specials.append([x for x in values if lo < x < hi])
    centre = np.array([s[0] if s else samples[0, i] for i, s in enumerate(specials)])
    special = [centre]
    for i, values in enumerate(specials):
        for x in values:
            for base in (centre, samples[i % SAMPLES]):
                q = base.copy()
                q[i] = x
                special.append(q)
    everything = np.vstack([samples, special])
    return everything[[domain.contains(q) for q in everything]]


def check_finite(what: str, values: Callable[[np.ndarray], Sequence[np.ndarray]],
                 samples: np.ndarray, coordinates: Sequence[str]) -> None:
    for q in samples:
        if not all(np.all(np.isfinite(v)) for v in values(q)):
            raise ValueError(f'{what} is not finite at {describe(coordinates, q)}')


def check_metric(metric: Callable[[np.ndarray], np.ndarray], samples: np.ndarray,
                 coordinates: Sequence[str]) -> None:
    for q in samples:
        g = metric(q)
        if not np.all(np.isfinite(g)) or not np.allclose(g, g.T) or (
                np.linalg.eigvalsh(0.5 * (g + g.T))[0] <= 0):
            raise ValueError('metric(q) is not symmetric positive definite at '
                             f'{describe(coordinates, q)}')


def check_constraint_rank(constraints: Callable[[np.ndarray], np.ndarray],
                          samples: np.ndarray, coordinates: Sequence[str]) -> None:
    """Refuse dependent rows (everywhere: a wrong k) or a rank drop (somewhere: a singularity)."""
    mus = np.stack([constraints(q) for q in samples])
    m = mus.shape[1]
    if m == 0:
        return
    norms = np.linalg.norm(mus, axis=2)  # (samples, m): each row at each configuration
    if np.any(np.all(norms == 0, axis=0)):
        raise ValueError('constraints(q) has a row that is zero at every sampled configuration')
    sv = np.array([_smallest_svs(mu) for mu in mus])
    rank_deficient = sv[:, -1]**2 < BASIS_CONDITION_MIN  # as for a basis: squared lengths
    if rank_deficient.all():
        rank = int(np.max(np.sum(sv**2 >= BASIS_CONDITION_MIN, axis=1)))
        raise ValueError(f'constraints(q) has {m} rows but rank {rank} at every sampled '
                         'configuration: the rows are dependent (a duplicated or combined row '
                         'gives the wrong number of degrees of freedom); give independent rows')
    if rank_deficient.any():
        worst = samples[int(np.argmin(sv[:, -1]))]
        near = implicated_coordinates(lambda q: float(_smallest_svs(constraints(q))[-1]),
                                      worst, coordinates)
        raise ValueError(f'constraints(q) lose rank near {near} (at '
                         f'{describe(coordinates, worst)}): the distribution changes rank '
                         'there; restrict the configurations with domain=')


def _smallest_svs(mu: np.ndarray) -> np.ndarray:
    """Singular values of ``mu`` with each row scaled to length 1 (a zero row: rank lost).

    Per configuration: the rows' lengths may vary over the domain (a polar coordinate's
    row grows with r) without any loss of rank.
    """
    norms = np.linalg.norm(mu, axis=1)
    if np.any(norms == 0):
        return np.zeros(min(mu.shape))
    return np.linalg.svd(mu / norms[:, None], compute_uv=False)


def basis_condition(rho_and_metric: Callable[[np.ndarray], tuple[np.ndarray, ...]],
                    samples: np.ndarray, coordinates: Sequence[str], what: str) -> float:
    """Smallest eigenvalue of the fields' Gram matrix, each field scaled to length 1 per sample.

    That measures how near dependent the fields are at each configuration, whatever their
    lengths do over the domain (a polar coordinate's field grows with r). A field shorter than
    :data:`VANISHING` of its RMS length somewhere is taken to vanish there (condition 0).
    Refuses (ValueError) a non-finite basis or one below :data:`BASIS_CONDITION_MIN`.
    """
    grams = []
    for q in samples:
        rho, g = rho_and_metric(q)
        if not (np.all(np.isfinite(rho)) and np.all(np.isfinite(g))):
            raise ValueError(f'{what} is not finite at {describe(coordinates, q)}')
        grams.append(rho.T @ g @ rho)
    gram = np.stack(grams)
    scale = np.sqrt(np.einsum('sii->i', gram) / len(gram))
    if np.any(scale == 0):
        raise ValueError(f'{what} has a field that is zero at every sampled configuration')

    def condition(q_gram: np.ndarray) -> float:
        lengths = np.sqrt(np.maximum(np.diag(q_gram), 0.0))
        if np.any(lengths < VANISHING * scale):
            return 0.0
        return float(np.linalg.eigvalsh(q_gram / np.outer(lengths, lengths))[0])

    values = np.array([condition(x) for x in gram])
    worst = int(np.argmin(values))
    if np.all(values < BASIS_CONDITION_MIN):
        raise ValueError(f'{what} loses rank at every sampled configuration: its fields are '
                         'dependent (or one of them vanishes) everywhere')
    if values[worst] < BASIS_CONDITION_MIN:
        def at(q: np.ndarray) -> float:
            rho, g = rho_and_metric(q)
            return condition(rho.T @ g @ rho)
        near = implicated_coordinates(at, samples[worst], coordinates)
        raise ValueError(f'{what} loses rank near {near}: condition {values[worst]:.2g} < '
                         f'{BASIS_CONDITION_MIN:g} at {describe(coordinates, samples[worst])} '
                         '(its fields shrink or become dependent there)')
    return float(values[worst])


def implicated_coordinates(score: Callable[[np.ndarray], float], worst: np.ndarray,
                           coordinates: Sequence[str]) -> str:
    """Name the coordinates whose change lifts ``score`` out of its low at ``worst``."""
    base = max(score(worst), 1e-9)  # (scores are scale-free: below this, rounding)
    names = []
    for i, c in enumerate(coordinates):
        best = 0.0
        for step in (0.5, -0.5):
            q = worst.copy()
            q[i] += step
            with np.errstate(all='ignore'):
                value = score(q)
            if np.isfinite(value):
                best = max(best, value)
        if best > _IMPLICATED * base:
            names.append(f'{c} = {worst[i]:.4g}')
    return ', '.join(names) or describe(coordinates, worst)


def numeric_map(q: ca.SX, *exprs: ca.SX) -> Callable[[np.ndarray], tuple[np.ndarray, ...]]:
    """Evaluate expressions in q with numpy: the checks run at sample configurations."""
    fn = ca.Function('data', [q], list(exprs))
    return lambda x: tuple(np.array(a) for a in fn(x))


def check_in_distribution(rho_and_mu: Callable[[np.ndarray], tuple[np.ndarray, ...]],
                          samples: np.ndarray, coordinates: Sequence[str]) -> None:
    for q in samples:
        rho, mu = rho_and_mu(q)
        mu = mu.reshape(-1, len(coordinates))
        if mu.size and np.abs(mu @ rho).max() > 1e-9 * max(1.0, np.abs(mu).max()):
            raise ValueError('basis(q) is not in the constraint distribution at '
                             f'{describe(coordinates, q)}')


def check_actuators(q: ca.SX, metric: ca.SX, rho: ca.SX, forces: ca.SX, samples: np.ndarray,
                    coordinates: Sequence[str]) -> None:
    """Refuse force directions F (n, r) whose projections onto D are not r independent fields."""
    (n, k), r = rho.shape, forces.shape[1]
    if forces.shape[0] != n or not 1 <= r <= k:
        raise ValueError(f'actuators(q) must be ({n}, r) with 1 <= r <= k = {k}, got '
                         f'{forces.shape}')
    projected = ca.solve(rho.T @ metric @ rho, rho.T @ forces)
    basis_condition(numeric_map(q, projected, ca.SX.eye(k)), samples, coordinates,
                    'the actuators projected onto D (an actuator that only pushes against the '
                    'constraints, or two that act alike?)')
