"""
A user's path over ROS: ``~/path`` in; its status, progress, refusals and markers out.

Everything here runs on the controller node's thread. A ``nav_msgs/Path`` is checked and
planned here (core/law/path.py), then handed to the control thread
(:meth:`~.control_loop.ControlLoop.follow_path`, a ``deque(maxlen=1)``), which installs it at
its next tick. A refused path is logged as a warning and its reason published on
``~/path_refused``; nothing reaches the control thread, so the current motion goes on, and so
does its status (a refusal on ``~/path_status`` once overwrote a running path's ``running``,
and a script waiting for its own path's end stopped early). Every :data:`POLL_S` the latest
tick's output (``ControlLoop.latest``) gives the path's progress and the markers (markers.py;
only while someone subscribes to them).

Each accepted path has a number, its identity (1 for the first accepted, an empty path
included). ``~/path_status`` (std_msgs/String, on change): the state of the latest accepted
path, ``idle``, ``waiting for contact``, ``running``, ``done`` or ``stopped`` (an empty path,
a held point or a ``ref_*``/``n`` change ended it). ``~/path_progress``
(std_msgs/Float64MultiArray, labelled dims ``fraction``, ``time_left_s``, ``path``,
``state``): the fraction of the plan done (the transit to the first pose included), the time
left at full rate (s), the path's number and its state's code (:data:`STATE_CODES`): the
identity and the state in one message, 10 Hz while a path is active and on every change. All
three are transient local (the last message reaches a late subscriber). An accepted path's
first status and progress are published at once, and a path's are published under one lock
with the acceptance of the next, so nothing of an older path follows a newer one's.
"""
from __future__ import annotations

import threading
from typing import Any

from nav_msgs.msg import Path
import numpy as np
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout, String

from .markers import MarkerOutput
from ..common.qos import DEFAULT_QOS, LATCHED_QOS
from ...core.law.path import check_path, PathError, PathLimits, plan_path
from ...core.runtime.modes import Mode
from ...core.runtime.path_run import (PATH_DONE, PATH_IDLE, PATH_RUNNING, PATH_STOPPED,
                                      PATH_WAITING)

__all__ = ['PathTopics', 'POLL_S', 'STATE_CODES', 'path_arrays']

POLL_S = 0.1  # progress and markers, s
_ACTIVE = (PATH_WAITING, PATH_RUNNING)
STATE_CODES = {PATH_IDLE: 0.0, PATH_WAITING: 1.0, PATH_RUNNING: 2.0, PATH_DONE: 3.0,
               PATH_STOPPED: 4.0}  # ~/path_progress's ``state``


