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

"""Lean derived equations: the expression graph AD builds, without what is constant or repeated.

Derived by automatic differentiation, the equations keep every intermediate of the derivation:
CasADi does not know that cos^2 + sin^2 = 1, that the metric on D of an orthonormal basis is the
identity (so its derivatives vanish and solving with it is a no-op), or that two differently built
subexpressions are the same function. Written by hand, none of that would be there, and every
solve evaluates what is left.

:func:`lean` rebuilds a Function's graph instruction by instruction while evaluating each
intermediate at random inputs of the model's domain (a probabilistic identity test: an analytic
expression that is not constant differs at random points with probability one). An intermediate
that takes one value at every sample becomes that constant (snapped to an integer when within
rounding of one); one that equals an earlier intermediate, or its negative, becomes that one.
CasADi's own simplifications (x*0, x*1, x+0, constant arithmetic) then fold whatever depended on
it. The result is checked against the original at fresh inputs and the original kept if they
differ — so the lean graph is never a different function, only a shorter one.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import casadi as ca
import numpy as np

from nh_tracking.core.regularity import Domain, random_configurations

SAMPLES = 12  # random inputs each intermediate is evaluated at
SAME = 1e-11  # relative spread (or difference) below which values are one value
AGREE = 1e-9  # lean vs original at fresh inputs, relative

Draw = Callable[[int], Sequence[np.ndarray]]  # seed -> one (SAMPLES, size) array per input
# Only polynomial and trigonometric arithmetic is folded, where a random-point identity test
# is sound: anything after another operation (non-smooth ones, and exp, tanh, atan2, ... that
# saturate or underflow to constants at the samples) is left as it is.
FOLDABLE = {ca.OP_ADD, ca.OP_SUB, ca.OP_MUL, ca.OP_DIV, ca.OP_NEG, ca.OP_SQ, ca.OP_TWICE,
            ca.OP_SIN, ca.OP_COS, ca.OP_SQRT, ca.OP_CONSTPOW, ca.OP_INV, ca.OP_ASSIGN}
UNARY: dict[int, Callable[[np.ndarray], np.ndarray]] = {
    ca.OP_NEG: np.negative, ca.OP_SQ: np.square, ca.OP_SQRT: np.sqrt, ca.OP_SIN: np.sin,
    ca.OP_COS: np.cos, ca.OP_TAN: np.tan, ca.OP_EXP: np.exp, ca.OP_LOG: np.log,
    ca.OP_TWICE: lambda x: 2.0 * x, ca.OP_INV: np.reciprocal, ca.OP_ASSIGN: np.copy}
BINARY: dict[int, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    ca.OP_ADD: np.add, ca.OP_SUB: np.subtract, ca.OP_MUL: np.multiply, ca.OP_DIV: np.divide,
    ca.OP_POW: np.power, ca.OP_CONSTPOW: np.power}


class _Node:
    """An intermediate: its expression, inputs it depends on and values at the samples.

    ``values[0]`` at the base samples, ``values[1 + j]`` with input element j redrawn.
    """

    __slots__ = ('expr', 'depends', 'values', 'rough')

    def __init__(self, expr: ca.SX, depends: frozenset[int], values: np.ndarray,
                 rough: bool = False) -> None:
        self.expr, self.depends, self.values, self.rough = expr, depends, values, rough


def lean(function: ca.Function, draw: Draw) -> ca.Function:
    """Rebuild ``function`` without constant, repeated or spuriously dependent intermediates.

    ``draw(seed)`` gives random inputs from where ``function`` will be evaluated (one
    (samples, size) array per input): seed 0 and 1 to fold, seed 2 to check the result.
    """
    symbols = [ca.SX.sym(name, function.size1_in(i), function.size2_in(i))
               for i, name in enumerate(function.name_in())]
    flat = ca.vertcat(*[ca.vec(s) for s in symbols])
    base, other = (np.hstack([np.asarray(x, float).reshape(SAMPLES, -1) for x in draw(seed)])
                   for seed in (0, 1))
    inputs = [_input(flat[j], j, base, other) for j in range(flat.shape[0])]
    offsets = np.cumsum([0] + [function.nnz_in(i) for i in range(function.n_in())])
    outputs = _Rebuild(flat, base).run(function, inputs, offsets)
    shaped = [ca.SX(function.sparsity_out(i), out) for i, out in enumerate(outputs)]
    result = ca.Function(function.name(), symbols, shaped, function.name_in(),
                         function.name_out(), {'cse': True})
    if result.n_instructions() >= function.n_instructions() or not _agree(
            function, result, draw(2)):
        return function
    return result


def draw_states(function: ca.Function, coordinates: Sequence[str], angles: Sequence[str],
                domain: Domain, sizes: Mapping[str, int],
                centres: Mapping[str, np.ndarray] | None = None) -> Draw:
    """Draw inputs for a function of (q[, v][, u][, p]): q in the domain, the others normal.

    An input in ``centres`` (physical parameters) is drawn around its values instead: within
    a factor of about 2 of each, keeping its sign (a zero one: normal).
    """
    centres = dict(centres or {})

    def draw(seed: int) -> list[np.ndarray]:
        rng = np.random.default_rng(seed)
        q = random_configurations(coordinates, angles, domain, rng, 4 * SAMPLES)
        q = q[[domain.contains(x) for x in q]][:SAMPLES]
        return [q if name == 'q' else _around(centres[name], rng) if name in centres
                else rng.normal(size=(SAMPLES, sizes[name])) for name in function.name_in()]
    return draw


def _around(centre: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    spread = rng.normal(scale=0.25, size=(SAMPLES, len(centre)))
    return np.where(centre == 0.0, spread, centre * np.exp(spread))


def _input(symbol: ca.SX, j: int, base: np.ndarray, other: np.ndarray) -> _Node:
    values = np.repeat(base[:, j][None, :], base.shape[1] + 1, axis=0)
    values[1 + j] = other[:, j]
    return _Node(symbol, frozenset((j,)), values)


class _Rebuild:
    def __init__(self, flat: ca.SX, base: np.ndarray) -> None:
        self.flat, self.base = flat, base
        self.seen: dict[bytes, ca.SX] = {}

    def run(self, function: ca.Function, inputs: list[_Node],
            offsets: np.ndarray) -> list[ca.SX]:
        work: dict[int, _Node] = {}
        outputs = [ca.SX.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        for k in range(function.n_instructions()):
            op, args = function.instruction_id(k), function.instruction_input(k)
            target = function.instruction_output(k)
            if op == ca.OP_OUTPUT:
                outputs[target[0]][target[1]] = work[args[0]].expr
            elif op == ca.OP_INPUT:
                work[target[0]] = inputs[offsets[args[0]] + args[1]]
            elif op == ca.OP_CONST:
                constant = function.instruction_constant(k)
                shape = inputs[0].values.shape
                work[target[0]] = _Node(ca.SX(constant), frozenset(), np.full(shape, constant))
            else:
                operands = [work[a] for a in args]
                work[target[0]] = self.fold(_apply(op, operands), operands, op)
        return outputs

    def fold(self, node: _Node, operands: list[_Node], op: int) -> _Node:
        """Replace ``node`` by the constant, reduced or earlier expression equal at the samples.

        Tolerances are relative to the node's own size (a 1e-12 term is kept), except that a
        sum or difference far below its operands is their cancellation, zero. Nothing built
        from a non-smooth operation is touched: a wall or a branch the samples missed would
        be folded away.
        """
        values = node.values
        if node.rough or node.expr.is_constant() or not np.all(np.isfinite(values)):
            return node
        size = float(np.abs(values).max())
        operand_size = max(float(np.abs(x.values).max()) for x in operands)
        if op in (ca.OP_ADD, ca.OP_SUB) and size <= SAME * operand_size:
            return self.constant(0.0, values.shape)
        if np.ptp(values) <= SAME * size:
            constant = float(np.mean(values))
            nearest = float(round(constant))
            return self.constant(nearest if abs(constant - nearest) <= SAME * size
                                 else constant, values.shape)
        change = np.ptp(values[1:] - values[0], axis=1)  # with each input redrawn
        spurious = [j for j in node.depends if change[j] <= SAME * size]
        if spurious:
            node = self.reduce(node, spurious)
        key = _key(values)
        if key in self.seen:
            return _Node(self.seen[key], node.depends, values)
        if _key(-values) in self.seen:
            return _Node(-self.seen[_key(-values)], node.depends, values)
        self.seen[key] = node.expr
        return node

    @staticmethod
    def constant(value: float, shape: tuple[int, ...]) -> _Node:
        return _Node(ca.SX(value), frozenset(), np.full(shape, value))

    def reduce(self, node: _Node, spurious: list[int]) -> _Node:
        """Substitute inputs the value does not depend on (cos^2 + sin^2 of a dropped angle)."""
        idx = list(spurious)
        for at in (np.zeros(len(idx)), self.base[0, idx]):  # 0 folds most (cos 0, sin 0)
            expr = ca.substitute(node.expr, self.flat[idx], ca.DM(at))
            reduced = ca.Function('reduced', [self.flat], [expr]).map(self.base.shape[0])
            if np.allclose(np.array(reduced(self.base.T)).ravel(), node.values[0],
                           rtol=10 * SAME, atol=10 * SAME * np.abs(node.values).max()):
                return _Node(expr, node.depends - set(idx), node.values)
        return node


def _apply(op: int, operands: list[_Node]) -> _Node:
    depends = frozenset().union(*(x.depends for x in operands))
    rough = op not in FOLDABLE or any(x.rough for x in operands) or _swamped(op, operands)
    shape = operands[0].values.shape
    with np.errstate(all='ignore'):
        if len(operands) == 1:
            x = operands[0]
            unary = UNARY.get(op)
            values = unary(x.values) if unary else np.array(
                ca.DM.unary(op, ca.DM(x.values.ravel()))).reshape(shape)
            return _Node(ca.SX.unary(op, x.expr), depends, values, rough)
        x, y = operands
        binary = BINARY.get(op)
        values = binary(x.values, y.values) if binary else np.array(ca.DM.binary(
            op, ca.DM(x.values.ravel()), ca.DM(y.values.ravel()))).reshape(shape)
    return _Node(ca.SX.binary(op, x.expr, y.expr), depends, values, rough)


def _swamped(op: int, operands: list[_Node]) -> bool:
    """Tell whether a sum adds a term invisible at the samples.

    E.g. 1e6 x^2 + 1e-6 sin y, or u minus a bump's force far from the bump: equal to its
    larger operand there, it must not be folded.
    """
    if op not in (ca.OP_ADD, ca.OP_SUB) or any(x.expr.is_constant() for x in operands):
        return False
    small, large = sorted(float(np.abs(x.values).max()) for x in operands)
    return 0.0 < small <= 1e-9 * large


def _key(values: np.ndarray) -> bytes:
    """Identify a node by its values at every sample and redraw, to 40 significant bits.

    The redraws too: two nodes equal at the base samples may still differ on them.
    """
    mantissa, exponent = np.frexp(values.ravel())
    return np.ldexp(np.round(mantissa * 2.0 ** 40), exponent).tobytes()


def _agree(original: ca.Function, result: ca.Function, check: Sequence[np.ndarray]) -> bool:
    """Whether ``result`` equals ``original`` at the samples, relative to each output's size."""
    expected, got = ([[np.array(x) for x in f.call(list(sample))] for sample in zip(*check)]
                     for f in (original, result))
    for i in range(original.n_out()):
        e, g = (np.stack([row[i] for row in rows]) for rows in (expected, got))
        if not np.allclose(g, e, rtol=AGREE, atol=AGREE * np.abs(e).max()):
            return False
    return True
