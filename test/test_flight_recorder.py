"""
The flight recorder offline: its ring, its triggers, its snapshot, the bag it becomes.

core/runtime/flight_recorder.py keeps the control thread's last ticks in preallocated arrays;
tools/flight_log.py writes a snapshot as an MCAP bag that ``load_run``, ``report`` and rosbags'
MCAP reader read; ros/controller/flight_dumps.py takes the requests on the node's thread and
writes off it, at most one dump per 5 s. Runs use the offline engine's input stream replayed
into a runtime (tools/flight_bench.py), as the control loop would tick it.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import threading
import tracemalloc

from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.scenario import ScenarioConfig
from hybrid_force_controller.core.runtime.flight_recorder import FlightRecorder, MODES
from hybrid_force_controller.core.runtime.inputs import JointSample
from hybrid_force_controller.core.runtime.modes import Mode, TickOutput
from hybrid_force_controller.ros.controller.flight_dumps import (AFTER_S, FlightDumps, kind_of,
                                                                 WRITE_TIMEOUT_S)
from hybrid_force_controller.tools import report
from hybrid_force_controller.tools.bag_io import load_run, TOPIC_X
from hybrid_force_controller.tools.flight_bench import _runtime, _stream
from hybrid_force_controller.tools.flight_log import (FLIGHT_TOPICS, TOPIC_FLIGHT_HOLD,
                                                      TOPIC_FLIGHT_MODE, TOPIC_FLIGHT_TRIGGER,
                                                      write_flight_log)
import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.storage_mcap import McapReader


MODEL = RobotModel.from_urdf()
MCAP_MAGIC = b'\x89MCAP0\r\n'
# join's wait here: the writer's own timeout, not the 10 s a node that ends waits (one CPU
# shared with the serial group's cells took longer: s51d)
JOIN = WRITE_TIMEOUT_S + 10.0
GAP = (2.0, 2.3)  # the inputs stop for 0.3 s: safe mode after state_timeout (0.1 s)


def tick_output(k: float, mode: Mode = Mode.RUNNING, contact: bool = True,
                f: float = 1.0, tau: bool = True) -> TickOutput:
    """Return a tick whose every field is ``k`` (the force ``f`` along y)."""
    v = np.full(3, float(k))
    return TickOutput(np.full(2, float(k)) if tau else None, mode, v, v + 1.0,
                      np.array([0.0, f, 0.0]), v + 3.0, np.zeros(3), np.full(2, float(k)),
                      contact, 'status')


def sample(k: float) -> JointSample:
    return JointSample(k - 0.5, np.full(2, float(k)), np.full(2, -float(k)))


def test_the_ring_gives_the_newest_rows_in_time_order_after_wrapping():
    rec = FlightRecorder(2, 2, capacity=5)
    for k in range(12):
        rec.record(float(k), sample(k), k - 0.25, tick_output(k, tau=k != 10))
        rec.note_hold(k * 1e-3)
    snap = rec.snapshot()
    # a full ring gives capacity - 1 rows (the slot the next tick writes is left out)
    assert snap.t.tolist() == [8.0, 9.0, 10.0, 11.0] and snap.dropped == 0
    assert snap.t_state.tolist() == [7.5, 8.5, 9.5, 10.5]
    assert snap.t_wrench.tolist() == [7.75, 8.75, 9.75, 10.75]
    assert snap.q[:, 0].tolist() == [8, 9, 10, 11] and snap.qdot[:, 1].tolist() == [-8, -9,
                                                                                    -10, -11]
    assert np.array_equal(snap.x_d_W[:, 2], snap.t + 1.0)
    assert np.array_equal(snap.f_d_W[:, 0], snap.t + 3.0)
    assert snap.theta_hat[:, 1].tolist() == [8, 9, 10, 11]
    assert np.isnan(snap.tau[2]).all() and snap.tau[3].tolist() == [11, 11]
    assert np.allclose(snap.hold_s, snap.t * 1e-3)
    assert [MODES[c] for c in snap.mode] == [Mode.RUNNING] * 4 and snap.in_contact.all()
    rec.record(12.0, None, math.nan, tick_output(12, Mode.WAITING))  # no input yet: NaN
    snap = rec.snapshot()
    assert np.isnan(snap.q[-1]).all() and np.isnan(snap.t_state[-1])
    assert np.isnan(snap.hold_s[-1])  # its callback has not returned yet


def test_a_record_allocates_nothing():
    """
    After a warm-up, 20000 records leave nothing behind and make no array.

    The only allocations are transient Python objects (a float, numpy's index view: a few
    hundred bytes at most at any time), freed within the call; the ring keeps its buffers.
    """
    rec = FlightRecorder(7, 10, capacity=2000, max_force=50.0, stall_s=0.1)
    outs = [TickOutput(np.ones(7), Mode.RUNNING, np.ones(3), np.ones(3), np.ones(3),
                       np.ones(3), np.zeros(3), np.ones(10), True, 'running')
            for _ in range(2)]
    state = JointSample(0.0, np.ones(7), np.ones(7))
    times = [1e-3 * k for k in range(22000)]
    buffers = [rec.q.ctypes.data, rec.theta_hat.ctypes.data, rec.t.ctypes.data]
    for k in range(2000):
        rec.record(times[k], state, 0.0, outs[k % 2])
    # what the recorder's own lines keep: this worker's other threads (a ROS test's executor)
    # may allocate meanwhile (s52h: 450 bytes kept in all over the 20000 records)
    own = [tracemalloc.Filter(True, '*flight_recorder.py')]
    # the peak is the process's: another thread's transient allocation lands in it too (s55f:
    # 1427 bytes once), so the recorder's is the least of three windows' peaks
    tracemalloc.start()
    try:
        snap0 = tracemalloc.take_snapshot().filter_traces(own)
        peaks = []
        for first, end in ((2000, 8000), (8000, 14000), (14000, 22000)):
            before, _ = tracemalloc.get_traced_memory()
            tracemalloc.reset_peak()
            for k in range(first, end):
                rec.record(times[k], state, 0.0, outs[k % 2])
                rec.note_hold(1e-4)
            peaks.append(tracemalloc.get_traced_memory()[1] - before)
        kept = tracemalloc.take_snapshot().filter_traces(own).compare_to(snap0, 'filename')
    finally:
        tracemalloc.stop()
    assert sum(d.size_diff for d in kept) < 256, kept  # not a byte per record
    assert min(peaks) < 1024, peaks
    assert [rec.q.ctypes.data, rec.theta_hat.ctypes.data, rec.t.ctypes.data] == buffers
    assert rec.count == 22000 and not rec.requests


def test_each_trigger_fires_once_on_its_edge():
    rec = FlightRecorder(2, 2, capacity=50, max_force=10.0, stall_s=0.1)
    t = iter(np.arange(1.0, 2.0, 0.001).tolist())

    def tick(**kw) -> str:
        return rec.record(next(t), sample(0), 0.0, tick_output(0, **kw))
    assert tick() == '' and tick() == ''
    assert tick(mode=Mode.SAFE).startswith('safe mode (status)')
    assert tick(mode=Mode.SAFE) == ''
    assert tick() == ''
    assert tick(f=12.0).startswith('|f| = 12 N above max_force = 10 N')
    assert tick(f=-12.0) == ''  # still above: no new trigger
    assert tick() == '' and tick(f=11.0) != ''  # below, then above again
    assert tick(mode=Mode.APPROACH, contact=False) == 'contact lost in the force loop'
    assert tick(mode=Mode.APPROACH, contact=True) == ''
    assert tick(mode=Mode.APPROACH, contact=False) == ''  # lost outside the force loop
    next(t)
    assert tick() == ''  # 2 ms since the previous tick
    for _ in range(150):
        next(t)
    assert tick().startswith('stall (151 ms since the previous tick)')
    for _ in range(150):
        next(t)
    rec.forget_last()  # a re-activation: the time inactive is no stall
    assert tick() == ''
    assert [r for r, _ in rec.requests] == [
        'safe mode (status)', '|f| = 12 N above max_force = 10 N',
        '|f| = 11 N above max_force = 10 N', 'contact lost in the force loop',
        'stall (151 ms since the previous tick)']


def replay(model: RobotModel, cfg: ScenarioConfig, gap: tuple[float, float] = (0.0, 0.0),
           t_offset: float = 100.0) -> tuple[FlightRecorder, list]:
    """Replay a run's inputs into a runtime (none within ``gap``), a tick for each, recorded."""
    stream, runtime = _stream(model, cfg), _runtime(model, cfg)
    rec = FlightRecorder(model.n, runtime.theta_hat.size, 2000, max_force=50.0,
                         stall_s=runtime.params.runtime.state_timeout)
    names, frame, fired = list(model.joint_names), model.end_effector_link, []
    for t, q, qdot, F_S in stream:
        if not gap[0] <= t < gap[1]:
            runtime.on_joint_state(names, q, qdot, t)
            runtime.on_wrench(frame, F_S, t)
        out = runtime.tick(t)
        if rec.record(t + t_offset, runtime.joint_sample, runtime.wrench_stamp, out):
            fired.append((t, out.mode))
        rec.note_hold(1e-4)
    return rec, fired


