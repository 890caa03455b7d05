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

"""The command line and the ament_python packaging, exercised as a user would."""
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys

import pytest

from nh_tracking.examples.cli import main
from processes import domain_env, Process, starts_and_stops

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


@pytest.mark.unit
def test_simulate_command_writes_plot_and_summary(tmp_path):
    assert main(['simulate', '--duration', '10', '--out', str(tmp_path)]) == 0
    summary = json.loads((tmp_path / 'simulation.json').read_text())
    assert summary['model'] == 'chaplygin_sleigh'
    assert summary['energy_drift_max'] < 1e-6 * summary['energy_initial']
    assert summary['constraint_residual_max'] < 1e-9
    assert (tmp_path / 'simulation.png').stat().st_size > 10_000


@pytest.mark.unit
def test_simulate_command_reports_bad_input_without_traceback(tmp_path, capsys):
    assert main(['simulate', '--model', 'unicycle', '--q0', '1 2', '--out', str(tmp_path)]) == 2
    assert 'must have 3 entries' in capsys.readouterr().err
    assert main(['simulate', '--model', 'unicycle', '--param', 'm=-1',
                 '--out', str(tmp_path)]) == 2


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.skipif(not (BIN / 'colcon').exists(), reason='colcon is installed by requirements')
def test_colcon_build_installs_the_package_and_its_executables(tmp_path):
    src = tmp_path / 'src' / 'nh_tracking'
    files = subprocess.run(['git', 'ls-files', '--cached', '--others', '--exclude-standard'],
                           cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    for name in files:
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    env = dict(os.environ, PATH=f"{BIN}:{os.environ['PATH']}")
    build = subprocess.run([str(BIN / 'colcon'), 'build', '--base-paths', 'src'], cwd=tmp_path,
                           capture_output=True, text=True, env=env, timeout=300)
    assert build.returncode == 0, build.stdout + build.stderr
    install = tmp_path / 'install' / 'nh_tracking'
    assert (install / 'share/ament_index/resource_index/packages/nh_tracking').exists()
    assert (install / 'share/nh_tracking/package.xml').exists()
    site = next(install.glob('lib/python3*/site-packages'))
    env = dict(env, PYTHONPATH=str(site))
    run = subprocess.run([str(install / 'lib/nh_tracking/nh-tracking'), '--help'],
                         capture_output=True, text=True, env=env, timeout=60)
    assert run.returncode == 0 and 'usage' in run.stdout
    share = install / 'share' / 'nh_tracking'
    assert (share / 'config' / 'sleigh.yaml').exists()
    assert (share / 'launch' / 'tracking.launch.py').exists()
    for exe, ready in (('planner', 'planning for'), ('sim', 'simulating')):
        path = install / 'lib' / 'nh_tracking' / exe
        assert path.exists(), f'{exe} not installed to lib/nh_tracking'
        starts_and_stops(Process(str(path), ['--ros-args', '--params-file',
                                             str(share / 'config' / 'sleigh.yaml')],
                                 dict(domain_env(), PATH=env['PATH'],
                                      PYTHONPATH=env['PYTHONPATH'])), ready)


@pytest.mark.ros
def test_executable_reports_bad_parameters_without_traceback():
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    run = subprocess.run([str(BIN / 'sim'), '--ros-args', '-p', 'initial_state:=[1.0, 2.0]',
                          '-r', f'__ns:=/bad{os.getpid()}'],
                         capture_output=True, text=True, env=env, timeout=60)
    assert run.returncode == 2
    assert 'initial_state needs 5 finite numbers' in run.stderr
    assert 'Traceback' not in run.stdout + run.stderr


@pytest.mark.solve
@pytest.mark.slow
def test_reproduce_writes_metrics_and_figures(tmp_path):
    lines = []
    from nh_tracking.examples.experiments import reproduce

    metrics = reproduce(tmp_path, log=lines.append)
    assert any(line.startswith('[4/4]') for line in lines)  # progress was shown
    assert abs(metrics['sleigh']['cost'] - 42.369) < 0.085
    assert metrics['sleigh_wrapped']['cost'] < 20.0
    assert metrics['sleigh']['replay_end_error'] < 0.01
    assert len(metrics['sleigh']['local_minima']) > 1
    for case in ('particle_case1', 'particle_case2'):
        assert metrics[case]['pmp_success'] and metrics[case]['relative_difference'] < 3e-3
    saved = json.loads((tmp_path / 'metrics.json').read_text())
    assert saved['sleigh']['admissibility_residual'] <= 1e-10
    for name in ('sleigh', 'sleigh_wrapped', 'particle_case1', 'particle_case2',
                 'sleigh_energy'):
        assert (tmp_path / f'{name}.png').stat().st_size > 10_000
