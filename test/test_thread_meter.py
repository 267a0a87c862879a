"""bench's per-thread meter (ros/lab/load.py): CPU and context switches of a named thread."""
from __future__ import annotations

import os
import threading
import time

from hybrid_force_controller.ros.common.scheduling import name_this_thread
from hybrid_force_controller.ros.lab.load import thread_switches, ThreadCpuMeter

SLEEPS = 200


def _sleeper(name: str, ready: threading.Event, go: threading.Event,
             done: threading.Event, release: threading.Event) -> None:
    name_this_thread(name)
    ready.set()
    go.wait()
    pause = threading.Event()
    for _ in range(SLEEPS):  # each timed wait puts the thread to sleep: a voluntary switch
        pause.wait(0.0005)
    done.set()
    release.wait(30.0)  # alive (and named) until the meter has read it


def test_a_thread_that_sleeps_n_times_switches_at_least_n_times():
    """thread_switches and ThreadCpuMeter.switches count one thread's sleeps by its name."""
    ready, go, done, release = (threading.Event() for _ in range(4))
    worker = threading.Thread(target=_sleeper, args=('hfc_sleeper', ready, go, done, release))
    worker.start()
    assert ready.wait(10.0)
    meter = ThreadCpuMeter(os.getpid())
    before = thread_switches(os.getpid())['hfc_sleeper']
    t0 = time.monotonic()
    meter.start()
    go.set()
    assert done.wait(30.0)
    cpu = meter.stop()
    window = time.monotonic() - t0  # at least the meter's own window
    after = thread_switches(os.getpid())['hfc_sleeper']
    release.set()
    worker.join(10.0)
    assert after[0] - before[0] >= SLEEPS
    voluntary_per_s, _ = meter.switches['hfc_sleeper']
    assert voluntary_per_s * window >= SLEEPS and 'hfc_sleeper' in cpu
    assert 'main' in meter.switches  # the process's own thread, as thread_cpu_seconds names it
