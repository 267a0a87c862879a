"""
The cell's gateway: the cell domain's nodes, topics and services shown on the user's domain.

``python -m hybrid_force_controller.ros.common.gateway --public P --cell C`` (started by the
first node of a cell, :func:`.cell.start_gateway`; one per cell, an abstract-socket lock
keeps it single). It has one participant on each domain, on the package's UDP-only profile
(config/fastdds_udp.xml), so a reader joining the user's domain never meets a cell
participant. Every
``SCAN_S`` it reads the cell's graph and keeps, on the user's domain:

* **nodes**: one node of the same name and namespace for each node of the cell (``ros2 node
  list``, ``ros2 param``, ``ros2 lifecycle`` find it), hosting
* **services**: each service of that node, forwarded to the cell and answered with the
  cell's response (parameters, lifecycle, ``~/tare`` ...);
* **topics the cell publishes**: a publisher of the same name, type and QoS, fed by a
  subscription in the cell that exists only while someone on the user's domain subscribes
  (so an unwatched cell sends the gateway nothing: the 1 kHz joint states and efforts cost
  the cell nothing until ``ros2 bag record`` asks for them);
* **topics the cell only subscribes**: a subscription on the user's domain whose messages
  are published into the cell (``~/path``, ``~/reference``, ``~/target_wrench``; a
  ``robot_description`` from outside). A topic a cell node has ever published is never fed
  from outside, nor is the loop's own I/O (``joint_states``, ``effort_controller/commands``,
  the wrench, ``clock``: :data:`LOOP_TOPICS`, in any namespace): a user's joint states or
  efforts cannot reach the loop, even while the graph momentarily misses the writer (a
  best-effort writer of the gateway's appeared on the cell's ``joint_states`` that way, and on
  one CPU one of the efforts before the controller's writer was discovered).

Messages pass as serialized bytes (no conversion). The scan runs on the user side's thread;
what it changes on the cell's node (the mirrors' subscriptions, the services' clients) it hands
to the cell side's thread, which makes the change between two of its spins: an entity made on
one thread while the other's executor waited on that node crashed the process once (a
segfault in ``create_subscription``, docs/results.md section 19). The gateway ends on
SIGINT/SIGTERM, or
``IDLE_EXIT_S`` after the last process of the cell has ended (:class:`Members`).
"""
from __future__ import annotations

import argparse
from collections import deque
import faulthandler
import importlib
import os
import signal
import sys
import threading
import time
from typing import Any, Sequence

import rclpy
from rclpy.context import Context
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from .cell import CellDomains, gateway_lock

__all__ = ['Gateway', 'main']

SCAN_S = 0.5
IDLE_EXIT_S = 2.0
MISSING_SCANS = 3  # a topic's mirror stays this many scans after its writer left the graph
STARTUP_S = 30.0  # a gateway that no node announced itself to ends after this long
SERVICE_TIMEOUT_S = 10.0
GATEWAY_NODE = '_hfc_gateway'
NO_TYPE_SERVICE = [Parameter('start_type_description_service', value=False)]
# No QoS event handlers on the mirrors (rclpy's default incompatible-QoS and -type warnings):
# a mirror meets writers and readers of every QoS, and with them the Jazzy EventsExecutor
# segfaulted as the mirrors started (a Python call without the GIL in spin_once), without them
# not once (docs/results.md section 34)
NO_EVENTS_PUB = {'event_callbacks': PublisherEventCallbacks(use_default_callbacks=False)}
NO_EVENTS_SUB = {'event_callbacks': SubscriptionEventCallbacks(use_default_callbacks=False)}
_PENDING = object()  # a mirror's cell subscription asked of the cell's thread, not made yet
#: the loop's own topics (their names in any namespace): never fed from outside, even before the
#: cell's writer of them is discovered (one CPU: the sim's reader of the efforts was seen first,
#: and the gateway made a writer of the efforts in the cell)
LOOP_TOPICS = ('joint_states', 'effort_controller/commands',
               'force_torque_sensor_broadcaster/wrench', 'clock')
_LOOP_SUFFIXES = tuple(f'/{t}' for t in LOOP_TOPICS)  # '/clock' is itself such a suffix


def fed_into_cell(topic: str, plant_topics: set[str]) -> bool:
    """Say whether a topic the cell subscribes (nobody there publishes) may be fed from outside."""
    return topic not in plant_topics and not topic.endswith(_LOOP_SUFFIXES)


def import_type(name: str) -> Any:
    """Return the Python class of a ROS type name ``pkg/msg/Name`` or ``pkg/srv/Name``."""
    pkg, kind, cls = name.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), cls)


