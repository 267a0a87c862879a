"""
``identify_tool``: the tool's mass and centre of mass from a bag of still poses (offline).

How a user does it: out of contact, hold the arm still in three or more poses that tilt the
tool about two axes (half a second or more each; by hand, a teach pendant, or any
controller), while ``ros2 bag record`` takes the joint states and the wrist wrench. Then::

    identify_tool BAG --urdf robot.urdf --gravity 0 0 -9.81 [--joints j1 j2 ...]

finds the still stretches (every joint within ``--q-tol`` rad for ``--hold`` s), averages the
wrench over each (the first ``SETTLE_S`` left out), turns each pose into the sensor frame's
rotation with the URDF (the wrench's ``frame_id``) and fits the mass, the centre of mass and
the sensor's biases (core/model/tool_identification.py). It prints them with their residuals,
and the parameters for the controller (``tool_mass``, ``tool_com``, ``wrench_offset``) as YAML.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys
from typing import Sequence

import numpy as np
from rosbags.highlevel import AnyReader

from .bag_io import BagError, TYPESTORE
from ..core.model.robot_model import ModelError, RobotModel
from ..core.model.tool_identification import IdentificationError, identify_tool, ToolFit

__all__ = ['main', 'still_poses']

SETTLE_S = 0.1  # the start of a still stretch is left out of its mean (the arm settling)


def still_poses(t: np.ndarray, q: np.ndarray, t_w: np.ndarray, w: np.ndarray,
                hold_s: float = 0.5, q_tol: float = 2e-4) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the mean joint positions and the mean wrench of each still stretch.

    ``t`` (s, increasing), ``q`` (rows): the joint states; ``t_w``, ``w``: the wrench stamps
    and rows (force and torque, 6 columns). A stretch is still while every joint stays within
    ``q_tol`` of where it began, and counts when it lasts ``hold_s`` and holds wrenches after
    its first ``SETTLE_S``.
    """
    poses_q, poses_w = [], []
    i, n = 0, len(t)
    while i < n:
        j = i
        while j + 1 < n and np.all(np.abs(q[j + 1] - q[i]) <= q_tol):
            j += 1
        inside = (t_w >= t[i] + SETTLE_S) & (t_w <= t[j])
        if t[j] - t[i] >= hold_s and inside.any():
            poses_q.append(q[i:j + 1].mean(axis=0))
            poses_w.append(w[inside].mean(axis=0))
        i = j + 1
    return np.array(poses_q).reshape(-1, q.shape[1]), np.array(poses_w).reshape(-1, 6)


def _read(bag: Path, js_topic: str, wrench_topic: str, joints: Sequence[str]):
    """Return joint-state times and positions (model order), wrench times, rows, frame."""
    t, q, t_w, w, frame = [], [], [], [], ''
    try:
        with AnyReader([bag], default_typestore=TYPESTORE) as reader:
            for topic in (js_topic, wrench_topic):
                if topic not in reader.topics:
                    raise BagError(f'topic {topic} is not in bag {bag}')
            conns = [c for c in reader.connections if c.topic in (js_topic, wrench_topic)]
            for conn, _, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                if conn.topic == js_topic:
                    index = {name: k for k, name in enumerate(msg.name)}
                    missing = [j for j in joints if j not in index]
                    if missing:
                        raise BagError(f'joint states without {missing} (the URDF has them)')
                    t.append(stamp)
                    q.append([msg.position[index[j]] for j in joints])
                else:
                    f, m = msg.wrench.force, msg.wrench.torque
                    t_w.append(stamp)
                    w.append((f.x, f.y, f.z, m.x, m.y, m.z))
                    frame = frame or msg.header.frame_id
    except BagError:
        raise
    except Exception as exc:  # rosbags raises many types on corrupt input
        raise BagError(f'{bag} is not a readable rosbag2 bag: '
                       f'{type(exc).__name__}: {exc}') from exc
    order = np.argsort(t, kind='stable')
    return (np.array(t)[order], np.array(q).reshape(-1, len(joints))[order], np.array(t_w),
            np.array(w).reshape(-1, 6), frame)


