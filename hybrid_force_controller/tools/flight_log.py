"""
Write a flight recorder's snapshot as a rosbag2 MCAP bag that ``report`` reads (rosbags only).

:func:`write_flight_log` turns a
:class:`~hybrid_force_controller.core.runtime.flight_recorder.FlightSnapshot` (the last ticks
of the control loop) into a bag of :class:`~.bag_io.BagWriter` (MCAP, metadata version 8) on
the topics a recording of the controller has, one message per tick, so ``load_run`` and
``report BAG --out DIR --t-start 0`` read it (a flight log lasts 2 s: the report's default
``--t-start 5`` finds no samples) and any MCAP reader opens it:

* ``/hybrid_force_controller/x``, ``x_desired`` (PointStamped), ``wrench``,
  ``wrench_desired`` (WrenchStamped, the filtered force and f_d n), ``theta_hat``
  (Float64MultiArray, the names in ``layout.dim[0].label``): stamped with the tick time;
* ``/joint_states``: the joint state the tick used (q, qdot; model order), stamped with its
  own stamp; ``/effort_controller/commands``: the effort sent (none while waiting);
* its own, ``std_msgs``: ``/hybrid_force_controller/flight/mode`` (String, the mode's value),
  ``.../in_contact`` (Bool), ``.../wrench_stamp`` (Float64: the stamp of the wrench the tick
  used, s), ``.../hold_s`` (Float64: how long the tick's callback held the control thread, s;
  NaN: unknown) and ``.../trigger`` (String, once, at the trigger's time: why it was written).

Log times are the tick times (the loop clock: wall or sim time), so headerless topics line
up with the stamped ones.

The controller writes its dumps in a process of their own (``python -m
hybrid_force_controller.tools.flight_log SNAPSHOT.npz BAG``): :func:`save_snapshot` puts the
copied ring in an ``.npz`` file (a few ms, mostly I/O), and this module's :func:`main` turns it
into the bag and removes it. The 0.3-0.5 s of Python that the messages take then never holds
the controller's GIL.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path
import re
import sys
import time
from typing import Any, Sequence

import numpy as np

from .bag_io import (BagError, BagWriter, TOPIC_EFFORT_COMMANDS, TOPIC_JOINT_STATES,
                     TOPIC_THETA_HAT, TOPIC_WRENCH, TOPIC_WRENCH_DESIRED, TOPIC_X,
                     TOPIC_X_DESIRED, TYPESTORE)
from ..core.runtime.flight_recorder import FlightSnapshot, MODES

__all__ = ['FLIGHT_TOPICS', 'TOPIC_FLIGHT_CONTACT', 'TOPIC_FLIGHT_HOLD', 'TOPIC_FLIGHT_MODE',
           'TOPIC_FLIGHT_TRIGGER', 'TOPIC_FLIGHT_WRENCH_STAMP', 'flight_log_path',
           'load_snapshot', 'main', 'save_snapshot', 'write_flight_log']

_PREFIX = '/hybrid_force_controller/flight/'
TOPIC_FLIGHT_MODE = _PREFIX + 'mode'
TOPIC_FLIGHT_CONTACT = _PREFIX + 'in_contact'
TOPIC_FLIGHT_WRENCH_STAMP = _PREFIX + 'wrench_stamp'
TOPIC_FLIGHT_HOLD = _PREFIX + 'hold_s'
TOPIC_FLIGHT_TRIGGER = _PREFIX + 'trigger'
_POINT = 'geometry_msgs/msg/PointStamped'
_WRENCH = 'geometry_msgs/msg/WrenchStamped'
_ARRAY = 'std_msgs/msg/Float64MultiArray'
FLIGHT_TOPICS: list[tuple[str, str]] = [
    (TOPIC_X, _POINT), (TOPIC_X_DESIRED, _POINT), (TOPIC_WRENCH, _WRENCH),
    (TOPIC_WRENCH_DESIRED, _WRENCH), (TOPIC_THETA_HAT, _ARRAY),
    (TOPIC_JOINT_STATES, 'sensor_msgs/msg/JointState'), (TOPIC_EFFORT_COMMANDS, _ARRAY),
    (TOPIC_FLIGHT_MODE, 'std_msgs/msg/String'), (TOPIC_FLIGHT_CONTACT, 'std_msgs/msg/Bool'),
    (TOPIC_FLIGHT_WRENCH_STAMP, 'std_msgs/msg/Float64'),
    (TOPIC_FLIGHT_HOLD, 'std_msgs/msg/Float64'), (TOPIC_FLIGHT_TRIGGER, 'std_msgs/msg/String'),
]
_T = TYPESTORE.types


def flight_log_path(directory: str | Path, reason: str, wall_s: float | None = None,
                    tag: str = '') -> Path:
    """
    Return the bag directory of a dump: ``DIR/flight_YYYYmmdd-HHMMSS_TAG_REASON``.

    ``wall_s``: the wall time of the dump (None: now); ``TAG`` tells apart the dumps of one
    second (the node gives its process id and a count); ``REASON`` is the reason's first
    words, letters and digits only.
    """
    wall_s = time.time() if wall_s is None else wall_s
    slug = '_'.join(re.findall(r'[a-z0-9]+', reason.lower())[:3]) or 'trigger'
    stamp = time.strftime('%Y%m%d-%H%M%S', time.localtime(wall_s))
    return Path(directory) / '_'.join(x for x in ('flight', stamp, tag, slug) if x)


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _header(ns: int, frame: str) -> Any:
    stamp = _T['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
    return _T['std_msgs/msg/Header'](stamp=stamp, frame_id=frame)


def _point(ns: int, frame: str, p: np.ndarray) -> Any:
    point = _T['geometry_msgs/msg/Point'](x=float(p[0]), y=float(p[1]), z=float(p[2]))
    return _T[_POINT](header=_header(ns, frame), point=point)


def _wrench(ns: int, frame: str, f: np.ndarray) -> Any:
    vec = _T['geometry_msgs/msg/Vector3']
    wrench = _T['geometry_msgs/msg/Wrench'](
        force=vec(x=float(f[0]), y=float(f[1]), z=float(f[2])), torque=vec(x=0.0, y=0.0, z=0.0))
    return _T[_WRENCH](header=_header(ns, frame), wrench=wrench)


def _array(values: np.ndarray, label: str = '') -> Any:
    dims = [_T['std_msgs/msg/MultiArrayDimension'](label=label, size=values.size,
                                                   stride=values.size)] if label else []
    layout = _T['std_msgs/msg/MultiArrayLayout'](dim=dims, data_offset=0)
    return _T[_ARRAY](layout=layout, data=np.array(values, dtype=np.float64))


def _tick_messages(snap: FlightSnapshot, k: int, joints: list[str], theta_label: str,
                   frame: str) -> list[tuple[str, Any]]:
    """Return the (topic, message) pairs of tick ``k`` of the snapshot."""
    ns = _ns(snap.t[k])
    std = _T['std_msgs/msg/Float64']
    out = [(TOPIC_X, _point(ns, frame, snap.x_W[k])),
           (TOPIC_X_DESIRED, _point(ns, frame, snap.x_d_W[k])),
           (TOPIC_WRENCH, _wrench(ns, frame, snap.f_W[k])),
           (TOPIC_WRENCH_DESIRED, _wrench(ns, frame, snap.f_d_W[k])),
           (TOPIC_THETA_HAT, _array(snap.theta_hat[k], theta_label)),
           (TOPIC_FLIGHT_MODE, _T['std_msgs/msg/String'](data=MODES[snap.mode[k]].value)),
           (TOPIC_FLIGHT_CONTACT, _T['std_msgs/msg/Bool'](data=bool(snap.in_contact[k]))),
           (TOPIC_FLIGHT_WRENCH_STAMP, std(data=float(snap.t_wrench[k]))),
           (TOPIC_FLIGHT_HOLD, std(data=float(snap.hold_s[k])))]
    if math.isfinite(snap.t_state[k]):
        out.append((TOPIC_JOINT_STATES, _T['sensor_msgs/msg/JointState'](
            header=_header(_ns(snap.t_state[k]), ''), name=joints,
            position=snap.q[k].copy(), velocity=snap.qdot[k].copy(),
            effort=np.zeros(0))))
    if np.all(np.isfinite(snap.tau[k])):
        out.append((TOPIC_EFFORT_COMMANDS, _array(snap.tau[k])))
    return out


def write_flight_log(path: str | Path, snap: FlightSnapshot, joint_names: Sequence[str],
                     theta_names: Sequence[str], base_frame: str = 'base_link',
                     reason: str = '', t_trigger: float = math.nan) -> Path:
    """
    Write ``snap`` as an MCAP rosbag2 bag at ``path`` (a directory that must not exist).

    Parameters
    ----------
    path : str or pathlib.Path
        The bag directory to create (its parent is created if missing).
    snap : FlightSnapshot
        The recorded ticks (FlightRecorder.snapshot, off the control thread).
    joint_names : sequence of str
        The model's joints, the order of q and qdot.
    theta_names : sequence of str
        Names of theta_hat's entries.
    base_frame : str
        frame_id of the stamped vectors.
    reason, t_trigger : str, float
        Why and when (tick time, s) the dump was asked for: one ``.../trigger`` message
        (none when ``reason`` is empty).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    BagError
        No ticks, a negative tick time, or the bag cannot be created or written.

    """
    path = Path(path)
    if len(snap) == 0:
        raise BagError(f'flight log {path}: the snapshot holds no ticks')
    joints, label = list(joint_names), ','.join(theta_names)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BagError(f'cannot create the directory of {path}: {exc}') from exc
    with BagWriter(path, FLIGHT_TOPICS) as writer:
        for k in range(len(snap)):
            ns = _ns(snap.t[k])
            for topic, msg in _tick_messages(snap, k, joints, label, base_frame):
                writer.write_msg(topic, ns, msg)
        if reason:
            t = t_trigger if math.isfinite(t_trigger) else float(snap.t[-1])
            writer.write_msg(TOPIC_FLIGHT_TRIGGER, _ns(t), _T['std_msgs/msg/String'](data=reason))
    return path


def save_snapshot(path: str | Path, snap: FlightSnapshot, joint_names: Sequence[str],
                  theta_names: Sequence[str], base_frame: str = 'base_link',
                  reason: str = '', t_trigger: float = math.nan) -> Path:
    """Save ``snap`` and :func:`write_flight_log`'s other arguments as an ``.npz`` file."""
    path = Path(path)
    arrays = {f.name: getattr(snap, f.name) for f in dataclasses.fields(snap)}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, 'wb') as out:
            np.savez(out, **arrays, joint_names=np.array(list(joint_names)),
                     theta_names=np.array(list(theta_names)), base_frame=np.array(base_frame),
                     reason=np.array(reason), t_trigger=np.array(t_trigger))
    except OSError as exc:
        raise BagError(f'cannot save the flight snapshot {path}: {exc}') from exc
    return path


