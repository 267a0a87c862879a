"""
``python -m hybrid_force_controller.ros.programs.send_path``: a user's script that wipes a square.

What a user writes to give the controller a task: it reads where the tool is (``~/x``) and the
surface's normal the controller presses along (``~/wrench_desired``), sends a square of side
``--side`` in the surface's tangent plane starting at the tool on ``~/path`` (untimed: the
controller times it at ``path_speed`` and rounds its corners within ``path_corner_tolerance``),
prints the progress from ``~/path_progress`` and waits until that topic says its own path
(the first path number after sending) is done: the number and the state come in one message.
Exit 0 when done, 2 when the path was refused (``~/path_refused``, with the reason), stopped or
replaced by another sender's path, or on ``--timeout``.
The demo's ``--task wipe`` runs it as a separate process, as a user's script would run.
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Sequence

import numpy as np

__all__ = ['main', 'square_poses']

# ~/path_progress's state codes (controller/path_topics.py STATE_CODES; not imported: this
# script needs only the controller's topics, as a user's would)
STATE_CODES = {'idle': 0.0, 'waiting for contact': 1.0, 'running': 2.0, 'done': 3.0,
               'stopped': 4.0}

CONTROLLER = 'hybrid_force_controller'


def square_poses(start_W: np.ndarray, n_W: np.ndarray, side: float,
                 centred: bool = False) -> np.ndarray:
    """
    Return the corners of a square of ``side`` m from ``start_W``, closed, in the tangent plane.

    Its edges run along the surface's in-plane axes (tools/path_analysis.py ``surface_basis``),
    counter-clockwise seen from the tool. ``centred``: ``start_W`` is its centre, not a corner.
    """
    from ...tools.path_analysis import surface_basis
    u, v = surface_basis(np.asarray(n_W, dtype=float))
    p0 = np.asarray(start_W, dtype=float) - (0.5 * side * (u + v) if centred else 0.0)
    return np.array([p0, p0 + side * u, p0 + side * (u + v), p0 + side * v, p0])


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='send_path', description=__doc__.splitlines()[1].strip())
    ap.add_argument('--side', type=float, default=0.1, help='side of the square, m')
    ap.add_argument('--controller', default=CONTROLLER,
                    help="the controller node (relative: under this process's namespace)")
    ap.add_argument('--timeout', type=float, default=120.0, help='wall-time limit, s')
    ap.add_argument('--normal', type=float, nargs=3, default=None, metavar=('X', 'Y', 'Z'),
                    help="the square's plane's normal, base frame (default: the one the "
                    'controller presses along)')
    ap.add_argument('--centred', action='store_true',
                    help='the square centred on the tool (default: its first corner there)')
    return ap


class _Script:
    """The script's node: the controller's position, normal, status and progress."""

    def __init__(self, node, ctrl: str) -> None:
        from geometry_msgs.msg import PointStamped, WrenchStamped
        from nav_msgs.msg import Path
        from rclpy.qos import DurabilityPolicy, QoSProfile
        from std_msgs.msg import Float64MultiArray, String
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.x = self.f_d = None
        self.refused: list[str] = []
        self.progress = (0.0, 0.0, 0.0, 0.0)  # fraction, time left, path number, state code
        node.create_subscription(PointStamped, f'{ctrl}/x', self._on_x, 10)
        node.create_subscription(WrenchStamped, f'{ctrl}/wrench_desired', self._on_f_d, 10)
        node.create_subscription(String, f'{ctrl}/path_refused',
                                 lambda m: self.refused.append(m.data), latched)
        node.create_subscription(Float64MultiArray, f'{ctrl}/path_progress',
                                 lambda m: setattr(self, 'progress', tuple(m.data[:4])), latched)
        self.pub = node.create_publisher(Path, f'{ctrl}/path', 10)

    def _on_x(self, msg) -> None:
        self.x = np.array((msg.point.x, msg.point.y, msg.point.z))

    def _on_f_d(self, msg) -> None:
        f = msg.wrench.force
        self.f_d = np.array((f.x, f.y, f.z))

    def ready(self) -> bool:
        return (self.x is not None and self.f_d is not None and np.linalg.norm(self.f_d) > 0.0
                and self.pub.get_subscription_count() > 0)

    def send(self, corners: np.ndarray) -> tuple[float, int]:
        """Publish the path (base frame, stamps all zero); the last path number, refusals seen."""
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Path
        path = Path()
        for c in corners:
            pose = PoseStamped()
            position = pose.pose.position
            position.x, position.y, position.z = (float(v) for v in c)
            pose.pose.orientation.w = 1.0
            path.poses.append(pose)
        before = (self.progress[2], len(self.refused))
        self.pub.publish(path)
        return before


def _run(script: _Script, spin, args: argparse.Namespace, deadline: float) -> int:
    while not script.ready():
        if not spin(deadline):
            print('send_path: the controller did not come up', file=sys.stderr)
            return 2
    n_W = np.asarray(args.normal if args.normal is not None else script.f_d, dtype=float)
    side = args.side
    seq0, refused0 = script.send(square_poses(script.x, n_W / np.linalg.norm(n_W), side,
                                              args.centred))
    print(f'send_path: a {side * 100:.0f} cm square from {np.round(script.x, 4).tolist()}')
    shown, mine = -1, None
    while True:
        if not spin(deadline):
            print('send_path: timed out', file=sys.stderr)
            return 2
        if len(script.refused) > refused0:
            print(f'send_path: refused: {script.refused[refused0]}', file=sys.stderr)
            return 2
        fraction, left, seq, state = script.progress
        if seq <= seq0:
            continue  # not accepted yet
        if mine is None:
            mine = seq
            print(f'send_path: accepted as path {seq:.0f}', flush=True)
        if seq != mine or state == STATE_CODES['stopped']:
            print(f'send_path: stopped (path {seq:.0f})', file=sys.stderr)
            return 2
        if state == STATE_CODES['done']:
            print('send_path: done')
            return 0
        if int(fraction * 10) != shown:
            shown = int(fraction * 10)
            print(f'send_path: {100 * fraction:3.0f} % done, {left:.1f} s left', flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Send the square and wait for it to be done (exit codes: module docstring)."""
    args = _parser().parse_args(argv)
    if args.normal is not None and not (np.all(np.isfinite(args.normal))
                                        and np.linalg.norm(args.normal) > 0.0):
        print(f'send_path: --normal must be finite and nonzero, got {args.normal}',
              file=sys.stderr)
        return 2
    import rclpy
    rclpy.init()
    node = rclpy.create_node('send_path')
    try:
        script = _Script(node, args.controller)

        def spin(deadline: float) -> bool:
            rclpy.spin_once(node, timeout_sec=0.05)
            return time.monotonic() < deadline
        return _run(script, spin, args, time.monotonic() + args.timeout)
    except KeyboardInterrupt:
        return 2
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