@pytest.fixture(scope='module')
def faulty(tmp_path_factory):
    """Cut the paper's arm's inputs for 0.3 s at 2 s: safe mode, a dump of 2 s."""
    rec, fired = replay(MODEL, ScenarioConfig(duration=3.0), GAP)
    reason, t = rec.requests[0]
    bag = write_flight_log(tmp_path_factory.mktemp('flight') / 'bag', rec.snapshot(),
                           MODEL.joint_names, MODEL.theta_names, MODEL.base_link, reason, t)
    return rec, fired, bag


def test_a_calm_run_triggers_nothing():
    rec, fired = replay(MODEL, ScenarioConfig(duration=3.0))
    assert fired == [] and not rec.requests and rec.count == 3000


def test_a_cut_input_triggers_safe_mode_once(faulty):
    rec, fired, _ = faulty
    assert len(fired) == 1 and fired[0][1] is Mode.SAFE
    assert abs(fired[0][0] - (GAP[0] + 0.1)) <= 0.002  # state_timeout after the last state
    assert rec.requests[0][0].startswith('safe mode (joint states older than state_timeout')


def test_the_dump_reads_back_with_load_run_and_the_mcap_reader(faulty):
    rec, _, bag = faulty
    snap = rec.snapshot()
    log = load_run(bag)
    assert len(log.t) == len(snap) == 1999
    assert np.array_equal(log.x_W, snap.x_W) and np.array_equal(log.f_d_W, snap.f_d_W)
    assert np.array_equal(log.theta_hat, snap.theta_hat)
    assert log.theta_names == MODEL.theta_names
    assert np.allclose(log.t, snap.t - snap.t[0], atol=1e-9)
    [mcap] = bag.glob('*.mcap')
    assert mcap.read_bytes()[:8] == mcap.read_bytes()[-8:] == MCAP_MAGIC  # the format's own
    with Reader(mcap) as reader:  # the .mcap file alone, without metadata.yaml
        assert isinstance(reader.storage, McapReader)
        counts = {c.topic: 0 for c in reader.connections}
        modes = []
        for c, _, raw in reader.messages():
            counts[c.topic] += 1
            modes += [bytes(raw)] if c.topic == TOPIC_FLIGHT_MODE else []
    assert set(counts) == {t for t, _ in FLIGHT_TOPICS}
    assert counts[TOPIC_X] == counts[TOPIC_FLIGHT_HOLD] == len(modes) == 1999
    assert counts[TOPIC_FLIGHT_TRIGGER] == 1
    assert sum(b'safe' in raw for raw in modes) == int((snap.mode == MODES.index(
        Mode.SAFE)).sum()) > 0


