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

"""Compiled solver structures, built once per (owner, structure) and freed with the owner.

The owner is a system, or the family of systems whose NLPs take its parameters' values as
numbers (:class:`~nh_tracking.core.family.DynamicsFamily`). Per owner only the structures of the
few horizon sizes used last are kept: a parameter storm (every ``steps`` value in turn) must not
grow memory without bound.

A replanning loop must never stop to build one: inside :func:`builds_deferred` a structure not
built yet is built on a background thread instead, and the call raises :class:`NotPrepared`
(the loop keeps the plan in force and finds the structure ready later). A solve with a deadline
(inside :func:`builds_until`) waits for its build only until the deadline: a build is C++ that
cannot be stopped (seconds at thousands of intervals), so it goes on in the background and the
call raises :class:`NotPrepared` in time, the structure ready for a later call.
"""
from __future__ import annotations

import atexit
from collections import deque, OrderedDict
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager, nullcontext
from contextvars import ContextVar
from dataclasses import dataclass
import logging
import threading
import time
from typing import Generic, TypeVar
import weakref

from nh_tracking.core.family import DynamicsFamily
from nh_tracking.core.system import NonholonomicSystem

LOG = logging.getLogger(__name__)
T = TypeVar('T')
Owner = NonholonomicSystem | DynamicsFamily
GROUPS = 3  # horizon sizes kept per owner


@dataclass(frozen=True)
class _Policy:
    """How a missing structure is built: in the background only, or awaited until ``stop``."""

    deferred: bool = False
    stop: float | None = None


_POLICY: ContextVar[_Policy | None] = ContextVar('nh_tracking_builds', default=None)


class NotPrepared(RuntimeError):
    """The structure a solve needs is being built in the background."""


@contextmanager
def builds_deferred() -> Iterator[None]:
    """Within this block, missing structures are built in the background, never in line."""
    with _policy(_Policy(deferred=True)):
        yield


@contextmanager
def builds_inline() -> Iterator[None]:
    """Within this block, missing structures are built in line, whatever the deadline."""
    with _policy(_Policy()):
        yield


@contextmanager
def builds_until(stop: float | None) -> Iterator[None]:
    """Within this block, builds are awaited until ``stop`` (perf_counter clock) at most.

    Unless an enclosing block already says how to build (a replanning loop's).
    """
    with _policy(_Policy(stop=stop)) if _POLICY.get() is None else nullcontext():
        yield


@contextmanager
def _policy(policy: _Policy) -> Iterator[None]:
    token = _POLICY.set(policy)
    try:
        yield
    finally:
        _POLICY.reset(token)


def by_steps(key: Hashable) -> Hashable:
    """Group a transcription's key by its horizon size (the key's first field)."""
    return key[0]  # type: ignore[index]