def _wrench_frame(bag: Path, wrench_topic: str) -> str:
    """Return the ``frame_id`` of the bag's first wrench (the sensor frame)."""
    try:
        with AnyReader([bag], default_typestore=TYPESTORE) as reader:
            conns = [c for c in reader.connections if c.topic == wrench_topic]
            for conn, _, raw in reader.messages(connections=conns):
                return reader.deserialize(raw, conn.msgtype).header.frame_id
    except Exception as exc:  # rosbags raises many types on corrupt input
        raise BagError(f'{bag} is not a readable rosbag2 bag: '
                       f'{type(exc).__name__}: {exc}') from exc
    raise BagError(f'topic {wrench_topic} is not in bag {bag}')


def identify_from_bag(bag: Path, model: RobotModel, js_topic: str, wrench_topic: str,
                      frame: str = '', hold_s: float = 0.5,
                      q_tol: float = 2e-4) -> tuple[ToolFit, str]:
    """Fit the tool from a bag's still poses; also return the sensor frame used."""
    t, q, t_w, w, msg_frame = _read(bag, js_topic, wrench_topic, model.joint_names)
    frame = frame or msg_frame
    poses_q, poses_w = still_poses(t, q, t_w, w, hold_s, q_tol)
    R_W_root = model.base_from_root(np.zeros(3), np.eye(3), np.zeros((3, 0)))[1]
    g_W = R_W_root @ model.model.gravity.linear
    R = np.array([model.frame_rotation(p, frame) for p in poses_q]).reshape(-1, 3, 3)
    return identify_tool(R, poses_w[:, :3], poses_w[:, 3:], g_W), frame


def _report(fit: ToolFit, frame: str) -> str:
    def vec(v) -> str:
        return '[' + ', '.join(f'{x:.4g}' for x in v) + ']'
    return '\n'.join([
        f'{fit.poses} still poses; sensor frame {frame!r}',
        f'mass {fit.tool_mass:.4g} kg, centre of mass {vec(fit.tool_com)} m',
        f'force bias {vec(fit.force_bias)} N, torque bias {vec(fit.torque_bias)} N m',
        f'residuals (RMS over the poses): force {fit.force_residual_n:.3g} N, '
        f'torque {fit.torque_residual_n_m:.3g} N m',
        '', '# for the controller (a parameter file, or -p name:=value):',
        f'tool_mass: {fit.tool_mass:.6g}', f'tool_com: {vec(fit.tool_com)}',
        f'wrench_offset: {vec(fit.force_bias)}'])


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line (module docstring); 0 on success, 1 with the reason otherwise."""
    ap = argparse.ArgumentParser(prog='identify_tool', description=__doc__.split('\n')[1])
    ap.add_argument('bag', type=Path)
    ap.add_argument('--urdf', default=None, help="the robot's URDF (default: the paper's arm)")
    ap.add_argument('--base', default=None, help="the base frame (default: the URDF's root)")
    ap.add_argument('--frame', default='', help="sensor frame (default: the wrench's frame_id)")
    ap.add_argument('--joints', nargs='+', default=None,
                    help="the arm's joints (default: every joint of the URDF)")
    ap.add_argument('--gravity', nargs=3, type=float, default=None, metavar=('X', 'Y', 'Z'),
                    help="gravity in the URDF's root frame, m/s^2 (default: the paper's, "
                         '0 -9.81 0; a z-up robot: 0 0 -9.81)')
    ap.add_argument('--joint-states', default='/joint_states')
    ap.add_argument('--wrench', default='/force_torque_sensor_broadcaster/wrench')
    ap.add_argument('--hold', type=float, default=0.5, help='still this long, s (default 0.5)')
    ap.add_argument('--q-tol', type=float, default=2e-4, help='still within, rad (default 2e-4)')
    args = ap.parse_args(argv)
    try:
        frame = args.frame or _wrench_frame(args.bag, args.wrench)
        model = RobotModel.from_urdf(args.urdf, base_link=args.base, joints=args.joints,
                                     gravity_root=args.gravity, end_effector_link=frame)
        fit, frame = identify_from_bag(args.bag, model, args.joint_states, args.wrench,
                                       frame, args.hold, args.q_tol)
    except (BagError, ModelError, IdentificationError, OSError) as exc:
        print(f'identify_tool: {exc}', file=sys.stderr)
        return 1
    print(_report(fit, frame))
    return 0
