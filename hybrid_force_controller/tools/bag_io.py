"""
Read and write the controller's rosbag2 recordings with ``rosbags`` (no rclpy).

:func:`load_run` turns a recording (MCAP or sqlite3) into an
:class:`~hybrid_force_controller.tools.analysis.RunLog`; :class:`BagWriter` writes an MCAP bag
with rosbag2 metadata version 8. Jazzy's rosbag2 (0.26) writes version 9 and reads both;
version 8 is kept for older readers (Humble-era tools).

Optional topics (a bag without them loads): ``/sim/contact_wrench`` (the true force),
``~/stiffness_estimate`` (``std_msgs/Float64``, the online stiffness estimate, NaN while
unknown), ``~/path_status`` (``std_msgs/String``: when a user's path was ``running``),
``~/surface_normal`` (the normal the controller used), ``/sim/contact_normal`` (the
surface's true normal at the tool) and ``/sim/tool_axis`` (the sim tool's axis; all three
``geometry_msgs/Vector3Stamped``).
"""
from __future__ import annotations

from pathlib import Path
import threading
from types import TracebackType
from typing import Any, Sequence

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                QosReliability, QosTime)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores

from .analysis import AnalysisError, RunLog
from .bag_series import (on_x_time, path_running, Series, sorted_by_stamp, stamp_ns, stiffness,
                         true_masses, unit_vectors)
from ..core.runtime.contact import CONTACT_FORCE_MIN_N, in_contact

__all__ = ['BAG_VERSION', 'BagError', 'BagWriter', 'DEFAULT_QOS', 'RECORD_TOPICS',
           'LATCHED_TOPICS', 'REQUIRED_TOPICS', 'TOPIC_CONTACT_WRENCH', 'TOPIC_DIAGNOSTICS',
           'TOPIC_EFFORT_COMMANDS', 'TOPIC_ERROR', 'TOPIC_FT_WRENCH', 'TOPIC_JOINT_STATES',
           'TOPIC_LINK_MASSES', 'TOPIC_CONTACT_NORMAL', 'TOPIC_SURFACE_NORMAL',
           'TOPIC_PATH_STATUS', 'TOPIC_STIFFNESS_ESTIMATE', 'TOPIC_THETA_HAT', 'TOPIC_TOOL_AXIS',
           'TOPIC_WRENCH',
           'TOPIC_WRENCH_DESIRED', 'TOPIC_X', 'TOPIC_X_DESIRED', 'TYPESTORE', 'load_run']

TOPIC_X = '/hybrid_force_controller/x'
TOPIC_X_DESIRED = '/hybrid_force_controller/x_desired'
TOPIC_WRENCH = '/hybrid_force_controller/wrench'
TOPIC_WRENCH_DESIRED = '/hybrid_force_controller/wrench_desired'
TOPIC_THETA_HAT = '/hybrid_force_controller/theta_hat'
TOPIC_ERROR = '/hybrid_force_controller/error'
TOPIC_JOINT_STATES = '/joint_states'
TOPIC_FT_WRENCH = '/force_torque_sensor_broadcaster/wrench'
TOPIC_EFFORT_COMMANDS = '/effort_controller/commands'
TOPIC_DIAGNOSTICS = '/diagnostics'
TOPIC_CONTACT_WRENCH = '/sim/contact_wrench'
TOPIC_STIFFNESS_ESTIMATE = '/hybrid_force_controller/stiffness_estimate'
TOPIC_PATH_STATUS = '/hybrid_force_controller/path_status'
TOPIC_LINK_MASSES = '/sim/link_masses'  # the sim's true masses: transient local, once
TOPIC_SURFACE_NORMAL = '/hybrid_force_controller/surface_normal'
TOPIC_CONTACT_NORMAL = '/sim/contact_normal'
TOPIC_TOOL_AXIS = '/sim/tool_axis'

_POINT = 'geometry_msgs/msg/PointStamped'
_WRENCH = 'geometry_msgs/msg/WrenchStamped'
_ARRAY = 'std_msgs/msg/Float64MultiArray'
_VECTOR = 'geometry_msgs/msg/Vector3Stamped'

