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

"""What RViz shows of a plan: line strips of the plan and its reference, discs of obstacles."""
from __future__ import annotations

from geometry_msgs.msg import Point, Vector3
import numpy as np
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from nh_tracking.ros.messages import time_msg


def line_strip(frame: str, stamp: int, ns: str, points: np.ndarray, rgba: tuple,
               width: float = 0.03) -> Marker:
    return Marker(
        header=Header(frame_id=frame, stamp=time_msg(stamp)), ns=ns, id=0,
        type=Marker.LINE_STRIP, action=Marker.ADD, scale=Vector3(x=width),
        color=ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
        points=[Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in points])


def plan_markers(frame: str, stamp: int, plan_poses: np.ndarray,
                 reference_poses: np.ndarray) -> MarkerArray:
    """Return the plan (green) and the reference over the same horizon (grey), for RViz."""
    return MarkerArray(markers=[
        line_strip(frame, stamp, 'planned_path', plan_poses, (0.1, 0.8, 0.2, 1.0)),
        line_strip(frame, stamp, 'reference', reference_poses, (0.6, 0.6, 0.6, 0.8), 0.02),
    ])


def obstacle_markers(frame: str, stamp: int, discs: np.ndarray) -> list[Marker]:
    """Discs (x, y, r, ...) as flat cylinders for RViz (namespace ``obstacles``), after a clear."""
    header = Header(frame_id=frame, stamp=time_msg(stamp))
    markers = [Marker(header=header, ns='obstacles', action=Marker.DELETEALL)]
    for i, (x, y, r) in enumerate(discs[:, :3]):
        marker = Marker(header=header, ns='obstacles', id=i, type=Marker.CYLINDER,
                        action=Marker.ADD, scale=Vector3(x=2 * r, y=2 * r, z=0.05),
                        color=ColorRGBA(r=0.8, g=0.2, b=0.2, a=0.6))
        marker.pose.position = Point(x=float(x), y=float(y), z=0.0)
        marker.pose.orientation.w = 1.0
        markers.append(marker)
    return markers
