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

"""Property-based tests of every message conversion.

Random and malformed messages give a valid value or a typed rejection with a reason — never another
exception, never NaN out.
"""
import math

from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion, Transform, Twist, Vector3
from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry, Path
import numpy as np
import pytest
from std_msgs.msg import Header
from trajectory_msgs.msg import (JointTrajectory, JointTrajectoryPoint, MultiDOFJointTrajectory,
                                 MultiDOFJointTrajectoryPoint)

import nh_tracking as nht
from nh_tracking.core.poses import PoseMap
from nh_tracking.ros import conversions as cv
from nh_tracking.ros import messages as msgs

SETTINGS = settings(max_examples=200, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
SLEIGH = nht.models.chaplygin_sleigh()
POSE_MAP = PoseMap(SLEIGH)

wild = st.floats(allow_nan=True, allow_infinity=True, width=64)
tame = st.floats(min_value=-50.0, max_value=50.0, allow_nan=False)
value = st.one_of(tame, tame, tame, wild)  # mostly plausible, sometimes anything
frames = st.sampled_from(['odom', '/odom', 'map', '', 'base_link'])
stamps = st.builds(Time, sec=st.integers(0, 2_000_000), nanosec=st.integers(0, 999_999_999))
durations = st.builds(Duration, sec=st.integers(0, 1000), nanosec=st.integers(0, 999_999_999))


@st.composite
def quaternions(draw):
    if draw(st.booleans()):
        yaw = draw(st.floats(-10, 10))
        return msgs.quaternion_of(yaw)
    return Quaternion(x=draw(value), y=draw(value), z=draw(value), w=draw(value))


@st.composite
def poses(draw):
    return Pose(position=Point(x=draw(value), y=draw(value), z=draw(value)),
                orientation=draw(quaternions()))


@st.composite
def twists(draw):
    return Twist(linear=Vector3(x=draw(value), y=draw(value), z=draw(value)),
                 angular=Vector3(x=draw(value), y=draw(value), z=draw(value)))


BAD_NUMBERS = st.sampled_from([float('nan'), float('inf'), -float('inf'), 1e300, -1e9])


@st.composite
def paths(draw):
    """Draw a valid timed path, then 0-2 mutations that make it malformed (or not)."""
    count = draw(st.integers(1, 12))
    t0 = draw(st.integers(0, 1000))
    steps = draw(st.lists(st.integers(1, 2_000_000_000), min_size=count, max_size=count))
    ns = t0 * 10**9 + np.cumsum(steps)
    msg = Path(header=Header(frame_id=draw(st.sampled_from(['odom', '/odom'])),
                             stamp=Time(sec=t0) if draw(st.booleans()) else Time()),
               poses=[PoseStamped(header=Header(frame_id=draw(st.sampled_from(['', 'odom'])),
                                                stamp=msgs.time_msg(int(t))),
                                  pose=msgs.pose_msg(np.array([draw(tame), draw(tame), 0.0,
                                                               draw(tame)])))
                      for t in ns])
    for _ in range(draw(st.integers(0, 2))):
        if not msg.poses:
            break
        i = draw(st.integers(0, count - 1))
        kind = draw(st.sampled_from(['nan', 'quaternion', 'frame', 'pose_frame', 'stamp',
                                     'empty']))
        if kind == 'nan':
            setattr(msg.poses[i].pose.position, draw(st.sampled_from('xyz')), draw(BAD_NUMBERS))
        elif kind == 'quaternion':
            msg.poses[i].pose.orientation = Quaternion(x=draw(value), y=draw(value),
                                                       z=draw(value), w=draw(value))
        elif kind == 'frame':
            msg.header.frame_id = draw(frames)
        elif kind == 'pose_frame':
            msg.poses[i].header.frame_id = draw(frames)
        elif kind == 'stamp':
            msg.poses[i].header.stamp = draw(stamps)
        else:
            msg.poses = []
    return msg


@st.composite
def multidof(draw):
    """Draw a valid one-joint trajectory, then 0-2 mutations."""
    count = draw(st.integers(1, 10))
    points = [MultiDOFJointTrajectoryPoint(
        transforms=[Transform(translation=Vector3(x=draw(tame), y=draw(tame), z=0.0),
                              rotation=msgs.quaternion_of(draw(tame)))],
        velocities=[Twist(linear=Vector3(x=draw(tame), y=draw(tame)),
                          angular=Vector3(z=draw(tame)))],
        time_from_start=Duration(sec=i, nanosec=draw(st.integers(0, 999_999_999))))
        for i in range(count)]
    msg = MultiDOFJointTrajectory(header=Header(frame_id='odom', stamp=draw(stamps)),
                                  joint_names=['base_link'], points=points)
    for _ in range(draw(st.integers(0, 2))):
        pt = msg.points[draw(st.integers(0, count - 1))]
        kind = draw(st.sampled_from(['nan', 'quaternion', 'lengths', 'names', 'time', 'frame']))
        if len(pt.transforms) != 1:
            break
        if kind == 'nan':
            pt.velocities[0].linear.x = draw(BAD_NUMBERS)
        elif kind == 'quaternion':
            pt.transforms[0].rotation = Quaternion(x=draw(value), y=draw(value), z=draw(value),
                                                   w=draw(value))
        elif kind == 'lengths':
            pt.transforms = list(pt.transforms) * draw(st.sampled_from([0, 2]))
        elif kind == 'names':
            msg.joint_names = draw(st.lists(st.just('j'), max_size=3))
        elif kind == 'time':
            pt.time_from_start = draw(durations)
        else:
            msg.header.frame_id = draw(frames)
    return msg


@pytest.mark.solve
def test_strategies_exercise_both_outcomes():
    """Guard against vacuous properties.

    The generators must give accepted and rejected messages alike.
    """
    outcomes = {'path': set(), 'trajectory': set()}

    @settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck))
    @given(paths(), multidof())
    def sample(path, trajectory):
        for key, convert, msg in (('path', cv.path_to_arrays, path),
                                  ('trajectory', cv.multidof_to_arrays, trajectory)):
            try:
                convert(msg, 'odom', 1)
                outcomes[key].add('accepted')
            except cv.InputRejected:
                outcomes[key].add('rejected')

    sample()
    assert outcomes == {'path': {'accepted', 'rejected'},
                        'trajectory': {'accepted', 'rejected'}}


