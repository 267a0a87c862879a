"""
Wrong inputs a real cell sends, in real time over DDS (issue 25), beside the real sim.

One sim (masses 50 % off) whose sensor clocks are off for the whole run (joint states 2 s
ahead, the wrench 2 s behind: drivers on PCs that are not synced) and one controller with
``config/params.yaml`` run for the module; an :class:`~hybrid_force_controller.ros.lab.
injector.Injector` in this process publishes on the controller's input topics. In order: a
copy of the newest wrench stamped an hour ahead, one a minute ahead, the same for the joint
states, a joint state with a 0.2 rad glitch on joint1, one with joint2 at 40 rad/s (the URDF
allows 10), and a fuzz of 1000 corrupted serialized messages over 2 s on both inputs. Each is
refused with the reason (/diagnostics ``last_input_fault`` and the counters), the true force
(``sim/contact_wrench``) stays within about 3x the issue's targets and in contact, and the
controller stays up. Last, the sim is restarted with the offsets swapped (joint states 2 s
behind, the wrench 2 s ahead) and the loop tracks again.

The controller keeps a burst of its inputs (``sensor_depth`` 10) so that a single injected
message cannot be superseded by the sim's next one before the loop reads it. Times are the
true force's stamps (the sim's wall clock); waits have a wall timeout against hangs only;
the exact figures (five runs per case) are in docs/results.md (``wrong_inputs``). The fuzz
needs a CPU for this process beside the loop's and is skipped on one CPU.
"""
from __future__ import annotations

import math
import re
import time

from helpers.bounds import check_bounds
from helpers.figures import current_test, needs_cpus, report_figure
from helpers.ros import domain_id, wait_for
from helpers.watch import MASSES_OFF, RealTimeRig, startup_clock_refusals
from helpers.witness import stalls_text
from hybrid_force_controller.core.runtime.contact import in_contact
from hybrid_force_controller.ros.lab.injector import Injector
from hybrid_force_controller.ros.lab.tracking import TrackingMeter
import numpy as np
import pytest


CTRL = 'hybrid_force_controller'
F_D = 1.0
N_W = np.array([0.0, -1.0, 0.0])
# bounds: 5 times the worst of the measured runs (test/realtime_bounds.json): the force's RMS
# error and peak after each message, the position's RMS error; the fuzz (skipped on one CPU,
# so not measured there) keeps the target for its peak
FUZZ_PEAK_N = 3.0
WINDOW_S = 1.5  # of true force checked after each single message


def _offsets(js: float, wrench: float) -> list[str]:
    return [*MASSES_OFF, '-p', f'joint_state_clock_offset:={js}',
            '-p', f'wrench_clock_offset:={wrench}']


class Cell:
    """The rig (sim with sensor clocks off, controller), the injector, the tracking."""

    def __init__(self, tmp_path, js_offset: float, wrench_offset: float) -> None:
        self.rig = RealTimeRig(tmp_path, domain_id('wrong_inputs'),
                               sim_args=_offsets(js_offset, wrench_offset))
        self.rig.ctrl.args += ['-p', 'sensor_depth:=10']
        self.injector = Injector(self.rig.log.node)
        self.tracking = TrackingMeter(self.rig.log.node, N_W, F_D)
        self.closed = False

    def start(self) -> 'Cell':
        self.rig.start()
        wait_for(lambda: self.now - self.rig.t_touch > 2.0 and self.injector.ready()
                 and self.rig.settled(F_D, hold_s=1.0) and self._tracking_covers(),
                 'the force to settle', alive=self.rig.procs, poll=0.05)
        return self

    def _tracking_covers(self) -> bool:
        """Say whether the telemetry (~/x, ~/x_desired) covers the last second."""
        t = self.now
        return not math.isnan(self.tracking.figures(t - 1.0, t - 0.5)['rms_position_error_m'])

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.rig.close()

    @property
    def now(self) -> float:
        return self.rig.log.latest_t()

    def diag(self) -> dict:
        return self.rig.log.fresh_diag(CTRL, alive=self.rig.procs)

    def refused(self, counter: str, before: dict, send) -> tuple[dict, float]:
        """
        ``send()`` until a status's ``counter`` grew since ``before`` (3 sends, 3 s apart).

        Return that status and the wall time of the last send.

        /diagnostics comes at 1 Hz. On one CPU a starved controller went 12-18 ms between the
        states it took (s46b, s47a), more than its ``sensor_depth`` of 10: an injected copy can
        then be pushed out of the queue unread (s47a: one never counted in 30 s).
        """
        sent: list[float] = []

        def counted_or_resend() -> bool:
            if self.rig.log.diag(CTRL).get(counter, 0) > before[counter]:
                return True
            if not sent or (len(sent) < 3 and time.time() - sent[-1] >= 3.0):
                sent.append(time.time())
                send()
            return False
        wait_for(counted_or_resend,
                 lambda: f'{counter} to count the injected message ({len(sent)} sent)',
                 alive=self.rig.procs, timeout=36.0)
        return self.rig.log.diag(CTRL), sent[-1]

    def check_force(self, t0: float, t1: float, peak: float | None = None) -> np.ndarray:
        """
        Assert the true force over [t0, t1]: RMS error, peak, contact kept; return it.

        ``peak``: bound the peak alone at that (N); None: the test's measured bounds.

        Times are the sim's stamps of the true force: the wall clock (``time.time()``).
        """
        wait_for(lambda: self.now >= t1, f'force up to {t1:.2f}', alive=self.rig.procs)
        t, f = self.rig.log.forces(t0, t1)
        assert f.size > 10
        figures = {'rms_force_error_n': float(np.sqrt(np.mean((f - F_D) ** 2))),
                   'f_min': float(f.min()), 'f_max': float(f.max()), 'window_s': t1 - t0,
                   'f_dev_max': float(np.abs(f - F_D).max())}
        report_figure(current_test(), **figures)
        np.savetxt(self.rig.sim.log_path.parent / f'force_{t0:.0f}.txt', np.c_[t - t0, f])
        if peak is None:
            check_bounds(figures)  # rms_force_error_n, f_dev_max
        else:
            assert figures['f_max'] <= peak, figures
        if not all(in_contact(v) for v in f):
            lost = t[[not in_contact(v) for v in f]]
            raise AssertionError(
                f'contact lost: min {f.min():.3f} N; {lost.size} samples out of contact from '
                f'{lost[0] - t0:.3f} to {lost[-1] - t0:.3f} s after the window began (series in '
                f"{self.rig.sim.log_path.parent / f'force_{t0:.0f}.txt'})")
        assert all(p.alive for p in self.rig.procs)
        return f


