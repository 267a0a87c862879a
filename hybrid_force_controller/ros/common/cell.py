"""
The cell's domain: where the sim and the controller talk at 1 kHz, apart from the user's tools.

A node that joins a running cell with Fast DDS's defaults (``ros2 bag record``, ``ros2 topic
echo``, rqt) made the first send of each cell writer to it run Fast DDS 2.14's shared-memory
port health check, which sleeps 333 ms under a lock that every writer of the participant
shares, while rclpy holds the GIL: the whole node stopped and the arm dropped
(docs/results.md, sections 11, 13 and 15). No setting on the cell's side shortens that sleep.

So the cell's nodes run on a DDS domain of their own, the **cell domain**, that no user's tool
joins: nothing a user starts meets the cell's participants. The **gateway**
(:mod:`.gateway`, one process a cell, UDP only: it never opens a shared-memory port and never
sleeps in that check) shows the cell on the user's domain (``ROS_DOMAIN_ID``): the same nodes,
topics and services, so ``ros2 param set``, ``ros2 lifecycle``, ``ros2 topic echo`` and ``ros2
bag record`` work as before, and a stall of the gateway never reaches the cell.

``HFC_CELL_DOMAIN_ID`` (environment, read before the node starts) chooses:

* unset or ``auto``: ``ROS_DOMAIN_ID + 100`` (``- 100`` above 132), the default;
* a number 0-232: that domain (every node of one cell must get the same);
* ``robot``: for a ros2_control robot. The controller's 1 kHz link (``joint_states``, the
  force/torque broadcaster's wrench, the effort controller's ``commands``) stays on
  ``ROS_DOMAIN_ID``, where the robot's ``controller_manager`` is; the rest of the node
  (parameters, lifecycle, telemetry, diagnostics, logs) is on the automatic cell domain behind
  the gateway. A reader of those 1 kHz topics themselves meets the link (README);
* ``off``: no cell domain and no gateway, every node on ``ROS_DOMAIN_ID`` (as before).
"""
from __future__ import annotations

import os
import socket
import sys
from typing import Mapping

__all__ = ['CELL_VAR', 'CellDomains', 'announce', 'cell_domains', 'gateway_lock',
           'start_gateway']

CELL_VAR = 'HFC_CELL_DOMAIN_ID'
CELL_OFFSET = 100
MAX_DOMAIN = 232  # Fast DDS's ports: 7400 + 250 * domain stay below 65536
GATEWAY_MODULE = 'hybrid_force_controller.ros.common.gateway'
GATEWAY_PROFILE = 'fastdds_udp.xml'  # UDP only: no shared-memory port, no health check


class CellDomains:
    """
    The user's domain and the cell's (``cell is None``: no cell domain, no gateway).

    ``robot_link``: the controller's 1 kHz link (``joint_states``, the wrench, the efforts)
    stays on the user's domain, the robot's graph, while the rest of the node is on the cell
    domain behind the gateway (``HFC_CELL_DOMAIN_ID=robot``).
    """

    def __init__(self, public: int, cell: int | None, robot_link: bool = False) -> None:
        self.public, self.cell, self.robot_link = public, cell, robot_link

    @property
    def link_domain(self) -> int | None:
        """Return the domain of the controller's 1 kHz link when not the node's, else None."""
        return self.public if self.robot_link else None

    @property
    def isolated(self) -> bool:
        """Tell whether the cell runs on a domain of its own, behind a gateway."""
        return self.cell is not None

    @property
    def node_domain(self) -> int:
        """Return the domain the cell's nodes join."""
        return self.public if self.cell is None else self.cell


def _domain(text: str, name: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"{name} must be a number 0-{MAX_DOMAIN}, got '{text}'") from None
    if not 0 <= value <= MAX_DOMAIN:
        raise ValueError(f'{name} must be 0-{MAX_DOMAIN}, got {value}')
    return value


