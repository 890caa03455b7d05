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

"""Compiled solver structures, built once per (system, structure) and freed with the system.

Per system only the structures of the few horizon sizes used last are kept: a parameter storm
(every ``steps`` value in turn) must not grow memory without bound (each size holds ~15 MB).

A replanning loop must never stop to build one: inside :func:`builds_deferred` a structure not
built yet is built on a background thread instead, and the call raises :class:`NotPrepared`
(the loop keeps the plan in force and finds the structure ready later).
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
import threading
from typing import Generic, TypeVar
import weakref

from nh_tracking.system import NonholonomicSystem

T = TypeVar('T')
GROUPS = 3  # horizon sizes kept per system
_DEFERRED: ContextVar[bool] = ContextVar('nh_tracking_builds_deferred', default=False)


class NotPrepared(RuntimeError):
    """The structure a solve needs is being built in the background."""


@contextmanager
def builds_deferred() -> Iterator[None]:
    """Within this block, missing structures are built in the background, never in line."""
    token = _DEFERRED.set(True)
    try:
        yield
    finally:
        _DEFERRED.reset(token)


def by_steps(key: Hashable) -> Hashable:
    """Group a transcription's key by its horizon size (the key's first field)."""
    return key[0]  # type: ignore[index]


class PerSystemCache(Generic[T]):
    """Building a CasADi NLP or flow takes far longer than solving it, so each is built once.

    Held per system, and dropped with it: a cached structure must not reference its system
    (the store holds the structure, so the weakly held system would live on, with its NLPs).
    Keys are grouped (``group(key)``: a horizon size); per system the ``groups`` used last are
    kept, an older group's structures are dropped together (a solve holding one keeps it alive).
    """

    def __init__(self, group: Callable[[Hashable], Hashable] = lambda key: key,
                 groups: int = GROUPS) -> None:
        self._store: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self._building: set[tuple[int, Hashable]] = set()
        self._lock = threading.Lock()
        self._group, self._groups = group, groups

    def get(self, system: NonholonomicSystem, key: Hashable, build: Callable[[], T]) -> T:
        with self._lock:
            found = self._lookup(system, key)
        if found is not None:
            return found
        if _DEFERRED.get():
            self._build_later(system, key, build)
            raise NotPrepared(f'its NLP ({key}) was not prepared; it is being built in the '
                              'background')
        return self._keep(system, key, build())

    def _lookup(self, system: NonholonomicSystem, key: Hashable) -> T | None:
        groups: OrderedDict = self._store.setdefault(system, OrderedDict())
        entries = groups.get(self._group(key))
        if entries is None or key not in entries:
            return None
        groups.move_to_end(self._group(key))
        return entries[key]

    def _keep(self, system: NonholonomicSystem, key: Hashable, built: T) -> T:
        with self._lock:
            groups: OrderedDict = self._store.setdefault(system, OrderedDict())
            groups.setdefault(self._group(key), {})[key] = built
            groups.move_to_end(self._group(key))
            while len(groups) > self._groups:
                groups.popitem(last=False)
        return built

    def __len__(self) -> int:
        """Return how many structures are held, over all systems."""
        with self._lock:
            return sum(len(entries) for groups in self._store.values()
                       for entries in groups.values())

    def _build_later(self, system: NonholonomicSystem, key: Hashable,
                     build: Callable[[], T]) -> None:
        ident = (id(system), key)
        with self._lock:
            if ident in self._building:
                return
            self._building.add(ident)
        held = weakref.ref(system)

        def work() -> None:
            try:
                built = build()
                alive = held()
                if alive is not None:
                    self._keep(alive, key, built)
            finally:
                with self._lock:
                    self._building.discard(ident)

        threading.Thread(target=work, name='nh_tracking_nlp_build', daemon=True).start()