def mirror_qos(infos: Sequence[Any]) -> QoSProfile:
    """Return a QoS that matches every endpoint of ``infos`` (reliable, durable if one is)."""
    reliable = any(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
    durable = any(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=100 if not durable else 10,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if durable else DurabilityPolicy.VOLATILE)


def _gateway_node(node_name: str) -> bool:
    return node_name == GATEWAY_NODE


class Graph:
    """The cell's graph, read once a scan: nodes, and per topic its publishers' and readers'."""

    def __init__(self, node: Node) -> None:
        self.nodes = [(n, ns) for n, ns in node.get_node_names_and_namespaces()
                      if not _gateway_node(n)]
        self.types: dict[str, str] = {}
        self.pub_infos: dict[str, list] = {}
        self.sub_infos: dict[str, list] = {}
        self.services: dict[tuple[str, str], list[tuple[str, str]]] = {}
        for name, ns in self.nodes:
            try:
                pubs = node.get_publisher_names_and_types_by_node(name, ns)
                subs = node.get_subscriber_names_and_types_by_node(name, ns)
                self.services[(name, ns)] = [
                    (s, t[0]) for s, t in node.get_service_names_and_types_by_node(name, ns)]
            except Exception:  # noqa: BLE001 - the node left between the two calls
                continue
            for topic, types in pubs + subs:
                self.types.setdefault(topic, types[0])
        for topic in self.types:
            self.pub_infos[topic] = [i for i in node.get_publishers_info_by_topic(topic)
                                     if not _gateway_node(i.node_name)]
            self.sub_infos[topic] = [i for i in node.get_subscriptions_info_by_topic(topic)
                                     if not _gateway_node(i.node_name)]


class Members:
    """
    The processes of the cell, as they announce themselves on the gateway's lock socket.

    Each cell node sends its pid every 2 s (:func:`.cell.announce`); the gateway runs while one
    of them lives, and ends ``IDLE_EXIT_S`` after the last one is gone (or ``STARTUP_S`` after
    its start if none ever announced itself). The processes, not the DDS graph: a node killed
    without a goodbye stays in the graph until its lease ends.
    """

    def __init__(self, sock: Any) -> None:
        self.sock, self.pids, self.announced = sock, set(), False
        self.sock.setblocking(False)
        self.t_last = time.monotonic()

    def alive(self) -> bool:
        """Read the announcements; tell whether a member lives (or may still come)."""
        now = time.monotonic()
        while True:
            try:
                self.pids.add(int(self.sock.recv(64)))
                self.announced = True
            except (BlockingIOError, ValueError):
                break
        self.pids = {pid for pid in self.pids if _process_alive(pid)}
        if self.pids:
            self.t_last = now
            return True
        return now - self.t_last < (IDLE_EXIT_S if self.announced else STARTUP_S)


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class Gateway:
    """The two participants and the mirrors between them (module docstring)."""

    def __init__(self, domains: CellDomains) -> None:
        self.domains = domains
        self.ctx_cell, self.ctx_user = Context(), Context()
        rclpy.init(context=self.ctx_cell, domain_id=domains.cell,
                   signal_handler_options=SignalHandlerOptions.NO)
        rclpy.init(context=self.ctx_user, domain_id=domains.public,
                   signal_handler_options=SignalHandlerOptions.NO)
        kw = {'start_parameter_services': False, 'enable_rosout': False,
              'parameter_overrides': NO_TYPE_SERVICE}
        self.cell = Node(GATEWAY_NODE, context=self.ctx_cell, **kw)
        self.user = Node(GATEWAY_NODE, context=self.ctx_user, **kw)
        self.exec_cell = EventsExecutor(context=self.ctx_cell)
        self.exec_user = EventsExecutor(context=self.ctx_user)
        self.exec_cell.add_node(self.cell)
        self.exec_user.add_node(self.user)
        self.nodes: dict[tuple[str, str], Node] = {}  # user-side twins of the cell's nodes
        self.services: dict[str, tuple[Any, Any]] = {}  # name: (server, client)
        self.out: dict[str, list] = {}  # cell -> user: [publisher, subscription or None, qos]
        self.plant_topics: set[str] = set()  # every topic a cell node has published
        self.missing: dict[str, int] = {}  # scans a mirrored topic has had no writer
        self.into: dict[str, tuple] = {}  # user -> cell: (subscription, [publisher], type, qos)
        self.cell_ops: deque = deque()  # changes of the cell's node, made on the cell's thread
        self.user.create_timer(SCAN_S, self._scan_guarded)

    # ------------------------------------------------------------------ the scan
    def _scan_guarded(self) -> None:
        try:
            self.scan()
        except Exception as exc:  # noqa: BLE001 - a graph that changed mid-scan: next scan
            self.user.get_logger().warning(f'scan: {exc!r}', throttle_duration_sec=5.0)

    def scan(self) -> None:
        """Bring the mirrors in line with the cell's graph."""
        graph = Graph(self.cell)
        self._sync_nodes(graph)
        published = {t for t, infos in graph.pub_infos.items() if infos}
        self.plant_topics |= published  # once published in the cell, never fed from outside
        for topic in list(self.out):  # a mirror outlives MISSING_SCANS scans without its writer
            self.missing[topic] = 0 if topic in published else self.missing.get(topic, 0) + 1
            if self.missing[topic] < MISSING_SCANS:
                published.add(topic)
        subscribed_only = {t for t, infos in graph.sub_infos.items()
                           if infos and fed_into_cell(t, self.plant_topics)}
        self._sync_into(graph, subscribed_only)  # first: a topic that turned published
        self._sync_out(graph, published)  # must not see the gateway's own reader as a user

    def _sync_nodes(self, graph: Graph) -> None:
        for key in [k for k in self.nodes if k not in graph.services]:
            self.exec_user.remove_node(self.nodes[key])
            self.nodes.pop(key).destroy_node()
        wanted: dict[str, tuple[tuple[str, str], str]] = {}
        for key, services in graph.services.items():
            if key not in self.nodes and not key[0].startswith('_'):
                name, ns = key
                self.nodes[key] = Node(name, namespace=ns, context=self.ctx_user,
                                       start_parameter_services=False, enable_rosout=False,
                                       parameter_overrides=NO_TYPE_SERVICE)
                self.exec_user.add_node(self.nodes[key])
            if key in self.nodes:
                wanted.update({s: (key, t) for s, t in services})
        for name in [s for s in self.services if s not in wanted]:
            server, client = self.services.pop(name)
            server.destroy()
            self.cell_ops.append(lambda c=client: c and self.cell.destroy_client(c[0]))
        for name, (key, type_name) in wanted.items():
            if name not in self.services:
                self._add_service(self.nodes[key], name, type_name)

    def _add_service(self, twin: Node, name: str, type_name: str) -> None:
        try:
            srv_type = import_type(type_name)
        except (ImportError, AttributeError, ValueError):
            return  # a type this Python cannot load: not shown
        made: list = []  # the cell's client, once the cell's thread has made it
        self.cell_ops.append(lambda: made.append(self.cell.create_client(srv_type, name)))

        def forward(request: Any, response: Any) -> Any:
            deadline = time.monotonic() + SERVICE_TIMEOUT_S
            while not made and time.monotonic() < deadline:
                time.sleep(0.01)  # the cell's thread makes it within one spin (0.1 s)
            if not made:
                return response
            client = made[0]
            if not client.service_is_ready():  # the gateway's client not matched yet
                client.wait_for_service(SERVICE_TIMEOUT_S)
            future = client.call_async(request)
            done = threading.Event()
            future.add_done_callback(lambda _: done.set())
            if done.wait(SERVICE_TIMEOUT_S) and future.result() is not None:
                return future.result()
            return response
        self.services[name] = (twin.create_service(srv_type, name, forward), made)

    def _sync_out(self, graph: Graph, published: set[str]) -> None:
        for topic in [t for t in self.out if t not in published]:
            entry = self.out.pop(topic)
            self.missing.pop(topic, None)
            self._drop_cell_subscription(entry)
            self.user.destroy_publisher(entry[0])
        for topic in published:
            if topic not in self.out:
                msg_type = self._type(graph, topic)
                if msg_type is None:
                    continue
                qos = mirror_qos(graph.pub_infos[topic])
                self.out[topic] = [self.user.create_publisher(msg_type, topic, qos,
                                                              **NO_EVENTS_PUB), None, qos]
            entry = self.out[topic]
            watched = entry[0].get_subscription_count() > 0
            if watched and entry[1] is None:
                entry[1] = _PENDING
                self.cell_ops.append(lambda e=entry, t=topic: self._make_cell_subscription(e, t))
            elif not watched and entry[1] is not None:
                self._drop_cell_subscription(entry)

    def _make_cell_subscription(self, entry: list, topic: str) -> None:
        """Make a mirror's subscription in the cell (on the cell's thread), if still wanted."""
        if entry[1] is _PENDING:
            pub = entry[0]
            entry[1] = self.cell.create_subscription(pub.msg_type, topic, pub.publish, entry[2],
                                                     raw=True, **NO_EVENTS_SUB)

    def _drop_cell_subscription(self, entry: list) -> None:
        """Stop a mirror's feed: its cell subscription destroyed on the cell's thread."""
        sub, entry[1] = entry[1], None
        if sub is not None and sub is not _PENDING:
            self.cell_ops.append(lambda: self.cell.destroy_subscription(sub))

    def _sync_into(self, graph: Graph, subscribed_only: set[str]) -> None:
        for topic in [t for t in self.into if t not in subscribed_only]:
            sub, made, _, _ = self.into.pop(topic)
            if sub is not None:
                self.user.destroy_subscription(sub)
            self.cell_ops.append(lambda m=made: m and self.cell.destroy_publisher(m[0]))
        for topic in subscribed_only:
            if topic not in self.into:  # first the cell's publisher, on the cell's thread
                msg_type = self._type(graph, topic)
                if msg_type is None:
                    continue
                qos = mirror_qos(graph.sub_infos[topic])
                made: list = []
                self.cell_ops.append(lambda m=made, a=(msg_type, topic, qos):
                                     m.append(self.cell.create_publisher(*a, **NO_EVENTS_PUB)))
                self.into[topic] = (None, made, msg_type, qos)
            sub, made, msg_type, qos = self.into[topic]
            if sub is None and made:  # then, at a scan after, the user's side that feeds it
                sub = self.user.create_subscription(msg_type, topic, made[0].publish, qos,
                                                    raw=True, **NO_EVENTS_SUB)
                self.into[topic] = (sub, made, msg_type, qos)

    @staticmethod
    def _type(graph: Graph, topic: str) -> Any:
        try:
            return import_type(graph.types[topic])
        except (ImportError, AttributeError, ValueError):
            return None

    # ------------------------------------------------------------------ running
    def run(self, stop: threading.Event, members: 'Members') -> None:
        """Spin both sides until ``stop`` or until no process of the cell is left."""
        thread = threading.Thread(target=self._spin_cell, args=(stop,), name='cell',
                                  daemon=True)
        thread.start()
        while not stop.is_set() and members.alive():
            self._spin_once(self.exec_user, self.user)
        stop.set()
        thread.join(2.0)

    def _spin_cell(self, stop: threading.Event) -> None:
        while not stop.is_set():
            while self.cell_ops:  # the scan's changes of the cell's node, between two spins
                try:
                    self.cell_ops.popleft()()
                except Exception as exc:  # noqa: BLE001 - one change failed: the rest go on
                    self.cell.get_logger().warning(f'cell change: {exc!r}',
                                                   throttle_duration_sec=5.0)
            self._spin_once(self.exec_cell, self.cell)

    @staticmethod
    def _spin_once(executor: Any, node: Node) -> None:
        """
        Spin once; a callback that met an endpoint the scan had just destroyed is skipped.

        A mirror's callback runs on the cell's thread while the scan (the user's thread) may
        destroy its publisher: rclpy then raises InvalidHandle (a RuntimeError), which would
        otherwise end that side's thread and every mirror with it.
        """
        try:
            executor.spin_once(timeout_sec=0.1)
        except RuntimeError as exc:
            node.get_logger().warning(f'callback skipped: {exc!r}', throttle_duration_sec=5.0)

    def close(self) -> None:
        """Destroy both sides' nodes and contexts."""
        self.exec_user.shutdown(timeout_sec=1.0)
        self.exec_cell.shutdown(timeout_sec=1.0)
        for node in [*self.nodes.values(), self.user, self.cell]:
            node.destroy_node()
        rclpy.try_shutdown(context=self.ctx_user)
        rclpy.try_shutdown(context=self.ctx_cell)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the gateway of one cell; 0 at its end, 0 at once if another holds the lock."""
    ap = argparse.ArgumentParser(prog='gateway', description=__doc__.splitlines()[1].strip())
    ap.add_argument('--public', type=int, required=True, help="the user's ROS_DOMAIN_ID")
    ap.add_argument('--cell', type=int, required=True, help='the cell domain')
    args = ap.parse_args(argv)
    faulthandler.enable()  # a crash leaves its stack in the log of the node that started it
    os.sched_setaffinity(0, range(os.cpu_count() or 1))  # not the control thread's CPUs
    domains = CellDomains(args.public, args.cell)
    lock = gateway_lock(domains)
    if lock is None:
        return 0  # another node of the cell started it first
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    gateway = Gateway(domains)
    try:
        gateway.run(stop, Members(lock))
    finally:
        gateway.close()
        lock.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