@pytest.fixture(scope='module')
def cell(tmp_path_factory):
    c = Cell(tmp_path_factory.mktemp('wrong_inputs'), 2.0, -2.0)
    try:
        yield c.start()
    finally:
        c.close()


def single(cell: Cell, send, counter: str, reason: str) -> None:
    """Send one wrong message: refused with ``reason`` (a regex), the force within bounds."""
    before = cell.diag()
    after, t0 = cell.refused(counter, before, send)
    assert re.search(reason, after['last_input_fault']), after['last_input_fault']
    safe, stalled = after['safe_mode_entries'] - before['safe_mode_entries'], stalls_text()
    if safe and stalled:  # the machine's, not the message's (s52i: a 100.5 ms stall of CPU 0)
        print(f"not asserted ({stalled}): {safe} safe mode(s), {after['last_safe_reason']}")
        report_figure(current_test(), machine_did_not_keep_up=stalled, safe_mode_entries=safe)
    else:
        assert safe == 0, after['last_safe_reason']
    f = cell.check_force(t0, t0 + WINDOW_S)
    print(f"{after['last_input_fault']}: refused; force {f.min():.3f}..{f.max():.3f} N over "
          f'{WINDOW_S} s')


def test_sensor_clocks_off_for_the_whole_run_are_measured_and_the_loop_tracks(cell):
    """Joint states 2 s ahead, the wrench 2 s behind: measured, logged once, tracking."""
    t1 = cell.now
    cell.check_force(t1 - 1.0, t1)
    d = cell.diag()
    assert d['joint_state_clock_offset_s'] == pytest.approx(2.0, abs=0.02)
    assert d['wrench_clock_offset_s'] == pytest.approx(-2.0, abs=0.02)
    # refused stamps only in a stream's first second, the middleware's start-up (helpers.
    # watch; 217 and 218 refused over 0.2 s in s50d, before the learning second)
    startup = startup_clock_refusals(d)
    for kind, stream in (('joint_states', 'joint_state'), ('wrench', 'wrench')):
        n = d[f'{stream}_clock_implausible']
        assert n == startup.get(kind, 0), (stream, n, d[f'{stream}_clock_startup_refusals'])
    fig = cell.tracking.figures(t1 - 1.0, t1)
    report_figure(current_test(), **fig)
    check_bounds(fig)  # rms_position_error_m
    log = cell.rig.ctrl.log_since()  # one warning per stream
    assert log.count('joint state stamps are 2.0') + log.count('are 1.99') == 1, log[-3000:]
    assert log.count('wrench stamps are 2.0') == 1, log[-3000:]


# the copies are of stamps already off by the sensor's offset (2 s ahead or behind)
CLOCK_REASON = r"{} stamp is {}(\.\d+)? s ahead of the controller's clock \(max_clock_skew 10 s\)"
SAID = {3600.0: '3(59[89]|60[0-2])', 60.0: '(5[789]|6[0-2])'}


@pytest.mark.parametrize('ahead', [3600.0, 60.0])
def test_one_wrench_stamped_ahead_is_refused(cell, ahead):
    single(cell, lambda: cell.injector.wrench(ahead), 'wrench_clock_implausible',
           CLOCK_REASON.format('wrench', SAID[ahead]))


