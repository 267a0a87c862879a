"""
The machine's own stalls, witnessed while the real-time tests run (issue 31).

This machine (a VM) sometimes stops a CPU for 30-130 ms: a loop that sleeps 5 ms at SCHED_FIFO
on an idle CPU saw gaps of 38-67 ms (docs/results.md section 27). No code of the cell can keep a
1 kHz loop through that, and the loop's figures over such a window are the machine's, not the
code's. So the suite runs one witness per CPU it may use: a process pinned to that CPU at
SCHED_FIFO 99, above every thread the product or the suite starts (so that a stall of the
cell's own never reads as the machine's), waking every 5 ms and writing down each gap longer
than :data:`STALL_S`. Without the permission for SCHED_FIFO it runs at normal priority and says
so in its file (its gaps may then be the load's: they are written down, and not counted).

* :func:`start_test`: start the witnesses (once) and mark the running real-time test's start;
* :func:`stalls_text`: the stalls since that start, as a sentence ('' for none, or outside a
  real-time test). :func:`helpers.bounds.check_bounds` skips a test whose figure is out of its
  bound when the machine stalled meanwhile, saying both; :func:`helpers.watch.assert_clean_run`
  then prints and hands on refused inputs and safe modes instead of asserting them.
"""
from __future__ import annotations

import atexit
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

STALL_S = 0.02  # a gap of the witness's 5 ms sleep this long: 2.5 times the loop's delay margin
_CODE = """
import os, sys, time
cpu, path, stall = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
os.sched_setaffinity(0, {cpu})
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(99))
    how = 'fifo'
except OSError:
    how = 'normal'
out = open(path, 'a', buffering=1)
last = time.monotonic()  # before the header: a stop after the header is a gap
out.write(f'# cpu {cpu} {how}\\n')
while True:
    time.sleep(0.005)
    now = time.monotonic()
    if now - last > stall:
        out.write(f'{time.time() - (now - last):.4f} {now - last:.4f} {cpu} {how}\\n')
    last = now
"""
_PROCS: list[subprocess.Popen] = []
_STATE: dict[str, object] = {'since': None, 'dir': None}


def start_test() -> None:
    """Mark a real-time test's start; start the witnesses on the first call."""
    if not _PROCS:
        folder = Path(tempfile.mkdtemp(prefix='hfc_witness_'))
        _STATE['dir'] = folder
        for cpu in sorted(os.sched_getaffinity(0)):
            _PROCS.append(subprocess.Popen(
                [sys.executable, '-c', _CODE, str(cpu), str(folder / f'cpu{cpu}.txt'),
                 str(STALL_S)], stdin=subprocess.DEVNULL))
        atexit.register(stop)
    _STATE['since'] = time.time()


def end_test() -> None:
    """Mark the end of a real-time test: no stall is anyone's until the next start."""
    _STATE['since'] = None


def stop() -> None:
    """Stop the witnesses (by pid)."""
    for proc in _PROCS:
        proc.kill()
        proc.wait()
    _PROCS.clear()


def stalls(since: float) -> list[tuple[float, float, int, str]]:
    """Return each stall that ended after ``since``: its start, seconds, CPU and priority."""
    folder = _STATE['dir']
    found = []
    for path in ([] if folder is None else sorted(Path(folder).glob('cpu*.txt'))):
        for line in path.read_text().splitlines():
            if line and not line.startswith('#'):
                t, gap, cpu, how = line.split()
                if float(t) + float(gap) >= since:
                    found.append((float(t), float(gap), int(cpu), how))
    return found


def stalls_text() -> str:
    """Say which stalls of the machine fell in the running real-time test ('' if none)."""
    since = _STATE['since']
    if since is None:
        return ''
    found = [s for s in stalls(float(since)) if s[3] == 'fifo']
    return '' if not found else 'the machine stalled: ' + ', '.join(
        f'CPU {cpu} {1e3 * gap:.0f} ms at {t - float(since):.2f} s into the test ({how})'
        for t, gap, cpu, how in found)
