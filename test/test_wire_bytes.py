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

"""The CDR bytes read and written by :mod:`nh_tracking.ros.cdr`, against rclpy's serializer.

The independent side is the middleware's own (de)serializer: every written sequence must read
back through it as the message :func:`conversions.control_sequence_msg` builds, and every
serialized Odometry must read as its fields — for frame and joint names of every length (the
alignment of what follows depends on them), any widths and stamps.
"""
import re

from geometry_msgs.msg import Point, PoseStamped
from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
from nav_msgs.msg import OccupancyGrid, Odometry, Path
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import ColorRGBA
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import Marker, MarkerArray

from nh_tracking.ros import cdr, conversions as cv, messages as msgs
from nh_tracking.ros.obstacle_bytes import Grid, grid_from_bytes, Markers, markers_from_bytes

SETTINGS = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
names = st.text(st.characters(codec='utf-8', exclude_characters='\x00'), max_size=13)
numbers = st.floats(-1e6, 1e6, allow_nan=False)
stamps = st.integers(0, 2**31 * 10**9 - 1)


@pytest.mark.solve
@pytest.mark.slow
@SETTINGS
@given(names, stamps, st.lists(names, min_size=1, max_size=4), st.integers(1, 40), st.data())
def test_a_written_control_sequence_reads_back_through_the_middleware(
        frame, stamp, joints, points, data):
    width = len(joints)
    efforts = np.array(data.draw(st.lists(numbers, min_size=points * width,
                                          max_size=points * width))).reshape(points, width)
    steps = data.draw(st.lists(st.floats(1e-3, 10.0), min_size=points, max_size=points))
    offsets = np.cumsum(steps) - steps[0]
    written = cdr.control_sequence(frame, stamp, offsets, joints, efforts)
    assert deserialize_message(written, JointTrajectory) == msgs.control_sequence_msg(
        frame, stamp, offsets, joints, efforts)


@pytest.mark.solve
@SETTINGS
@given(names, names, stamps, st.lists(numbers, min_size=4, max_size=4),
       st.lists(numbers, min_size=4, max_size=4))
def test_serialized_odometry_reads_as_the_message_does(frame, child, stamp, pose, twist):
    msg = msgs.odometry_msg(frame, child, stamp, np.array(pose), np.array(twist))
    msg.pose.pose.orientation.x = 1e-4  # a general quaternion (within the unit tolerance)
    msg.twist.twist.angular.y = twist[0]
    for expected in ('odom', frame):
        try:
            from_message = cv.odom_to_arrays(msg, expected)
        except cv.InputRejected as exc:
            with pytest.raises(cv.InputRejected, match=re.escape(str(exc))):
                cv.odom_to_arrays(serialize_message(msg), expected)
            continue
        stamp_ns, pose_arr, body = cv.odom_to_arrays(serialize_message(msg), expected)
        assert stamp_ns == from_message[0] == stamp
        assert np.array_equal(pose_arr, from_message[1])
        assert np.array_equal(body, from_message[2])


@pytest.mark.unit
@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 720))
def test_damaged_odometry_bytes_are_rejected_with_a_reason(noise, cut):
    good = serialize_message(msgs.odometry_msg('odom', 'base', 5, np.array([1.0, 2.0, 0.0, 0.5]),
                                               np.zeros(4)))
    for data in (good[:cut], cdr.ENCAPSULATION + noise, noise, b'\x00\x00\x00\x00' + good[4:]):
        if data == good:
            continue
        try:
            _, pose, body = cv.odom_to_arrays(data, 'odom')
        except cv.InputRejected as exc:
            assert str(exc)
            continue
        assert np.all(np.isfinite(pose)) and np.all(np.isfinite(body))


@pytest.mark.unit
def test_this_middleware_agrees_and_the_nan_in_odometry_is_still_refused():
    assert cdr.agrees_with_rmw()
    msg = Odometry()
    msg.header.frame_id = 'odom'
    msg.pose.pose.orientation.w = 1.0
    msg.twist.twist.linear.x = float('nan')
    with pytest.raises(cv.InputRejected, match='NaN'):
        cv.odom_to_arrays(serialize_message(msg), 'odom')


@pytest.mark.solve
@SETTINGS
@given(names, stamps, st.lists(st.tuples(st.sampled_from(['', 'odom', 'odom_frame', 'map']),
                                         stamps, st.lists(numbers, min_size=7, max_size=7)),
                               max_size=30))
