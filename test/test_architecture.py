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

"""The package's shape: layers that only import downwards, small modules.

The version in one place, and new robots, methods and interfaces each as one new file plus one
registry line.
"""
import ast
from pathlib import Path
import re

import pytest

import nh_tracking

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / 'nh_tracking'
LAYERS = [  # lowest first; a module may import from its own layer and the ones below
    {'core'},
    {'models'},
    {'problem', 'estimation'},
    {'solvers'},
    {'planning', 'navigation'},
    {'session'},
    {'ros'},
    {'examples'},
]
MAX_LINES = 400  # a guide that flags a module to look at, not a reason to split one
ROS = re.compile(r'^(rclpy|rcl_interfaces|\w+_msgs|std_srvs|builtin_interfaces|launch)\b')


def _layer(module: str) -> int:
    first = module.split('.')[1]
    return next(i for i, names in enumerate(LAYERS) if first in names)


def _modules():
    for path in sorted(PACKAGE.rglob('*.py')):
        name = '.'.join(path.relative_to(ROOT).with_suffix('').parts)
        if name != 'nh_tracking.__init__':  # the top-level API re-exports lower layers
            yield name.removesuffix('.__init__'), path


def _imports(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):  # function-level imports count too
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module == 'nh_tracking':
            found += [f'nh_tracking.{a.name}' for a in node.names if a.name in _packages()]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append(node.module)
    return found


def _packages() -> set[str]:
    return {p.parent.name for p in PACKAGE.glob('*/__init__.py')}


def test_every_module_lives_in_a_layer():
    """The tree is the architecture: no module beside the packages, each package a layer."""
    loose = sorted(p.name for p in PACKAGE.glob('*.py') if p.name != '__init__.py')
    assert loose == []
    assert _packages() == set().union(*LAYERS)


def test_the_user_guide_lists_the_packages():
    """The layout table names each package once, in the order of the layers, with its modules."""
    table = (ROOT / 'docs' / 'user_guide.md').read_text().split('## Layout', 1)[1]
    rows = re.findall(r'^\| `nh_tracking/(\w+)/` \|[^|]*\|([^|]*)\|$', table, re.M)
    assert [name for name, _ in rows] == [name for layer in LAYERS for name in sorted(layer)]
    for name, cell in rows:
        if listed := re.findall(r'`(\w+)`', cell):  # a row that names modules names them all
            modules = {p.stem for p in (PACKAGE / name).glob('*.py')} - {'__init__'}
            assert sorted(listed) == sorted(modules), name


def test_no_module_imports_from_a_layer_above_it():
    upward = []
    for module, path in _modules():
        for imported in _imports(path):
            if imported.startswith('nh_tracking.') and _layer(imported) > _layer(module):
                upward.append(f'{module} imports {imported}')
    assert upward == []


def test_only_the_ros_layer_and_examples_import_ros():
    offenders = [f'{module} imports {imported}' for module, path in _modules()
                 if _layer(module) < _layer('nh_tracking.ros')
                 for imported in _imports(path) if ROS.match(imported)]
    assert offenders == []


def _length(path: Path) -> int:
    """Lines after the licence header."""
    lines = path.read_text().splitlines()
    return len(lines) - next(i for i, line in enumerate(lines) if not line.startswith('#'))


def test_no_module_is_long():
    """Modules split where the seams are; one past this length is worth a look for one."""
    long = {m: n for m, p in _modules() if (n := _length(p)) > MAX_LINES}
    assert long == {}


RCLPY_PRIVATE = 'nh_tracking.ros.rclpy_private'  # the one module that may use rclpy's privates
RCLPY_PRIVATE_NAMES = {'_state_machine', '_service_change_state', '_parameter_overrides',
                       '_take_service'}  # those it uses


def _private_uses(path: Path) -> list[str]:
    """Return where ``path`` reads a private attribute off anything but ``self`` or ``cls``.

    Or names one of :data:`RCLPY_PRIVATE_NAMES` at all (on ``self``, in an override, as a
    string).
    """
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Attribute):
            name = node.attr
            dunder = name.startswith('__') and name.endswith('__')
            own = isinstance(node.value, ast.Name) and node.value.id in ('self', 'cls')
            if name in RCLPY_PRIVATE_NAMES or (name.startswith('_') and not dunder and not own):
                found.append(f'{node.lineno}: .{name}')
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) \
                and node.name in RCLPY_PRIVATE_NAMES:
            found.append(f'{node.lineno}: def {node.name}')
        elif isinstance(node, ast.Constant) and node.value in RCLPY_PRIVATE_NAMES:
            found.append(f'{node.lineno}: {node.value!r}')
    return found


def test_only_one_module_uses_rclpys_private_attributes():
    """The layers that import rclpy reach into its objects only through :data:`RCLPY_PRIVATE`.

    There each use is a small function saying which public API is missing, so a new rclpy that
    changes them breaks one module.
    """
    offenders = {module: uses for module, path in _modules()
                 if _layer(module) >= _layer('nh_tracking.ros') and module != RCLPY_PRIVATE
                 and (uses := _private_uses(path))}
    assert offenders == {}
    assert _private_uses(PACKAGE / 'ros' / 'rclpy_private.py')  # (the rule sees them there)


def test_the_version_has_one_source():
    xml = re.search(r'<version>([^<]+)</version>', (ROOT / 'package.xml').read_text()).group(1)
    assert nh_tracking.__version__ == xml
    assert re.search(rf'^{re.escape(xml)} \(', (ROOT / 'CHANGELOG.rst').read_text(), re.M)


def test_registries_are_one_line_each():
    """Check that a model or a method is a module of its own and one registry entry.

    This is what a user's pull request for a new one would touch.
    """
    from nh_tracking import models, solvers

    for spec in models.MODELS.values():
        assert spec.factory.__module__ == f'nh_tracking.models.{spec.name}'
    for name, method in solvers.METHODS.items():
        assert method.__module__.startswith('nh_tracking.solvers.') and method.name == name
