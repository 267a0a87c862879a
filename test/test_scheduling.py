"""
Where the nodes ask for SCHED_FIFO (ros/controller/control_loop.py), checked in child processes.

* On more than one CPU, ``schedule_process`` gives the calling thread FIFO ``priority`` and the
  process's other threads (the middleware's) ``others``.
* Confined to one CPU (``taskset -c 0``, a 1-core PC) with the kernel's real-time budget on,
  no thread is given FIFO: the call returns one warning that says why and what to do, and
  every thread keeps the normal policy. (A sim and a controller at FIFO on one CPU used up
  the budget and the kernel stopped them for up to 50 ms: docs/results.md, section 1.)

FIFO needs CAP_SYS_NICE: the granted case is skipped where it is refused.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

from hybrid_force_controller.ros.common.scheduling import rt_budget_on
import pytest

CHILD = """
import json, os, threading, time
from hybrid_force_controller.ros.common.scheduling import schedule_process
stop = threading.Event()
worker = threading.Thread(target=stop.wait)  # another thread, as the middleware's are
worker.start()
warnings = schedule_process(50, 'sim thread', others=49)
policies = {int(t): [os.sched_getscheduler(int(t)), os.sched_getparam(int(t)).sched_priority]
            for t in os.listdir('/proc/self/task')}
stop.set()
print(json.dumps({'warnings': warnings, 'policies': policies, 'me': threading.get_native_id()}))
"""


def _run(cpus: str) -> dict:
    out = subprocess.run(['taskset', '-c', cpus, sys.executable, '-c', CHILD],
                         capture_output=True, text=True, timeout=60, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _fifo_granted() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except OSError:
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


@pytest.mark.skipif(not rt_budget_on(), reason='real-time budget off: FIFO on one CPU too')
def test_on_one_cpu_no_thread_gets_fifo_and_one_warning_says_why():
    result = _run('0')
    assert len(result['warnings']) == 1, result
    warning = result['warnings'][0]
    assert 'one CPU only' in warning and 'sched_rt_runtime_us' in warning, warning
    assert all(p == [os.SCHED_OTHER, 0] for p in result['policies'].values()), result


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2 or not _fifo_granted(),
                    reason='needs 2 CPUs for this process and CAP_SYS_NICE')
def test_on_two_cpus_the_caller_gets_fifo_and_the_other_threads_one_below():
    result = _run('0,1')
    assert result['warnings'] == [], result
    policies = {int(t): tuple(p) for t, p in result['policies'].items()}
    assert policies.pop(result['me']) == (os.SCHED_FIFO, 50), result
    assert policies and all(p == (os.SCHED_FIFO, 49) for p in policies.values()), result
