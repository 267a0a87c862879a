"""
The controller node's side of the flight recorder: dumps written off the control thread.

The control thread's :class:`~hybrid_force_controller.core.runtime.flight_recorder.FlightRecorder`
only appends ``(reason, t)`` to its ``requests`` when a tick triggers (safe mode, a force above
``flight_recorder_max_force``, contact lost in the force loop, a stall). :meth:`FlightDumps.poll`
runs on the node's thread (its housekeeping, every 100 ms): it takes the requests, copies the
ring (:meth:`FlightRecorder.snapshot`) :data:`AFTER_S` (0.5 s) after the first (or after a
request that joined it), so a dump shows what followed the fault as well as what led to it, and
hands it to a thread of its own at normal
priority, which saves the copy as an ``.npz`` file (a few ms, mostly I/O) and runs the bag's
writing (tools/flight_log.py, 0.3-0.5 s of Python for 2000 ticks, and about 1 s to import
rosbags) in a process of its own, at the ordinary scheduling policy, and waits for it. So no
Python of the dump takes this process's GIL. Measured beside a FIFO thread waking every 1 ms
(12 dumps of 2000 ticks): written on a thread, the dump made it late by a median 1.0-2.2 ms
and at most 5.3-6.7 ms; in a process, 0.12-0.23 and at most 0.43 ms, as with no dump.

At most one dump per ``min_interval_s`` (5 s) for each kind of trigger (:func:`kind_of`: safe
mode, a stall, the force, contact lost): the requests of a burst (one fault often trips
several triggers, and a flapping one trips them again and again) go into the dump they fall
in or are dropped and counted (:attr:`FlightDumps.skipped`). One interval for all kinds
dropped the fault that mattered: a freeze of the controller in an approach 0.4 s after a
contact loss had been dumped, and the pressing that followed it, were in no dump (docs/results.md
section 30). A node writes at most
``max_dumps`` (100, some 200-300 MB) in its life: a fault that keeps coming back does not fill
the disk (one line says so when the last is written). Each
finished dump is logged on the node's thread (at its next poll) as
``flight recorder: REASON at t=T: PATH``, T the tick time of the first trigger (loop clock).
"""
from __future__ import annotations

from collections import deque
import itertools
import math
import os
from pathlib import Path
import subprocess
import sys
import threading
import time
from typing import Any, Callable

from ...core.runtime.flight_recorder import FlightRecorder, FlightSnapshot
from ...tools.bag_io import BagError
from ...tools.flight_log import flight_log_path, save_snapshot

__all__ = ['AFTER_S', 'FlightDumps', 'kind_of', 'MIN_INTERVAL_S']

MIN_INTERVAL_S = 5.0  # at most one dump this often (no dump storm)
AFTER_S = 0.5  # a dump's ring is copied this long after its first trigger (what followed)
JOIN_AFTER = 3  # ... or after a request that joined it, at most this many AFTER_S after the first
MAX_DUMPS = 100  # and at most this many per node
KINDS = ('safe mode', 'stall', '|f|', 'contact lost')  # the recorder's triggers (should_dump)
_COUNT = itertools.count()  # the dumps of this process (two nodes' names never collide)
JOIN_S = 10.0  # a node that ends waits this long for a dump being written
WRITER = 'hybrid_force_controller.tools.flight_log'  # the dump's own process (python -m)
WRITE_TIMEOUT_S = 120.0  # rosbags' import alone is about 1 s of CPU
_ROOT = str(Path(__file__).resolve().parents[3])  # the tree this package was imported from


def _writer_env() -> dict[str, str]:
    """Return the environment of the writer: this package's tree first on its path."""
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (_ROOT, env.get('PYTHONPATH', '')) if p)
    return env


def kind_of(reason: str) -> str:
    """Return the kind of a dump's ``reason`` (one of :data:`KINDS`, or the reason itself)."""
    return next((kind for kind in KINDS if reason.startswith(kind)), reason)