RECORD_TOPICS: list[tuple[str, str]] = [
    (TOPIC_X, _POINT),
    (TOPIC_X_DESIRED, _POINT),
    (TOPIC_WRENCH, _WRENCH),
    (TOPIC_WRENCH_DESIRED, _WRENCH),
    (TOPIC_THETA_HAT, _ARRAY),
    (TOPIC_ERROR, _VECTOR),
    (TOPIC_JOINT_STATES, 'sensor_msgs/msg/JointState'),
    (TOPIC_FT_WRENCH, _WRENCH),
    (TOPIC_EFFORT_COMMANDS, _ARRAY),
    (TOPIC_DIAGNOSTICS, 'diagnostic_msgs/msg/DiagnosticArray'),
    (TOPIC_CONTACT_WRENCH, _WRENCH),
    (TOPIC_STIFFNESS_ESTIMATE, 'std_msgs/msg/Float64'),
    (TOPIC_PATH_STATUS, 'std_msgs/msg/String'),
    (TOPIC_LINK_MASSES, _ARRAY),
    (TOPIC_SURFACE_NORMAL, _VECTOR),
    (TOPIC_CONTACT_NORMAL, _VECTOR),
    (TOPIC_TOOL_AXIS, _VECTOR),
]
# published once, transient local: a recorder that joins later still gets them
LATCHED_TOPICS = (TOPIC_LINK_MASSES,)
REQUIRED_TOPICS = (TOPIC_X, TOPIC_X_DESIRED, TOPIC_WRENCH, TOPIC_WRENCH_DESIRED,
                   TOPIC_THETA_HAT)

BAG_VERSION = 8
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
_UNSPECIFIED = QosTime(0, 0)
#: rmw_qos_profile_default: what an rclpy/rclcpp publisher with depth 10 offers.
DEFAULT_QOS = Qos(QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE, QosDurability.VOLATILE,
                  _UNSPECIFIED, _UNSPECIFIED, QosLiveliness.SYSTEM_DEFAULT, _UNSPECIFIED,
                  False)


class BagError(ValueError):
    """A bag cannot be read or written; the message names the bag, topic or problem."""


class BagWriter:
    """
    Write a rosbag2 MCAP bag (metadata version 8, Jazzy typestore).

    The bag is created (and its directory must not exist) on construction; use it as a
    context manager or call :meth:`close`, which writes ``metadata.yaml``. Thread-safe.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag directory to create.
    topics : list of (str, str)
        ``(topic, msgtype)`` pairs, e.g. :data:`RECORD_TOPICS`.

    """

    def __init__(self, path: str | Path, topics: Sequence[tuple[str, str]]) -> None:
        self.path = Path(path)
        names = [topic for topic, _ in topics]
        if len(set(names)) != len(names):
            raise BagError(f'duplicate topics in {names}')
        unknown = [typ for _, typ in topics if typ not in TYPESTORE.types]
        if unknown:
            raise BagError(f'message types not in the Jazzy typestore: {unknown}')
        self._lock = threading.Lock()
        self._writer: Writer | None = None
        try:
            self._writer = Writer(self.path, version=BAG_VERSION,
                                  storage_plugin=StoragePlugin.MCAP)
            self._writer.open()
            self._connections = {
                topic: self._writer.add_connection(topic, typ, typestore=TYPESTORE,
                                                   offered_qos_profiles=[DEFAULT_QOS])
                for topic, typ in topics}
        except Exception as exc:  # rosbags raises WriterError, OSError, ...
            if self._writer is not None and self._writer.storage is not None:
                self._writer.abort()
            self._writer = None
            raise BagError(f'cannot create bag {self.path}: {exc}') from exc
        self._counts = dict.fromkeys(names, 0)

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, by topic."""
        with self._lock:
            return dict(self._counts)

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has run."""
        return self._writer is None

    def write(self, topic: str, stamp_ns: int, raw_cdr: bytes) -> None:
        """
        Append one serialized (CDR, with encapsulation header) message.

        Raises
        ------
        BagError
            Closed writer, unknown topic or negative stamp.

        """
        if topic not in self._connections:
            raise BagError(f'topic {topic} was not declared for bag {self.path}')
        if stamp_ns < 0:
            raise BagError(f'negative stamp {stamp_ns} ns on {topic}')
        with self._lock:
            if self._writer is None:
                raise BagError(f'bag {self.path} is closed')
            self._writer.write(self._connections[topic], int(stamp_ns), bytes(raw_cdr))
            self._counts[topic] += 1

    def write_msg(self, topic: str, stamp_ns: int, msg: Any) -> None:
        """Serialize a ``rosbags`` message object with the Jazzy typestore and write it."""
        conn = self._connections.get(topic)
        if conn is None:
            raise BagError(f'topic {topic} was not declared for bag {self.path}')
        try:
            raw = TYPESTORE.serialize_cdr(msg, conn.msgtype)
        except Exception as exc:  # rosbags SerdeError, AttributeError on a wrong type
            raise BagError(f'cannot serialize {type(msg).__name__} as {conn.msgtype} '
                           f'on {topic}: {exc}') from exc
        self.write(topic, stamp_ns, raw)

    def close(self) -> None:
        """Finish the MCAP file and write ``metadata.yaml``; later calls do nothing."""
        with self._lock:
            writer, self._writer = self._writer, None
        if writer is not None:
            writer.close()

    def __enter__(self) -> BagWriter:
        """Return the (already open) writer."""
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        """Close the bag, keeping what was written even when the block raised."""
        self.close()


