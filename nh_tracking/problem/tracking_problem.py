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

"""The optimal tracking problem (paper §3) and what a solver returns.

Cost: 1/2 int (|q - q_r|^2 + |v - v_r|^2 + eps |u|^2) dt, plus omega/2 |q(T) - q_r(T)|^2 when
``terminal="cost"``; with ``terminal="equality"`` the end state equals the reference's.
"""
from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
import functools
import math
from typing import Literal

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from nh_tracking.core.system import NonholonomicSystem
from nh_tracking.core.trajectory import Trajectory
from nh_tracking.problem.attempts import Attempt, Status
from nh_tracking.problem.limits import BoundsLike, Limits

ReferenceFunction = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
Terminal = Literal['equality', 'cost']


@dataclass(frozen=True)
class TrackingProblem:
    """Track ``reference`` from (q0, v0) over ``horizon`` seconds on ``steps`` intervals.

    ``reference`` is a :class:`Trajectory` (interpolated in time) or a function of a times
    array returning (q (len, n), v (len, k)); ``t0`` is where on the reference's clock the
    problem starts (default: the reference's start). Outside a Trajectory's time span the
    reference holds its end configuration at rest (v_r = 0; before its start, its first
    configuration): a robot asked to track past the end stops there. With ``wrap_angles``
    (the default, what a robot needs) angle coordinates of the reference are moved by whole
    turns onto q0's branch, so heading errors are taken modulo 2 pi; ``wrap_angles=False``
    subtracts angles as numbers, the paper's literal formulation.

    Limits (:mod:`nh_tracking.problem.limits`): ``control_bounds`` and ``velocity_bounds`` are (lo,
    hi) pairs (scalars or one value per control/velocity, +-inf allowed) held on every interval's
    control and every knot's velocity; ``obstacles`` are discs (x, y, r) in the plane of the pose's
    position that the robot, a disc of ``robot_radius``, keeps clear of at every knot and interval
    midpoint, or moving discs (x, y, r, vx, vy): at (x, y) at the start, moving at a constant
    velocity (m/s), kept clear of where they are at each knot's and midpoint's time. A problem is
    immutable: ``dataclasses.replace(problem, steps=100)`` makes a changed copy.
    """

    system: NonholonomicSystem
    reference: Trajectory | ReferenceFunction
    q0: np.ndarray
    v0: np.ndarray
    horizon: float
    steps: int
    epsilon: float = 1.0
    terminal: Terminal = 'equality'
    omega: float = 1.0
    wrap_angles: bool = True
    t0: float | None = None
    control_bounds: BoundsLike = None
    velocity_bounds: BoundsLike = None
    obstacles: ArrayLike = ()
    robot_radius: float = 0.0
    angle_shift: np.ndarray = field(init=False, repr=False)
    limits: Limits = field(init=False, repr=False)

    def __post_init__(self) -> None:
        sys = self.system
        if not isinstance(sys, NonholonomicSystem):
            raise TypeError(f'system must be a NonholonomicSystem, got {type(sys).__name__}')
        if not (isinstance(self.reference, Trajectory) or callable(self.reference)):
            raise TypeError('reference must be a Trajectory or a function of times, got '
                            f'{type(self.reference).__name__}')
        set_ = functools.partial(object.__setattr__, self)
        set_('q0', sys.check_configuration(self.q0, 'q0').copy())
        set_('v0', sys.as_velocity(self.v0, 'v0').copy())
        if not np.isfinite(self.v0).all():
            raise ValueError('initial state (q0, v0) must be finite')
        for name in ('horizon', 'epsilon', 'omega'):
            value = _number(name, getattr(self, name))
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {value}')
            set_(name, value)
        steps = _number('steps', self.steps)
        if int(steps) != steps or steps < 2:
            raise ValueError(f'steps must be an integer >= 2, got {self.steps}')
        set_('steps', int(steps))
        if self.terminal not in ('equality', 'cost'):
            raise ValueError(f"terminal must be 'equality' or 'cost', got {self.terminal!r}")
        if self.t0 is None:
            set_('t0', float(self.reference.t[0]) if isinstance(self.reference, Trajectory)
                 else 0.0)
        t0 = _number('t0', self.t0)
        if not math.isfinite(t0):
            raise ValueError(f't0 must be finite, got {t0}')
        set_('t0', t0)
        if isinstance(self.reference, Trajectory):
            widths = (self.reference.q.shape[1], self.reference.v.shape[1])
            if widths != (sys.n, sys.k):
                raise ValueError(f'reference has q and v of widths {widths}; {sys.name} needs '
                                 f'({sys.n}, {sys.k}) (n configuration coordinates, k velocities)')
        set_('limits', Limits.of(sys, self.control_bounds, self.velocity_bounds, self.obstacles,
                                 self.robot_radius))
        set_('angle_shift', np.zeros(sys.n))
        if self.wrap_angles and sys.angle_mask.any():
            q_ref0 = self._raw_point(t0)[0]
            turns = np.rint((self.q0 - q_ref0) / (2 * np.pi))
            set_('angle_shift', np.where(sys.angle_mask, 2 * np.pi * turns, 0.0))

    @property
    def h(self) -> float:
        """Time step of the discretisation."""
        return self.horizon / self.steps

    @property
    def start(self) -> float:
        """Return t0, where the problem starts on the reference's clock (set by then)."""
        return 0.0 if self.t0 is None else self.t0

    @functools.cached_property
    def grid(self) -> np.ndarray:
        """The N+1 knot times on the reference's clock (read-only: computed once)."""
        grid = self.start + self.h * np.arange(self.steps + 1)
        grid.flags.writeable = False
        return grid

    def reference_at(self, times: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Return Reference (q_r, v_r) at ``times``, angles on q0's branch when wrapping."""
        q, v = self._raw_reference(np.atleast_1d(np.asarray(times, dtype=float)))
        return q + self.angle_shift, v

    @functools.cached_property
    def reference_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(q_r, v_r) at the N+1 knots and at the N interval midpoints, sampled once.

        Every solver and every read-out needs them, and replanning builds a problem per cycle.
        """
        q, v = self.reference_at(self.start + 0.5 * self.h * np.arange(2 * self.steps + 1))
        return q[::2], v[::2], q[1::2], v[1::2]  # knots and midpoints alternate

    def reference_point(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """(q_r, v_r) at one time, as 1-D arrays (fast path for ODE right-hand sides)."""
        q, v = self._raw_point(time)
        return q + self.angle_shift, v

    def _raw_point(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        if isinstance(self.reference, Trajectory):
            q, v = self.reference.at(time)
            if not self.reference.t[0] <= time <= self.reference.t[-1]:
                v = np.zeros_like(v)
            return q, v
        q, v = self._raw_reference(np.array([time]))
        return q[0], v[0]

    def _raw_reference(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n, k = self.system.n, self.system.k
        if isinstance(self.reference, Trajectory):  # finite, as every Trajectory is
            q, v = self.reference.sample(times)
            start, end = self.reference.t[0], self.reference.t[-1]
            if times.min() < start or times.max() > end:
                v[(times < start) | (times > end)] = 0.0  # at rest outside the reference's span
            return q, v
        try:
            q, v = self.reference(times)
            q = np.asarray(q, dtype=float).reshape(len(times), n)
            v = np.asarray(v, dtype=float).reshape(len(times), k)
        except (TypeError, ValueError) as exc:
            raise ValueError(f'reference(times) must return (q ({len(times)}, {n}), '
                             f'v ({len(times)}, {k})) arrays: {exc}') from None
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise ValueError('reference has non-finite values on the horizon')
        return q, v


def _number(name: str, value: object) -> float:
    """Return ``value`` as a float, or raise a TypeError naming it (numpy would say 'ufunc')."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise TypeError(f'{name} must be a number, got {value!r}')
    return float(value)


def tracking_residual(system: NonholonomicSystem) -> ca.Function:
    """r(q, v, u, q_r, v_r, eps) = (q - q_r, v - v_r, sqrt(eps) u): L = 1/2 |r|^2.

    The cost as a sum of squares, for Gauss-Newton steps; the Lagrangian is built from it.
    """
    q, qr = ca.SX.sym('q', system.n), ca.SX.sym('q_r', system.n)
    v, vr = ca.SX.sym('v', system.k), ca.SX.sym('v_r', system.k)
    u, eps = ca.SX.sym('u', system.r), ca.SX.sym('eps')
    return ca.Function('r', [q, v, u, qr, vr, eps], [ca.vertcat(q - qr, v - vr, ca.sqrt(eps) * u)],
                       ['q', 'v', 'u', 'q_r', 'v_r', 'eps'], ['r'])


def tracking_lagrangian(system: NonholonomicSystem) -> ca.Function:
    """L(q, v, u, q_r, v_r, eps) = 1/2 (|q - q_r|^2 + |v - v_r|^2 + eps |u|^2).

    One symbolic definition shared by every solver, so they optimise the same cost.
    """
    args = [ca.SX.sym(name, size) for name, size in (
        ('q', system.n), ('v', system.k), ('u', system.r), ('q_r', system.n),
        ('v_r', system.k), ('eps', 1))]
    value = 0.5 * ca.sumsqr(tracking_residual(system)(*args))
    return ca.Function('L', args, [value], ['q', 'v', 'u', 'q_r', 'v_r', 'eps'], ['L'])


def terminal_cost(problem: TrackingProblem, q_final: np.ndarray) -> float:
    """Omega Phi(gamma(T)) with Phi = 1/2 |q(T) - q_r(T)|^2 (zero for terminal equality)."""
    if problem.terminal != 'cost':
        return 0.0
    q_ref = problem.reference_samples[0][-1]
    return 0.5 * problem.omega * float(np.sum((q_final - q_ref) ** 2))


@dataclass(frozen=True)
class Multipliers:
    """The multipliers of an NLP's constraints at a plan, and which NLP's rows they belong to.

    A later solve of the same NLP (``layout`` equal) from this plan, shifted in time, starts
    its Newton steps' curvature from them, shifted the same: the first step is then Newton's,
    not Gauss-Newton's (:mod:`nh_tracking.solvers.duals`).
    """

    values: np.ndarray  # one per row of g, CasADi's sign (∇f + Gᵀλ = 0)
    t0: float  # the plan's first knot: the time axis the rows are placed on
    h: float
    layout: Hashable  # equal layouts: the same rows in the same order
    obstacles: np.ndarray  # the clearance rows' disc parameters: other discs, other rows


@dataclass(frozen=True)
class LimitCheck:
    """What a converged plan's limits call for, beyond whether it keeps them.

    ``least_violating``: its start breaks a limit, and it is the least-violating plan (a soft
    NLP's); ``other_disc``: it converged into a disc its clearance points were not given (solve
    again with the discs nearest it); ``through_disc``: clear at its points, it passes through a
    disc between two of them (solve again from rest).
    """

    least_violating: bool = False
    other_disc: bool = False
    through_disc: bool = False


@dataclass
class Solution:
    """A plan: knots t (N+1,), q (N+1, n), v (N+1, k); controls u (N, r) held per interval.

    ``u`` held on each interval replays the plan on the continuous dynamics (to the method's
    accuracy); where the optimal control is continuous in time (PMP), ``control_law(t)`` is
    that law. ``cost`` is the problem's cost as the method evaluates it (the discrete cost for
    the variational method); ``message`` the outcome in words; ``route`` says how the method
    got there; ``local_minimum`` is True where the KKT matrix's inertia at the plan proved a
    strict local minimum (False: not shown, or not one); ``costates`` holds (lambda (N+1, n),
    mu (N+1, k)) where the method provides them; ``minima`` lists the distinct local minima
    (cost, times found) of a multi-start search; ``details`` holds method-specific figures
    (e.g. the discrete admissibility residual, ``violation``: by how much a limit is broken);
    ``limit_check`` what its limits call for (a retry, or a least-violating plan);
    ``multipliers`` the NLP's multipliers, for a warm start from this plan;
    ``minimum_check()`` tells whether the KKT matrix's inertia proves it a strict local minimum,
    from what its solve had at hand (None: the method works it out again, if it can);
    ``attempts`` what ran, in order (:class:`~nh_tracking.problem.attempts.Attempt`: backend,
    status, iterations, time), of which ``route`` and ``message`` are the words;
    ``working_set_misses`` how many warm solves in a row, up to this plan, had a working set that
    did not settle (a warm start from it takes the count on).
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    cost: float
    success: bool
    iterations: int
    solve_time: float
    terminal_error: float
    method: str
    message: str = ''
    route: str = ''
    local_minimum: bool = False
    costates: tuple[np.ndarray, np.ndarray] | None = None
    minima: list[tuple[float, int]] = field(default_factory=list)
    details: dict[str, float] = field(default_factory=dict)
    limit_check: LimitCheck = LimitCheck()
    control_law: Callable[[float], np.ndarray] | None = field(default=None, repr=False)
    multipliers: Multipliers | None = field(default=None, repr=False)
    minimum_check: Callable[[], bool] | None = field(default=None, repr=False, compare=False)
    attempts: list[Attempt] = field(default_factory=list)
    working_set_misses: int = 0

    def follows(self, *earlier: Solution) -> Solution:
        """Count the solves that ran before this one in its time and attempts; return it."""
        self.solve_time += sum(plan.solve_time for plan in earlier)
        self.attempts[:0] = [attempt for plan in earlier for attempt in plan.attempts]
        return self

    @property
    def ran_out_of_time(self) -> bool:
        """Whether its last attempt stopped at its deadline (no other route has time after)."""
        return bool(self.attempts) and self.attempts[-1].status is Status.DEADLINE

    def trajectory(self) -> Trajectory:
        """Return the plan as a Trajectory (e.g. to use as a reference or to plot)."""
        return Trajectory(t=self.t, q=self.q, v=self.v, u=self.u)


def running_cost_profile(problem: TrackingProblem, solution: Solution) -> np.ndarray:
    """H L at each interval's midpoint: the discrete running action of a plan.

    Interval by interval (its sum is the variational method's running cost).
    """
    lagrangian = tracking_lagrangian(problem.system)
    q_ref, v_ref = problem.reference_samples[2:]
    q_mid = 0.5 * (solution.q[1:] + solution.q[:-1])
    v_mid = 0.5 * (solution.v[1:] + solution.v[:-1])
    values = lagrangian.map(problem.steps)(q_mid.T, v_mid.T, solution.u.T, q_ref.T, v_ref.T,
                                           problem.epsilon)
    return problem.h * np.array(values).ravel()


def terminal_error(problem: TrackingProblem, q_final: np.ndarray, v_final: np.ndarray) -> float:
    """|gamma(T) - gamma_r(T)|, angles on q0's branch when wrapping."""
    q_ref, v_ref = problem.reference_samples[0][-1], problem.reference_samples[1][-1]
    return float(np.linalg.norm(np.concatenate([q_final - q_ref, v_final - v_ref])))
