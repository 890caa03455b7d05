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

"""What the planner reads of ``obstacles`` and ``costmap`` messages, from messages or CDR bytes.

rclpy builds a MarkerArray in C, holding the interpreter throughout (a time that grows with the
markers; figures in docs/performance.md): no other thread of the process runs meanwhile. Read
from the bytes, a marker array whose markers share one layout (the usual case: one frame, one
namespace length, no points or text) is one numpy record array; others are read marker by
marker, in Python, which other threads can interrupt. An OccupancyGrid's cells are a view of
the bytes.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import functools
import struct

from geometry_msgs.msg import Point
from nav_msgs.msg import OccupancyGrid
import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from nh_tracking.ros import cdr
from nh_tracking.ros.cdr import aligned, ENCAPSULATION, HEAD, Unreadable


@dataclass(frozen=True)
class Markers:
    """The fields of each marker that can make a disc, in the message's order."""

    keys: list[tuple[str, int]]  # (ns, id)
    frames: list[str]
    stamps: np.ndarray  # (M,) int64 [ns]
    types: np.ndarray  # (M,) int32
    actions: np.ndarray  # (M,) int32
    xy: np.ndarray  # (M, 2) pose.position x, y
    diameters: np.ndarray  # (M,) scale.x

    @classmethod
    def of(cls, msg: MarkerArray) -> Markers:
        markers = msg.markers
        return cls([(m.ns, m.id) for m in markers], [m.header.frame_id for m in markers],
                   np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                             for m in markers], dtype=np.int64),
                   np.array([m.type for m in markers], dtype=np.int32),
                   np.array([m.action for m in markers], dtype=np.int32),
                   np.array([(m.pose.position.x, m.pose.position.y) for m in markers],
                            dtype=float).reshape(-1, 2),
                   np.array([m.scale.x for m in markers], dtype=float))


@dataclass(frozen=True)
class Grid:
    """An OccupancyGrid's frame, geometry and cells (row-major, int8)."""

    frame: str
    resolution: float
    width: int
    height: int
    origin: tuple[float, ...]  # x, y, z, qx, qy, qz, qw
    data: np.ndarray

    @classmethod
    def of(cls, msg: OccupancyGrid) -> Grid:
        info, p, o = msg.info, msg.info.origin.position, msg.info.origin.orientation
        return cls(msg.header.frame_id, float(np.float32(info.resolution)), info.width,
                   info.height,
                   (p.x, p.y, p.z, o.x, o.y, o.z, o.w), np.asarray(msg.data, dtype=np.int8))


_GRID_INFO = struct.Struct('<iIfII')  # map_load_time, resolution, width, height
_SEVEN = struct.Struct('<7d')


def read_markers(msg: MarkerArray | bytes) -> Markers:
    """Read a MarkerArray or its bytes (other encodings than plain CDR: by the middleware)."""
    return _read(msg, MarkerArray, Markers.of, markers_from_bytes)


def read_grid(msg: OccupancyGrid | bytes) -> Grid:
    """Read an OccupancyGrid or its bytes (other encodings than plain CDR: by the middleware)."""
    return _read(msg, OccupancyGrid, Grid.of, grid_from_bytes)


def _read(msg, msg_type: type, of: Callable, from_bytes: Callable):
    if isinstance(msg, msg_type):
        return of(msg)
    if msg[:HEAD] == ENCAPSULATION:
        return from_bytes(msg)
    try:
        return of(deserialize_message(msg, msg_type))
    except Exception as exc:  # noqa: BLE001 - rclpy raises plain exceptions for bad bytes
        raise Unreadable(f'{msg_type.__name__} cannot be read: {exc}') from None


def grid_from_bytes(data: bytes) -> Grid:
    """Read an OccupancyGrid's CDR bytes (the cells are a view of them)."""
    cdr.check_head(data, 'costmap')
    try:
        frame, at = cdr.string_at(data, HEAD + 8)
        _, _, resolution, width, height = _GRID_INFO.unpack_from(data, aligned(at, 4))
        at = aligned(aligned(at, 4) + _GRID_INFO.size, 8)
        origin = _SEVEN.unpack_from(data, at)
        at += _SEVEN.size
        (count,) = struct.unpack_from('<I', data, at)
    except struct.error:
        raise Unreadable('costmap message is truncated') from None
    if at + 4 + count > len(data):
        raise Unreadable(f'costmap says {count} cells, more than its bytes hold')
    return Grid(frame, resolution, width, height, origin,
                np.frombuffer(data, np.int8, count, offset=at + 4))