def _all_finite(*arrays) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, dtype=float))) for a in arrays)


@pytest.mark.solve
@SETTINGS
@given(paths())
def test_path_conversion_is_valid_or_rejected(msg):
    try:
        times, poses_ = cv.path_to_arrays(msg, 'odom', receipt_ns=5_000_000_000)
    except cv.InputRejected as exc:
        assert str(exc)
        return
    assert np.all(np.abs(poses_[:, 3]) <= math.pi + 1e-12) and _all_finite(poses_)
    if times is None:  # an untimed route: its poses all carried one stamp
        stamps = [p.header.stamp for p in msg.poses]
        assert all(s == stamps[0] for s in stamps)
        return
    assert _all_finite(times) and np.all(np.diff(times) > 0)
    reference = POSE_MAP.reference((times - times[0]) * 1e-9, poses_)  # numerics downstream
    assert _all_finite(reference.q, reference.v)


@pytest.mark.solve
@SETTINGS
@given(multidof())
def test_multidof_conversion_is_valid_or_rejected(msg):
    try:
        times, poses_, body = cv.multidof_to_arrays(msg, 'odom', receipt_ns=1)
    except cv.InputRejected as exc:
        assert str(exc)
        return
    assert _all_finite(times, poses_, body) and np.all(np.diff(times) > 0)
    reference = POSE_MAP.reference((times - times[0]) * 1e-9, poses_, body)
    assert _all_finite(reference.q, reference.v)


@pytest.mark.unit
@SETTINGS
@given(frames, stamps, poses(), twists())
def test_odometry_conversion_is_valid_or_rejected(frame, stamp, pose, twist):
    msg = Odometry(header=Header(frame_id=frame, stamp=stamp))
    msg.pose.pose, msg.twist.twist = pose, twist
    try:
        ns, pose_arr, body = cv.odom_to_arrays(msg, 'odom')
    except cv.InputRejected as exc:
        assert str(exc)
        return
    q = POSE_MAP.configuration(pose_arr)
    assert ns >= 0 and _all_finite(pose_arr, body, q, POSE_MAP.velocity(q, body))


@pytest.mark.unit
@SETTINGS
@given(st.lists(st.sampled_from(['torque', 'force', 'left']), max_size=3),
       st.lists(st.tuples(durations, st.lists(value, max_size=3)), max_size=8), stamps)
def test_control_sequence_conversion_is_valid_or_rejected(names, points, stamp):
    msg = JointTrajectory(header=Header(stamp=stamp), joint_names=names, points=[
        JointTrajectoryPoint(time_from_start=d, effort=e) for d, e in points])
    try:
        start, offsets, efforts = cv.controls_to_arrays(msg, SLEIGH.control_names)
    except cv.InputRejected as exc:
        assert str(exc)
        return
    assert efforts.shape == (len(points), 2) and _all_finite(offsets, efforts)
    assert len(offsets) < 2 or np.all(np.diff(offsets) > 0)


