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

"""The installed parameter file and launch file.

Checked without the launch tooling (not installable here): the launch file is run against stand-ins
of the launch API that record what it asks for.
"""
import importlib.util
from pathlib import Path
import sys
import types

import pytest
import yaml

from nh_tracking.ros import planner_node, simulator_node
from nh_tracking.ros.parameters import MODEL, model_specs

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
SECTIONS = {'/**/nh_tracking_planner': planner_node.PARAMETERS,
            '/**/nh_tracking_sim': simulator_node.PARAMETERS}


def _console_scripts() -> set[str]:
    setup = (ROOT / 'setup.py').read_text()
    return {line.split('=')[0].strip(" '\"") for line in setup.splitlines()
            if '= nh_tracking' in line}


# what config/diff_drive.yaml (a Nav2 diff-drive robot) sets otherwise than the defaults
DIFF_DRIVE = {'model': 'unicycle', 'epsilon': 0.05, 'robot_radius': 0.2,
              'v_min': [-0.7, -3.0], 'v_max': [0.7, 3.0]}


@pytest.mark.parametrize('name, changed', [('sleigh.yaml', {}), ('diff_drive.yaml', DIFF_DRIVE)])
def test_parameter_files_list_every_parameter_with_its_default(name, changed):
    params = yaml.safe_load((ROOT / 'config' / name).read_text())
    assert set(params) == set(SECTIONS)
    for section, specs in SECTIONS.items():
        values = params[section]['ros__parameters']
        expected = {s.name: list(s.default) if isinstance(s.default, tuple) else s.default
                    for s in (MODEL, *specs, *model_specs(values['model']))}
        expected.update({k: v for k, v in changed.items() if k in expected})
        if section.endswith('sim'):
            expected['initial_state'] = [0.0] * 5
        assert values == expected, section


class _Recorder:
    """Stands in for a launch API class: keeps its arguments."""

    made: list = []

    def __init__(self, *args, **kwargs) -> None:
        self.args, self.kwargs = args, kwargs
        _Recorder.made.append(self)


def _stub_launch_api(monkeypatch) -> None:
    names = {'launch': ['LaunchDescription'], 'launch.actions': ['DeclareLaunchArgument'],
             'launch.conditions': ['IfCondition'],
             'launch.substitutions': ['LaunchConfiguration', 'PathJoinSubstitution'],
             'launch_ros.actions': ['Node'], 'launch_ros.substitutions': ['FindPackageShare']}
    for module, classes in names.items():
        stub = types.ModuleType(module)
        for cls in classes:
            setattr(stub, cls, type(cls, (_Recorder,), {}))
        monkeypatch.setitem(sys.modules, module, stub)
    monkeypatch.setitem(sys.modules, 'launch_ros', types.ModuleType('launch_ros'))


def test_launch_file_starts_installed_executables_with_declared_parameters(monkeypatch):
    _stub_launch_api(monkeypatch)
    _Recorder.made = []
    spec = importlib.util.spec_from_file_location('tracking_launch',
                                                  ROOT / 'launch' / 'tracking.launch.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    actions = description.args[0]
    arguments = {a.args[0]: a.kwargs for a in actions
                 if type(a).__name__ == 'DeclareLaunchArgument'}
    assert {'params_file', 'namespace', 'use_sim_time', 'autostart'} <= set(arguments)
    default_file = arguments['params_file']['default_value'].args[0]
    assert default_file[0].args == ('nh_tracking',)
    assert default_file[1:] == ['config', 'sleigh.yaml']
    assert (ROOT / 'config' / 'sleigh.yaml').exists()
    nodes = [a.kwargs for a in actions if type(a).__name__ == 'Node']
    rviz = [n for n in nodes if n['package'] == 'rviz2']
    nodes = [n for n in nodes if n['package'] != 'rviz2']
    assert {n['executable'] for n in nodes} == {'planner', 'sim'} <= _console_scripts()
    # RViz on request, with the installed configuration
    assert len(rviz) == 1 and 'rviz' in arguments
    assert rviz[0]['condition'].args[0].args == ('rviz',)
    assert rviz[0]['arguments'][0] == '-d'
    assert rviz[0]['arguments'][1].args[0][1:] == ['config', 'nh_tracking.rviz']
    declared = {'planner': {s.name for s in planner_node.PARAMETERS},
                'sim': {s.name for s in simulator_node.PARAMETERS}}
    for node in nodes:
        assert node['package'] == 'nh_tracking'
        assert node['name'] == {'planner': 'nh_tracking_planner',
                                'sim': 'nh_tracking_sim'}[node['executable']]
        overrides = [p for p in node['parameters'] if isinstance(p, dict)]
        for name in (k for p in overrides for k in p):
            assert name in declared[node['executable']] | {'use_sim_time'}, name
        launch_args = {p.args[0] for p in node['parameters']
                       if type(p).__name__ == 'LaunchConfiguration'}
        used = {v.args[0] for p in overrides for v in p.values()} | launch_args
        assert used <= set(arguments), used - set(arguments)
    # installed where `ros2 launch nh_tracking tracking.launch.py` looks
    setup = (ROOT / 'setup.py').read_text()
    assert "glob('launch/*.launch.py')" in setup and "glob('config/*.yaml')" in setup
    assert "glob('config/*.rviz')" in setup


def test_the_rviz_configuration_shows_what_the_nodes_publish_in_the_odom_frame():
    config = yaml.safe_load((ROOT / 'config' / 'nh_tracking.rviz').read_text())
    manager = config['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == 'odom'
    displays = {d['Class'].split('/')[-1]: d for d in manager['Displays']}
    assert {'TF', 'Odometry', 'Path', 'MarkerArray', 'Map'} <= set(displays)
    topics = {d['Topic']['Value'] for d in manager['Displays'] if 'Topic' in d}
    assert {'/odom', '/reference_path', '/planned_path', '/planned_markers', '/obstacles',
            '/costmap'} == topics
    latched = [d for d in manager['Displays']
               if d.get('Topic', {}).get('Value') in ('/planned_path', '/planned_markers')]
    assert all(d['Topic']['Durability Policy'] == 'Transient Local' for d in latched)


def test_ros_reference_parameter_tables_are_the_declared_ones():
    """The parameter tables of docs/ros.md are generated from the ROS descriptors' declarations.

    The same declarations give the checks and --help: regenerate the tables when a setting
    changes.
    """
    from nh_tracking.ros.parameters import parameter_table

    reference = (ROOT / 'docs' / 'ros.md').read_text()
    for specs in (planner_node.PARAMETERS, simulator_node.PARAMETERS):
        assert parameter_table(specs) in reference