def test_report_reads_the_dump(faulty, tmp_path):
    _, _, bag = faulty
    assert report.main([str(bag), '--out', str(tmp_path), '--t-start', '0']) == 0
    metrics = json.loads((tmp_path / 'metrics.json').read_text())
    assert metrics['rms_force_error_n'] > 0.0 and (tmp_path / 'fig4_force.png').exists()


def test_a_snapshot_never_returns_a_torn_row():
    """The loop writes on one thread while another copies: every row is one tick's."""
    rec = FlightRecorder(7, 10, capacity=64)
    outs = [TickOutput(np.full(7, k), Mode.RUNNING, np.full(3, k), np.full(3, k),
                       np.full(3, k), np.full(3, k), np.zeros(3), np.full(10, k), True)
            for k in range(1000)]
    stop = threading.Event()

    def loop() -> None:
        k = 0
        while not stop.is_set():
            rec.record(float(k), None, float(k), outs[k % 1000])
            k += 1
    writer = threading.Thread(target=loop)
    writer.start()
    try:
        snaps = [rec.snapshot() for _ in range(300)]
    finally:
        stop.set()
        writer.join()
    assert any(len(s) == 63 for s in snaps)
    # a copy the writer raced may lose its oldest rows, even all of them (this writer runs
    # flat out over 64 rows, s51j; the node's ring is 2 s at 1 kHz), never mix two
    for snap in snaps:
        assert len(snap) <= 63
        k = snap.t
        assert np.array_equal(np.diff(k), np.ones(max(k.size - 1, 0))), 'rows out of order'
        assert np.array_equal(snap.t_wrench, k)
        for column in (snap.x_W, snap.f_d_W, snap.theta_hat, snap.tau):
            assert np.array_equal(column, np.repeat((k % 1000)[:, None], column.shape[1], 1))


