"""
Read the 1 kHz input messages straight from their CDR bytes (``raw=True`` subscriptions).

rclpy turns every received message into Python objects (the message, its header, its
time, ...), which costs more CPU at 1 kHz than the control law's own arithmetic; the
controller and the sim need a few numbers from each message. These readers take the
serialized message (XCDR1, as rmw_fastrtps sends it: a 4-byte encapsulation header, then
the fields, each aligned to its size counted from the end of that header) and return
plain values. Malformed bytes raise :class:`CdrError` (a ValueError).

The other way, :class:`RawMessage` keeps one serialized message (built once from a template
message by rclpy's serializer) and refills its stamp and double arrays in place; publishing
its bytes (``publish_raw``) skips rclpy's Python-to-C conversion of every field (a
JointState: 11 -> 3.6 us, a WrenchStamped 12.5 -> 3 us, here).
"""
from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

__all__ = ['CdrError', 'JointStateData', 'RawMessage', 'WrenchData', 'double_spans',
           'read_float64_array', 'read_joint_state', 'read_wrench_stamped']


class CdrError(ValueError):
    """The bytes are not a well-formed serialized message of the expected type."""


class JointStateData(NamedTuple):
    """The fields of a sensor_msgs/JointState the controller uses."""

    stamp_s: float
    names: list[str]
    position: np.ndarray
    velocity: np.ndarray


class WrenchData(NamedTuple):
    """The fields of a geometry_msgs/WrenchStamped the controller uses."""

    stamp_s: float
    frame_id: str
    force: tuple[float, float, float]
    torque: tuple[float, float, float]


_STRUCT = {fmt: struct.Struct(fmt) for fmt in ('<I', '<iI', '<II', '<3d', '<d')}


class _Reader:
    """Cursor over one serialized message."""

    __slots__ = ('buf', 'pos', 'end')

    def __init__(self, buf: bytes) -> None:
        if len(buf) < 4 or buf[1] not in (0, 1):
            raise CdrError('not a CDR message (encapsulation header)')
        if buf[1] == 0:
            raise CdrError('big-endian CDR is not supported')
        self.buf, self.pos, self.end = buf, 4, len(buf)

    def _take(self, fmt: str, size: int) -> tuple:
        s = _STRUCT[fmt]
        self.pos = 4 + (self.pos - 4 + size - 1) // size * size
        if self.pos + s.size > self.end:
            raise CdrError('message ends early')
        values = s.unpack_from(self.buf, self.pos)
        self.pos += s.size
        return values

    def uint32(self) -> int:
        return self._take('<I', 4)[0]

    def string(self) -> str:
        n = self.uint32()
        if n == 0 or self.pos + n > self.end:
            raise CdrError('bad string length')
        text = self.buf[self.pos:self.pos + n - 1]
        self.pos += n
        return text.decode()

    def stamp(self) -> float:
        sec, nanosec = self._take('<iI', 4)
        return sec + 1e-9 * nanosec

    def doubles(self) -> np.ndarray:
        n = self.uint32()
        if n == 0:
            return np.empty(0)
        self.pos = 4 + (self.pos - 4 + 7) // 8 * 8
        if self.pos + 8 * n > self.end:
            raise CdrError('message ends early')
        out = np.frombuffer(self.buf, '<f8', n, self.pos)
        self.pos += 8 * n
        return out


def read_joint_state(buf: bytes) -> JointStateData:
    """Read stamp, names, positions and velocities of a serialized JointState."""
    r = _Reader(buf)
    stamp = r.stamp()
    r.string()  # frame_id
    names = [r.string() for _ in range(r.uint32())]
    position = r.doubles()
    return JointStateData(stamp, names, position, r.doubles())


def read_wrench_stamped(buf: bytes) -> WrenchData:
    """Read stamp, frame, force and torque of a serialized WrenchStamped."""
    r = _Reader(buf)
    stamp = r.stamp()
    frame_id = r.string()
    force = r._take('<3d', 8)
    return WrenchData(stamp, frame_id, force, r._take('<3d', 8))