def _normal_priority() -> None:
    """Put the calling thread at SCHED_OTHER (it inherits the node thread's FIFO level)."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass


class FlightDumps:
    """
    Take the recorder's requests on the node's thread and write the dumps on another.

    Parameters
    ----------
    directory : str or pathlib.Path
        Where the bags go (created when needed).
    model : RobotModel
        The arm: its joints (the order of q), theta_hat's names and base frame.
    log : callable
        Logs one line (the node's ``get_logger().warning``); called on the caller's thread.
    min_interval_s : float
        At most one dump this often for each kind of trigger (:func:`kind_of`), s
        (``clock``'s seconds).
    max_dumps : int
        At most this many dumps in the object's life.
    clock : callable
        Monotonic seconds (``time.monotonic``; the node's wall clock, also with sim time).
    after_s : float
        The ring is copied this long (``clock``'s seconds) after the dump's first request,
        so that the dump shows what followed the trigger as well as what led to it (with
        2000 ticks at 1 kHz: 1.5 s before, 0.5 s after). Requests in that time join it and
        put the copy off to ``after_s`` after them, at most ``JOIN_AFTER after_s`` after the
        first (its trigger still in the ring): a node thread frozen with the loop polls late,
        and the copy then held nothing of what followed the freeze.

    """

    def __init__(self, directory: str | Path, model: Any, log: Callable[[str], Any],
                 min_interval_s: float = MIN_INTERVAL_S, max_dumps: int = MAX_DUMPS,
                 clock: Callable[[], float] = time.monotonic, after_s: float = AFTER_S) -> None:
        self.directory, self._log = Path(directory), log
        self._names = (tuple(model.joint_names), tuple(model.theta_names), model.base_link)
        self.min_interval_s, self.max_dumps, self._clock = min_interval_s, max_dumps, clock
        self.after_s = after_s
        self._pending: list | None = None  # [reasons, t, copy at, copy at the latest]
        self._last: dict[str, float] = {}  # kind -> when its last dump was started
        self.dumps = 0  # dumps started
        self.skipped = 0  # requests dropped: within min_interval_s of a dump, or past the cap
        self._done: deque = deque()  # lines to log, from the writer threads
        self._writers: list[threading.Thread] = []

    def poll(self, recorder: FlightRecorder) -> None:
        """
        Take the requests; copy the ring and start its dump ``after_s`` after the first.

        The requests taken together make one dump: their reasons joined, the first's time.
        A request within ``min_interval_s`` of the last dump of its kind, or past
        ``max_dumps``, is dropped and counted.
        """
        now = self._clock()
        while recorder.requests:
            reason, t = recorder.requests.popleft()
            kind = kind_of(reason)
            if self._pending is not None:
                if reason not in self._pending[0]:
                    self._pending[0].append(reason)
                # what followed the joined request too, within the ring's reach
                self._pending[2] = min(max(self._pending[2], now + self.after_s),
                                       self._pending[3])
                self._last[kind] = now
            elif (now - self._last.get(kind, -math.inf) < self.min_interval_s
                  or self.dumps >= self.max_dumps):
                self.skipped += 1
            else:
                self._last[kind] = now
                self._pending = [[reason], t, now + self.after_s,
                                 now + JOIN_AFTER * self.after_s]
        self._dump_pending(recorder, now)
        while self._done:
            self._log(self._done.popleft())

    def _dump_pending(self, recorder: FlightRecorder, now: float | None) -> None:
        """Start the pending dump once its time has come (``now`` None: at once)."""
        if self._pending is not None and (now is None or now >= self._pending[2]):
            reasons, t = self._pending[:2]
            self._pending = None
            self._start(recorder.snapshot(), '; '.join(reasons), t)

    def _start(self, snap: FlightSnapshot, reason: str, t: float) -> None:
        tag = f'{os.getpid()}_{next(_COUNT):03d}'
        path = flight_log_path(self.directory, reason, tag=tag)
        self.dumps += 1
        if self.dumps == self.max_dumps:
            self._done.append(f'flight recorder: {self.max_dumps} dumps written, the last '
                              'in this run (the node writes no more until it is configured '
                              'again)')
        self._writers = [w for w in self._writers if w.is_alive()]
        writer = threading.Thread(target=self._write, args=(path, snap, reason, t),
                                  name='flight_log', daemon=True)
        self._writers.append(writer)
        writer.start()

    def _write(self, path: Path, snap: FlightSnapshot, reason: str, t: float) -> None:
        """Write one bag in a process of its own (waited on this thread); queue its line."""
        _normal_priority()
        joints, theta, frame = self._names
        npz = path.parent / f'.{path.name}.npz'
        try:
            save_snapshot(npz, snap, joints, theta, frame, reason, t)
            done = subprocess.run([sys.executable, '-m', WRITER, str(npz), str(path)],
                                  env=_writer_env(), stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE, timeout=WRITE_TIMEOUT_S)
            if done.returncode != 0:
                raise BagError(done.stderr.decode(errors='replace').strip()[-300:])
            self._done.append(f'flight recorder: {reason} at t={t:.3f}: {path}')
        except (BagError, OSError, subprocess.SubprocessError) as exc:
            try:
                npz.unlink(missing_ok=True)
            except OSError:  # its directory is what failed
                pass
            self._done.append(f'flight recorder: {reason} at t={t:.3f}: could not write '
                              f'{path}: {exc}')

    def join(self, timeout: float = JOIN_S, recorder: FlightRecorder | None = None) -> None:
        """
        Wait for the dumps being written (the node ends) and log them.

        With ``recorder``, a pending dump is started first (its ring as it is now).
        """
        if recorder is not None:
            self._dump_pending(recorder, None)
        deadline = time.monotonic() + timeout
        for writer in self._writers:
            writer.join(max(0.0, deadline - time.monotonic()))
        while self._done:
            self._log(self._done.popleft())