def test_of_copies_that_each_lost_rows_the_snapshot_keeps_the_fullest():
    """Three raced copies, none within a tenth of the ring: the one that lost fewest rows."""
    rec = FlightRecorder(2, 1, capacity=100)
    copies = iter([dataclasses.replace(rec._copy(), dropped=d) for d in (60, 20, 40)])
    rec._copy = lambda: next(copies)
    assert rec.snapshot().dropped == 20


def filled(rows: int = 100) -> FlightRecorder:
    """Return a recorder with ``rows`` ticks at 1 kHz from t = 100 s."""
    rec = FlightRecorder(2, 2, capacity=2000)
    for k in range(rows):
        rec.record(100.0 + 1e-3 * k, sample(k), 100.0, tick_output(k))
    return rec


def test_dumps_are_written_off_the_thread_at_most_one_per_interval(tmp_path):
    rec, now = filled(), [1000.0]
    lines: list[str] = []
    dumps = FlightDumps(tmp_path / 'flight', MODEL, lines.append, clock=lambda: now[0],
                        after_s=0.0)
    rec.trigger('safe mode (x)', 101.5)
    rec.trigger('stall (120 ms since the previous tick)', 101.6)
    dumps.poll(rec)
    rec.trigger('safe mode (y)', 103.0)
    now[0] += 4.9
    dumps.poll(rec)  # within 5 s of the first: dropped, counted
    dumps.join(JOIN)
    assert dumps.dumps == 1 and dumps.skipped == 1 and not rec.requests
    assert len(lines) == 1, lines
    prefix = ('flight recorder: safe mode (x); stall (120 ms since the previous tick) at '
              't=101.500: ')
    assert lines[0].startswith(prefix), lines
    path = lines[0][len(prefix):]
    assert path.startswith(str(tmp_path / 'flight' / 'flight_')) and path.endswith('_safe_mode_x')
    assert f'_{os.getpid()}_' in path  # two processes' dumps of one second never collide
    assert len(load_run(path).t) == 100
    now[0] += 0.2
    rec.trigger('contact lost in the force loop', 104.0)
    dumps.poll(rec)
    dumps.join(JOIN)
    assert dumps.dumps == 2 and len(lines) == 2 and lines[1].endswith('_contact_lost_in')
    dumps.max_dumps = 3  # the cap: a third dump, said to be the last, then none
    for t in (110.0, 120.0):
        now[0] += 5.0
        rec.trigger('stall (1 s)', t)
        dumps.poll(rec)
    dumps.join(JOIN)
    assert dumps.dumps == 3 and dumps.skipped == 2 and len(lines) == 4, lines
    assert lines[2].startswith('flight recorder: 3 dumps written, the last in this run')


