"""
Synthetic rosbag2 runs for the tools' tests: messages of known errors, written with BagWriter.

* :func:`synthetic_messages`: 10 s at 100 Hz (the wrench at 200 Hz) with a 1 mm tangential
  error, a 0.2 N sine on the normal force, contact lost over [2.0, 2.5) s and theta_hat
  converging; :func:`write_bag` writes them (or any messages) as an MCAP bag;
* :func:`path_messages`: a 5 cm square traced in the surface plane (n = -y) while
  ``~/path_status`` says ``running`` (:data:`RUNNING_S`), with a known tangential error then
  (0.5 mm) and another before and after (5 mm), plus 3 mm along n that must never count;
* :func:`point_msg`, :func:`wrench_msg`, :func:`array_msg`, :func:`header`: single messages of
  the Jazzy typestore; :func:`samples`: the stamps and times of a run at 100 Hz;
  :func:`run_report`: ``report.main`` with its output captured.

Header stamps start at :data:`T0_NS`; the recorder's log times are the stamps plus
:data:`LOG_OFFSET_NS`.
"""
from __future__ import annotations

import math
from pathlib import Path

from hybrid_force_controller.tools import report
from hybrid_force_controller.tools.bag_io import (BagWriter, RECORD_TOPICS, TOPIC_CONTACT_WRENCH,
                                                  TOPIC_PATH_STATUS, TOPIC_THETA_HAT,
                                                  TOPIC_WRENCH, TOPIC_WRENCH_DESIRED, TOPIC_X,
                                                  TOPIC_X_DESIRED, TYPESTORE)
import numpy as np


T = TYPESTORE.types
T0_NS = 1_700_000_000_000_000_000  # header stamps (e.g. the controller clock)
LOG_OFFSET_NS = 123_456_789  # recorder receive time = stamp + offset
DT_NS = 10_000_000
N_SAMPLES = 1001  # 10 s at 100 Hz
FORCE_AMPLITUDE_N = 0.2
N_SURF = (0.0, -1.0, 0.0)