class PerSystemCache(Generic[T]):
    """Building a CasADi NLP or flow takes far longer than solving it, so each is built once.

    Held per owner, and dropped with it: a cached structure must not reference its owner
    (the store holds the structure, so the weakly held owner would live on, with its NLPs).
    Keys are grouped (``group(key)``: a horizon size); per owner the ``groups`` used last are
    kept, an older group's structures are dropped together (a solve holding one keeps it alive).
    """

    def __init__(self, group: Callable[[Hashable], Hashable] = lambda key: key,
                 groups: int = GROUPS) -> None:
        self._store: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self._building: dict[tuple[int, Hashable], threading.Event] = {}
        self._errors: dict[tuple[int, Hashable], Exception] = {}
        self._lock = threading.Lock()
        self._group, self._groups = group, groups

    def get(self, owner: Owner, key: Hashable, build: Callable[[], T]) -> T:
        with self._lock:
            found = self._lookup(owner, key)
        if found is not None:
            return found
        policy = _POLICY.get() or _Policy()
        if policy.deferred:
            self._build_later(owner, key, build)
            raise NotPrepared(f'its NLP ({key}) was not prepared; it is being built in the '
                              'background')
        if policy.stop is None:
            return self._keep(owner, key, build())
        return self._await(owner, key, build, policy.stop)

    def ready(self, owner: Owner, key: Hashable, build: Callable[[], T]
              ) -> T | None:
        """Return the structure if built; else None, and it is built in the background."""
        with self._lock:
            found = self._lookup(owner, key)
        if found is None:
            self._build_later(owner, key, build)
        return found

    def _await(self, owner: Owner, key: Hashable, build: Callable[[], T],
               stop: float) -> T:
        """Build on a background thread and wait for it until ``stop``; raise if not done."""
        ident = (id(owner), key)
        done = self._build_later(owner, key, build)
        done.wait(max(0.0, stop - time.perf_counter()))
        with self._lock:
            found = self._lookup(owner, key)
            error = self._errors.pop(ident, None) if done.is_set() else None
        if found is not None:
            return found
        if error is not None:
            raise error
        raise NotPrepared(f'deadline reached while building its NLP ({key}); the build goes '
                          'on in the background, ready for a later call')

    def _lookup(self, owner: Owner, key: Hashable) -> T | None:
        groups: OrderedDict = self._store.setdefault(owner, OrderedDict())
        entries = groups.get(self._group(key))
        if entries is None or key not in entries:
            return None
        groups.move_to_end(self._group(key))
        return entries[key]

    def _keep(self, owner: Owner, key: Hashable, built: T) -> T:
        """Store ``built``; the groups it pushes out are freed after the lock is let go.

        (Freeing an NLP of GBs takes seconds, which a lookup must not wait for.)
        """
        dropped = []
        with self._lock:
            groups: OrderedDict = self._store.setdefault(owner, OrderedDict())
            groups.setdefault(self._group(key), {})[key] = built
            groups.move_to_end(self._group(key))
            while len(groups) > self._groups:
                dropped.append(groups.popitem(last=False))
        del dropped
        return built

    def held(self, owner: Owner) -> list[T]:
        """Return the structures held for ``owner`` (none built: empty)."""
        with self._lock:
            groups = self._store.get(owner, {})
            return [built for entries in groups.values() for built in entries.values()]

    def __len__(self) -> int:
        """Return how many structures are held, over all owners."""
        with self._lock:
            return sum(len(entries) for groups in self._store.values()
                       for entries in groups.values())

    def _build_later(self, owner: Owner, key: Hashable,
                     build: Callable[[], T]) -> threading.Event:
        """Queue a build (once) for the background builder; the event is set when it ends."""
        ident = (id(owner), key)
        with self._lock:
            if ident in self._building:
                return self._building[ident]
            done = self._building[ident] = threading.Event()
        held = weakref.ref(owner)

        def work() -> None:
            try:
                built = build()
                alive = held()
                if alive is not None:
                    self._keep(alive, key, built)
            except Exception as exc:  # noqa: B902 - handed to the caller that awaits it
                LOG.exception('building %s failed', key)
                with self._lock:
                    self._errors[ident] = exc
            finally:
                with self._lock:
                    del self._building[ident]
                done.set()

        _BUILDER.submit(work)
        return done


class _Builder:
    """One background thread builds the queued structures in turn.

    Builds at once would only share the GIL and add up their peak memory (a storm of horizon
    sizes, each up to GBs while its derivatives are formed). At exit the queue is dropped and
    the build under way awaited: CasADi torn down under a running build aborts the interpreter.
    """

    def __init__(self) -> None:
        self._jobs: deque[Callable[[], None]] = deque()
        self._lock = threading.Lock()
        self.idle = threading.Event()
        self.idle.set()
        atexit.register(self._drop_queue)

    def submit(self, job: Callable[[], None]) -> None:
        with self._lock:
            self._jobs.append(job)
            if self.idle.is_set():
                self.idle.clear()
                threading.Thread(target=self._run, name='nh_tracking_nlp_build',
                                 daemon=True).start()

    def _run(self) -> None:
        while True:
            with self._lock:
                if not self._jobs:
                    self.idle.set()
                    return
                job = self._jobs.popleft()
            job()

    def _drop_queue(self) -> None:
        with self._lock:
            self._jobs.clear()
        self.idle.wait()


_BUILDER = _Builder()


def await_builds(timeout: float | None = None) -> bool:
    """Wait until no structure is being built in the background; False if ``timeout`` passed."""
    return _BUILDER.idle.wait(timeout)
