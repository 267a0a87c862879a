"""
Running a node process: ``--help``, the executor, and a clean exit on SIGINT/SIGTERM.

:func:`run_node` builds the node, spins it with the executor its ``executor`` parameter names
(``events``: :func:`rclpy.experimental.EventsExecutor`, ``single_threaded``) and returns
0 when a signal ends it. rclpy's own signal handler is not installed: it shuts the context
down under a running callback (an ``RCLError`` from a publisher) and never wakes
``EventsExecutor.spin()``. Here SIGINT/SIGTERM complete a future instead, and the executor
spins until that future is done, in slices (``spin_until_future_complete`` without a
timeout busy-waits in the Jazzy EventsExecutor), so the node is destroyed before shutdown.
A node with ``take_pacing`` (the sim) is stepped by this loop instead of by a timer: it spins
one event at a time, at most until the node's next period ends.
"""
from __future__ import annotations

import os
import signal
import sys
from typing import Any, Callable, Sequence

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from .cell import announce, cell_domains, CellDomains, start_gateway

__all__ = ['EXECUTORS', 'make_executor', 'print_help', 'run_node', 'spin_until_signal',
           'wants_help']

EXECUTORS = ('events', 'single_threaded')
GATEWAY_CHECK_S = 2.0  # a cell node starts the gateway again within this long if it ended
SPIN_SLICE_S = 0.25  # a signal is acted on within this long even when nothing else runs
README = ('README.md of hybrid_force_controller (source tree, or share/hybrid_force_controller/'
          'README.md once installed): sections "ROS 2 usage", "Topics and QoS", "Parameters"')


def make_executor(kind: str, context: Any = None) -> Executor:
    """Create an executor of ``kind`` (one of :data:`EXECUTORS`)."""
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == 'single_threaded':
        return SingleThreadedExecutor(context=context)
    raise ValueError(f"executor must be one of {EXECUTORS}, got '{kind}'")


def spin_until_signal(node: Node, executor: Executor) -> int:
    """Spin ``node`` until SIGINT or SIGTERM (or the context ends); the signal number or 0."""
    stop = Future()

    def on_signal(signum: int, _frame: Any) -> None:
        if not stop.done():
            stop.set_result(signum)

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    # a node that steps on its own period (the sim) is called at each period's end, from here
    pace = getattr(node, 'take_pacing', lambda: None)()
    try:
        executor.add_node(node)
        while not stop.done() and node.context.ok():
            if pace is None:
                executor.spin_until_future_complete(stop, timeout_sec=SPIN_SLICE_S)
            else:  # wait for an event at most until the next period, then step what is due
                executor.spin_once(timeout_sec=min(pace(), SPIN_SLICE_S))
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return stop.result() if stop.done() else 0


def wants_help(args: Sequence[str] | None) -> bool:
    """``-h``/``--help`` before any ``--ros-args``."""
    argv = list(sys.argv[1:] if args is None else args)
    head = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    return any(a in ('-h', '--help') for a in head)


def print_help(executable: str, summary: str, parameters: Sequence[tuple[str, str]]) -> None:
    """Usage of a node executable: how to start it, its main parameters, where to read more."""
    lines = [f'usage: {executable} [--help] [--ros-args [-p NAME:=VALUE] [--params-file FILE]'
             ' [-r __ns:=/NAMESPACE] [-r FROM:=TO]]', '', summary, '',
             'Executables of hybrid_force_controller: controller, sim (nodes); demo, bench,'
             ' report, paper (programs, each with --help).', '', 'Main parameters:']
    lines += [f'  {name:<22} {text}' for name, text in parameters]
    lines += ['', 'Example: ros2 run hybrid_force_controller controller --ros-args '
              '--params-file config/params.yaml', f'More: {README}']
    print('\n'.join(lines))


def _keep_gateway(node: Node, domains: CellDomains) -> None:
    """Start the cell's gateway now, and again whenever it is found gone (node thread)."""
    started: list[int] = []

    def check() -> None:
        for pid in list(started):  # reap the ones that ended (no zombie)
            if os.waitpid(pid, os.WNOHANG)[0]:
                started.remove(pid)
        pid = start_gateway(domains)
        if pid is not None:
            started.append(pid)
        announce(domains, os.getpid())
    check()
    node.create_timer(GATEWAY_CHECK_S, check)


def run_node(make_node: Callable[[], Node], label: str, args: list[str] | None = None,
             cell: bool = False) -> int:
    """
    Init rclpy, build the node and spin it until SIGINT/SIGTERM.

    A ``cell`` node (the sim, the controller) joins the cell domain and makes sure the cell's
    gateway runs (cell.py; ``HFC_CELL_DOMAIN_ID``): it starts it after the node is built, and
    again within ``GATEWAY_CHECK_S`` if it ended. Returns 0 then, 1 (with the reason on
    stderr) if the node cannot be configured (a ValueError subclass or a ParameterException).
    """
    try:
        domains = cell_domains() if cell else None
    except ValueError as exc:
        print(f'{label}: {exc}', file=sys.stderr)
        return 1
    domain = None if domains is None else domains.node_domain
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO, domain_id=domain)
    try:
        node = make_node()
    except (ValueError, ParameterException) as exc:
        print(f'{label}: invalid configuration: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return 1
    except KeyboardInterrupt:
        rclpy.try_shutdown()
        return 0
    executor = None
    if domains is not None and domains.isolated:
        _keep_gateway(node, domains)
    try:
        kind = node.get_parameter('executor').value if node.has_parameter('executor') \
            else 'events'
        executor = make_executor(kind)
        spin_until_signal(node, executor)
    except KeyboardInterrupt:  # a signal before the handlers were installed
        pass
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=5.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
