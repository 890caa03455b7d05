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

"""ROS messages to and from plain arrays, with validation; unit conversion only, no numerics.

Every ``*_to_arrays`` function either returns clean numbers or raises :class:`InputRejected`
with a reason a user can act on — the nodes log that reason once and keep their last good
plan (the pattern of ros2_controllers' ``validate_trajectory_msg``).
"""
from __future__ import annotations

from collections.abc import Sequence
import math

from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import (Pose, PoseStamped, Quaternion, Transform, Twist, TwistStamped,
                               Vector3)
from nav_msgs.msg import Odometry, Path
import numpy as np
from std_msgs.msg import Header
from trajectory_msgs.msg import (JointTrajectory, JointTrajectoryPoint, MultiDOFJointTrajectory,
                                 MultiDOFJointTrajectoryPoint)

from nh_tracking.poses import PoseMap
from nh_tracking.ros import cdr
from nh_tracking.trajectory import Trajectory

QUATERNION_TOLERANCE = 1e-3  # |q| may differ from 1 by this much (float32 round trips)
MAX_POSITION = 1e6  # m: finite but absurd values would overflow the numerics downstream
MAX_RATE = 1e3  # m/s, rad/s, and control effort per unit


class InputRejected(ValueError):
    """A message that cannot be used, with the reason."""