def test_serialized_paths_read_as_the_message_does(frame, stamp, poses):
    """The fixed-stride reading (all frame_ids as long) and the pose-by-pose one alike."""
    msg = Path()
    msg.header.frame_id = frame
    msg.header.stamp = msgs.time_msg(stamp)
    for pose_frame, pose_stamp, values in poses:
        ps = PoseStamped()
        ps.header.frame_id, ps.header.stamp = pose_frame, msgs.time_msg(pose_stamp)
        p, o = ps.pose.position, ps.pose.orientation
        p.x, p.y, p.z, o.x, o.y, o.z, o.w = values
        msg.poses.append(ps)
    read_stamp, read_frame, read_stamps, read_poses, frames = cdr.path_values(
        serialize_message(msg))
    assert (read_stamp, read_frame) == (stamp, frame)
    assert read_stamps.tolist() == [s for _, s, _ in poses]
    assert read_poses.tolist() == [v for _, _, v in poses]
    assert frames == {f: next(i for i, (g, _, _) in enumerate(poses) if g == f)
                      for f, _, _ in poses}
    for expected in ('odom', frame):  # and it is judged as the message is
        try:
            from_message = cv.path_to_arrays(msg, expected, 7)
        except cv.InputRejected as exc:
            with pytest.raises(cv.InputRejected, match=re.escape(str(exc))):
                cv.path_to_arrays(serialize_message(msg), expected, 7)
            continue
        from_bytes = cv.path_to_arrays(serialize_message(msg), expected, 7)
        assert all(a is b is None or np.array_equal(a, b)
                   for a, b in zip(from_message, from_bytes))


@pytest.mark.unit
@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 400))
def test_damaged_path_bytes_are_rejected_with_a_reason(noise, cut):
    good = serialize_message(msgs.path_msg('odom', [5, 6, 7], np.eye(3, 4)))
    for data in (good[:cut], cdr.ENCAPSULATION + noise, noise):
        if data == good:
            continue
        try:
            stamps, poses = cv.path_to_arrays(data, 'odom', 0)
        except cv.InputRejected as exc:
            assert str(exc)
            continue
        assert np.all(np.isfinite(poses)) and (stamps is None or len(stamps) == len(poses))


@st.composite
def marker_arrays(draw) -> MarkerArray:
    """Markers of every layout: strings of any length, sequences empty or not; often alike."""
    alike = draw(st.booleans())  # one layout for all (the fast, record-array reading)
    template = draw(marker_layouts())
    markers = []
    for i in range(draw(st.integers(0, 12))):
        frame, ns, points, colors, text, mesh = template if alike else draw(marker_layouts())
        marker = Marker(ns=ns, id=draw(st.integers(-2**31, 2**31 - 1)),
                        type=draw(st.integers(0, 12)), action=draw(st.sampled_from([0, 2, 3])),
                        points=[Point(x=1.0)] * points, colors=[ColorRGBA()] * colors, text=text)
        marker.mesh_file.data = [7] * mesh
        marker.header.frame_id, marker.header.stamp = frame, msgs.time_msg(draw(stamps))
        p = marker.pose.position
        p.x, p.y, p.z, marker.scale.x = (draw(numbers) for _ in range(4))
        markers.append(marker)
    return MarkerArray(markers=markers)


def marker_layouts():
    return st.tuples(names, names, st.integers(0, 3), st.integers(0, 3), names,
                     st.integers(0, 9))


@pytest.mark.solve
@SETTINGS
@given(marker_arrays())
def test_serialized_markers_read_as_the_message_does(msg):
    read, expected = markers_from_bytes(serialize_message(msg)), Markers.of(msg)
    assert read.keys == expected.keys and read.frames == expected.frames
    for name in ('stamps', 'types', 'actions', 'xy', 'diameters'):
        assert np.array_equal(getattr(read, name), getattr(expected, name)), name


@pytest.mark.solve
@pytest.mark.slow
@SETTINGS
@given(names, st.floats(0.0009765625, 16.0, width=32), st.integers(0, 40), st.integers(0, 40),
       st.lists(numbers, min_size=7, max_size=7), st.data())
def test_serialized_costmaps_read_as_the_message_does(frame, resolution, width, height,
                                                      origin, data):
    grid = OccupancyGrid(data=data.draw(st.lists(st.integers(-128, 127), min_size=width * height,
                                                 max_size=width * height)))
    grid.header.frame_id, grid.info.resolution = frame, resolution
    grid.info.width, grid.info.height = width, height
    p, o = grid.info.origin.position, grid.info.origin.orientation
    p.x, p.y, p.z, o.x, o.y, o.z, o.w = origin
    read, expected = grid_from_bytes(serialize_message(grid)), Grid.of(grid)
    assert (read.frame, read.resolution, read.width, read.height, read.origin) == (
        expected.frame, expected.resolution, expected.width, expected.height, expected.origin)
    assert np.array_equal(read.data, expected.data)


@pytest.mark.unit
@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400), st.integers(0, 1200))
def test_damaged_obstacle_bytes_are_unreadable_or_read(noise, cut):
    """Cut or random bytes: Unreadable, or values of the right shapes; never another error."""
    markers = MarkerArray(markers=[Marker(ns='people', id=i, type=Marker.CYLINDER)
                                   for i in range(6)])
    grid = OccupancyGrid(data=[0, 100, 50, -1])
    grid.info.width, grid.info.height, grid.info.resolution = 2, 2, 0.1
    for good, read in ((serialize_message(markers), markers_from_bytes),
                       (serialize_message(grid), grid_from_bytes)):
        for data in (good[:cut], cdr.ENCAPSULATION + noise, noise):
            try:
                values = read(data)
            except cdr.Unreadable as exc:
                assert str(exc)
                continue
            if isinstance(values, Markers):
                assert len(values.keys) == len(values.stamps) == len(values.xy)
            else:
                assert len(values.data) <= len(data)
