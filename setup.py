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

"""ament_python package setup: installs the library, the ament index marker, the executables.

The parameter file and the launch file.
"""
from glob import glob
from pathlib import Path
import re

from setuptools import find_packages, setup

package_name = 'nh_tracking'
# the version lives in package.xml alone (the ROS convention); Python reads it from here
version = re.search(r'<version>([^<]+)</version>',
                    (Path(__file__).parent / 'package.xml').read_text()).group(1)

setup(
    name=package_name,
    version=version,
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.rviz')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    extras_require={'bench': ['do-mpc==5.1.2']},
    zip_safe=True,
    maintainer='nh_tracking maintainers',
    maintainer_email='maintainers@nh-tracking.invalid',
    description='Optimal trajectory tracking for nonholonomic mechanical systems (ROS 2).',
    license='Apache-2.0',
    python_requires='>=3.10',
    entry_points={
        'console_scripts': [
            'nh-tracking = nh_tracking.examples.cli:main',
            'planner = nh_tracking.ros:planner_main',
            'sim = nh_tracking.ros:sim_main',
        ],
    },
)