@pytest.mark.parametrize('ahead', [3600.0, 60.0])
def test_one_joint_state_stamped_ahead_is_refused(cell, ahead):
    single(cell, lambda: cell.injector.joint_state(ahead), 'joint_state_clock_implausible',
           CLOCK_REASON.format('joint state', SAID[ahead]))


def test_a_position_glitch_of_0_2_rad_is_refused(cell):
    single(cell, lambda: cell.injector.joint_state(dq=[0.2, 0.0]), 'joint_state_implausible',
           r'implausible joint state: joint1 moved \+0\.(2|19)')


def test_a_velocity_beyond_the_urdf_limit_is_refused(cell):
    single(cell, lambda: cell.injector.joint_state(dv=[0.0, 40.0]), 'joint_state_implausible',
           "joint2's velocity")


@needs_cpus(2, 'the injector publishes 500 messages/s from this process; on the CPU of the '
            'loop it starves it (630-1010 N peaks in 2 of 3 runs under taskset -c 0)')
def test_a_fuzz_of_1000_corrupted_messages_over_2_s(cell):
    """
    The CDR readers and the checks refuse what is wrong; force peak bounded, in contact.

    Corruptions within the plausibility bounds (a bit of a velocity, a force changing slower
    than wrench_rate_limit) are indistinguishable from real readings and reach the law: the
    issue's target is the force peak (3 N), not its RMS. Meaningful only with a CPU for the
    injector beside the loop's (checked first: skipped on one CPU).

    Beside a CPU-bound process (the suite's other worker; a busy loop here) 2 of 26 episodes
    failed before (S10): the stiffness estimate learnt 51-300 N/m on 1700 from the corrupted
    joint states that pass the checks, and k_s followed it down to a fifth of k: a 504 N impact
    (docs/results.md, section 25). With (S10), 14 of 14 passed (0.54-1.43 N, k_hat 1635-1700).
    test_fuzz_offline replays the same fuzz deterministically.
    """
    before, sim_before = cell.diag(), cell.rig.log.fresh_diag('sim', alive=cell.rig.procs)
    t0 = time.time()  # the sim stamps the true force with the wall clock
    cell.injector.start_fuzz(1000, seed=25)
    wait_for(cell.injector.fuzz_done.is_set, 'the fuzz to be sent', alive=cell.rig.procs)
    t1 = time.time()

    def errors(d: dict) -> dict:  # every refused message, decode errors too
        return {k: d.get(f'callback_errors_{k}', 0) - before.get(f'callback_errors_{k}', 0)
                for k in ('joint_states', 'wrench')}
    wait_for(lambda: min(errors(cell.rig.log.diag(CTRL)).values()) > 100,
             'the controller to refuse the fuzz', alive=cell.rig.procs)
    sim_after = cell.rig.log.fresh_diag('sim', alive=cell.rig.procs)
    k_s = [(d['mode'], d.get('stiffness_k_hat'), d.get('stiffness_k_s'))
           for d in cell.rig.log.statuses(CTRL, t0 - 1.0, t1 + 2.0)]
    print(f"fuzz: the plant's command timeouts "
          f"{sim_after['command_timeouts'] - sim_before['command_timeouts']}; mode, k_hat, k_s "
          f'at 1 Hz {k_s}')  # a failure's first figures (a k_s far below k breaks the loop)
    f = cell.check_force(t0, t1 + 1.0, peak=FUZZ_PEAK_N)  # the target: the peak
    after = cell.diag()
    grew = {k: after[k] - before[k] for k in (
        'joint_state_dropped', 'joint_state_implausible', 'joint_state_clock_implausible',
        'wrench_dropped', 'wrench_implausible', 'wrench_clock_implausible')}
    assert all(grew.values()), grew
    assert after['mode'] == 'running', after['message']
    span = cell.injector.fuzz_span[1] - cell.injector.fuzz_span[0]
    print(f'fuzz: sent over {span:.2f} s; refused {grew}, callback errors {errors(after)}; '
          f'force '
          f'{f.min():.3f}..{f.max():.3f} N over {t1 + 1.0 - t0:.1f} s')


def test_swapped_offsets_for_a_whole_run(cell, tmp_path):
    """Restart with joint states 2 s behind and the wrench 2 s ahead: the loop tracks."""
    cell.close()
    other = Cell(tmp_path, -2.0, 2.0)
    try:
        other.start()
        t1 = other.now
        other.check_force(t1 - 1.0, t1)
        d = other.diag()
        assert d['joint_state_clock_offset_s'] == pytest.approx(-2.0, abs=0.02)
        assert d['wrench_clock_offset_s'] == pytest.approx(2.0, abs=0.02)
        fig = other.tracking.figures(t1 - 1.0, t1)
        report_figure(current_test(), **fig)
        check_bounds(fig)  # rms_position_error_m
    finally:
        other.close()