def path_arrays(msg: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Return the positions (N, 3), stamps (N,) s, orientations (N, 4) and frames of a Path."""
    poses = msg.poses
    points = np.array([(p.pose.position.x, p.pose.position.y, p.pose.position.z)
                       for p in poses], dtype=float).reshape(-1, 3)
    stamps = np.array([p.header.stamp.sec + 1e-9 * p.header.stamp.nanosec for p in poses],
                      dtype=float)
    quats = np.array([(p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z,
                       p.pose.orientation.w) for p in poses], dtype=float).reshape(-1, 4)
    return points, stamps, quats, [p.header.frame_id for p in poses]


class PathTopics:
    """The path's subscription and the progress, status and marker publishers of a node."""

    def __init__(self, node: Any, base_frame: str, guard: Any) -> None:
        self.node, self.base = node, base_frame
        self.sub = node.create_subscription(Path, '~/path', guard('path', self.on_path),
                                            DEFAULT_QOS)
        self.pub_status = node.create_publisher(String, '~/path_status', LATCHED_QOS)
        self.pub_progress = node.create_publisher(Float64MultiArray, '~/path_progress',
                                                  LATCHED_QOS)
        self.pub_refused = node.create_publisher(String, '~/path_refused', LATCHED_QOS)
        self.markers = MarkerOutput(node, base_frame)
        dims = [MultiArrayDimension(label=k, size=1, stride=1)
                for k in ('fraction', 'time_left_s', 'path', 'state')]
        self.progress_msg = Float64MultiArray(layout=MultiArrayLayout(dim=dims))
        self.seq, self.plan = 0, None  # the last accepted path (None: empty, or none yet)
        self.status = ''
        self.lock = threading.Lock()  # a path's acceptance against the poll's publishing
        self.timer = node.create_timer(POLL_S, guard('path_poll', self.poll))
        self._publish_status(PATH_IDLE)

    # ------------------------------------------------------------------ in
    def on_path(self, msg: Path) -> None:
        """Check and plan a path, hand it to the control thread; refuse it with the reason."""
        loop = self.node.loop
        if loop is None:
            return
        try:
            plan = self._plan(msg, loop.latest)
        except PathError as exc:
            self.node.get_logger().warning(f'path refused: {exc}')
            self.pub_refused.publish(String(data=str(exc)))
            return
        with self.lock:
            self.seq += 1
            self.plan = plan
            loop.follow_path(plan, self.seq)
            if plan is None:
                self._publish_status(PATH_STOPPED)
                self._publish_progress(0.0, 0.0)
                return
            out = loop.latest[0] if loop.latest is not None else None
            running = out is not None and out.mode == Mode.RUNNING and out.in_contact
            self._publish_status(PATH_RUNNING if running else PATH_WAITING)
            self._publish_progress(0.0, plan.duration)

    def _plan(self, msg: Path, latest: Any) -> Any:
        """Return the plan of ``msg`` (None for an empty path) or raise :class:`PathError`."""
        frames = {msg.header.frame_id}
        points, stamps, quats, pose_frames = path_arrays(msg)
        frames.update(f for f in pose_frames if f)
        wrong = sorted(f for f in frames if f not in ('', self.base))
        if wrong:
            raise PathError(f"frame_id '{wrong[0]}' is not the base frame '{self.base}' "
                            '(no TF here)')
        rt = self.node.params.runtime
        limits = PathLimits(rt.path_speed, rt.path_max_accel, rt.path_max_speed,
                            rt.path_max_poses, rt.path_corner_tolerance)
        check_path(points, stamps, limits, quats)
        if not len(points):
            return None
        out = latest[0] if latest is not None else None
        start = None if out is None else out.x_d_W
        start_v = None if out is None else out.xdot_d_W
        return plan_path(points, stamps, start, self.node.params.law.n,
                         self.node.model.task_axes, limits, start_v_W=start_v)

    # ------------------------------------------------------------------ out
    def poll(self) -> None:
        """Publish the path's progress and status, and the markers, from the latest tick."""
        latest = self.node.loop.latest if self.node.loop is not None else None
        if latest is None:
            return
        out, stamp_ns = latest
        p = out.path
        with self.lock:  # the seq compared is the one published: no older path's state after
            if p.seq == self.seq and self.seq and self.plan is not None:
                changed = p.state != self.status
                if changed:
                    self._publish_status(p.state)
                if p.state in _ACTIVE or changed:
                    self._publish_progress(p.fraction, p.time_left_s)
        if self.markers.pub.get_subscription_count() == 0:
            return  # nobody looks (RViz closed): no markers built
        drawn = self.plan is not None and self.status not in (PATH_STOPPED, PATH_IDLE)
        self.markers.set_path((self.seq, drawn), self.plan.polyline() if drawn else None)
        self.markers.publish(out, stamp_ns,
                             self.node.params.law.n if out.n_W is None else out.n_W)

    def _publish_status(self, status: str) -> None:
        self.status = status
        self.pub_status.publish(String(data=status))

    def _publish_progress(self, fraction: float, time_left_s: float) -> None:
        self.progress_msg.data = [float(fraction), float(time_left_s), float(self.seq),
                                  STATE_CODES.get(self.status, -1.0)]
        self.pub_progress.publish(self.progress_msg)

    def destroy(self) -> None:
        """Destroy the subscription, publishers and timer (lifecycle cleanup)."""
        node = self.node
        node.destroy_subscription(self.sub)
        node.destroy_timer(self.timer)
        for pub in (self.pub_status, self.pub_progress, self.pub_refused):
            node.destroy_publisher(pub)
        self.markers.destroy()
