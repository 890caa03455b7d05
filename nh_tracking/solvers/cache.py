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

"""Compiled solver structures, built once per (system, structure) and freed with the system."""
from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Generic, TypeVar
import weakref

from nh_tracking.system import NonholonomicSystem

T = TypeVar('T')


class PerSystemCache(Generic[T]):
    """Building a CasADi NLP or flow takes far longer than solving it, so each is built once."""

    def __init__(self) -> None:
        self._store: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    def get(self, system: NonholonomicSystem, key: Hashable, build: Callable[[], T]) -> T:
        per_system = self._store.setdefault(system, {})
        if key not in per_system:
            per_system[key] = build()
        return per_system[key]
