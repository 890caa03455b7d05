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


"""Compiled NLPs and steps: C code of their functions, built in the background, cached on disk.

Compiled, a solve's function evaluations cost a fraction of the interpreted ones (figures in
docs/performance.md). Building takes seconds to tens of seconds (growing with N), so it never
happens where a caller waits: a child process (at the lowest priority, one at a time)
generates the C code from the serialized NLP and compiles it, while solves go on interpreted;
the solver switches to the library when it is ready.

A library is keyed by its content — the serialized expressions, the solver and its options,
the CasADi version and the compiler's identity and flags — and kept in ``$NH_TRACKING_CACHE``
(default ``~/.cache/nh_tracking``): a stale library is never loaded, and a structure built
once per machine loads in milliseconds afterwards. Without a C compiler everything stays
interpreted, said once at INFO level.
"""
from __future__ import annotations

import atexit
from functools import lru_cache
import hashlib
import json
import logging
import os
from pathlib import Path
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from typing import Any, Callable

import casadi as ca

LOG = logging.getLogger(__name__)
FLAGS = ('-O1', '-fPIC', '-shared')
SOLVER_SETTINGS = ('fatrop', 'iteration_callback')  # not in the library: left out of its key


class _Job:
    """One library to build: its job directory, and how the build ended."""

    def __init__(self, directory: Path, library: Path) -> None:
        self.directory, self.library = directory, library
        self.finished = False  # the child has ended (under _LOCK)
        self.ready: list[Callable[[Path], None]] = []  # called with the library when built
        self.done = threading.Event()  # ... and after them
        self.error = ''
        self.child: subprocess.Popen | None = None
        self.cancelled = False  # (under _LOCK)


_BUILDS: dict[Path, _Job] = {}  # library -> its build, in this process
_QUEUE: queue.Queue[_Job] = queue.Queue()  # one build at a time: they compete for the CPU
_WORKER: list[threading.Thread] = []
_LOCK = threading.Lock()


def cache_dir() -> Path:
    return Path(os.environ.get('NH_TRACKING_CACHE', Path.home() / '.cache' / 'nh_tracking'))


@lru_cache(maxsize=None)
def compiler() -> tuple[str, str] | None:
    """Return the C compiler's path and identity (its --version line), or None (said once)."""
    path = shutil.which(os.environ.get('CC', 'gcc'))
    if path is None:
        LOG.info('no C compiler found (set CC): NLPs stay interpreted')
        return None
    done = subprocess.run([path, '--version'], capture_output=True, text=True)
    return path, done.stdout.splitlines()[0] if done.stdout else path


class LibraryBuild:
    """A shared library of CasADi functions: found in the cache, or built in the background.

    ``library()`` is its path once it exists (None before, and for good if it cannot be built).
    Made by :meth:`of_nlp` (an NLP solver's functions: CasADi's nlpsol loads them by name;
    solver settings — iteration limits, tolerances — are not part of the library, so NLPs that
    differ only in them share one) or :meth:`of_function` (one function, for ``ca.external``).
    """

    def __init__(self, function: ca.Function, job: dict[str, Any]) -> None:
        """Build ``function`` as the child's ``job`` says; both are the library's key."""
        tool = compiler()
        self.path: Path | None = None
        if tool is None:
            return
        serialized = function.serialize()
        content = json.dumps([job, ca.CasadiMeta.version(), tool[1], FLAGS], sort_keys=True,
                             default=str)
        digest = hashlib.sha256(serialized.encode() + content.encode()).hexdigest()[:24]
        self.path = cache_dir() / f"{job['kind']}-{digest}.so"
        if self.path.exists() or self.path in _BUILDS:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        build = _Job(Path(tempfile.mkdtemp(prefix='nh_tracking_build_')), self.path)
        (build.directory / 'function.casadi').write_text(serialized)
        (build.directory / 'job.json').write_text(json.dumps({
            **job, 'library': str(self.path), 'compiler': tool[0]}))
        LOG.info('compiling %s in the background into %s', job['name'], self.path)
        _BUILDS[self.path] = build
        _QUEUE.put(build)
        if not _WORKER:
            _WORKER.append(threading.Thread(target=_work, name='nh_tracking_compiler',
                                            daemon=True))
            _WORKER[0].start()

    @classmethod
    def of_nlp(cls, name: str, backend: str, nlp: dict[str, ca.SX],
               options: dict[str, Any]) -> LibraryBuild:
        kept = {k: v for k, v in options.items()
                if k not in SOLVER_SETTINGS and not k.startswith('ipopt.')}
        function = ca.Function('nlp', [nlp['x'], nlp['p']], [nlp['f'], nlp['g']])
        return cls(function, {'kind': 'nlp', 'name': name, 'backend': backend,
                              'options': kept})

    @classmethod
    def of_function(cls, function: ca.Function) -> LibraryBuild:
        return cls(function, {'kind': 'function', 'name': function.name()})

    def when_ready(self, use: Callable[[Path], None]) -> None:
        """Call ``use(library)`` on the compiler's thread once it is built (never if it fails).

        So that loading it (tens of milliseconds in CasADi) happens off the solver's thread.
        """
        job = _BUILDS.get(self.path) if self.path is not None else None
        with _LOCK:
            if job is not None and not job.finished:
                job.ready.append(use)
                return
        if self.path is not None and self.path.exists():
            use(self.path)

    def library(self) -> Path | None:
        if self.path is None:
            return None
        if self.path.exists():
            return self.path
        job = _BUILDS.get(self.path)
        if job is not None and job.done.is_set():
            LOG.warning('compiling failed, staying interpreted: %s', job.error)
            self.path = None
        return None


