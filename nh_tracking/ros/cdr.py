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

"""The wire bytes (CDR) of the messages on the replanning path, read and written directly.

rclpy turns a received Odometry into Python objects before the callback runs, and a published
JointTrajectory is built from an object per point and field that rclpy then walks again to
convert: a large share of a real-time replan's latency (figures in docs/performance.md). The
bytes themselves are a fixed layout — the encapsulation header, then each field little-endian
at its natural alignment (at most 8) counted from the end of that header, strings as a length
(with the terminating NUL) and the characters — read with one ``struct.unpack_from`` and
written with one ``struct.pack``. Raw subscriptions and publishers carry them (the pattern of
rclpy's ``raw=True``). :func:`agrees_with_rmw` checks both directions against the middleware's
own serializer; where they differ the nodes use messages as usual.
"""
from __future__ import annotations

from collections.abc import Sequence
import functools
import struct

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from trajectory_msgs.msg import JointTrajectory

from nh_tracking.ros import messages as msgs

ENCAPSULATION = b'\x00\x01\x00\x00'  # plain CDR, little-endian
HEAD = len(ENCAPSULATION)
_ODOMETRY_DOUBLES = struct.Struct('<85d')  # pose (7), its covariance (36), twist (6), its (36)


class Unreadable(ValueError):
    """Bytes that are not a little-endian CDR message of the expected type."""


def check_head(data: bytes, what: str) -> None:
    """Raise Unreadable unless ``data`` starts with the plain little-endian CDR header."""
    if data[:HEAD] != ENCAPSULATION:
        raise Unreadable(f'{what} is not little-endian CDR (header {data[:HEAD].hex()})')


def aligned(position: int, size: int) -> int:
    """``position`` (from the start of the bytes) moved to a multiple of ``size`` in the body."""
    return position + (-(position - HEAD) % size)


def string_at(data: bytes, position: int) -> tuple[str, int]:
    position = aligned(position, 4)
    (length,) = struct.unpack_from('<I', data, position)
    end = position + 4 + length
    if length < 1 or end > len(data) or data[end - 1] != 0:
        raise Unreadable('a string runs past the end of the message')
    return data[position + 4:end - 1].decode('utf-8', 'replace'), end


def odometry_values(data: bytes) -> tuple[int, str, tuple[float, ...]]:
    """(stamp [ns], frame_id, (x, y, z, qx, qy, qz, qw, vx, vy, vz, wx, wy, wz)) of an Odometry."""
    check_head(data, 'odometry')
    try:
        sec, nanosec = struct.unpack_from('<iI', data, HEAD)
        frame, position = string_at(data, HEAD + 8)
        _, position = string_at(data, position)  # child_frame_id
        values = _ODOMETRY_DOUBLES.unpack_from(data, aligned(position, 8))
    except struct.error:
        raise Unreadable('odometry message is truncated') from None
    return sec * 1_000_000_000 + nanosec, frame, values[:7] + values[43:49]


_POSE_DOUBLES = struct.Struct('<7d')  # position, orientation


def path_values(data: bytes) -> tuple[int, str, np.ndarray, np.ndarray, dict[str, int]]:
    """(stamp [ns], frame_id, pose stamps [ns] (N,), poses (N, 7), pose frame -> first index).

    A pose (x, y, z, qx, qy, qz, qw) of a nav_msgs/Path. Every pose after the first starts at a
    multiple of 8, so when all frame_ids are as long as the first, the rest is one numpy record
    array of a fixed stride, read in one call; otherwise pose by pose.
    """
    check_head(data, 'path')
    try:
        sec, nanosec = struct.unpack_from('<iI', data, HEAD)
        frame, position = string_at(data, HEAD + 8)
        position = aligned(position, 4)
        (count,) = struct.unpack_from('<I', data, position)
        if count * 64 > len(data):
            raise Unreadable(f'path says {count} poses, more than its bytes hold')
        stamps, poses = np.empty(count, np.int64), np.empty((count, 7))
        frames: dict[str, int] = {}
        position, i = position + 4, 0
        while i < count:
            if i == 1 and (rest := _fixed_stride(data, position, count, stamps, poses)
                           ) is not None:
                frames.setdefault(rest, 1)
                break
            pose_sec, pose_nanosec = struct.unpack_from('<iI', data, aligned(position, 4))
            pose_frame, position = string_at(data, aligned(position, 4) + 8)
            frames.setdefault(pose_frame, i)
            position = aligned(position, 8)
            stamps[i] = pose_sec * 1_000_000_000 + pose_nanosec
            poses[i] = _POSE_DOUBLES.unpack_from(data, position)
            position, i = position + _POSE_DOUBLES.size, i + 1
    except struct.error:
        raise Unreadable('path message is truncated') from None
    return sec * 1_000_000_000 + nanosec, frame, stamps, poses, frames


def _fixed_stride(data: bytes, start: int, count: int, stamps: np.ndarray,
                  poses: np.ndarray) -> str | None:
    """Read poses 1.. as records of pose 1's layout and return their frame, if all have it."""
    frame, _ = string_at(data, start + 8)
    (length,) = struct.unpack_from('<I', data, start + 8)
    pose_at = 12 + length + (-(12 + length) % 8)
    stride, rest = pose_at + _POSE_DOUBLES.size, count - 1
    if start + rest * stride > len(data):
        return None
    layout = np.dtype({'names': ['sec', 'nanosec', 'length', 'pose'],
                       'formats': ['<i4', '<u4', '<u4', ('<f8', 7)],
                       'offsets': [0, 4, 8, pose_at], 'itemsize': stride})
    records = np.frombuffer(data, layout, rest, offset=start)
    raw = np.frombuffer(data, np.uint8, rest * stride, offset=start).reshape(rest, stride)
    first = np.frombuffer(data, np.uint8, length, offset=start + 12)
    if not (np.all(records['length'] == length) and np.all(raw[:, 12:12 + length] == first)):
        return None
    stamps[1:] = records['sec'].astype(np.int64) * 1_000_000_000 + records['nanosec']
    poses[1:] = records['pose']
    return frame


