"""
Faults ``bench --ros`` plays during a run: freezes of a process, and a parameter storm.

:func:`freeze` stops a process (SIGSTOP, a scheduler hiccup) and lets it go (SIGCONT);
:func:`param_storm` sends :func:`storm_values` at a rate without waiting for the answers, as a
script hammering ``ros2 param set`` would, and counts the answers.
"""
from __future__ import annotations

import subprocess
import time
from typing import Any

from .tracking import TrackingMeter

__all__ = ['freeze', 'LONG_FREEZE_S', 'param_storm', 'storm_values']

WARM_UP_TIMEOUT_S = 90.0
LONG_FREEZE_S = 0.1  # the sim's command_timeout: a longer freeze drops the arm


def freeze(proc: subprocess.Popen, count: int, hold_s: float,
           tracking: TrackingMeter) -> list[tuple[float, float]]:
    """
    SIGSTOP the process for ``hold_s`` ``count`` times; wall times of each stop and release.

    Freezes shorter than the sim's watchdog come 2 s apart; longer ones (the arm falls) wait
    for theta_hat to be learned and come 7 s apart (6 s of recovery figures each).
    """
    long = hold_s >= LONG_FREEZE_S
    deadline = time.monotonic() + WARM_UP_TIMEOUT_S
    while long and count and not tracking.theta_steady() and time.monotonic() < deadline:
        time.sleep(0.2)
    times = []
    for _ in range(count):
        time.sleep(7.0 if long and times else 2.0)
        t_stop = time.time()
        proc.send_signal(19)  # SIGSTOP: a scheduler hiccup of hold_s
        time.sleep(hold_s)
        proc.send_signal(18)  # SIGCONT
        times.append((t_stop, time.time()))
    return times


def storm_values(rate_hz: float, duration_s: float) -> list[tuple[str, float]]:
    """Return the sets: f_d and lambda1 alternate, the last f_d is 1.5 N, the last lambda1 40."""
    count = max(2, int(round(rate_hz * duration_s)))
    n_f, n_l = (count + 1) // 2, count // 2
    f_d = [1.5 if (n_f - 1 - j) % 2 == 0 else 1.0 for j in range(n_f)]
    l1 = [40.0 if (n_l - 1 - j) % 2 == 0 else 42.0 for j in range(n_l)]
    return [('f_d', f_d[k // 2]) if k % 2 == 0 else ('lambda1', l1[k // 2])
            for k in range(count)]


def param_storm(diag: Any, rate_hz: float, duration_s: float) -> dict[str, Any]:
    """Send the storm's sets at ``rate_hz`` without waiting for answers; count the answers."""
    from rclpy.parameter import Parameter
    futures, t_start = [], time.monotonic()
    for k, (name, value) in enumerate(storm_values(rate_hz, duration_s)):
        time.sleep(max(t_start + k / rate_hz - time.monotonic(), 0.0))
        if name == 'f_d':
            diag.tracking.set_f_d(time.time(), value)
        futures.append(diag.params.set_parameters([Parameter(name, value=value)]))
    t_end = time.time()
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and not all(f.done() for f in futures):
        time.sleep(0.05)
    ok = sum(1 for f in futures if f.done() and all(r.successful for r in f.result().results))
    return {'storm_sets': len(futures), 'storm_sets_successful': ok, 'storm_end_wall': t_end}