def test_a_request_that_joins_a_dump_puts_its_copy_off_within_the_ring():
    """A request 0.8 s after the first: copied 0.5 s after it; one 1.4 s after: at 1.5 s."""
    for joined, copied in ((0.8, 1.3), (1.4, 1.5)):
        rec, now = filled(), [1000.0]
        dumps = FlightDumps('/nonexistent', MODEL, print, clock=lambda: now[0])
        rec.trigger('contact lost in the force loop', 100.0)
        dumps.poll(rec)
        now[0] += joined
        rec.trigger('safe mode (x)', 100.9)
        dumps.poll(rec)  # late: the node's thread was frozen with the loop
        assert dumps.dumps == 0 and dumps._pending[2] == pytest.approx(1000.0 + copied)


def test_the_interval_holds_for_each_kind_of_trigger(tmp_path):
    """
    A contact loss dumped does not hide a force or a safe mode 1 s later; its own kind waits.

    (A freeze in an approach 0.4 s after a contact loss: the pressing after it was in no dump.)
    """
    rec, now, lines = filled(), [1000.0], []
    dumps = FlightDumps(tmp_path / 'flight', MODEL, lines.append, clock=lambda: now[0],
                        after_s=0.0)
    assert [kind_of(r) for r in ('safe mode (x)', 'stall (300 ms since the previous tick)',
                                 '|f| = 63 N above max_force = 50 N',
                                 'contact lost in the force loop', 'other')] == [
        'safe mode', 'stall', '|f|', 'contact lost', 'other']
    for reason in ('contact lost in the force loop', '|f| = 63 N above max_force = 50 N',
                   'contact lost in the force loop', 'safe mode (x)'):
        rec.trigger(reason, 100.0)
        dumps.poll(rec)
        now[0] += 1.0
    dumps.join(JOIN)
    assert dumps.dumps == 3 and dumps.skipped == 1, lines
    assert sorted(line.split(' at t=')[0] for line in lines) == [  # written in any order
        'flight recorder: contact lost in the force loop', 'flight recorder: safe mode (x)',
        'flight recorder: |f| = 63 N above max_force = 50 N']


def test_a_dump_holds_what_followed_its_trigger(tmp_path):
    """The ring is copied AFTER_S after the first request: the ticks after the fault are in it."""
    rec, now, lines = filled(), [1000.0], []
    dumps = FlightDumps(tmp_path / 'flight', MODEL, lines.append, clock=lambda: now[0])
    assert dumps.after_s == AFTER_S == 0.5
    rec.trigger('safe mode (x)', 100.099)
    dumps.poll(rec)
    for k in range(100, 400):  # the loop goes on: 0.3 s of ticks
        rec.record(100.0 + 1e-3 * k, sample(k), 100.0, tick_output(k))
    rec.trigger('a force above 50 N', 100.2)
    now[0] += 0.1
    dumps.poll(rec)  # the request joined the pending dump: copied 0.5 s after it
    now[0] += 0.49
    dumps.poll(rec)
    dumps.join(JOIN)
    assert dumps.dumps == 0 and not lines and dumps.skipped == 0
    now[0] += 0.01
    dumps.poll(rec)
    dumps.join(JOIN)
    assert dumps.dumps == 1 and lines[0].startswith(
        'flight recorder: safe mode (x); a force above 50 N at t=100.099: '), lines
    t = load_run(lines[0].split(': ')[-1]).t
    assert len(t) == 400 and t[-1] - t[0] == pytest.approx(0.399)  # 300 ticks after the trigger
    rec.trigger('stall (1 s)', 101.0)  # pending when the node ends: written with what is there
    now[0] += 5.0
    dumps.poll(rec)
    dumps.join(JOIN, recorder=rec)
    assert dumps.dumps == 2 and lines[1].endswith('_stall_1_s'), lines


def test_a_dump_that_cannot_be_written_says_why(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('')
    lines: list[str] = []
    rec, dumps = filled(), FlightDumps(blocker / 'flight', MODEL, lines.append, after_s=0.0)
    rec.trigger('stall (1 s)', 5.0)
    dumps.poll(rec)
    dumps.join(JOIN)
    assert len(lines) == 1 and 'could not write' in lines[0], lines