def read_float64_array(buf: bytes) -> np.ndarray:
    """Read the data of a serialized std_msgs/Float64MultiArray (the layout is skipped)."""
    r = _Reader(buf)
    for _ in range(r.uint32()):  # layout.dim: label, size, stride
        r.string()
        r._take('<II', 4)
    r.uint32()  # layout.data_offset
    return r.doubles()


class RawMessage:
    """
    A serialized message whose stamp and double arrays are refilled in place.

    ``kind`` is ``'joint_state'`` (position, velocity, effort), ``'wrench_stamped'`` (force,
    torque), ``'point_stamped'`` or ``'vector3_stamped'`` (the point or vector),
    ``'float64_array'`` (data) or ``'float64'`` (data); ``template`` is a message of that type
    with the final names, frame and array sizes. :attr:`arrays` are numpy views into the bytes.
    """

    def __init__(self, kind: str, template: object) -> None:
        from rclpy.serialization import serialize_message
        self.buf = bytearray(serialize_message(template))
        r = _Reader(bytes(self.buf))
        spans = _SPANS[kind](r)
        self.has_stamp = kind not in _UNSTAMPED
        self.arrays = [np.frombuffer(self.buf, '<f8', n, pos) for pos, n in spans]

    def set_stamp(self, t_ns: int) -> None:
        """Set ``header.stamp`` to ``t_ns`` nanoseconds."""
        _STRUCT['<iI'].pack_into(self.buf, 4, *divmod(t_ns, 1_000_000_000))

    def serialized(self) -> bytes:
        """Return the serialized message (a copy: the publisher may keep it)."""
        return bytes(self.buf)


def _double_spans(r: _Reader, count: int) -> list[tuple[int, int]]:
    """Return (offset, length) of the next ``count`` double sequences."""
    spans = []
    for _ in range(count):
        n = r.uint32()
        r.pos = 4 + (r.pos - 4 + 7) // 8 * 8
        spans.append((r.pos, n))
        r.pos += 8 * n
    return spans


def _joint_state_spans(r: _Reader) -> list[tuple[int, int]]:
    r.stamp()
    r.string()
    for _ in range(r.uint32()):
        r.string()
    return _double_spans(r, 3)


def _float64_array_spans(r: _Reader) -> list[tuple[int, int]]:
    for _ in range(r.uint32()):
        r.string()
        r._take('<II', 4)
    r.uint32()
    return _double_spans(r, 1)


def _stamped_vector_spans(r: _Reader) -> list[tuple[int, int]]:
    """Return the span of a PointStamped's or Vector3Stamped's three doubles (after a header)."""
    r.stamp()
    r.string()
    r._take('<3d', 8)
    return [(r.pos - 24, 3)]


def _wrench_spans(r: _Reader) -> list[tuple[int, int]]:
    """WrenchStamped: the force as a stamped vector, the torque right after it."""
    return [*_stamped_vector_spans(r), (r.pos, 3)]


def _float64_spans(r: _Reader) -> list[tuple[int, int]]:
    r._take('<d', 8)
    return [(r.pos - 8, 1)]


_SPANS = {'joint_state': _joint_state_spans, 'wrench_stamped': _wrench_spans,
          'float64_array': _float64_array_spans, 'point_stamped': _stamped_vector_spans,
          'vector3_stamped': _stamped_vector_spans, 'float64': _float64_spans}
_UNSTAMPED = ('float64_array', 'float64')


def double_spans(kind: str, buf: bytes) -> list[tuple[int, int]]:
    """
    Return (byte offset, count) of each double array of a serialized message.

    ``kind`` as for :class:`RawMessage`. Raises :class:`CdrError`.
    """
    return _SPANS[kind](_Reader(bytes(buf)))
