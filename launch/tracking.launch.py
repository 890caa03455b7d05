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

"""Planner and simulator for one robot: ``ros2 launch nh_tracking tracking.launch.py``.

Arguments: ``params_file`` (default: the installed config/sleigh.yaml), ``namespace`` (one
robot per namespace), ``use_sim_time``, ``autostart`` (false: the planner waits for a lifecycle
manager to configure and activate it, as Nav2's servers do), ``rviz`` (true: RViz 2 with the
installed config/nh_tracking.rviz: the robot via /tf, odometry, reference, plan, obstacles).
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    params_file = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    use_sim_time = LaunchConfiguration('use_sim_time')
    autostart = LaunchConfiguration('autostart')
    share = FindPackageShare('nh_tracking')
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution(
                [share, 'config', 'sleigh.yaml']),
            description='parameter file for both nodes (standard ros__parameters layout)'),
        DeclareLaunchArgument('namespace', default_value='',
                              description="namespace of this robot's nodes and topics"),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='follow /clock'),
        DeclareLaunchArgument('autostart', default_value='true',
                              description='planner configures and activates itself'),
        DeclareLaunchArgument('rviz', default_value='false',
                              description='start RViz 2 with config/nh_tracking.rviz'),
        Node(package='nh_tracking', executable='planner', name='nh_tracking_planner',
             namespace=namespace, output='screen',
             parameters=[params_file, {'use_sim_time': use_sim_time,
                                       'autostart': autostart}]),
        Node(package='nh_tracking', executable='sim', name='nh_tracking_sim',
             namespace=namespace, output='screen',
             parameters=[params_file, {'use_sim_time': use_sim_time}]),
        Node(package='rviz2', executable='rviz2', name='rviz2', output='screen',
             arguments=['-d', PathJoinSubstitution([share, 'config', 'nh_tracking.rviz'])],
             parameters=[{'use_sim_time': use_sim_time}],
             condition=IfCondition(LaunchConfiguration('rviz'))),
    ])