def _value(topic: str, msg: Any) -> Any:
    """Extract the numbers :func:`load_run` needs from one message."""
    if topic in (TOPIC_X, TOPIC_X_DESIRED):
        return (msg.point.x, msg.point.y, msg.point.z)
    if topic == TOPIC_STIFFNESS_ESTIMATE:
        return float(msg.data)
    if topic == TOPIC_PATH_STATUS:  # 1: a path is being followed
        return 1.0 if msg.data == 'running' else 0.0
    if topic == TOPIC_LINK_MASSES:
        return np.array(msg.data, dtype=float)
    if topic in (TOPIC_SURFACE_NORMAL, TOPIC_CONTACT_NORMAL, TOPIC_TOOL_AXIS):
        return (msg.vector.x, msg.vector.y, msg.vector.z)
    if topic == TOPIC_THETA_HAT:
        label = msg.layout.dim[0].label if len(msg.layout.dim) else ''
        return np.array(msg.data, dtype=float), label
    force = msg.wrench.force
    if topic == TOPIC_CONTACT_WRENCH:  # the true moment too
        torque = msg.wrench.torque
        return (force.x, force.y, force.z, torque.x, torque.y, torque.z)
    return (force.x, force.y, force.z)


def _read_series(bag_path: Path) -> dict[str, Series]:
    """
    Deserialize the topics :func:`load_run` uses.

    Raises
    ------
    BagError
        Unreadable or empty bag, or a required topic absent.

    """
    wanted = (*REQUIRED_TOPICS, TOPIC_CONTACT_WRENCH, TOPIC_STIFFNESS_ESTIMATE,
              TOPIC_PATH_STATUS, TOPIC_LINK_MASSES, TOPIC_SURFACE_NORMAL, TOPIC_CONTACT_NORMAL,
              TOPIC_TOOL_AXIS)
    try:
        with AnyReader([bag_path], default_typestore=TYPESTORE) as reader:
            if reader.message_count == 0 or not reader.connections:
                raise BagError(f'bag {bag_path} is empty (no messages)')
            for topic in REQUIRED_TOPICS:
                if topic not in reader.topics:
                    raise BagError(f'required topic {topic} missing from bag {bag_path}')
            series = {t: Series() for t in wanted if t in reader.topics}
            conns = [c for c in reader.connections if c.topic in series]
            for conn, log_ns, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                s = series[conn.topic]
                s.has_header = hasattr(msg, 'header')
                s.stamp_ns.append(stamp_ns(msg, log_ns))
                s.log_ns.append(log_ns)
                s.values.append(_value(conn.topic, msg))
    except BagError:
        raise
    except Exception as exc:  # rosbags raises many types on corrupt input
        raise BagError(f'{bag_path} is not a readable rosbag2 bag: '
                       f'{type(exc).__name__}: {exc}') from exc
    for topic in REQUIRED_TOPICS:
        if not series[topic].values:
            raise BagError(f'no messages on required topic {topic} in bag {bag_path}')
    return series


def _theta(series: Series, x: Series, bag_path: Path) -> tuple[np.ndarray, tuple[str, ...]]:
    """``theta_hat`` on the position samples and its names from ``layout.dim[0].label``."""
    sizes = {data.size for data, _ in series.values}
    if len(sizes) != 1 or 0 in sizes:
        raise BagError(f'{TOPIC_THETA_HAT} in {bag_path}: inconsistent or empty arrays '
                       f'(sizes {sorted(sizes)})')
    p = sizes.pop()
    names = tuple(s.strip() for s in series.values[0][1].split(','))
    if len(names) != p or not all(names):
        names = tuple(f'theta_{i}' for i in range(p))
    stacked = Series(series.stamp_ns, series.log_ns,
                     [data for data, _ in series.values], series.has_header)
    return on_x_time(stacked, x), names


