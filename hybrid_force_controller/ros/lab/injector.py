"""
Wrong inputs on the controller's input topics, as another node of a real cell sends (issue 25).

An :class:`Injector` rides on any spun node. It keeps the newest serialized joint state and
wrench the sim published (raw subscriptions; what it published itself is recognised by its
bytes and skipped) and publishes, on the same topics:

* a copy of the newest one with its stamp moved (``wrench(3600.0)``: an hour ahead),
* a copy of the newest joint state with positions or velocities changed (an encoder glitch),
* a fuzz: ``count`` malformed or corrupted serialized messages over ``duration`` s on both
  inputs, from a seeded generator (:func:`corrupt`), sent by a timer of the node.

Used by ``wrong_inputs`` (the figures of docs/results.md) and test/test_wrong_inputs.py.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Any, Sequence

import numpy as np

from ..common.cdr import CdrError, double_spans, read_joint_state, read_wrench_stamped

__all__ = ['CORRUPTIONS', 'Injector', 'corrupt']

TOPICS = {'joint_state': 'joint_states', 'wrench': 'force_torque_sensor_broadcaster/wrench'}
FRESH_LEAD_S = 0.03  # a "fresh" copy is stamped this far ahead of now (within state_timeout)
CORRUPTIONS = ('random_bytes', 'truncated', 'byte_flips', 'value_bit_flip', 'bad_header',
               'extreme_values')


def _stamped(raw: bytes, stamp_offset: float) -> bytes:
    """Return ``raw`` (a serialized stamped message) with its stamp moved by ``stamp_offset`` s."""
    buf = bytearray(raw)
    sec, nsec = np.frombuffer(buf, '<i4', 1, 4)[0], np.frombuffer(buf, '<u4', 1, 8)[0]
    t_ns = int(sec) * 1_000_000_000 + int(nsec) + round(stamp_offset * 1e9)
    sec, nsec = divmod(t_ns, 1_000_000_000)
    buf[4:12] = int(sec).to_bytes(4, 'little', signed=True) + int(nsec).to_bytes(4, 'little')
    return bytes(buf)


def read_stamp(raw: bytes) -> float:
    """Return the stamp of a serialized stamped message, s."""
    sec, nsec = np.frombuffer(raw, '<i4', 1, 4)[0], np.frombuffer(raw, '<u4', 1, 8)[0]
    return int(sec) + 1e-9 * int(nsec)


def _doubles_at(raw: bytes, kind: str) -> list[int]:
    """Byte offsets of the doubles the controller reads (positions, velocities; or the force)."""
    spans = double_spans('joint_state' if kind == 'joint_state' else 'wrench_stamped', raw)
    spans = spans[:2] if kind == 'joint_state' else spans[:1]
    return [pos + 8 * i for pos, n in spans for i in range(n)]


def corrupt(raw: bytes, kind: str, rng: np.random.Generator, how: str) -> bytes:
    """
    Return a corrupted copy of ``raw``, a serialized message of ``kind`` (joint_state, wrench).

    ``how`` is one of :data:`CORRUPTIONS`: random bytes, a truncated copy, 1-3 random bytes
    changed anywhere, one bit of one double the controller reads flipped (decodes, values
    wrong), a wrong encapsulation header, or doubles set to extreme values (NaN, +-1e300, 1e3).
    """
    buf = bytearray(raw)
    if how == 'random_bytes':
        return rng.integers(0, 256, int(rng.integers(0, 300)), dtype=np.uint8).tobytes()
    if how == 'truncated':
        return bytes(buf[:int(rng.integers(0, len(buf)))])
    if how == 'byte_flips':
        for i in rng.integers(0, len(buf), int(rng.integers(1, 4))):
            buf[i] = int(rng.integers(0, 256))
        return bytes(buf)
    if how == 'bad_header':
        buf[:4] = rng.integers(0, 256, 4, dtype=np.uint8).tobytes()
        return bytes(buf)
    at = _doubles_at(raw, kind)
    if how == 'value_bit_flip':
        bit = int(rng.integers(0, 64))
        i = at[int(rng.integers(0, len(at)))] + bit // 8
        buf[i] ^= 1 << (bit % 8)
        return bytes(buf)
    value = float(rng.choice([np.nan, 1e300, -1e300, 1e3, -1e3]))
    i = at[int(rng.integers(0, len(at)))]
    buf[i:i + 8] = np.array([value], '<f8').tobytes()
    return bytes(buf)


class Injector:
    """Publishes wrong inputs beside the sim's (module docstring) on ``node``, a spun node."""

    def __init__(self, node: Any, fuzz_period: float = 0.002) -> None:
        from geometry_msgs.msg import WrenchStamped
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import JointState
        self.node, self.lock = node, threading.Lock()
        self.latest: dict[str, bytes] = {}
        self.skew: dict[str, float] = {}  # the largest stamp - time.time() seen, s
        self._own: set[bytes] = set()  # bytes this injector published (not the sim's)
        types = {'joint_state': JointState, 'wrench': WrenchStamped}
        self.pubs = {k: node.create_publisher(types[k], TOPICS[k], QoSProfile(depth=10))
                     for k in TOPICS}
        for kind in TOPICS:
            node.create_subscription(types[kind], TOPICS[kind],
                                     lambda raw, kind=kind: self._on_raw(kind, raw),
                                     QoSProfile(depth=10), raw=True)
        self._plan: list[tuple[str, str]] = []
        self._sent, self._t_fuzz, self.fuzz_period = 0, 0.0, fuzz_period
        self.fuzz_span = (0.0, 0.0)  # monotonic times of the first and last fuzz message
        self.fuzz_done = threading.Event()
        self.fuzz_done.set()
        node.create_timer(fuzz_period, self._on_fuzz_timer)

    def _on_raw(self, kind: str, raw: bytes) -> None:
        with self.lock:
            if raw in self._own:
                self._own.discard(raw)
                return
        try:
            stamp = (read_joint_state if kind == 'joint_state' else read_wrench_stamped)(
                raw).stamp_s
        except (CdrError, ValueError):
            return  # (not the sim's)
        skew = stamp - time.time()  # the sender's clock less the transport and this lag
        with self.lock:
            self.latest[kind] = raw
            self.skew[kind] = max(self.skew.get(kind, -math.inf), skew)

    def ready(self) -> bool:
        """Say whether a joint state and a wrench of the sim have been seen."""
        with self.lock:
            return len(self.latest) == len(TOPICS)

    def publish(self, kind: str, raw: bytes) -> None:
        """Publish serialized bytes on the ``kind`` input topic."""
        with self.lock:
            if len(self._own) > 10000:  # published, never received back (lost): forget
                self._own.clear()
            self._own.add(raw)
        self.pubs[kind].publish(raw)

    def newest(self, kind: str, fresh: bool = False) -> bytes:
        """
        Return the newest message of ``kind`` the sim sent.

        ``fresh``: stamped now on the sender's clock (the largest skew seen: this process may
        take a message a few ms after the controller did), plus FRESH_LEAD_S, so that it is
        not older than the sim's state that reaches the controller just before it.
        """
        with self.lock:
            raw, skew = self.latest[kind], self.skew[kind]
        if not fresh:
            return raw
        return _stamped(raw, time.time() + skew + FRESH_LEAD_S - read_stamp(raw))

    def wrench(self, stamp_offset: float) -> None:
        """Republish the newest wrench once with its stamp moved by ``stamp_offset`` s."""
        self.publish('wrench', _stamped(self.newest('wrench'), stamp_offset))

    def joint_state(self, stamp_offset: float = 0.0, dq: Sequence[float] | None = None,
                    dv: Sequence[float] | None = None) -> None:
        """
        Publish the newest joint state once more: stamp moved, ``dq``/``dv`` added.

        Stamped as sent now (:meth:`newest` ``fresh``) plus ``stamp_offset``: not older than
        the last the controller took.
        """
        raw = _stamped(self.newest('joint_state', fresh=True), stamp_offset)
        msg = read_joint_state(raw)
        buf = bytearray(raw)
        at = _doubles_at(raw, 'joint_state')
        n = len(msg.position)
        for i, add in enumerate(list(dq or [0.0] * n) + list(dv or [0.0] * n)):
            value = (msg.position if i < n else msg.velocity)[i % n] + add
            buf[at[i]:at[i] + 8] = np.array([value], '<f8').tobytes()
        self.publish('joint_state', bytes(buf))

    def start_fuzz(self, count: int, seed: int = 0) -> None:
        """Send ``count`` corrupted messages, alternating inputs, one per ``fuzz_period``."""
        self._rng = np.random.default_rng(seed)
        self._sent, self._t_fuzz = 0, time.monotonic()
        self.fuzz_done.clear()
        self._plan = [(('joint_state', 'wrench')[k % 2], CORRUPTIONS[(k // 2) % len(CORRUPTIONS)])
                      for k in range(count)]  # last: the timer's thread starts on it

    def _on_fuzz_timer(self) -> None:
        """Send what is due (a late callback catches up: the rate holds on a loaded machine)."""
        plan = self._plan
        due = min(len(plan), int((time.monotonic() - self._t_fuzz) / self.fuzz_period) + 1)
        if self._sent < due and not self._sent:
            self.fuzz_span = (time.monotonic(), time.monotonic())
        while self._sent < due:
            kind, how = plan[self._sent]
            self._sent += 1
            try:  # a corrupted copy of a fresh message of the sender
                raw = corrupt(self.newest(kind, fresh=True), kind, self._rng, how)
            except (CdrError, ValueError, IndexError):
                raw = b'\x00\x01\x00\x00'  # the newest could not be parsed: an empty message
            self.publish(kind, raw)
        if plan and self._sent == len(plan):
            self.fuzz_span = (self.fuzz_span[0], time.monotonic())
            self._plan = []
            self.fuzz_done.set()