def _work() -> None:
    """Run the queued builds one after the other, each a child process at low priority."""
    nice = shutil.which('nice')
    while True:
        job = _QUEUE.get()
        command = [sys.executable, '-m', 'nh_tracking.solvers.compiled', str(job.directory)]
        with _LOCK:
            if not job.cancelled:
                job.child = subprocess.Popen(
                    [nice, '-n', '19', *command] if nice else command,
                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
        if job.child is not None:
            _, error = job.child.communicate()
            job.error = error.decode()[-500:] if job.child.returncode else ''
        if job.cancelled:
            job.error = 'cancelled'
        shutil.rmtree(job.directory, ignore_errors=True)
        with _LOCK:
            job.finished = True
            users = [] if job.error else list(job.ready)
            job.ready.clear()  # they hold their NLPs: let them go with their systems
        for use in users:
            try:
                use(job.library)
            except Exception as exc:  # noqa: BLE001 - a bad library must not stop the others
                LOG.warning('loading the compiled %s failed, staying interpreted: %s',
                            job.library, exc)
        job.done.set()


def cancel_builds() -> int:
    """Stop every build not finished, its compiler too; return how many (asked again: anew)."""
    with _LOCK:
        jobs = [job for job in _BUILDS.values() if not job.finished]
        for job in jobs:
            job.cancelled = True
            job.ready.clear()
            del _BUILDS[job.library]
    for job in jobs:
        _stop(job)
    if jobs:
        LOG.info('cancelled %d background builds', len(jobs))
    return len(jobs)


def _stop(job: _Job) -> None:
    if job.child is not None and job.child.poll() is None:
        try:
            os.killpg(job.child.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass


def wait_for_builds(timeout: float = 600.0) -> None:
    """Block until every background build of this process has ended (benchmarks, tests)."""
    for job in list(_BUILDS.values()):
        if not job.done.wait(timeout):
            LOG.warning('a background NLP build is still running after %.0f s', timeout)


@atexit.register
def _stop_builds() -> None:
    """Stop an unfinished build (and its compiler) when the process that wanted it ends.

    Its working directory goes too: the compiler's thread, which would remove it, is a daemon
    that never gets there: without this, each queued build would leave its directory behind.
    """
    for job in _BUILDS.values():
        _stop(job)
        if not job.finished:
            shutil.rmtree(job.directory, ignore_errors=True)


def _build(job: Path) -> None:
    """Do the child's work: the functions as C, compiled, then moved in atomically."""
    spec = json.loads((job / 'job.json').read_text())
    function = ca.Function.deserialize((job / 'function.casadi').read_text())
    generator = ca.CodeGenerator(f"{spec['kind']}.c")
    if spec['kind'] == 'nlp':  # the solver's own functions, by the names nlpsol looks up
        x, p = ca.SX.sym('x', function.size1_in(0)), ca.SX.sym('p', function.size1_in(1))
        f, g = function(x, p)
        solver = ca.nlpsol(spec['name'], spec['backend'], {'x': x, 'p': p, 'f': f, 'g': g},
                           spec['options'])
        generator.add(solver.oracle())
        for name in solver.get_function():
            generator.add(solver.get_function(name))
    else:
        generator.add(function)
    source = generator.generate(str(job) + os.sep)
    library = Path(spec['library'])
    partial = library.with_suffix(f'.{os.getpid()}.tmp')
    done = subprocess.run([spec['compiler'], *FLAGS, source, '-o', str(partial)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        partial.unlink(missing_ok=True)
        sys.exit(done.stderr[-500:])
    partial.replace(library)  # atomic: concurrent builders never load a partial file


if __name__ == '__main__':
    _build(Path(sys.argv[1]))
