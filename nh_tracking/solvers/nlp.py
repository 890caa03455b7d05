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

"""One NLP solve under a wall-time limit, whatever the backend, with a status in words.

IPOPT is stopped by an iteration callback that reads the deadline of the solve in progress
(so one NLP serves every time limit). fatrop calls no callback: under a deadline it runs in
chunks of iterations, each warm-started from the last, until it converges, fails for another
reason, or the time is up — overrunning the limit by at most one chunk. A chunk is
:data:`FATROP_CHUNK` iterations for an equality-constrained NLP; with inequalities (limits) it
is :data:`FATROP_CHUNK_INTERIOR`, longer: every restart resets the interior-point barrier, so
chunks of :data:`FATROP_CHUNK` would keep a replanning solve with limits from converging.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import math
from pathlib import Path
import threading
import time
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from nh_tracking.problem.attempts import Status
from nh_tracking.solvers.compiled import LibraryBuild

MAX_ITERATIONS = 500
PACE_MAX = 0.1  # [s] the longest rest after a background build step
WARM_MU = 1e-5  # fatrop's initial barrier from a warm start with inequalities (default 0.1)
FATROP_CHUNK = 10
FATROP_CHUNK_INTERIOR = 50
FATROP_OPTIONS = {'print_level': 0, 'tol': 1e-10, 'max_iter': MAX_ITERATIONS}
IPOPT_OPTIONS: dict[str, Any] = {
    'ipopt.print_level': 0,
    'ipopt.sb': 'yes',
    'print_time': False,
    'ipopt.tol': 1e-10,
    'ipopt.constr_viol_tol': 1e-12,
    'ipopt.max_iter': MAX_ITERATIONS,
}
FATROP_STATUS = ('converged', 'maximum iterations reached', 'stopped at a tiny step',
                 'converged to the acceptable level', 'locally infeasible',
                 'feasible point found', 'diverging iterates', 'error in the step computation',
                 'invalid option', 'internal error')
DEADLINE = 'deadline reached'
STOPPED = 'User_Requested_Stop'  # IPOPT's status when the deadline's callback stopped it


def deadline_after(max_time: float | None) -> float | None:
    """Absolute stop time (perf_counter clock) of a solve allowed ``max_time`` seconds."""
    if max_time is None:
        return None
    if isinstance(max_time, bool) or not isinstance(max_time, (int, float)) or not (
            max_time > 0 and math.isfinite(max_time)):
        raise ValueError(f'max_time must be a finite number of seconds > 0, got {max_time!r}')
    return time.perf_counter() + float(max_time)


def before(stop: float | None) -> bool:
    """Whether an absolute stop time (or None: none) is still ahead."""
    return stop is None or time.perf_counter() < stop


class Pace:
    """Says whether a step as long as the longest so far still ends before an absolute stop.

    An iterative route asks before each step (a factorisation, an iteration, a chunk of them):
    it then returns by its stop, not one step after it. The first step may start whenever the
    stop is ahead.
    """

    def __init__(self, stop: float | None) -> None:
        self.stop = stop
        self.step = 0.0  # [s] the longest step so far
        self._began: float | None = None

    def has_time_for_step(self) -> bool:
        """Whether the next step, beginning now, would end before the stop."""
        now = time.perf_counter()
        if self._began is not None:
            self.step = max(self.step, now - self._began)
        self._began = now
        return self.stop is None or now + self.step < self.stop


def halfway(stop: float | None) -> float | None:
    """Return the stop time of a first try that leaves the next at least half the time left."""
    return None if stop is None else 0.5 * (time.perf_counter() + stop)


def status_message(status: object) -> str:
    """Put a solver's status in words: fatrop says 0, 1, ..., IPOPT 'Solve_Succeeded'."""
    text = str(status)
    if text.isdigit():
        code = int(text)
        return FATROP_STATUS[code] if code < len(FATROP_STATUS) else f'status {code}'
    if text == STOPPED:
        return DEADLINE
    return 'converged' if text == 'Solve_Succeeded' else text.replace('_', ' ').lower()


