"""Compiled solver structures, built once per (system, structure) and freed with the system."""
from __future__ import annotations

import weakref
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

from nh_tracking.system import NonholonomicSystem

T = TypeVar("T")


class PerSystemCache(Generic[T]):
    """Building a CasADi NLP or flow takes far longer than solving it, so each is built once."""

    def __init__(self) -> None:
        self._store: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    def get(self, system: NonholonomicSystem, key: Hashable, build: Callable[[], T]) -> T:
        per_system = self._store.setdefault(system, {})
        if key not in per_system:
            per_system[key] = build()
        return per_system[key]