def cell_domains(environ: Mapping[str, str] | None = None) -> CellDomains:
    """
    Read ``ROS_DOMAIN_ID`` and ``HFC_CELL_DOMAIN_ID`` (module docstring).

    Raises
    ------
    ValueError
        A domain that is not a number 0-232, or a cell domain equal to the user's.

    """
    env = os.environ if environ is None else environ
    public = _domain(env.get('ROS_DOMAIN_ID', '') or '0', 'ROS_DOMAIN_ID')
    choice = env.get(CELL_VAR, '').strip().lower() or 'auto'
    if choice == 'off':
        return CellDomains(public, None)
    robot_link = choice == 'robot'
    if choice in ('auto', 'robot'):
        cell = public + CELL_OFFSET if public + CELL_OFFSET <= MAX_DOMAIN else public - CELL_OFFSET
    else:
        cell = _domain(choice, CELL_VAR)
    if cell == public:
        raise ValueError(f'{CELL_VAR} ({cell}) must differ from ROS_DOMAIN_ID ({public}); '
                         "'off' puts the cell on ROS_DOMAIN_ID without a gateway")
    return CellDomains(public, cell, robot_link)


def _lock_name(domains: CellDomains) -> str:
    return f'\0hfc_gateway_{domains.cell}_{domains.public}'


def announce(domains: CellDomains, pid: int) -> None:
    """Tell the cell's gateway that ``pid`` is a node of the cell (it runs while one is)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        try:
            sock.sendto(str(pid).encode(), _lock_name(domains))
        except OSError:  # no gateway yet (the next check starts one), or its queue is full
            pass


def gateway_lock(domains: CellDomains) -> socket.socket | None:
    """
    Take the cell's gateway lock: an abstract Unix socket named after both domains.

    Returns the bound socket (hold it for as long as the gateway runs; the kernel frees it
    when the process ends, however it ends), or None when another process holds it.
    """
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        sock.bind(_lock_name(domains))
    except OSError:
        sock.close()
        return None
    return sock


def gateway_running(domains: CellDomains) -> bool:
    """Tell whether a gateway holds the cell's lock (a bind that fails; microseconds)."""
    sock = gateway_lock(domains)
    if sock is None:
        return True
    sock.close()
    return False


def start_gateway(domains: CellDomains) -> int | None:
    """
    Start the cell's gateway unless one runs (the first node of a cell starts it).

    The gateway runs on the package's UDP-only profile whatever the caller set (config/
    fastdds_udp.xml: no shared-memory transport, so no 333 ms health check), in a session of
    its own (a Ctrl-C to the node's terminal does not end the gateway the other nodes of the
    cell still use); it ends by itself 2 s after the last process of the cell
    (:func:`announce`). It is started with
    ``posix_spawn`` (a vfork: no copy of the node's address space under the GIL) at the
    ordinary policy: started from a SCHED_FIFO thread it inherited FIFO, and its 250 ms
    scans, at the priority of the sim's own thread, held that thread off the CPU 106-136 ms
    (the sim's watchdog dropped the arm in 4 of 4 starts; docs/results.md, section 15); it
    also leaves the node's CPU affinity. Returns its pid, or None when a gateway already runs
    or there is no cell domain.
    """
    if not domains.isolated or gateway_running(domains):
        return None
    from .package_files import find_config, PROFILE_VAR
    # SYSTEM_DEFAULT: with LOCALHOST rmw_fastrtps would replace the profile's transports by
    # its own localhost set, shared memory included (the profile keeps the gateway on 127.0.0.1)
    env = dict(os.environ, **{PROFILE_VAR: str(find_config(GATEWAY_PROFILE)),
                              'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SYSTEM_DEFAULT'})
    cmd = [sys.executable, '-m', GATEWAY_MODULE, '--public', str(domains.public),
           '--cell', str(domains.cell)]
    return os.posix_spawn(sys.executable, cmd, env, setsid=True,
                          scheduler=(os.SCHED_OTHER, os.sched_param(0)))