def header(ns: int):
    stamp = T['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
    return T['std_msgs/msg/Header'](stamp=stamp, frame_id='base_link')


def point_msg(ns: int, p) -> object:
    point = T['geometry_msgs/msg/Point'](x=float(p[0]), y=float(p[1]), z=float(p[2]))
    return T['geometry_msgs/msg/PointStamped'](header=header(ns), point=point)


def wrench_msg(ns: int, f, m=(0.0, 0.0, 0.0)) -> object:
    vec = T['geometry_msgs/msg/Vector3']
    wrench = T['geometry_msgs/msg/Wrench'](force=vec(x=float(f[0]), y=float(f[1]),
                                                     z=float(f[2])),
                                           torque=vec(x=float(m[0]), y=float(m[1]),
                                                      z=float(m[2])))
    return T['geometry_msgs/msg/WrenchStamped'](header=header(ns), wrench=wrench)


def array_msg(values, label: str) -> object:
    dim = T['std_msgs/msg/MultiArrayDimension'](label=label, size=len(values),
                                                stride=len(values))
    layout = T['std_msgs/msg/MultiArrayLayout'](dim=[dim], data_offset=0)
    return T['std_msgs/msg/Float64MultiArray'](layout=layout,
                                               data=np.asarray(values, dtype=float))


def synthetic_messages(skip=(), true_force=False, header_t0_ns=T0_NS, theta_label='m1,m2'):
    """
    (topic, log_ns, msg) of a run with known errors.

    Tangential error 1 mm (plus a 2 mm error along n, which must not count); normal force
    error ``0.2 sin(2 pi t)`` N; contact lost for t in [2.0, 2.5); theta_hat -> (1.3, 0.5).
    With ``true_force`` the measured wrench carries a large bias and the true one is on
    ``/sim/contact_wrench``. The wrench is published at 200 Hz, the rest at 100 Hz.
    Header stamps start at ``header_t0_ns``; log (receive) times at ``T0_NS``.
    """
    n = np.array(N_SURF)
    for k in range(2 * N_SAMPLES - 1):
        ns = header_t0_ns + k * DT_NS // 2
        log_ns = T0_NS + k * DT_NS // 2 + LOG_OFFSET_NS
        t = k * DT_NS / 2 * 1e-9
        lost = 2.0 <= t < 2.5
        f_W = np.zeros(3) if lost else (1.0 + FORCE_AMPLITUDE_N * np.sin(2 * np.pi * t)) * n
        measured_W = f_W + 5.0 * n if true_force else f_W
        out = [(TOPIC_WRENCH, ns, wrench_msg(ns, measured_W))]
        if true_force:
            out.append((TOPIC_CONTACT_WRENCH, ns, wrench_msg(ns, f_W)))
        if k % 2 == 0:
            x_d = np.array([1.0 + 0.1 * np.sin(t), 0.0, 0.0])
            theta = [1.3, 0.5 + 0.4 * math.exp(-t)]
            out += [(TOPIC_X, ns, point_msg(ns, x_d + [1e-3, 2e-3, 0.0])),
                    (TOPIC_X_DESIRED, ns, point_msg(ns, x_d)),
                    (TOPIC_WRENCH_DESIRED, ns, wrench_msg(ns, n)),
                    (TOPIC_THETA_HAT, ns, array_msg(theta, theta_label))]
        for topic, _, msg in out:
            if topic not in skip:
                yield topic, log_ns, msg


def write_bag(path: Path, drop=(), silence=(), true_force=False, messages=None) -> Path:
    """
    Bag of :func:`synthetic_messages`; ``drop``.

    Topics not even declared, ``silence``: topics declared without messages.
    """
    topics = [(t, typ) for t, typ in RECORD_TOPICS if t not in drop]
    with BagWriter(path, topics) as writer:
        for topic, log_ns, msg in (messages if messages is not None
                                   else synthetic_messages((*drop, *silence), true_force)):
            writer.write_msg(topic, log_ns, msg)
    return path


def samples(n: int = N_SAMPLES):
    """Yield (header stamp ns, log ns, t s) of ``n`` samples at 100 Hz from :data:`T0_NS`."""
    for k in range(n):
        ns = T0_NS + k * DT_NS
        yield ns, ns + LOG_OFFSET_NS, k * DT_NS * 1e-9


def run_report(bag: Path, out: Path, capsys, *extra: str) -> tuple[int, str, str]:
    rc = report.main([str(bag), '--out', str(out), *extra])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


# ------------------------------------------------------------------ a user's path
SIDE_M = 0.05
RUNNING_S = (2.0, 8.0)  # the path runs between these log times
STATUS = ((1.0, 'waiting for contact'), (RUNNING_S[0], 'running'), (RUNNING_S[1], 'done'))
ERR_RUNNING = np.array([5e-4, 3e-3, 0.0])  # 0.5 mm along x (tangential) + 3 mm along n
ERR_OTHER = np.array([0.0, 3e-3, 5e-3])  # 5 mm along z (tangential) + 3 mm along n


def square_point(t: float) -> np.ndarray:
    """Return the desired point at t: the square's corner before, along it, at the end after."""
    s = np.clip((t - RUNNING_S[0]) / (RUNNING_S[1] - RUNNING_S[0]), 0.0, 1.0) * 4 * SIDE_M
    corners = np.array([[1.0, 1.6, 0.0], [1.0 + SIDE_M, 1.6, 0.0],
                        [1.0 + SIDE_M, 1.6, SIDE_M], [1.0, 1.6, SIDE_M], [1.0, 1.6, 0.0]])
    k = min(int(s // SIDE_M), 3)
    return corners[k] + (s - k * SIDE_M) / SIDE_M * (corners[k + 1] - corners[k])


def path_messages(with_status: bool = True):
    """(topic, log_ns, msg) of 10 s at 100 Hz with the path running over RUNNING_S."""
    n = np.array(N_SURF)
    status = list(STATUS) if with_status else []
    for ns, log_ns, t in samples():
        while status and status[0][0] <= t + 1e-9:
            yield TOPIC_PATH_STATUS, log_ns, TYPESTORE.types['std_msgs/msg/String'](
                data=status.pop(0)[1])
        x_d = square_point(t)
        err = ERR_RUNNING if RUNNING_S[0] <= t < RUNNING_S[1] else ERR_OTHER
        yield TOPIC_X, log_ns, point_msg(ns, x_d + err)
        yield TOPIC_X_DESIRED, log_ns, point_msg(ns, x_d)
        yield TOPIC_WRENCH, log_ns, wrench_msg(ns, n)
        yield TOPIC_WRENCH_DESIRED, log_ns, wrench_msg(ns, n)
        yield TOPIC_THETA_HAT, log_ns, array_msg([1.3, 0.9], 'm1,m2')