@pytest.mark.unit
@SETTINGS
@given(twists())
def test_twist_conversion_is_valid_or_rejected(twist):
    try:
        body = cv.twist_array(twist)
    except cv.InputRejected as exc:
        assert str(exc)
        return
    assert _all_finite(body, POSE_MAP.velocity(np.zeros(3), body))


@pytest.mark.unit
@SETTINGS
@given(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), st.floats(-50, 50))
def test_outgoing_messages_round_trip(x, y, yaw):
    """What the nodes publish reads back as what they meant (within float precision)."""
    pose = np.array([x, y, 0.0, yaw])
    back = cv.pose_array(msgs.pose_msg(pose), 'pose')
    assert np.allclose(back[:3], pose[:3])
    assert abs(math.remainder(back[3] - yaw, 2 * math.pi)) < 1e-9
    seq = msgs.control_sequence_msg('odom', 10**9, np.array([0.0, 0.1]), ['torque', 'force'],
                                    np.array([[x, y], [y, x]]) * 1e-3)
    start, offsets, efforts = cv.controls_to_arrays(seq, ['torque', 'force'])
    assert start == 10**9 and np.allclose(efforts, np.array([[x, y], [y, x]]) * 1e-3)
    assert offsets == pytest.approx([0.0, 0.1])


@st.composite
def marker_arrays(draw):
    from visualization_msgs.msg import Marker, MarkerArray

    markers = []
    for i in range(draw(st.integers(0, 4))):
        marker = Marker(id=draw(st.integers(0, 3)), ns=draw(st.sampled_from(['a', 'b'])),
                        type=draw(st.sampled_from([Marker.CYLINDER, Marker.SPHERE,
                                                   Marker.TEXT_VIEW_FACING])),
                        action=draw(st.sampled_from([Marker.ADD, Marker.DELETE,
                                                     Marker.DELETEALL])))
        marker.header.frame_id = draw(frames)
        marker.header.stamp.sec = draw(st.integers(0, 3))  # repeated, backwards, jumps
        marker.header.stamp.nanosec = draw(st.integers(0, 999_999_999))
        marker.pose = draw(poses())
        marker.scale.x = draw(value)
        markers.append(marker)
    return MarkerArray(markers=markers)


@pytest.mark.solve
@given(st.lists(marker_arrays(), max_size=4))
@SETTINGS
def test_obstacle_markers_give_finite_discs_or_a_rejection(messages):
    from nh_tracking.ros.obstacle_messages import MarkerObstacles

    from nh_tracking.problem.disc_tracks import MAX_SPEED

    obstacles = MarkerObstacles('odom')
    for msg in messages:
        before = obstacles.discs()
        try:
            obstacles.apply(msg)
        except cv.InputRejected:
            assert np.array_equal(obstacles.discs(), before)  # the set in force stays
        discs = obstacles.discs(5 * 10**9)
        assert discs.shape[1] == 5 and np.all(np.isfinite(discs)) and np.all(discs[:, 2] >= 0)
        assert np.all(np.hypot(discs[:, 3], discs[:, 4]) <= MAX_SPEED * (1 + 1e-12))


@pytest.mark.unit
@given(resolution=value, width=st.integers(0, 6), height=st.integers(0, 6),
       data=st.lists(st.integers(-128, 127), max_size=40), origin=poses(), frame=frames)
@SETTINGS
def test_costmaps_give_finite_cells_or_a_rejection(resolution, width, height, data, origin,
                                                   frame):
    from nav_msgs.msg import OccupancyGrid

    from nh_tracking.navigation.costmap import costmap_discs
    from nh_tracking.problem.limits import nearest_discs
    from nh_tracking.ros.obstacle_messages import occupied_cells

    grid = OccupancyGrid()
    grid.header.frame_id = frame
    grid.info.resolution, grid.info.width, grid.info.height = resolution, width, height
    grid.info.origin, grid.data = origin, data
    try:
        cells, size = occupied_cells(grid, 'odom')
    except cv.InputRejected:
        return
    assert np.all(np.isfinite(cells)) and size > 0
    assert len(cells) == sum(d >= 100 for d in data)
    discs = nearest_discs(costmap_discs(cells, size, 0.5), np.zeros(2), 8, 1e9)
    assert len(discs) <= 8 and np.all(np.isfinite(discs))
    for cell in cells[:20]:  # every cell is inside some disc, or left for lack of discs
        assert len(discs) == 8 or np.any(np.hypot(*(discs[:, :2] - cell).T) <= discs[:, 2])
