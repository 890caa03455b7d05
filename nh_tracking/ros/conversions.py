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

"""ROS messages read into plain arrays, with validation; unit conversion only, no numerics.

Every ``*_to_arrays`` function either returns clean numbers or raises :class:`InputRejected`
with a reason a user can act on — the nodes log that reason once and keep their last good
plan (the pattern of ros2_controllers' ``validate_trajectory_msg``).
"""
from __future__ import annotations

from collections.abc import Sequence
import math

from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Pose, Twist
from nav_msgs.msg import Odometry, Path
import numpy as np
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory

from nh_tracking.ros import cdr

QUATERNION_TOLERANCE = 1e-3  # |q| may differ from 1 by this much (float32 round trips)
MAX_POSITION = 1e6  # m: finite but absurd values would overflow the numerics downstream
MAX_RATE = 1e3  # m/s, rad/s, and control effort per unit


class InputRejected(ValueError):
    """A message that cannot be used, with the reason."""


# time -----------------------------------------------------------------------------------------
def stamp_ns(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def duration_seconds(d: Duration) -> float:
    return d.sec + d.nanosec * 1e-9


# orientation ----------------------------------------------------------------------------------
def _yaw(x: float, y: float, z: float, w: float) -> float:
    """Yaw of a unit quaternion (x, y, z, w); rejects non-finite and non-unit ones."""
    if not all(math.isfinite(c) for c in (x, y, z, w)):
        raise InputRejected('orientation has non-finite components')
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise InputRejected(f'orientation quaternion is not unit (norm {norm:.4g})')
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _finite(values: Sequence[float], what: str, bound: float = MAX_POSITION) -> None:
    if not all(math.isfinite(v) for v in values):
        raise InputRejected(f'{what} has NaN or Inf values')
    if any(abs(v) > bound for v in values):
        raise InputRejected(f'{what} has values beyond {bound:g}')


def pose_array(pose: Pose, what: str) -> np.ndarray:
    """(x, y, z, yaw) of a pose, validated."""
    p, o = pose.position, pose.orientation
    return pose_values((p.x, p.y, p.z, o.x, o.y, o.z, o.w), what)


def _poses(values: np.ndarray, what: str) -> np.ndarray:
    """(x, y, z, yaw) rows of (x, y, z, qx, qy, qz, qw) rows, validated; errors name the row."""
    bad = ~np.isfinite(values).all(axis=1) | (np.abs(values[:, :3]) > MAX_POSITION).any(axis=1)
    bad |= np.abs(np.linalg.norm(values[:, 3:], axis=1) - 1.0) > QUATERNION_TOLERANCE
    if bad.any():
        i = int(np.argmax(bad))
        pose_values(values[i], f'{what} {i}')  # raises, saying what is wrong
    x, y, z, w = values[:, 3:].T
    return np.c_[values[:, :3], np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))]


def pose_values(values: Sequence[float], what: str) -> np.ndarray:
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
def path_to_arrays(msg: Path | bytes, frame: str, receipt_ns: int
                   ) -> tuple[np.ndarray | None, np.ndarray]:
    """Return (times [ns, absolute], poses (N, 4)) of a Path (or of its CDR bytes).

    Timing comes from each pose's stamp; a path whose header stamp is zero starts on receipt,
    its pose stamps then offsets from the first pose's stamp. A path whose poses all carry one
    stamp (what Nav2's planners publish) is an untimed route: times None.
    """
    if isinstance(msg, bytes):  # from a raw subscription: read without building the message
        try:
            header_ns, frame_id, stamps, values, frames = cdr.path_values(msg)
        except cdr.Unreadable as exc:
            raise InputRejected(str(exc)) from None
    else:
        header_ns, frame_id = stamp_ns(msg.header.stamp), msg.header.frame_id
        stamps = np.array([stamp_ns(ps.header.stamp) for ps in msg.poses], dtype=np.int64)
        values = np.array([(ps.pose.position.x, ps.pose.position.y, ps.pose.position.z,
                            ps.pose.orientation.x, ps.pose.orientation.y,
                            ps.pose.orientation.z, ps.pose.orientation.w)
                           for ps in msg.poses]).reshape(-1, 7)
        frames = {}
        for i, ps in enumerate(msg.poses):
            frames.setdefault(ps.header.frame_id, i)
    if not len(stamps):
        raise InputRejected('path is empty')
    check_frame(frame_id, frame, 'path')
    for pose_frame, i in frames.items():
        if pose_frame:
            check_frame(pose_frame, frame, f'path pose {i}')
    poses = _poses(values, 'path pose')
    if (stamps == stamps[0]).all():
        return None, poses
    if header_ns == 0:
        stamps = stamps - stamps[0] + receipt_ns
    _increasing(stamps.astype(float), 'path')
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
        poses.append(pose_values((xyz.x, xyz.y, xyz.z, rotation.x, rotation.y, rotation.z,
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
    return stamp, pose_values(values[:7], 'odometry pose'), _twist(values[7:], 'odometry twist')


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


def joint_state_arrays(msg: JointState) -> tuple[int, list[str], np.ndarray, np.ndarray]:
    """(stamp [ns], names, positions, velocities (empty: not given)) of a JointState.

    Joints of other parts of the robot may be NaN; the hidden coordinates' values are checked
    where they are read (:mod:`nh_tracking.core.joints`).
    """
    names, count = list(msg.name), len(msg.name)
    if len(msg.position) != count:
        raise InputRejected(f'joint_states has {count} names and {len(msg.position)} positions')
    if len(msg.velocity) not in (0, count):
        raise InputRejected(f'joint_states has {count} names and {len(msg.velocity)} '
                            'velocities (0 or one per name)')
    return (stamp_ns(msg.header.stamp), names, np.asarray(msg.position, dtype=float),
            np.asarray(msg.velocity, dtype=float))