class _Cursor:
    """Reads fields in order at their alignment, noting where each length and value lies."""

    def __init__(self, data: bytes, at: int) -> None:
        self.data, self.at = data, at
        self.where: dict[str, int] = {}
        self.lengths: list[tuple[int, int, bool]] = []  # (position, value, of a string)

    def take(self, name: str, layout: struct.Struct, alignment: int) -> tuple:
        self.at = aligned(self.at, alignment)
        self.where[name] = self.at
        values = layout.unpack_from(self.data, self.at)
        self.at += layout.size
        return values

    def length(self) -> int:
        self.at = aligned(self.at, 4)
        (count,) = struct.unpack_from('<I', self.data, self.at)
        self.lengths.append((self.at, count, False))
        self.at += 4
        return count

    def string(self, name: str = '') -> str:
        """Read a string; ``name``: note where its characters lie, and how many."""
        at = aligned(self.at, 4)
        text, self.at = cdr.string_at(self.data, at)
        self.lengths.append((at, self.at - at - 4, True))
        if name:
            self.where[name], self.where[f'{name}_size'] = at + 4, self.at - at - 5
        return text

    def skip(self, item: int, alignment: int) -> None:
        """Skip a sequence of ``item``-byte elements aligned to ``alignment``."""
        count = self.length()
        if count:
            self.at = aligned(self.at, alignment) + count * item
        if self.at > len(self.data):
            raise Unreadable('a sequence runs past the end of the message')


_STAMP, _IDS = struct.Struct('<iI'), struct.Struct('<3i')
_TWO, _ONE = struct.Struct('<2d'), struct.Struct('<d')


@dataclass
class _Marker:
    """One marker read field by field: its values, and the layout they came in."""

    start: int
    cursor: _Cursor
    values: tuple  # stamp, frame, ns, (id, type, action), (x, y), diameter


def _marker(data: bytes, start: int) -> _Marker:
    c = _Cursor(data, start)
    sec, nanosec = c.take('stamp', _STAMP, 4)
    frame, ns = c.string('frame'), c.string('ns')
    ids = c.take('ids', _IDS, 4)
    xy = c.take('xy', _TWO, 8)
    c.at += 5 * 8  # z, orientation
    (diameter,) = c.take('diameter', _ONE, 8)
    c.at = aligned(c.at + 2 * 8, 4) + 16 + 8 + 1  # scale y, z; color; lifetime; frame_locked
    c.skip(24, 8)  # points
    c.skip(16, 4)  # colors
    c.string()  # texture_resource
    c.at = aligned(c.at, 4) + 8  # texture: its header's stamp
    c.string(), c.string()  # frame_id, format
    c.skip(1, 1)  # data
    c.skip(8, 4)  # uv_coordinates
    c.string(), c.string(), c.string()  # text, mesh_resource, mesh_file.filename
    c.skip(1, 1)  # mesh_file.data
    c.at += 1  # mesh_use_embedded_materials
    return _Marker(start, c, (sec * 1_000_000_000 + nanosec, frame, ns, ids, xy, diameter))


def markers_from_bytes(data: bytes) -> Markers:
    """Read a MarkerArray's CDR bytes; Unreadable if they are not one."""
    cdr.check_head(data, 'obstacles')
    try:
        (count,) = struct.unpack_from('<I', data, HEAD)
        if count * 40 > len(data):
            raise Unreadable(f'obstacles say {count} markers, more than their bytes hold')
        values: list[tuple] = []
        head: list[_Marker] = []  # markers 0-3, read field by field
        at = HEAD + 4
        while len(values) < count:
            if len(values) == len(head) == 4:
                rest = _same_layout(data, head[1:], count - 1)
                head = []  # (looked for once)
                if rest is not None:
                    rows, at = rest
                    values = values[:1] + rows
                    continue
            marker = _marker(data, at)
            if len(values) < 4:
                head.append(marker)
            values.append(marker.values)
            at = marker.cursor.at
    except struct.error:
        raise Unreadable('obstacles message is truncated') from None
    return _markers(values)


def _markers(values: list[tuple]) -> Markers:
    stamps, frames, ns, ids, xy, diameters = zip(*values) if values else ((),) * 6
    id_type_action = np.array(ids, dtype=np.int32).reshape(-1, 3)
    return Markers(list(zip(ns, id_type_action[:, 0].tolist())), list(frames),
                   np.array(stamps, dtype=np.int64), id_type_action[:, 1],
                   id_type_action[:, 2], np.array(xy, dtype=float).reshape(-1, 2),
                   np.array(diameters, dtype=float))


