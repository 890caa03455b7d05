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

"""Settings as data: each field of a settings dataclass carries its meaning, unit and limits.

One declaration gives the check (:func:`check`), the ROS parameter descriptors and ``--help``
(:mod:`nh_tracking.ros.parameters`) and the parameter tables of docs/ros.md
(:func:`markdown_table`), so the three cannot disagree. The pattern of do-mpc's settings
dataclasses, with the limits machine-readable.
"""
from __future__ import annotations

import array
import dataclasses
from dataclasses import dataclass, field
from enum import Enum
import math
from typing import Any


class ValueEnum(str, Enum):
    """An enumeration of words: compares, prints and formats as its value."""

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class Setting:
    """What a settings field means: its description, unit, numeric bounds or choices."""

    description: str
    unit: str = ''
    bounds: tuple[float, float] | None = None
    choices: tuple[str, ...] = ()


def setting(default: Any, description: str, unit: str = '',
            bounds: tuple[float, float] | None = None, choices: tuple[str, ...] = ()) -> Any:
    """Return a dataclass field with its :class:`Setting` as metadata."""
    return field(default=default, metadata={'setting': Setting(description, unit, bounds,
                                                               choices)})


def described(cls: type) -> list[tuple[str, Any, Setting]]:
    """(name, default, setting) of each described field of a settings dataclass."""
    return [(f.name, f.default, f.metadata['setting']) for f in dataclasses.fields(cls)
            if 'setting' in f.metadata]


def check(value: Any, name: str, default: Any, meta: Setting) -> Any:
    """Return ``value`` as the type of ``default`` within ``meta``'s limits.

    ValueError names the field otherwise (an integer is accepted for a floating-point field).
    """
    kind = type(default)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if kind is tuple:  # a list of numbers (a ROS double array)
        return _numbers(value, name)
    if kind is list:  # a list of strings (a ROS string array)
        return _strings(value, name)
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise ValueError(f'{name} must be {_type_name(kind)}, got {value!r}')
    if meta.bounds is not None and not (math.isfinite(value)
                                        and meta.bounds[0] <= value <= meta.bounds[1]):
        raise ValueError(f'{name} must be in [{meta.bounds[0]:g}, {meta.bounds[1]:g}], '
                         f'got {value!r}')
    if meta.choices and value not in meta.choices:
        raise ValueError(f'{name} must be one of {list(meta.choices)}, got {value!r}')
    return value


def check_fields(obj: Any) -> None:
    """Check every described field of a frozen settings instance (coercing ints to floats)."""
    problems = []
    for name, default, meta in described(type(obj)):
        try:
            object.__setattr__(obj, name, check(getattr(obj, name), name, default, meta))
        except ValueError as exc:
            problems.append(str(exc))
    if problems:
        raise ValueError(f"invalid {type(obj).__name__}: {'; '.join(problems)}")


def _numbers(value: Any, name: str) -> tuple[float, ...]:
    if value is None:  # what a params file's [] becomes (rcl has no typed empty array)
        return ()
    # array('d'): how a double array set through the set_parameters service arrives
    if isinstance(value, array.array):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise ValueError(f'{name} must be a list of numbers, got {value!r}')
    if any(math.isnan(v) for v in value):
        raise ValueError(f'{name} must not contain NaN (use +-inf for no bound), got {value}')
    return tuple(float(v) for v in value)


def _strings(value: Any, name: str) -> list[str]:
    if value is None:
        return []
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise ValueError(f'{name} must be a list of strings, got {value!r}')
    return list(value)


def _type_name(kind: type) -> str:
    return {bool: 'true or false', int: 'an integer', float: 'a number',
            str: 'a string'}.get(kind, kind.__name__)


def markdown_table(rows: list[tuple[str, Any, Setting]]) -> str:
    """Return a parameter table (docs/ros.md): name, default, unit, range or choices, meaning."""
    lines = ['| parameter | default | unit | range | meaning |', '|---|---|---|---|---|']
    for name, default, meta in rows:
        limits = (f'{meta.bounds[0]:g} – {meta.bounds[1]:g}' if meta.bounds else
                  ' \\| '.join(meta.choices))
        shown = str(default).lower() if isinstance(default, bool) else (
            list(default) if isinstance(default, tuple) else default)
        lines.append(f'| `{name}` | `{shown}` | {meta.unit} | {limits} | {meta.description} |')
    return '\n'.join(lines)
