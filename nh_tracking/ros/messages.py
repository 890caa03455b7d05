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

"""Plain arrays as ROS messages: what the nodes publish (readings are in :mod:`conversions`)."""
from __future__ import annotations

from collections.abc import Sequence
import math

from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import (Pose, PoseStamped, Quaternion, Transform, TransformStamped,
                               Twist, TwistStamped, Vector3)
from nav_msgs.msg import Odometry, Path
import numpy as np
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import (JointTrajectory, JointTrajectoryPoint, MultiDOFJointTrajectory,
                                 MultiDOFJointTrajectoryPoint)

from nh_tracking.core.poses import PoseMap
from nh_tracking.core.trajectory import Trajectory


def time_msg(ns: int) -> Time:
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def duration_msg(seconds: float) -> Duration:
    ns = int(round(seconds * 1e9))
    return Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def quaternion_of(yaw: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def pose_msg(pose: np.ndarray, into: Pose | None = None) -> Pose:
    """(x, y, z, yaw) as a Pose, filled ``into`` an existing one if given."""
    msg = Pose() if into is None else into
    x, y, z, yaw = (float(c) for c in pose)
    msg.position.x, msg.position.y, msg.position.z = x, y, z
    msg.orientation.z, msg.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return msg


def _stamp(header: Header, frame: str, ns: int) -> Header:
    """Fill ``header`` in place: several times cheaper than keyword construction (replans)."""
    header.frame_id = frame
    header.stamp.sec, header.stamp.nanosec = divmod(int(ns), 1_000_000_000)
    return header


def path_msg(frame: str, stamps_ns: Sequence[int], poses: np.ndarray) -> Path:
    msg = Path()
    _stamp(msg.header, frame, stamps_ns[0])
    stamped = []
    for ns, pose in zip(stamps_ns, np.asarray(poses, dtype=float)):
        ps = PoseStamped()
        _stamp(ps.header, frame, ns)
        pose_msg(pose, ps.pose)
        stamped.append(ps)
    msg.poses = stamped
    return msg


def transform_msg(pose: np.ndarray) -> Transform:
    """(x, y, z, yaw) as a Transform."""
    return Transform(translation=Vector3(x=float(pose[0]), y=float(pose[1]), z=float(pose[2])),
                     rotation=quaternion_of(float(pose[3])))


def tf_msg(frame: str, child: str, stamp: int, pose: np.ndarray) -> TFMessage:
    """Return the transform ``frame`` -> ``child`` at ``pose``, as /tf carries it."""
    transform = TransformStamped(child_frame_id=child, transform=transform_msg(pose))
    _stamp(transform.header, frame, stamp)
    return TFMessage(transforms=[transform])


def joint_state_msg(stamp: int, names: Sequence[str], positions: np.ndarray,
                    velocities: np.ndarray) -> JointState:
    """Return the joints' positions and velocities at ``stamp`` (no frame: joints have none)."""
    msg = JointState(name=list(names), position=[float(p) for p in positions],
                     velocity=[float(v) for v in velocities])
    _stamp(msg.header, '', stamp)
    return msg


def multidof_msg(frame: str, start_ns: int, offsets: np.ndarray, poses: np.ndarray,
                 body_twists: np.ndarray, joint: str = 'base_link') -> MultiDOFJointTrajectory:
    """Return a one-joint trajectory: pose and body twist per point, timed from ``start_ns``."""
    points = []
    for dt, pose, twist in zip(offsets, poses, body_twists):
        point = MultiDOFJointTrajectoryPoint(time_from_start=duration_msg(float(dt)))
        point.transforms = [transform_msg(pose)]
        point.velocities = [twist_msg(twist)]
        points.append(point)
    return MultiDOFJointTrajectory(header=Header(frame_id=frame, stamp=time_msg(start_ns)),
                                   joint_names=[joint], points=points)


def control_sequence_msg(frame: str, start_ns: int, offsets: np.ndarray, names: Sequence[str],
                         efforts: np.ndarray) -> JointTrajectory:
    """One point per control interval: ``effort`` held from ``time_from_start`` on."""
    msg = JointTrajectory()
    _stamp(msg.header, frame, start_ns)
    msg.joint_names = list(names)
    points = []
    offsets_ns = np.round(np.asarray(offsets, dtype=float) * 1e9).astype(np.int64).tolist()
    for ns, effort in zip(offsets_ns, np.asarray(efforts, dtype=float).tolist()):
        point = JointTrajectoryPoint()
        point.effort = effort
        since = point.time_from_start
        since.sec, since.nanosec = divmod(ns, 1_000_000_000)
        points.append(point)
    msg.points = points
    return msg


def twist_msg(body_twist: np.ndarray) -> Twist:
    vx, vy, vz, wz = (float(x) for x in body_twist)
    return Twist(linear=Vector3(x=vx, y=vy, z=vz), angular=Vector3(z=wz))


def twist_stamped_msg(frame: str, stamp: int, body_twist: np.ndarray) -> TwistStamped:
    return TwistStamped(header=Header(frame_id=frame, stamp=time_msg(stamp)),
                        twist=twist_msg(body_twist))


def odometry_msg(frame: str, child: str, stamp: int, pose: np.ndarray,
                 body_twist: np.ndarray) -> Odometry:
    msg = Odometry(child_frame_id=child)
    _stamp(msg.header, frame, stamp)
    pose_msg(pose, msg.pose.pose)
    msg.twist.twist = twist_msg(body_twist)
    return msg


def reference_message(reference: Trajectory, pose_map: PoseMap, start: float, kind: str,
                      frame: str = 'odom'):
    """Return the reference as a Path or MultiDOFJointTrajectory, from ``start`` s on."""
    start_ns = int(round(start * 1e9))
    poses = np.array([pose_map.pose(q) for q in reference.q])
    if kind == 'path':
        return path_msg(frame, [start_ns + int(round(t * 1e9)) for t in reference.t], poses)
    twists = np.array([pose_map.body_twist(q, v) for q, v in zip(reference.q, reference.v)])
    return multidof_msg(frame, start_ns, reference.t, poses, twists)


def diagnostic_status(name: str, hardware_id: str, level: bytes, message: str,
                      values: dict[str, object]) -> DiagnosticStatus:
    """``level`` is one of DiagnosticStatus.OK, WARN, ERROR, STALE."""
    return DiagnosticStatus(
        level=level, name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