def _surface_normal(f_d_W: np.ndarray, bag_path: Path) -> np.ndarray:
    """Return the unit normal from the largest desired force sample."""
    norms = np.linalg.norm(f_d_W, axis=1)
    k = int(np.argmax(norms))
    if not np.isfinite(norms[k]) or norms[k] <= 1e-12:
        raise BagError(f'{TOPIC_WRENCH_DESIRED} in {bag_path} is zero everywhere: '
                       'cannot infer the surface normal')
    return f_d_W[k] / norms[k]


def load_run(bag_path: str | Path,
             contact_threshold_n: float = CONTACT_FORCE_MIN_N) -> RunLog:
    """
    Load a controller recording as a :class:`RunLog` on the stamps of ``TOPIC_X``.

    Parameters
    ----------
    bag_path : str or pathlib.Path
        rosbag2 directory (MCAP or sqlite3), or a single ``.mcap``/``.db3`` file.
    contact_threshold_n : float
        Contact is the core predicate (``core.contact.in_contact``) on ``n^T f`` with this
        minimum force, ``f`` the true contact force (``/sim/contact_wrench``) when
        recorded, else the measured one; the offline ``paper`` run uses the same test.
        ``k_hat`` is the recorded stiffness estimate (None without the topic),
        ``path_running`` whether ``~/path_status`` said ``running`` (None without it),
        ``theta_true`` the sim's link masses (``/sim/link_masses``) when theta_hat has as
        many entries (the ``link_masses`` parameter set), ``n_hat_W`` the controller's
        normal (``~/surface_normal``) and ``n_true_W`` the surface's (``/sim/contact_normal``)
        when recorded; contact is then tested along the true normal (else the controller's).
        ``tool_axis_W`` the sim tool's axis (``/sim/tool_axis``) and ``m_true_W`` the true
        contact moment (``/sim/contact_wrench``'s torque) when recorded.

    Returns
    -------
    RunLog
        ``t`` in seconds from the first position sample; ``n_W`` from the desired wrench.

    Raises
    ------
    BagError
        Missing path, unreadable/corrupt or empty bag, missing or empty required topic,
        zero desired wrench, or signals that do not form a valid run log.

    """
    path = Path(bag_path)
    if not path.exists():
        raise BagError(f'bag not found: {path}')
    series = _read_series(path)
    x = sorted_by_stamp(series[TOPIC_X])
    f_d_W = on_x_time(series[TOPIC_WRENCH_DESIRED], x)
    n_W = _surface_normal(f_d_W, path)
    f_W = on_x_time(series[TOPIC_WRENCH], x)
    true = series.get(TOPIC_CONTACT_WRENCH)
    wrench_true = on_x_time(true, x) if true is not None and true.values else None
    f_true_W = None if wrench_true is None else wrench_true[:, :3]
    theta_hat, names = _theta(series[TOPIC_THETA_HAT], x, path)
    stamps = np.asarray(x.stamp_ns, dtype=np.int64)
    n_hat_W = unit_vectors(series.get(TOPIC_SURFACE_NORMAL), x)
    n_true_W = unit_vectors(series.get(TOPIC_CONTACT_NORMAL), x)
    n_contact = n_true_W if n_true_W is not None else n_hat_W
    f_c = f_W if f_true_W is None else f_true_W
    f_contact_n = f_c @ n_W if n_contact is None else np.sum(f_c * n_contact, axis=1)
    try:
        return RunLog(t=(stamps - stamps[0]) * 1e-9, x_W=np.asarray(x.values, dtype=float),
                      x_d_W=on_x_time(series[TOPIC_X_DESIRED], x), f_W=f_W, f_d_W=f_d_W,
                      n_W=n_W, theta_hat=theta_hat, theta_names=names,
                      in_contact=np.array([in_contact(f, minimum=contact_threshold_n)
                                           for f in f_contact_n], dtype=bool),
                      f_true_W=f_true_W,
                      k_hat=stiffness(series.get(TOPIC_STIFFNESS_ESTIMATE), x),
                      path_running=path_running(series.get(TOPIC_PATH_STATUS), x),
                      theta_true=true_masses(series.get(TOPIC_LINK_MASSES), theta_hat),
                      n_hat_W=n_hat_W, n_true_W=n_true_W,
                      tool_axis_W=unit_vectors(series.get(TOPIC_TOOL_AXIS), x),
                      m_true_W=None if wrench_true is None else wrench_true[:, 3:])
    except AnalysisError as exc:
        raise BagError(f'{path}: recorded signals are not a valid run: {exc}') from exc
