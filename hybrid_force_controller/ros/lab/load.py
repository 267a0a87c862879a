"""
Process measurements for ``bench --ros``: CPU time from ``/proc`` and a CPU load generator.

``python -m hybrid_force_controller.ros.lab.load --duty 0.3`` busy-loops 30 % of one core (in
10 ms windows: busy for ``duty`` of each, asleep for the rest) until SIGINT/SIGTERM.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from typing import Iterator, Sequence

__all__ = ['cpu_seconds', 'main', 'CpuMeter', 'thread_cpu_seconds', 'thread_switches',
           'ThreadCpuMeter']

_TICKS = os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far, s (``/proc/<pid>/stat``)."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICKS  # utime, stime (fields 14, 15)


def _each_thread(pid: int, file: str) -> Iterator[tuple[bool, str]]:
    """Yield ``(is the process's own thread, text of /proc/<pid>/task/<tid>/<file>)``."""
    for tid in os.listdir(f'/proc/{pid}/task'):
        try:
            with open(f'/proc/{pid}/task/{tid}/{file}') as f:
                yield int(tid) == pid, f.read()
        except OSError:  # the thread ended
            continue


def thread_cpu_seconds(pid: int) -> dict[str, float]:
    """
    User + system CPU time of each thread of ``pid`` so far, s, by thread name.

    The process's own thread is ``main``; threads sharing a name (the middleware's) are summed.
    """
    out: dict[str, float] = {}
    for own, text in _each_thread(pid, 'stat'):
        head, tail = text.rsplit(')', 1)
        name = 'main' if own else head.split('(', 1)[1]
        fields = tail.split()
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / _TICKS
    return out


def thread_switches(pid: int) -> dict[str, tuple[int, int]]:
    """
    Context switches of each thread of ``pid`` so far, ``(voluntary, involuntary)``, by name.

    From ``/proc/<pid>/task/<tid>/status``. A voluntary switch is the thread going to sleep
    (a futex wait, a poll): each one ends in a wake-up. Names as :func:`thread_cpu_seconds`.
    """
    out: dict[str, tuple[int, int]] = {}
    for own, text in _each_thread(pid, 'status'):
        fields = dict(line.split(':', 1) for line in text.splitlines() if ':' in line)
        name = 'main' if own else fields['Name'].strip()
        v0, i0 = out.get(name, (0, 0))
        out[name] = (v0 + int(fields['voluntary_ctxt_switches']),
                     i0 + int(fields['nonvoluntary_ctxt_switches']))
    return out


class ThreadCpuMeter:
    """
    CPU use of each thread (by name) of one process over a window, % of one core.

    After :meth:`stop`, :attr:`switches` holds each thread's context switches per second
    over the same window: ``{name: (voluntary, involuntary)}``.
    """

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self._t0, self._cpu0, self._sw0 = 0.0, {}, {}
        self.switches: dict[str, tuple[float, float]] = {}

    def start(self) -> None:
        self._sw0 = thread_switches(self.pid)
        self._t0, self._cpu0 = time.monotonic(), thread_cpu_seconds(self.pid)

    def stop(self) -> dict[str, float]:
        """``{thread name: percent of one core}`` since :meth:`start`."""
        wall, now = time.monotonic() - self._t0, thread_cpu_seconds(self.pid)
        sw = thread_switches(self.pid)
        self.switches = {n: (round((v - self._sw0.get(n, (0, 0))[0]) / wall, 1),
                             round((i - self._sw0.get(n, (0, 0))[1]) / wall, 1))
                         for n, (v, i) in sorted(sw.items())}
        return {n: round(100.0 * (v - self._cpu0.get(n, 0.0)) / wall, 2)
                for n, v in sorted(now.items())}


class CpuMeter:
    """CPU use of a set of processes between :meth:`start` and :meth:`stop`, % of one core."""

    def __init__(self, pids: dict[str, int]) -> None:
        self.pids = dict(pids)
        self._t0 = 0.0
        self._cpu0: dict[str, float] = {}

    def start(self) -> None:
        self._t0 = time.monotonic()
        self._cpu0 = {name: cpu_seconds(pid) for name, pid in self.pids.items()}

    def stop(self) -> dict[str, float]:
        """``{name: percent of one core}`` since :meth:`start`."""
        wall = time.monotonic() - self._t0
        return {name: 100.0 * (cpu_seconds(pid) - self._cpu0[name]) / wall
                for name, pid in self.pids.items()}


def busy_loop(duty: float, window_s: float = 0.01) -> None:
    """Keep ``duty`` of one core busy until a signal ends the process."""
    while True:
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < duty * window_s:
            pass
        time.sleep(max(0.0, (1.0 - duty) * window_s))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the load generator; exit 0 on SIGINT/SIGTERM."""
    ap = argparse.ArgumentParser(prog='load', description=__doc__.splitlines()[0])
    ap.add_argument('--duty', type=float, default=0.3, help='busy fraction of one core (0-1)')
    args = ap.parse_args(argv)
    if not 0.0 < args.duty <= 1.0:
        print('error: --duty must be in (0, 1]', file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        busy_loop(args.duty)
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == '__main__':
    sys.exit(main())
