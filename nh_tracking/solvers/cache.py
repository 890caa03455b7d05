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

A replanning loop must never stop to build one: inside :func:`builds_deferred` a structure not
built yet is built on a background thread instead, and the call raises :class:`NotPrepared`
(the loop keeps the plan in force and finds the structure ready later).
"""
from __future__ import annotations

from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
import threading
from typing import Generic, TypeVar
import weakref

from nh_tracking.system import NonholonomicSystem

T = TypeVar('T')
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


class PerSystemCache(Generic[T]):
    """Building a CasADi NLP or flow takes far longer than solving it, so each is built once.

    Held per system, and dropped with it: a cached structure must not reference its system
    (the store holds the structure, so the weakly held system would live on, with its NLPs).
    """

    def __init__(self) -> None:
        self._store: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self._building: set[tuple[int, Hashable]] = set()
        self._lock = threading.Lock()

    def get(self, system: NonholonomicSystem, key: Hashable, build: Callable[[], T]) -> T:
        per_system = self._store.setdefault(system, {})
        if key in per_system:
            return per_system[key]
        if _DEFERRED.get():
            self._build_later(per_system, (id(system), key), key, build)
            raise NotPrepared(f'its NLP ({key}) was not prepared; it is being built in the '
                              'background')
        per_system[key] = build()
        return per_system[key]

    def _build_later(self, per_system: dict, ident: tuple[int, Hashable], key: Hashable,
                     build: Callable[[], T]) -> None:
        with self._lock:
            if ident in self._building:
                return
            self._building.add(ident)

        def work() -> None:
            try:
                per_system[key] = build()
            finally:
                with self._lock:
                    self._building.discard(ident)

        threading.Thread(target=work, name='nh_tracking_nlp_build', daemon=True).start()