def load_snapshot(path: str | Path) -> tuple[FlightSnapshot, dict[str, Any]]:
    """Return the snapshot :func:`save_snapshot` saved and its write_flight_log arguments."""
    with np.load(path) as data:
        snap = FlightSnapshot(**{f.name: (int(data[f.name]) if f.name == 'dropped'
                                          else data[f.name].copy())
                                 for f in dataclasses.fields(FlightSnapshot)})
        kwargs = {'joint_names': [str(j) for j in data['joint_names']],
                  'theta_names': [str(j) for j in data['theta_names']],
                  'base_frame': str(data['base_frame']), 'reason': str(data['reason']),
                  't_trigger': float(data['t_trigger'])}
    return snap, kwargs


def main(argv: Sequence[str] | None = None) -> int:
    """Write the bag ``argv[1]`` from the snapshot file ``argv[0]``, then remove it; 0 or 2."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 2:
        print('usage: python -m hybrid_force_controller.tools.flight_log SNAPSHOT.npz BAG',
              file=sys.stderr)
        return 2
    try:
        snap, kwargs = load_snapshot(args[0])
        write_flight_log(args[1], snap, **kwargs)
    except (BagError, OSError, KeyError, ValueError) as exc:
        print(f'flight_log: {exc}', file=sys.stderr)
        return 2
    finally:
        Path(args[0]).unlink(missing_ok=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
