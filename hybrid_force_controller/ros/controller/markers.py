"""
``~/markers`` (visualization_msgs/MarkerArray, base frame) for RViz, built on the node's thread.

From the latest tick's output (never on the control thread), about 10 Hz: the path being
followed as a line strip, the current reference point, the measured contact force as an
arrow (the force the tool exerts, :data:`FORCE_SCALE_M_PER_N`), the normal the controller uses
as an arrow from the tool (n, or its estimate n_hat with ``n_estimation``), a patch of the
tangent plane through the tool and, while the tool's orientation is controlled
(``orientation_mode``), the tool's axis as an arrow (removed otherwise). The messages are built
once and refilled in place; the path's points only when the path changes.
"""
from __future__ import annotations

from typing import Any, Sequence

from geometry_msgs.msg import Point
import numpy as np
from visualization_msgs.msg import Marker, MarkerArray

from ..common.qos import DEFAULT_QOS

__all__ = ['FORCE_SCALE_M_PER_N', 'MarkerOutput', 'TOPIC_MARKERS']

TOPIC_MARKERS = '~/markers'
FORCE_SCALE_M_PER_N = 0.01  # 1 N of contact force draws 1 cm
NORMAL_LENGTH_M = 0.05
PLANE_SIDE_M = 0.2
_NS = 'hybrid_force_controller'
# (id, type, rgba, scale) of path, reference, force, normal, surface
_SPECS = ((0, Marker.LINE_STRIP, (0.1, 0.4, 1.0, 1.0), (0.002, 0.0, 0.0)),
          (1, Marker.SPHERE, (0.1, 0.9, 0.2, 1.0), (0.008, 0.008, 0.008)),
          (2, Marker.ARROW, (0.9, 0.1, 0.1, 1.0), (0.003, 0.006, 0.01)),
          (3, Marker.ARROW, (1.0, 0.85, 0.1, 1.0), (0.002, 0.005, 0.01)),
          (4, Marker.CUBE, (0.6, 0.6, 0.6, 0.35), (PLANE_SIDE_M, PLANE_SIDE_M, 0.0005)),
          (5, Marker.ARROW, (0.1, 0.8, 0.9, 1.0), (0.002, 0.005, 0.01)))


def quaternion_z_to(n_W: np.ndarray) -> tuple[float, float, float, float]:
    """Return the quaternion (x, y, z, w) that turns the z axis onto the unit vector ``n_W``."""
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ n_W)
    if c < -1.0 + 1e-9:
        return (1.0, 0.0, 0.0, 0.0)  # half a turn about x
    axis = np.cross(z, n_W)
    q = np.array([axis[0], axis[1], axis[2], 1.0 + c])
    x, y, zz, w = q / np.linalg.norm(q)
    return float(x), float(y), float(zz), float(w)


def _point(p: Sequence[float]) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


class MarkerOutput:
    """The ``~/markers`` publisher and its reusable message."""

    def __init__(self, node: Any, base_frame: str) -> None:
        self.node = node
        self.pub = node.create_publisher(MarkerArray, TOPIC_MARKERS, DEFAULT_QOS)
        self.msg = MarkerArray()
        for marker_id, kind, rgba, scale in _SPECS:
            m = Marker(ns=_NS, id=marker_id, type=kind, action=Marker.ADD)
            m.header.frame_id = base_frame
            m.color.r, m.color.g, m.color.b, m.color.a = rgba
            m.scale.x, m.scale.y, m.scale.z = scale
            m.pose.orientation.w = 1.0
            self.msg.markers.append(m)
        self.path, self.ref, self.force, self.normal, self.plane, self.axis = self.msg.markers
        for arrow in (self.force, self.normal, self.axis):
            arrow.points = [Point(), Point()]
        self._path_key: Any = None

    def set_path(self, key: Any, points_W: np.ndarray | None) -> None:
        """Draw ``points_W`` (base frame) as the path, or no path (None); ``key`` names it."""
        if key == self._path_key:
            return
        self._path_key = key
        if points_W is None or len(points_W) < 2:
            self.path.action, self.path.points = Marker.DELETE, []
        else:
            self.path.action, self.path.points = Marker.ADD, [_point(p) for p in points_W]

    def publish(self, out: Any, stamp_ns: int, n_W: np.ndarray) -> None:
        """Refill the markers from a tick's output (positions, force) and publish them."""
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        for m in self.msg.markers:
            m.header.stamp.sec, m.header.stamp.nanosec = sec, nanosec
        x = out.x_W
        p = self.ref.pose.position
        p.x, p.y, p.z = (float(v) for v in out.x_d_W)
        tip = x + FORCE_SCALE_M_PER_N * out.f_W
        arrows = [(self.force, x, tip), (self.normal, x, x + NORMAL_LENGTH_M * n_W)]
        axis = getattr(out, 'axis_W', None)
        self.axis.action = Marker.DELETE if axis is None else Marker.ADD
        if axis is not None:  # the tool's axis, pointing at the tool from the flange's side
            arrows.append((self.axis, x - NORMAL_LENGTH_M * axis, x))
        for arrow, start, end in arrows:
            a, b = arrow.points
            a.x, a.y, a.z = (float(v) for v in start)
            b.x, b.y, b.z = (float(v) for v in end)
        c = self.plane.pose.position
        c.x, c.y, c.z = (float(v) for v in x)
        o = self.plane.pose.orientation
        o.x, o.y, o.z, o.w = quaternion_z_to(n_W)
        self.pub.publish(self.msg)

    def destroy(self) -> None:
        self.node.destroy_publisher(self.pub)
