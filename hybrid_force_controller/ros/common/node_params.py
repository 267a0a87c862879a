"""
Parameters of the ROS nodes themselves (not of the control law): one schema per node.

Declared through :func:`~.parameters.declare_schema` like the controller's
:data:`~hybrid_force_controller.core.config.params.CONTROLLER_SCHEMA`, so they have descriptors,
ranges and appear in ``ros2 param dump``.
"""
from __future__ import annotations

import os

from ...core.config.params import ParamSpec as _S

__all__ = ['CONTROLLER_NODE_SCHEMA', 'CPU_AFFINITY_SPEC', 'EXECUTOR_SPEC', 'SENSOR_QOS',
           'THREAD_PRIORITY_SPEC', 'TICK_MODES', 'check_choice', 'check_cpus',
           'default_flight_dir']

TICK_MODES = ('auto', 'timer', 'joint_state')
SENSOR_QOS = ('best_effort', 'reliable')
EXECUTOR_SPEC = _S('executor', 'string', 'events',
                   "Executor: 'events' (rclpy.experimental.EventsExecutor, least CPU) or "
                   "'single_threaded'.", read_only=True)
THREAD_PRIORITY_SPEC = _S(
    'thread_priority', 'integer', 50,
    'SCHED_FIFO priority of the control thread (as controller_manager sets it: 50; the '
    "node's thread and the middleware's run 1 and 2 below); 0 leaves the scheduler alone, as "
    'does sim time (lockstep). Refused by the OS (no rtprio limit): one warning, it runs on.',
    0, 99, read_only=True)
CPU_AFFINITY_SPEC = _S(
    'cpu_affinity', 'integer_array', [],
    'CPUs the control thread may run on ([] = any).', read_only=True)


def default_flight_dir() -> str:
    """Return ``$ROS_HOME/hybrid_force_controller/flight`` (``~/.ros`` without ROS_HOME)."""
    home = os.environ.get('ROS_HOME') or os.path.join(os.path.expanduser('~'), '.ros')
    return os.path.join(home, 'hybrid_force_controller', 'flight')


CONTROLLER_NODE_SCHEMA: tuple[_S, ...] = (
    _S('telemetry_rate_hz', 'double', 100.0,
       'Rate of ~/x, ~/x_desired, ~/wrench, ~/wrench_desired, ~/error, ~/theta_hat, Hz '
       '(every k-th tick, k = round(rate_hz / telemetry_rate_hz); 0: off). Efforts go out '
       'every tick.', 0.0, 10000.0),
    _S('tick_mode', 'string', 'auto',
       "'timer': tick at rate_hz on the node clock; 'joint_state': tick on each new joint "
       'state (less delay and CPU; a watchdog checks every 5 periods and ticks after 2 '
       "periods without a tick, so stale or slow inputs still lead to safe mode); 'auto': "
       'joint_state on the wall clock, timer with use_sim_time (a lockstep sim steps only '
       'on commands).', read_only=True),
    EXECUTOR_SPEC,
    _S('autostart', 'bool', True,
       'Configure and activate at start (false: a managed node that waits for the '
       'lifecycle services).', read_only=True),
    _S('use_bundled_model', 'bool', False,
       "When robot_description is '': true = the bundled 2-link arm of the paper, false = "
       'wait for the robot_description topic (robot_state_publisher).', read_only=True),
    _S('sensor_qos', 'string', 'best_effort',
       "Reliability of the joint_states and wrench subscriptions: 'best_effort' (matches "
       "reliable and best-effort publishers) or 'reliable'.", read_only=True),
    _S('sensor_depth', 'integer', 1,
       'Queue depth of the joint_states and wrench subscriptions (1: only the newest sample '
       'is kept; more keeps every sample of a burst).', 1, 1000, read_only=True),
    THREAD_PRIORITY_SPEC,
    CPU_AFFINITY_SPEC,
    _S('flight_recorder_dir', 'string', '',
       'Directory of the flight recorder: the control thread keeps the last 2 s of its ticks '
       '(inputs and stamps, x, x_d, f, f_d, mode, theta_hat, effort, hold time) and, on safe '
       'mode, a force above flight_recorder_max_force, contact lost in the force loop or a '
       'stall longer than state_timeout, the node writes them there as an MCAP bag (at most '
       'one every 5 s, written by a process of its own; its path is logged; readable by '
       "report --t-start 0). '' (the default): off; e.g. $ROS_HOME/hybrid_force_controller/"
       'flight.',
       read_only=True),
    _S('flight_recorder_max_force', 'double', 50.0,
       'A filtered force |f| above this (N) makes the flight recorder write its last 2 s '
       '(0: never for the force).', 0.0, 1e6, read_only=True),
    _S('diagnostic_updater.period', 'double', 1.0,
       "Period of the node's /diagnostics status, s, on the node's clock (sim time with "
       "use_sim_time); the name and default of diagnostic_updater's.", 0.01, 60.0,
       read_only=True),
)


def check_choice(name: str, value: str, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of ``choices``; else a ValueError naming them."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {list(choices)}, got '{value}'")
    return value


def check_cpus(cpus: list[int]) -> list[int]:
    """``cpus`` if every entry is a CPU of this machine; else a ValueError naming them."""
    available = sorted(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else []
    bad = [c for c in cpus if not isinstance(c, int) or isinstance(c, bool) or (
        available and c not in available)]
    if bad:
        raise ValueError(f'cpu_affinity must list CPUs of this machine {available}, got {bad}')
    return list(cpus)