class _Deadline(ca.Callback):
    """IPOPT's iteration callback: asks it to stop once the solve's deadline has passed."""

    def __init__(self, nx: int, ng: int, np_: int) -> None:
        ca.Callback.__init__(self)
        self.sizes = {'x': nx, 'lam_x': nx, 'g': ng, 'lam_g': ng, 'lam_p': np_, 'f': 1}
        self.pace = Pace(None)
        self.construct('deadline', {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return 'stop'

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.sizes.get(ca.nlpsol_out(i), 0), 1)

    def eval(self, arg: Sequence[ca.DM]) -> list[ca.DM]:  # noqa: A003 - CasADi's name
        return [ca.DM(0.0 if self.pace.has_time_for_step() else 1.0)]


class Iterate(NamedTuple):
    """A primal-dual point of an NLP: its unknowns w and the multipliers of its rows g."""

    w: np.ndarray
    lam_g: np.ndarray

    @classmethod
    def of(cls, result: dict[str, Any]) -> Iterate:
        """Return the iterate of a CasADi NLP solver's result (x, lam_g)."""
        return cls(np.array(result['x']).ravel(), np.array(result['lam_g']).ravel())


@dataclass
class Outcome:
    """One backend's result: the iterate it ended at, and how it ended."""

    iterate: Iterate
    success: bool
    iterations: int
    message: str  # in words (the status below is read from the flags, not from these)
    minimum: bool = False  # the KKT matrix's inertia at x proved a strict local minimum
    minimum_check: Callable[[], bool] | None = None  # ... or how to tell, if not checked
    readout: list[np.ndarray] = field(default_factory=list)  # the plan read at x, if at hand
    not_finite: bool = False  # the NLP gives NaN or Inf at the guess, or at x
    to_convergence: bool = True  # False: a fixed number of steps (a real-time iteration)
    handed_over: bool = False  # Newton steps that did not settle: the next backend solves
    ran_out: bool = False  # stopped at its deadline (a step more would have passed it)

    @property
    def status(self) -> Status:
        if self.handed_over:
            return Status.HANDED_OVER
        if self.not_finite:
            return Status.NOT_FINITE
        if self.success:
            return Status.CONVERGED if self.to_convergence else Status.ITERATED
        return Status.DEADLINE if self.ran_out else Status.FAILED


def _paced_nlpsol(name: str, backend: str, source: dict[str, ca.SX] | str,
                  options: dict[str, Any]) -> ca.Function:
    """``ca.nlpsol``; off the main thread, followed by a rest as long as it took.

    Building holds the interpreter for tens of milliseconds at a time; a background build
    (after a parameter change, or loading a compiled library) that went on at full speed would
    starve the threads publishing the robot's commands. At half duty they keep their rates.
    """
    started = time.perf_counter()
    solver = ca.nlpsol(name, backend, source, options)
    if threading.current_thread() is not threading.main_thread():
        time.sleep(min(time.perf_counter() - started, PACE_MAX))
    return solver


class BoundedNlp:
    """An NLP solver whose every solve can be given a deadline."""

    def __init__(self, name: str, backend: str, nlp: dict[str, ca.SX], options: dict[str, Any],
                 bounded: bool, compiled: bool = False, inequalities: bool = False,
                 iterations: int = 0) -> None:
        """``bounded``: solves will be given deadlines; ``compiled``: NLP functions as C.

        ``iterations`` > 0: every solve takes at most that many iterations and counts as done
        when it has taken them (a real-time iteration), converged or not.
        """
        self.backend = backend
        self.iterations = iterations
        budget = iterations or MAX_ITERATIONS
        self._callback: _Deadline | None = None
        if backend == 'ipopt':
            options = {**IPOPT_OPTIONS, **options, 'ipopt.max_iter': budget}
            if bounded:
                sizes = (nlp['x'].numel(), nlp['g'].numel(), nlp['p'].numel())
                self._callback = _Deadline(*sizes)
                options['iteration_callback'] = self._callback
        else:
            options = {**options, 'fatrop': {**FATROP_OPTIONS, 'max_iter': budget}}
        self._name, self._options = name, options
        self._chunked = bounded and backend == 'fatrop' and not iterations
        self._chunk_size = FATROP_CHUNK_INTERIOR if inequalities else FATROP_CHUNK
        self._warm = backend == 'fatrop' and inequalities
        self.build = LibraryBuild.of_nlp(name, backend, nlp, options) if compiled else None
        library = self.build.library() if self.build is not None else None
        self.compiled = library is not None
        self._solvers = self._load(str(library) if library is not None else nlp)
        self.solver = self._solvers[False]
        if self.build is not None and not self.compiled:
            self.build.when_ready(self._use_library)

    def _load(self, source: dict[str, ca.SX] | str) -> dict[bool, ca.Function]:
        """Build the solvers: cold and warm; in chunks of iterations if bounded, else whole.

        Warm (with inequalities only): a small initial barrier, since the guess is near the
        optimum and a large barrier would push it away from its active constraints.
        """
        solvers: dict[bool, ca.Function] = {}
        for warm in (False, True) if self._warm else (False,):
            options = self._options
            if self.backend == 'fatrop':
                chunk = {'max_iter': self._chunk_size} if self._chunked else {}
                options = {**options, 'fatrop': {**options['fatrop'], **chunk,
                                                 **({'mu_init': WARM_MU} if warm else {})}}
            solvers[warm] = _paced_nlpsol(self._name, self.backend, source, options)
        return solvers

    def _use_library(self, library: Path) -> None:
        """Switch to the compiled library (on the compiler's thread; solves go on meanwhile)."""
        solvers = self._load(str(library))
        self._solvers, self.solver, self.compiled = solvers, solvers[False], True

    def solve(self, pace: Pace, warm: bool = False, **args: Any) -> Outcome:
        """Solve from ``args`` (x0, p, bounds); ``warm``: x0 is a near-optimal plan.

        ``pace``: the route's, its steps so far measured (none: the solve starts if its stop is
        ahead).
        """
        if not pace.has_time_for_step():  # not started
            return Outcome(Iterate(args['x0'], np.zeros(len(args['lbg']))), False, 0, DEADLINE,
                           ran_out=True)
        solver = self._solvers[warm and self._warm]  # (the set may be swapped meanwhile)
        if self._chunked:
            return self._chunks(solver, pace, args)
        if self._callback is not None:
            self._callback.pace = pace
        result = solver(**args)
        stats = solver.stats()
        status = stats.get('return_status', 'failed')
        message, success = status_message(status), bool(stats['success'])
        if self.iterations and message in (FATROP_STATUS[1], 'maximum number of iterations '
                                           'exceeded'):
            success, message = True, 'real-time iteration'
        return Outcome(Iterate.of(result), success, int(stats.get('iter_count', -1)), message,
                       ran_out=status == STOPPED)

    def _chunks(self, chunk: ca.Function, pace: Pace, args: dict[str, Any]) -> Outcome:
        """Solve in chunks of iterations, the next only if it ends before the pace's stop."""
        iterations = 0
        while True:
            result = chunk(**args)
            stats = chunk.stats()
            iterations += int(stats.get('iter_count', 0))
            message = status_message(stats.get('return_status', 'failed'))
            if stats['success'] or message != FATROP_STATUS[1]:
                return Outcome(Iterate.of(result), bool(stats['success']), iterations, message)
            if iterations >= MAX_ITERATIONS:
                return Outcome(Iterate.of(result), False, iterations, message)
            if not pace.has_time_for_step():
                return Outcome(Iterate.of(result), False, iterations, DEADLINE, ran_out=True)
            args = {**args, 'x0': result['x'], 'lam_g0': result['lam_g']}
