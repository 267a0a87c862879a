"""
A flight recorder: the last ticks of what the control loop saw and did, in a ring (numpy).

:class:`FlightRecorder` keeps ``capacity`` rows (2 s at 1 kHz by default) in arrays made once:
per tick the tick time, the inputs with their stamps (the joint state's q, qdot and stamp, the
wrench's stamp, both on the loop clock), what the tick computed (x_W, x_d_W, f_W, f_d_W, the
mode, the contact state, theta_hat, the effort tau) and how long the callback that ran the tick
held the control thread (``hold_s``, written when it returns: :meth:`note_hold`).
:meth:`record` writes one row in place (no array is made and nothing is kept: only a few
transient Python objects, a float and numpy's index views; 2-4 us per tick measured, with
tools/flight_bench.py) and decides, against the previous tick, whether something went wrong
(:meth:`should_dump`): safe mode entered, |f_W| above ``max_force``, contact lost in the force
loop, or a stall (more than ``stall_s`` since the previous tick). A trigger only appends
``(reason, t)`` to :attr:`requests`; the caller's other thread takes :meth:`snapshot` and
writes it (never the control thread). Vectors are in the base frame and already 3-D for a
planar arm (TickOutput pads them). Times are seconds on the caller's clock; nothing here
reads a clock.

The torn read. :meth:`snapshot` runs on another thread while the control thread goes on
writing (numpy may release the GIL while it copies). It copies the whole ring between two
readings of the write count, ``k0`` before and ``k1`` after, and keeps only the rows that were
complete before the copy began and whose slots no write during the copy can have reached:
sequence numbers ``k1 - capacity + 1 .. k0 - 1``. A copy that races the loop drops as many
of the oldest rows as ticks ran meanwhile (a few at most: the copy takes ~0.1 ms, and a copy
that lost more than a tenth of the ring is taken again), never returns a row half old and
half new, and costs the control thread nothing (no lock). The newest row's ``hold_s`` may
still be NaN: its callback had not returned when the copy ran.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from .inputs import JointSample
from .modes import Mode, TickOutput

__all__ = ['FlightRecorder', 'FlightSnapshot', 'MODES', 'mode_code']

MODES: tuple[Mode, ...] = tuple(Mode)  # the ``mode`` column's codes index this
_CODES = {mode: code for code, mode in enumerate(MODES)}
_SAFE, _RUNNING, _WAITING = Mode.SAFE, Mode.RUNNING, Mode.WAITING  # an Enum lookup costs 0.1 us
_NAN = math.nan


def mode_code(mode: Mode) -> int:
    """Return the integer code of ``mode`` in the ``mode`` column (an index into MODES)."""
    return _CODES[mode]


@dataclass(frozen=True)
class FlightSnapshot:
    """
    The recorded ticks in time order (copies), for a writer off the control thread.

    Attributes
    ----------
    t, t_state, t_wrench : numpy.ndarray, shape (N,)
        Tick time, joint-state stamp and wrench stamp, s (NaN: no input yet).
    q, qdot : numpy.ndarray, shape (N, n_joints)
        The joint state the tick used, model order (NaN: none yet).
    x_W, x_d_W, f_W, f_d_W : numpy.ndarray, shape (N, 3)
        Position, desired position, filtered force, desired force, base frame.
    mode : numpy.ndarray of int8, shape (N,)
        Index into :data:`MODES`.
    in_contact : numpy.ndarray of bool, shape (N,)
    theta_hat : numpy.ndarray, shape (N, n_theta)
    tau : numpy.ndarray, shape (N, n_joints)
        The effort sent, command order (NaN: none, while waiting).
    hold_s : numpy.ndarray, shape (N,)
        How long the callback that ran the tick held the control thread, s (NaN: unknown).
    dropped : int
        Ticks that ran while the ring was copied: as many of the oldest rows were left out
        (the torn-read rule, module docstring; a full ring gives ``capacity - 1`` rows).

    """

    t: np.ndarray
    t_state: np.ndarray
    t_wrench: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    x_W: np.ndarray
    x_d_W: np.ndarray
    f_W: np.ndarray
    f_d_W: np.ndarray
    mode: np.ndarray
    in_contact: np.ndarray
    theta_hat: np.ndarray
    tau: np.ndarray
    hold_s: np.ndarray
    dropped: int = 0

    def __len__(self) -> int:
        """Return the number of ticks."""
        return int(self.t.size)


COLUMNS = ('t', 't_state', 't_wrench', 'q', 'qdot', 'x_W', 'x_d_W', 'f_W', 'f_d_W', 'mode',
           'in_contact', 'theta_hat', 'tau', 'hold_s')


class FlightRecorder:
    """
    A preallocated ring of the last ``capacity`` ticks (module docstring).

    Parameters
    ----------
    n_joints : int
        Joints of q, qdot and tau.
    n_theta : int
        Entries of theta_hat.
    capacity : int
        Rows kept (2 s at 1 kHz: 2000).
    max_force : float
        |f_W| above which a tick triggers a dump, N (inf: never).
    stall_s : float
        A gap between ticks longer than this triggers a dump, s (inf: never).

    """

    def __init__(self, n_joints: int, n_theta: int, capacity: int = 2000,
                 max_force: float = math.inf, stall_s: float = math.inf) -> None:
        if capacity < 2:
            raise ValueError(f'capacity must be at least 2 rows, got {capacity}')
        self.capacity = int(capacity)
        n, c = int(n_joints), self.capacity
        self.t, self.t_state, self.t_wrench, self.hold_s = (np.full(c, _NAN) for _ in range(4))
        self.q, self.qdot, self.tau = (np.full((c, n), _NAN) for _ in range(3))
        self.x_W, self.x_d_W, self.f_W, self.f_d_W = (np.zeros((c, 3)) for _ in range(4))
        self.mode = np.zeros(c, dtype=np.int8)
        self.in_contact = np.zeros(c, dtype=bool)
        self.theta_hat = np.zeros((c, int(n_theta)))
        self.count = 0  # rows written so far; the row of tick k is slot k % capacity
        self.requests: deque = deque(maxlen=16)  # (reason, t) for the other thread
        self._open = -1  # the slot whose hold_s is still to come (-1: none)
        self.configure(max_force, stall_s)
        self.forget_last()

    def configure(self, max_force: float, stall_s: float) -> None:
        """Set the force (N) and the gap (s) above which a tick triggers (inf: never)."""
        self.max_force, self.stall_s = float(max_force), float(stall_s)
        self._max_f_sq = self.max_force * self.max_force

    def forget_last(self) -> None:
        """Compare the next tick with nothing (a restart after a deactivation: no stall)."""
        self._last_t, self._last_mode, self._last_contact = _NAN, _WAITING, False
        self._code = _CODES[_WAITING]
        self._last_over = False

    # ------------------------------------------------------------------ the control thread
    def record(self, t: float, state: JointSample | None, t_wrench: float,
               out: TickOutput) -> str:
        """
        Write one tick's row in place and return why it triggers a dump ('' if it does not).

        Parameters
        ----------
        t : float
            The tick's time, s.
        state : JointSample or None
            The joint state the tick used (None before the first).
        t_wrench : float
            The stamp of the wrench the tick used, s (NaN: none yet).
        out : TickOutput
            What the tick gave.

        """
        i = self.count % self.capacity
        self.t[i] = t
        self.t_wrench[i] = t_wrench
        self.hold_s[i] = _NAN
        if state is None:
            self.t_state[i] = self.q[i] = self.qdot[i] = _NAN
        else:
            self.t_state[i] = state.t
            self.q[i] = state.q
            self.qdot[i] = state.qdot
        self.x_W[i] = out.x_W
        self.x_d_W[i] = out.x_d_W
        self.f_W[i] = out.f_W
        self.f_d_W[i] = out.f_d_W
        mode = out.mode
        if mode is not self._last_mode:
            self._code = _CODES[mode]
        self.mode[i] = self._code
        self.in_contact[i] = out.in_contact
        self.theta_hat[i] = out.theta_hat
        self.tau[i] = _NAN if out.tau is None else out.tau
        self.count += 1  # after the row: snapshot() takes rows below the count as complete
        self._open = i
        reason = self.should_dump(out, t - self._last_t)
        self._last_t, self._last_mode, self._last_contact = t, mode, out.in_contact
        if reason:
            self.trigger(reason, t)
        return reason

    def should_dump(self, out: TickOutput, gap_s: float) -> str:
        """
        Say why this tick, ``gap_s`` after the previous one, is worth a dump ('' if it is not).

        Edges against the previous tick only, so a fault triggers once: safe mode entered;
        |f_W| rose above ``max_force``; contact lost in the force loop (the previous tick
        RUNNING and in contact, this one out of contact: the runtime turns to APPROACH at that
        tick); a stall (``gap_s`` above ``stall_s``). Updates the force's edge state.
        """
        fx, fy, fz = out.f_W.tolist()
        f_sq = fx * fx + fy * fy + fz * fz
        over = f_sq > self._max_f_sq
        rose, self._last_over = over and not self._last_over, over
        if out.mode is _SAFE and self._last_mode is not _SAFE:
            return f'safe mode ({out.status})'
        if gap_s > self.stall_s:
            return f'stall ({gap_s * 1e3:.0f} ms since the previous tick)'
        if rose:
            return f'|f| = {math.sqrt(f_sq):.3g} N above max_force = {self.max_force:g} N'
        if self._last_contact and not out.in_contact and self._last_mode is _RUNNING:
            return 'contact lost in the force loop'
        return ''

    def note_hold(self, hold_s: float) -> None:
        """Write how long the callback of the last recorded tick held the thread, s (once)."""
        if self._open >= 0:
            self.hold_s[self._open] = hold_s
            self._open = -1

    def trigger(self, reason: str, t: float) -> None:
        """Ask the other thread for a dump (a deque append: nothing else on this thread)."""
        self.requests.append((reason, t))

    # ------------------------------------------------------------------ the other thread
    def snapshot(self, attempts: int = 3) -> FlightSnapshot:
        """
        Return the complete rows in time order, copied while the loop writes (module doc).

        A copy that lost more than a tenth of the ring to the loop's writes (the copying
        thread held off meanwhile) is taken again, ``attempts`` times at most; the one that
        lost the fewest rows is returned (a starved machine: s52a's dump held 841 of 2000).
        """
        best = None
        for _ in range(attempts):
            snap = self._copy()
            if best is None or snap.dropped < best.dropped:
                best = snap
            if 10 * snap.dropped <= self.capacity:
                break
        return best

    def _copy(self) -> FlightSnapshot:
        k0 = self.count
        copies: dict[str, Any] = {name: getattr(self, name).copy() for name in COLUMNS}
        k1 = self.count
        first = max(0, k1 - self.capacity + 1)
        order = np.arange(first, k0) % self.capacity
        return FlightSnapshot(**{name: a[order] for name, a in copies.items()}, dropped=k1 - k0)
