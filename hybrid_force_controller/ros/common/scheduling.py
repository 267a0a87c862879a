"""
Scheduling of a node's threads: SCHED_FIFO priorities and CPU affinity (Linux), never raising.

A refusal (no permission, one CPU with the kernel's real-time budget on) comes back as a
warning, and the thread runs on at normal priority. Used by the controller's control thread
and by the sim; design.md ("The control thread and what stays off it") explains the levels.
"""
from __future__ import annotations

import os
import threading
from typing import Sequence

__all__ = ['LIMITS_HINT', 'name_this_thread', 'one_cpu_reason', 'rt_budget_on',
           'schedule_process', 'set_thread_scheduling']

LIMITS_HINT = ('allow real-time scheduling for your user, as the ros2_control docs say: add '
               "'@realtime soft rtprio 99', '@realtime soft priority 99', '@realtime soft "
               "memlock unlimited' (and the hard ones) to /etc/security/limits.conf, add "
               'yourself to the realtime group, log in again; or set thread_priority:=0')


def name_this_thread(name: str) -> None:
    """
    Give the calling thread a name the OS shows (``/proc/<pid>/task/<tid>/comm``, top -H, perf).

    Python's thread names stay inside Python; this sets the kernel's (at most 15 bytes). Never
    raises: where prctl is missing nothing changes.
    """
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(15, name.encode()[:15], 0, 0, 0)  # PR_SET_NAME
    except (OSError, AttributeError):
        pass


def rt_budget_on() -> bool:
    """Say whether the kernel limits real-time threads (``kernel.sched_rt_runtime_us`` >= 0)."""
    try:
        with open('/proc/sys/kernel/sched_rt_runtime_us', encoding='ascii') as f:
            return int(f.read().strip()) >= 0
    except (OSError, ValueError):
        return True  # unknown: assume the default budget


def one_cpu_reason() -> str:
    """
    Say why SCHED_FIFO is not used when this process may run on one CPU only ('' otherwise).

    ``taskset -c 0`` or a 1-core PC: the real-time threads of every process on that CPU
    share its real-time budget (``kernel.sched_rt_runtime_us``, 95 % of each second). A sim
    and a controller at FIFO on one CPU used it up here: the kernel then stopped every FIFO
    thread for up to 50 ms (`RT throttling activated`), and the plant's watchdog dropped the
    arm (537 ms without a command, 17 timeouts in 20 s); with the middleware at normal
    priority beside the FIFO loops, that middleware starved instead (110 ms). At normal
    priority both ran clean (docs/results.md, section 1). With the budget off
    (``sched_rt_runtime_us = -1``, a tuned real-time machine) FIFO is used on one CPU too.
    """
    try:
        if len(os.sched_getaffinity(os.getpid())) != 1 or not rt_budget_on():
            return ''
    except (OSError, AttributeError):
        return ''
    return ('this process may run on one CPU only and the kernel limits real-time threads to '
            'sched_rt_runtime_us of each second: SCHED_FIFO is not used (normal priority), '
            'so that the other processes on that CPU (the sim, the middleware) are not '
            'starved; give the process more CPUs, or set kernel.sched_rt_runtime_us=-1 on a '
            'tuned real-time machine')


def set_thread_scheduling(priority: int, cpus: Sequence[int]) -> list[str]:
    """
    Give the calling thread SCHED_FIFO at ``priority`` (0: leave it) and pin it to ``cpus``.

    Returns the warnings (empty when everything was granted); never raises.
    """
    warnings = []
    shared = one_cpu_reason() if priority > 0 else ''
    if shared:
        warnings.append(shared)
    elif priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, AttributeError) as exc:
            warnings.append(f'could not set SCHED_FIFO priority {priority} on the control '
                            f'thread ({exc}); it runs at normal priority: {LIMITS_HINT}')
    if cpus:
        try:
            os.sched_setaffinity(0, set(cpus))
        except (OSError, AttributeError, ValueError) as exc:
            warnings.append(f'could not pin the control thread to CPUs {list(cpus)} ({exc}); '
                            'it runs on any CPU')
    return warnings


def schedule_process(priority: int, what: str, keep: tuple[int, ...] = (),
                     cpus: Sequence[int] = (), others: int | None = None) -> list[str]:
    """
    Give the calling thread SCHED_FIFO ``priority`` and the process's other threads ``others``.

    Called by a node's ``main`` on the thread that spins the node, once the node exists: the
    other threads then are the middleware's (DDS receive, events, shared-memory watchdog).
    A loop that waits for a DDS thread to deliver its input, or for the node's thread to let
    the GIL go, waits as long as ordinary processes keep those threads off the CPU (a
    priority inversion: 167 ms holds and 217 ms effort gaps beside two busy processes); at
    FIFO they preempt ordinary processes, and a loop above them still preempts them.
    ``keep``: thread ids left as they are (a control thread scheduled already); ``cpus``:
    the calling thread's CPUs; ``others`` (default ``priority - 1``): the priority of the
    other threads. ``priority`` <= 0 leaves the scheduler alone. Returns the first warning,
    if any.
    """
    if priority <= 0:
        return []
    me = threading.get_native_id()
    shared = one_cpu_reason()  # then no thread gets FIFO; cpus still apply
    warnings = set_thread_scheduling(0 if shared else priority, cpus)
    if shared:
        return [shared]
    level = max(1, priority - 1 if others is None else others)
    tids = [int(t) for t in os.listdir('/proc/self/task') if int(t) not in (me, *keep)]
    for tid in tids:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(level))
        except OSError as exc:
            warnings.append(f'could not set SCHED_FIFO on the middleware threads ({exc})')
            break
    return [w.replace('control thread', what) for w in warnings[:1]]