def _same_layout(data: bytes, first: list[_Marker], count: int
                 ) -> tuple[list[tuple], int] | None:
    """Read markers 1..count as records laid out as markers 1.. were, if every one is.

    Markers 1, 2, 3 (``first``) were read field by field. A record spans one marker, or two
    where one ends 4 bytes off a multiple of 8 (the next is padded otherwise). Every length in
    every record equal to its first's means the same layout: the values are read from it.
    """
    base = first[0].start
    for period in (1, 2):
        stride = first[period].start - base
        if stride % 8 == 0:
            break
    else:
        return None
    whole = min(count // period, (len(data) - base) // stride)
    fields: dict[str, tuple[str, int]] = {}  # name -> (numpy type, offset in the record)
    for j, marker in enumerate(first[:period]):
        where, shift = marker.cursor.where, marker.start - base
        columns = [('stamp', '<i4', where['stamp']), ('nanosec', '<u4', where['stamp'] + 4),
                   ('ids', '(3,)<i4', where['ids']), ('xy', '(2,)<f8', where['xy']),
                   ('diameter', '<f8', where['diameter'])]
        columns += [(name, f"S{max(where[f'{name}_size'], 1)}", where[name])
                    for name in ('frame', 'ns')]
        for k, (position, value, string) in enumerate(marker.cursor.lengths):
            columns.append((f'length{k}_', '<u4', position))
            if string:  # its terminating NUL
                columns.append((f'end{k}_', 'u1', position + 3 + value))
        fields.update({f'{name}{j}': (kind, position - marker.start + shift)
                       for name, kind, position in columns})
    names = list(fields)
    layout = np.dtype({'names': names, 'formats': [fields[n][0] for n in names],
                       'offsets': [fields[n][1] for n in names], 'itemsize': stride})
    records = np.frombuffer(data, layout, whole, offset=base)
    for j, marker in enumerate(first[:period]):
        for k, (_, value, string) in enumerate(marker.cursor.lengths):
            if np.any(records[f'length{k}_{j}'] != value) or (
                    string and np.any(records[f'end{k}_{j}'] != 0)):
                return None
    values = []
    for j, marker in enumerate(first[:period]):
        frame, ns = marker.values[1], marker.values[2]
        stamps = records[f'stamp{j}'].astype(np.int64) * 1_000_000_000 + records[f'nanosec{j}']
        frames = _strings(records[f'frame{j}'], frame)
        namespaces = _strings(records[f'ns{j}'], ns)
        values.append(list(zip(stamps.tolist(), frames, namespaces,
                               map(tuple, records[f'ids{j}'].tolist()),
                               map(tuple, records[f'xy{j}'].tolist()),
                               records[f'diameter{j}'].tolist())))
    ordered = [row for group in zip(*values) for row in group]
    return ordered, base + whole * stride


def _strings(raw: np.ndarray, first: str) -> list[str]:
    """Decode a column of fixed-width strings (all of ``first``'s length; '' if it is empty)."""
    if not first:
        return [''] * len(raw)
    unique, index = np.unique(raw, return_inverse=True)
    decoded = [u.decode('utf-8', 'replace') for u in unique.tolist()]
    return [decoded[i] for i in index.ravel().tolist()]


@functools.cache
def agrees_with_rmw() -> bool:
    """Whether these readers read what the middleware's serializer writes (checked once)."""
    markers = MarkerArray(markers=[  # the first apart, the others alike (read as records)
        Marker(ns='n' * (i == 0), id=i, type=Marker.CYLINDER, action=i % 4,
               points=[Point(x=1.0)] * (i == 0)) for i in range(12)])
    for i, marker in enumerate(markers.markers):
        marker.header.frame_id, marker.header.stamp.sec = 'odom_x', 1_700_000_000 + i
        position = marker.pose.position
        position.x, position.y, marker.scale.x = 0.5 * i, -1.0 * i, 0.25 + i
    grid = OccupancyGrid(data=[0, 100, -1, 50, 99, 100])
    grid.header.frame_id, grid.info.resolution = 'map_y', 0.05
    grid.info.width, grid.info.height = 3, 2
    grid.info.origin.position.x, grid.info.origin.orientation.z = -1.5, 1.0
    read, expected = markers_from_bytes(serialize_message(markers)), Markers.of(markers)
    cells, expected_cells = grid_from_bytes(serialize_message(grid)), Grid.of(grid)
    return (read.keys == expected.keys and read.frames == expected.frames and all(
        np.array_equal(getattr(read, name), getattr(expected, name))
        for name in ('stamps', 'types', 'actions', 'xy', 'diameters'))
        and cells.origin == expected_cells.origin and np.array_equal(cells.data,
                                                                     expected_cells.data)
        and (cells.frame, cells.resolution, cells.width, cells.height) == (
            expected_cells.frame, expected_cells.resolution, expected_cells.width,
            expected_cells.height))