# time -----------------------------------------------------------------------------------------
def stamp_ns(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def time_msg(ns: int) -> Time:
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def duration_seconds(d: Duration) -> float:
    return d.sec + d.nanosec * 1e-9


def duration_msg(seconds: float) -> Duration:
    ns = int(round(seconds * 1e9))
    return Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


# orientation ----------------------------------------------------------------------------------
def _yaw(x: float, y: float, z: float, w: float) -> float:
    """Yaw of a unit quaternion (x, y, z, w); rejects non-finite and non-unit ones."""
    if not all(math.isfinite(c) for c in (x, y, z, w)):
        raise InputRejected('orientation has non-finite components')
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise InputRejected(f'orientation quaternion is not unit (norm {norm:.4g})')
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_of(yaw: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def _finite(values: Sequence[float], what: str, bound: float = MAX_POSITION) -> None:
    if not all(math.isfinite(v) for v in values):
        raise InputRejected(f'{what} has NaN or Inf values')
    if any(abs(v) > bound for v in values):
        raise InputRejected(f'{what} has values beyond {bound:g}')


def pose_array(pose: Pose, what: str) -> np.ndarray:
    """(x, y, z, yaw) of a pose, validated."""
    p, o = pose.position, pose.orientation
    return _pose((p.x, p.y, p.z, o.x, o.y, o.z, o.w), what)


def _pose(values: Sequence[float], what: str) -> np.ndarray:
    """(x, y, z, yaw) of (x, y, z, qx, qy, qz, qw), validated."""
    _finite(values[:3], f'{what} position')
    return np.array([*values[:3], _yaw(*values[3:])])


def twist_array(twist: Twist, what: str = 'twist') -> np.ndarray:
    """(vx, vy, vz, wz) of a twist, validated (roll and pitch rates are ignored)."""
    linear, angular = twist.linear, twist.angular
    return _twist((linear.x, linear.y, linear.z, angular.x, angular.y, angular.z), what)


def _twist(values: Sequence[float], what: str) -> np.ndarray:
    """(vx, vy, vz, wz) of (vx, vy, vz, wx, wy, wz), validated."""
    _finite(values, what, MAX_RATE)
    return np.array([*values[:3], values[5]])


def check_frame(frame_id: str, expected: str, what: str) -> None:
    if frame_id.lstrip('/') != expected.lstrip('/'):
        raise InputRejected(f"{what} is in frame '{frame_id}', expected '{expected}'")


def _increasing(times: np.ndarray, what: str) -> None:
    if len(times) < 2:
        raise InputRejected(f'{what} needs at least 2 points, got {len(times)}')
    if np.any(np.diff(times) <= 0):
        i = int(np.argmax(np.diff(times) <= 0))
        raise InputRejected(f'{what} times are not strictly increasing at point {i + 1} (each '
                            'point needs its own time: the stamp at which it is to be reached)')


# inputs ---------------------------------------------------------------------------------------
def path_to_arrays(msg: Path, frame: str, receipt_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Return (times [ns, absolute], poses (N, 4)) of a timed Path.

    Timing comes from each pose's stamp. A path whose header stamp is zero starts on receipt:
    its pose stamps are then offsets from the first pose's stamp.
    """
    if not msg.poses:
        raise InputRejected('path is empty')
    check_frame(msg.header.frame_id, frame, 'path')
    for i, ps in enumerate(msg.poses):
        if ps.header.frame_id:
            check_frame(ps.header.frame_id, frame, f'path pose {i}')
    stamps = np.array([stamp_ns(ps.header.stamp) for ps in msg.poses], dtype=np.int64)
    if stamp_ns(msg.header.stamp) == 0:
        stamps = stamps - stamps[0] + receipt_ns
    _increasing(stamps.astype(float), 'path')
    poses = np.array([pose_array(ps.pose, f'path pose {i}') for i, ps in enumerate(msg.poses)])
    return stamps, poses


def multidof_to_arrays(msg: MultiDOFJointTrajectory, frame: str, receipt_ns: int
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (times [ns], poses (N, 4), body twists (N, 4)) of a one-joint trajectory."""
    if not msg.points:
        raise InputRejected('trajectory has no points')
    if len(msg.joint_names) != 1:
        raise InputRejected(f'trajectory must have exactly 1 joint, got {len(msg.joint_names)}')
    check_frame(msg.header.frame_id, frame, 'trajectory')
    base = stamp_ns(msg.header.stamp) or receipt_ns
    poses, twists, times = [], [], []
    for i, pt in enumerate(msg.points):
        if len(pt.transforms) != 1 or len(pt.velocities) != 1:
            raise InputRejected(
                f'trajectory point {i} has {len(pt.transforms)} transforms and '
                f'{len(pt.velocities)} velocities for 1 joint')
        xyz, rotation = pt.transforms[0].translation, pt.transforms[0].rotation
        poses.append(_pose((xyz.x, xyz.y, xyz.z, rotation.x, rotation.y, rotation.z,
                            rotation.w), f'point {i}'))
        twists.append(twist_array(pt.velocities[0], f'point {i} velocity'))
        times.append(base + int(round(duration_seconds(pt.time_from_start) * 1e9)))
    stamps = np.array(times, dtype=np.int64)
    _increasing(stamps.astype(float), 'trajectory')
    return stamps, np.array(poses), np.array(twists)


def odom_to_arrays(msg: Odometry | bytes, frame: str) -> tuple[int, np.ndarray, np.ndarray]:
    """(stamp [ns], pose (4,), body twist (4,)) of an Odometry message or of its CDR bytes."""
    if isinstance(msg, bytes):  # from a raw subscription: read without building the message
        try:
            stamp, frame_id, values = cdr.odometry_values(msg)
        except cdr.Unreadable as exc:
            raise InputRejected(str(exc)) from None
    else:
        p, o = msg.pose.pose.position, msg.pose.pose.orientation
        linear, angular = msg.twist.twist.linear, msg.twist.twist.angular
        stamp, frame_id = stamp_ns(msg.header.stamp), msg.header.frame_id
        values = (p.x, p.y, p.z, o.x, o.y, o.z, o.w, linear.x, linear.y, linear.z, angular.x,
                  angular.y, angular.z)
    check_frame(frame_id, frame, 'odometry')
    return stamp, _pose(values[:7], 'odometry pose'), _twist(values[7:], 'odometry twist')


def controls_to_arrays(msg: JointTrajectory, names: Sequence[str]
                       ) -> tuple[int, np.ndarray, np.ndarray]:
    """(start stamp [ns], times from start (N,), efforts (N, k) in ``names`` order)."""
    if not msg.points:
        raise InputRejected('control sequence has no points')
    if sorted(msg.joint_names) != sorted(names):
        raise InputRejected(f'control sequence joints {list(msg.joint_names)} are not '
                            f'the controls {list(names)}')
    order = [list(msg.joint_names).index(n) for n in names]
    efforts, times = [], []
    for i, pt in enumerate(msg.points):
        if len(pt.effort) != len(names):
            raise InputRejected(f'control point {i} has {len(pt.effort)} efforts for '
                                f'{len(names)} joints')
        _finite(pt.effort, f'control point {i} effort', MAX_RATE)
        efforts.append([pt.effort[j] for j in order])
        times.append(duration_seconds(pt.time_from_start))
    times_arr = np.array(times)
    if len(times_arr) > 1:
        _increasing(times_arr, 'control sequence')
    return stamp_ns(msg.header.stamp), times_arr, np.array(efforts)


# outputs --------------------------------------------------------------------------------------
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


def multidof_msg(frame: str, start_ns: int, offsets: np.ndarray, poses: np.ndarray,
                 body_twists: np.ndarray, joint: str = 'base_link') -> MultiDOFJointTrajectory:
    """Return a one-joint trajectory: pose and body twist per point, timed from ``start_ns``."""
    points = []
    for dt, pose, twist in zip(offsets, poses, body_twists):
        point = MultiDOFJointTrajectoryPoint(time_from_start=duration_msg(float(dt)))
        point.transforms = [Transform(
            translation=Vector3(x=float(pose[0]), y=float(pose[1]), z=float(pose[2])),
            rotation=quaternion_of(float(pose[3])))]
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