class _Writer:
    """One ``struct`` format and its values, with the position kept for alignment."""

    def __init__(self) -> None:
        self.format, self.position = ['<'], HEAD
        self.values: list[object] = []

    def align(self, size: int) -> None:
        pad = aligned(self.position, size) - self.position
        if pad:
            self.format.append(f'{pad}x')
            self.position += pad

    def add(self, code: str, size: int, *values: object) -> None:
        """Append ``values`` packed by ``code`` (``size`` bytes each, aligned to ``size``)."""
        self.align(min(size, 8))
        self.format.append(f'{len(values)}{code}')
        self.values += values
        self.position += size * len(values)

    def string(self, text: str) -> None:
        data = text.encode() + b'\0'
        self.add('I', 4, len(data))
        self.format.append(f'{len(data)}s')
        self.values.append(data)
        self.position += len(data)

    def packed(self) -> bytes:
        return ENCAPSULATION + struct.pack(''.join(self.format), *self.values)


def control_sequence(frame: str, start_ns: int, offsets: np.ndarray, names: Sequence[str],
                     efforts: np.ndarray) -> bytes:
    """Return the JointTrajectory of :func:`conversions.control_sequence_msg` as wire bytes.

    Its points in one numpy record array: each is (0, 0, 0, r) — no positions, velocities,
    accelerations; r efforts — the efforts, then time_from_start. Only the first point can need
    padding before its efforts: each ends at a multiple of 8, so the next needs none.
    """
    efforts = np.asarray(efforts, dtype=float).reshape(len(offsets), -1)
    head, position = _trajectory_head(frame, tuple(names))
    width = efforts.shape[1]
    points = np.zeros(len(efforts), dtype=_point_type(width))
    points['counts'][:, 3] = width
    points['effort'] = efforts
    offsets_ns = np.rint(np.asarray(offsets, dtype=float) * 1e9).astype(np.int64)
    points['sec'], points['nanosec'] = np.divmod(offsets_ns, 1_000_000_000)
    block = points.tobytes()
    if width and len(points) and aligned(position + 4 + 16, 8) != position + 4 + 16:
        block = block[:16] + bytes(4) + block[16:]
    stamp = struct.pack('<iI', *divmod(int(start_ns), 1_000_000_000))
    return ENCAPSULATION + stamp + head + struct.pack('<I', len(points)) + block


@functools.lru_cache(maxsize=16)
def _point_type(width: int) -> np.dtype:
    """Return a point's record (packed, no padding): made once per width, not per message."""
    return np.dtype([('counts', '<u4', 4), ('effort', '<f8', width), ('sec', '<i4'),
                     ('nanosec', '<u4')])


@functools.lru_cache(maxsize=16)
def _trajectory_head(frame: str, names: tuple[str, ...]) -> tuple[bytes, int]:
    """Return the frame and joint names after a header stamp, and where they end (per node)."""
    out = _Writer()
    out.position += 8  # the stamp
    out.string(frame)
    out.add('I', 4, len(names))
    for name in names:
        out.string(name)
    out.align(4)
    return out.packed()[HEAD:], out.position


@functools.cache
def agrees_with_rmw() -> bool:
    """Whether the middleware's serializer writes and reads these bytes (checked once)."""
    odometry = msgs.odometry_msg('odom_x', 'base', 1_700_000_000_123_456_789,
                                 np.array([1.5, -2.25, 0.125, 0.75]),
                                 np.array([0.5, -0.25, 0.0, 0.125]))
    p, o = odometry.pose.pose.position, odometry.pose.pose.orientation
    linear, angular = odometry.twist.twist.linear, odometry.twist.twist.angular
    expected = (1_700_000_000_123_456_789, 'odom_x', (
        p.x, p.y, p.z, o.x, o.y, o.z, o.w, linear.x, linear.y, linear.z, angular.x, angular.y,
        angular.z))
    path = msgs.path_msg('odom_x', [5, 1_700_000_000_000_000_007], np.array(
        [[1.0, 2.0, 0.0, 0.5], [-3.0, 0.25, 1.0, -2.0]]))
    stamp, frame, stamps, poses, frames = path_values(serialize_message(path))
    read_path = (stamp == 5 and frame == 'odom_x' and frames == {'odom_x': 0}
                 and stamps.tolist() == [5, 1_700_000_000_000_000_007] and poses.tolist() == [
                     [ps.pose.position.x, ps.pose.position.y, ps.pose.position.z,
                      ps.pose.orientation.x, ps.pose.orientation.y, ps.pose.orientation.z,
                      ps.pose.orientation.w] for ps in path.poses])
    offsets, efforts = np.array([0.0, 0.1, 0.25]), np.array([[1.0, -2.0], [3.5, 0.0], [-1e-3, 7]])
    sequence = ('odom', 1_700_000_000_987_654_321, offsets, ['u_a', 'torque'], efforts)
    written = deserialize_message(control_sequence(*sequence), JointTrajectory)
    return (odometry_values(serialize_message(odometry)) == expected and read_path
            and written == msgs.control_sequence_msg(*sequence))
