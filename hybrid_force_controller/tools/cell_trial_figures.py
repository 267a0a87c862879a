"""
Figures of one wipe under a fault, from its bag (``wipe_trials``; issue 30's targets).

Times are the bag's stamps (s, the sim's clock: the wall clock in real time), so a stall's
wall times (``time.time()`` at SIGSTOP and SIGCONT) compare with them directly.

* ``max_joint_speed_ratio``: the largest ``|q̇_i| / q̇_max,i`` over the run (``/joint_states``
  against the URDF's velocity limits), and ``fastest_joint``;
* ``path_s``: how long the path ran (``~/path_status`` ``running``);
* with a stall: ``stall_in_path`` (it began while the path ran), ``back_s`` (from the release
  to the start of the first 0.2 s in contact), ``settle_s`` (to the first 0.2 s within 10 % of
  f_d), ``peak_force_n`` (the largest true normal force from the stall to 2 s after it);
* ``rms_force_error_n`` and ``contact_lost_s`` over the path, outside ``[stop, release + 2]``.
"""
from __future__ import annotations

import math
from pathlib import Path
import xml.etree.ElementTree as ET

import numpy as np
from rosbags.highlevel import AnyReader

from .bag_io import load_run, TOPIC_JOINT_STATES, TOPIC_X, TYPESTORE
from .recovery_figures import first_hold, settle_time

__all__ = ['AFTER_STALL_S', 'trial_figures', 'urdf_velocity_limits']

AFTER_STALL_S = 2.0  # the force RMS is taken outside the stall and this long after it
HOLD_S = 0.2
PANDA_URDF = Path(__file__).resolve().parents[1] / 'robots' / 'panda.urdf'


def urdf_velocity_limits(urdf: Path = PANDA_URDF) -> dict[str, float]:
    """Return each joint's ``<limit velocity>`` (rad/s or m/s) by joint name."""
    return {j.get('name'): float(j.find('limit').get('velocity'))
            for j in ET.parse(urdf).getroot().iter('joint')
            if j.find('limit') is not None and j.find('limit').get('velocity')}


def _joint_speed(bag: Path, limits: dict[str, float]) -> tuple[float, str, float]:
    """Return the largest speed ratio, its joint, and the first position sample's stamp (s)."""
    worst, name, t0 = 0.0, '', math.nan
    with AnyReader([bag], default_typestore=TYPESTORE) as reader:
        conns = [c for c in reader.connections if c.topic in (TOPIC_JOINT_STATES, TOPIC_X)]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            if conn.topic == TOPIC_X:
                t0 = stamp if math.isnan(t0) else min(t0, stamp)
                continue
            for joint, v in zip(msg.name, msg.velocity):
                ratio = abs(float(v)) / limits.get(joint, math.inf)
                if ratio > worst:
                    worst, name = ratio, joint
    return worst, name, t0


def trial_figures(bag: Path, stall: tuple[float, float] | None = None,
                  urdf: Path = PANDA_URDF) -> dict[str, float | str | bool]:
    """Return the module docstring's figures; ``stall``: wall times of stop and release."""
    ratio, joint, t0 = _joint_speed(bag, urdf_velocity_limits(urdf))
    log = load_run(bag)
    t = log.t + t0
    f = log.f_true_W if log.f_true_W is not None else log.f_W
    n = log.n_true_W if log.n_true_W is not None else np.broadcast_to(log.n_W, f.shape)
    f_n, f_d = np.sum(f * n, axis=1), np.linalg.norm(log.f_d_W, axis=1)
    running = log.path_running if log.path_running is not None else np.zeros(t.shape, bool)
    out: dict[str, float | str | bool] = {
        'max_joint_speed_ratio': round(ratio, 3), 'fastest_joint': joint,
        'path_s': round(float(t[running][-1] - t[running][0]), 2) if running.any() else 0.0}
    keep = running.copy()
    if stall is not None:
        t_stop, t_release = stall
        after = (t >= t_stop) & (t <= t_release + AFTER_STALL_S)
        keep &= ~after
        out.update(stall_in_path=bool(running.any() and t[running][0] < t_stop
                                      < t[running][-1]),
                   back_s=round(first_hold(t, log.in_contact, t_release, HOLD_S), 3),
                   settle_s=round(settle_time(t, f_n - f_d, t_release, 0.0,
                                              0.1 * float(np.max(f_d)), HOLD_S), 3),
                   peak_force_n=round(float(f_n[after].max()), 2) if after.any() else math.nan)
    dt = np.diff(t, append=t[-1])
    out['rms_force_error_n'] = (round(float(np.sqrt(np.mean((f_n - f_d)[keep] ** 2))), 4)
                                if keep.any() else math.nan)
    out['contact_lost_s'] = round(float(dt[keep & ~log.in_contact].sum()), 3)
    return out
