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

"""The ament linters' checks, run here without ament.

flake8 at ament_flake8's configuration (with pep257 docstrings, import order, quotes), licence
headers as ament_copyright wants them, package.xml against the format 3 rules, and mypy on the
package.
"""
from pathlib import Path
import subprocess
import sys
import xml.etree.ElementTree as ElementTree

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ['nh_tracking', 'test', 'launch', 'setup.py']
HEADER = ['# Copyright 2026 nh_tracking maintainers', '#',
          '# Licensed under the Apache License, Version 2.0 (the "License");']


def _python_files() -> list[Path]:
    listed = subprocess.run(['git', 'ls-files', '--cached', '--others', '--exclude-standard',
                             '*.py'], cwd=ROOT, capture_output=True, text=True, check=True)
    return [ROOT / name for name in listed.stdout.split() if (ROOT / name).exists()]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)


@pytest.mark.solve
@pytest.mark.slow
def test_flake8_at_the_ament_configuration():
    done = _run('flake8', *SOURCES)  # the [flake8] section of setup.cfg
    assert done.returncode == 0, done.stdout + done.stderr


@pytest.mark.unit
def test_every_python_file_has_the_licence_header():
    missing = [str(p.relative_to(ROOT)) for p in _python_files()
               if p.read_text().splitlines()[:3] != HEADER]
    assert missing == []


@pytest.mark.unit
def test_package_xml_is_format_3_with_its_required_elements_in_order():
    root = ElementTree.parse(ROOT / 'package.xml').getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    tags = [child.tag for child in root]
    required = ['name', 'version', 'description', 'maintainer', 'license']
    assert [t for t in tags if t in required][:5] == required  # REP 149's order
    assert root.findtext('name') == 'nh_tracking'
    assert root.find('export/build_type').text == 'ament_python'
    for dependency in root.iter('exec_depend'):
        assert dependency.text and dependency.text.strip() == dependency.text


@pytest.mark.solve
@pytest.mark.slow
@pytest.mark.timeout(600)
def test_mypy_is_clean_on_the_package():
    done = _run('mypy', 'nh_tracking')  # the [mypy] section of setup.cfg
    assert done.returncode == 0, done.stdout[-5000:] + done.stderr
