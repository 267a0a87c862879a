"""
Wrong inputs a real cell sends, offline (issue 25): stamps off the controller's clock, joint jumps.

* :class:`SenderClock` (core/runtime/sender_clock.py) alone: a stamp beyond ``max_clock_skew``
  or jumping from its sender's offset is refused with the reason and never learned from; a
  constant offset of a few seconds is removed with the stamps' differences kept; a clock that
  steps is re-learned after ``relearn_after``; one that drifts is followed.
* :class:`JointInput` (core/runtime/inputs.py): a position step beyond what the velocities
  explain plus ``max_joint_jump``, or a velocity beyond the URDF limit times the margin, is
  refused (:class:`ImplausibleJointState`) and never becomes the reference.
* The runtime in closed loop through the loop engine (the paper's scenario, masses 50 % off),
  each message given a reception time (the plant's time: lockstep) by the input hook: the faults
  of the issue leave the run as the clean one, and without the checks (negative controls) the
  hour-ahead wrench locks the wrench out (safe mode for good) and the glitch reaches the law.
"""
from __future__ import annotations

import math

from hybrid_force_controller.core.config.params import build_params, ParameterValidationError
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.engine import LoopEngine
from hybrid_force_controller.core.offline.environment import ElasticSurface
from hybrid_force_controller.core.offline.scenario import PAPER_Q0
from hybrid_force_controller.core.offline.simulator import ArmSimulator
from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime, InputError
from hybrid_force_controller.core.runtime.inputs import (ImplausibleJointState, JointInput,
                                                         JointSample)
from hybrid_force_controller.core.runtime.sender_clock import (ImplausibleStamp, RATE_DOWN,
                                                               SenderClock)
import numpy as np
import pytest


Q0 = np.array(PAPER_Q0)
T0 = 1.7e9  # a wall-clock stamp, s
HOUR = 3600.0


# ---------------------------------------------------------------- SenderClock
def feed(clock: SenderClock, offset: float, t0: float, n: int, latency=lambda k: 2e-4,
         period: float = 1e-3) -> list[float]:
    """Feed n messages sampled every period from t0 by a sender whose clock is ``offset`` ahead."""
    out = []
    for k in range(n):
        t_sample = t0 + k * period
        out.append(clock.receive(t_sample + offset, t_sample + latency(k)))
    return out


@pytest.mark.parametrize('skew', [HOUR, 60.0, -HOUR, -60.0, math.nan])
def test_stamp_beyond_max_clock_skew_is_refused_and_never_learned(skew):
    clock = SenderClock('wrench', 10.0, 0.1, 0.2)
    with pytest.raises(ImplausibleStamp, match=r"wrench stamp is .* the controller's clock "
                       r'\(max_clock_skew 10 s\)') as exc:
        clock.receive(T0 + skew, T0)
    if skew == HOUR:
        assert '3600 s ahead of' in str(exc.value)
    assert clock.offset is None  # not learned from
    assert clock.receive(T0 + 1e-3, T0 + 1.2e-3) == T0 + 1.2e-3  # the first good one: learned


@pytest.mark.parametrize('offset', [2.0, -2.0, 0.0])
def test_constant_offset_is_removed_and_stamp_differences_kept(offset):
    clock = SenderClock('joint state')
    rng = np.random.default_rng(1)
    lat = 2e-4 + 3e-4 * rng.random(5000)  # 0.2-0.5 ms transport
    t = np.array(feed(clock, offset, T0, 5000, lambda k: lat[k]))
    recv = T0 + 1e-3 * np.arange(5000) + lat
    assert np.all(t <= recv + 5e-4)  # never dated after it arrived (+ half a period)
    steady = np.diff(t[2000:])  # after the learning second: the stamps' differences
    assert np.max(np.abs(steady - 1e-3)) < 2.5e-6  # 0.25 % of a period
    assert np.all(recv[2000:] - t[2000:] < 4e-4)  # staleness: about the transport delay
    assert abs(clock.offset - (offset - 2e-4)) < 1e-4  # the offset less the fastest transport


def test_slow_first_message_is_forgotten_within_the_learning_second():
    clock = SenderClock('wrench')
    t = feed(clock, 2.0, T0, 1000, lambda k: 0.03 if k == 0 else 2e-4)
    # by 0.4 s the stamps' differences, to float resolution (2.4e-7 s at 1.7e9 s)
    assert np.max(np.abs(np.diff(t[400:]) - 1e-3)) < 5e-7


@pytest.mark.parametrize('late', [0.15, 0.333])
def test_a_first_message_held_up_costs_one_refused_message(late):
    """
    The first sample 150 or 333 ms late (Fast DDS's first send to a new reader can sleep).

    The second looks that much early and is refused; the third agrees with it: the offset is
    learned again, and the samples after it are dated by their stamps.
    """
    clock = SenderClock('joint state', 10.0, 0.1, 0.2)
    refused, out = [], []
    for k in range(600):
        t_s = T0 + k * 1e-3
        try:
            out.append(clock.receive(t_s + 2.0, t_s + (late if k == 0 else 2e-4)))
        except ImplausibleStamp:
            refused.append(k)
    assert refused == [1] and clock.relearns == 1 == clock.startup_refusals
    assert abs(clock.offset - (2.0 - 2e-4)) < 1e-4
    assert np.max(np.abs(np.diff(out[3:]) - 1e-3)) < 1e-5


def test_a_backlog_delivered_in_a_burst_costs_one_refusal_per_state_timeout_of_it():
    """
    333 ms of samples held up, then delivered at once (10 us apart), then on time.

    Through the burst each skew is 1 ms more than the one before: every ``tolerance`` (0.1 s)
    of backlog one sample is refused and the next relearns, so 333 ms cost 3 refused samples,
    each ended in a relearn (s51k refused 3 per stream of a clean cell), and the stream goes on.
    """
    clock = SenderClock('wrench', 10.0, 0.1, 0.2)
    refused = []
    for k in range(1000):
        t_s = T0 + k * 1e-3
        t_r = T0 + 0.333 + k * 1e-5 if k < 333 else t_s + 2e-4
        try:
            clock.receive(t_s - 2.0, t_r)
        except ImplausibleStamp:
            refused.append(k)
    assert len(refused) == clock.relearns == clock.startup_refusals == 3, refused
    assert max(refused) < 333, refused
    assert abs(clock.offset - (-2.0 - 2e-4)) < 1e-3


def test_the_dates_never_go_back_not_even_at_a_relearn():
    """
    A relearned sample is dated when it arrived, but never before the stream's last date.

    In the burst above each accepted sample is dated half a period after it arrived (its stamp
    says later: the lead's cap), and the relearned one 10 us after it: dated at its arrival it
    was older than the last one and the runtime dropped it (s58g: one joint state and one
    wrench of a clean cell, 0.27 ms back).
    """
    clock = SenderClock('wrench', 10.0, 0.1, 0.2)
    dates = []
    for k in range(333):  # the burst, received 10 us apart
        try:
            dates.append(clock.receive(T0 + k * 1e-3 - 2.0, T0 + 0.333 + k * 1e-5))
        except ImplausibleStamp:
            pass
    assert clock.relearns == 3
    assert np.all(np.diff(dates) >= 0.0), np.flatnonzero(np.diff(dates) < 0.0)


def test_after_the_learning_second_two_agreeing_jumps_are_still_refused():
    """Past LEARN_S a jump needs relearn_after (0.2 s) of agreement, as before."""
    clock = SenderClock('joint state', 10.0, 0.1, 0.2)
    feed(clock, 1.0, T0, 1500)
    for k in range(2):
        t_s = T0 + 1.5 + k * 1e-3
        with pytest.raises(ImplausibleStamp, match=r'jumps 0\.500\d* s ahead'):
            clock.receive(t_s + 1.5, t_s)
    assert clock.relearns == 0


@pytest.mark.parametrize('ppm', [100.0, -100.0])
def test_a_drifting_sender_clock_is_followed(ppm):
    """100 s of a sender clock running 100 ppm fast or slow: 10 ms, followed, none refused."""
    clock = SenderClock('joint state')
    t_recv = T0 + np.arange(0.0, 100.0, 2e-3)
    stamps = t_recv - 2e-4 + 1.5 + (t_recv - T0) * ppm * 1e-6
    out = np.array([clock.receive(s, r) for s, r in zip(stamps, t_recv)])
    assert np.all(t_recv - out < 2e-3)  # never stale by the drift
    assert abs(clock.offset - (stamps[-1] - t_recv[-1])) < 1e-4


def test_a_stamp_that_jumps_is_refused_and_never_becomes_the_last():
    clock = SenderClock('wrench', 10.0, 0.1, 0.2)
    feed(clock, 2.0, T0, 100)
    with pytest.raises(ImplausibleStamp, match=r'wrench stamp jumps 5 s ahead of its sender'):
        clock.receive(T0 + 0.1 + 2.0 + 5.0, T0 + 0.1)
    with pytest.raises(ImplausibleStamp, match=r'jumps 0.4998 s behind'):
        clock.receive(T0 + 0.1 + 2.0 - 0.5, T0 + 0.1)
    t = clock.receive(T0 + 0.101 + 2.0, T0 + 0.101 + 2e-4)
    assert abs(t - (T0 + 0.1012)) < 1e-5  # the next good one as before (+ transport)
    assert clock.startup_refusals == 2 and clock.relearns == 0  # in the stream's first second


@pytest.mark.parametrize('step', [5.0, -5.0])
def test_a_clock_step_is_relearned_after_relearn_after(step):
    """
    An NTP step of the sender: refused for relearn_after (0.2 s), then the new offset.

    After the stream's learning second (in it, two refused in a row that agree re-learn).
    """
    clock = SenderClock('joint state', 10.0, 0.1, 0.2)
    feed(clock, 1.0, T0, 1500)
    refused, accepted = [], []
    for k in range(1500, 2000):
        t_s = T0 + k * 1e-3
        try:
            accepted.append((t_s, clock.receive(t_s + 1.0 + step, t_s + 2e-4)))
        except ImplausibleStamp:
            refused.append(t_s)
    assert refused[-1] - refused[0] == pytest.approx(0.2, abs=2e-3)  # locked out 0.2 s only
    assert clock.relearns == 1 and len(accepted) == 500 - len(refused)
    assert clock.startup_refusals == 0  # after the first second: the sender's clock, not DDS
    assert np.max(np.abs(np.diff([t for _, t in accepted][10:]) - 1e-3)) < 1e-5


def test_garbage_among_good_messages_is_never_relearned():
    clock = SenderClock('wrench', 10.0, 0.1, 0.2)
    rng = np.random.default_rng(0)
    for k in range(2000):
        t_s = T0 + k * 1e-3
        clock.receive(t_s + 2.0, t_s + 2e-4)
        with pytest.raises(ImplausibleStamp):
            clock.receive(t_s + 2.0 + float(rng.choice([-1, 1]) * rng.uniform(0.2, 9.0)),
                          t_s + 3e-4)
    assert clock.relearns == 0 and abs(clock.offset - (2.0 - 2e-4)) < 1e-4


def test_max_clock_skew_zero_passes_stamps_through():
    clock = SenderClock('wrench', 0.0, 0.1, 0.2)
    assert clock.receive(T0 + HOUR, T0) == T0 + HOUR and clock.offset is None


def test_one_stray_message_moves_the_offset_by_microseconds_only():
    clock = SenderClock('wrench')
    feed(clock, 0.0, T0, 3000)
    before = clock.offset
    clock.receive(T0 + 3.0 + 0.09, T0 + 3.0)  # 90 ms early: within tolerance, accepted...
    assert abs(clock.offset - before) <= 2e-3 * 1e-3 + 1e-12  # ...moving d_hat 2 us at most
    assert clock.receive(T0 + 3.001 + 0.0, T0 + 3.0012) <= T0 + 3.0012
    assert RATE_DOWN < 1e-3


# ---------------------------------------------------------------- JointInput
NAMES = ['joint1', 'joint2']


def joints(max_jump=0.01, margin=1.5, limits=(10.0, 10.0), accel=1000.0) -> JointInput:
    j = JointInput(NAMES, NAMES)
    j.configure_checks(np.array(limits), margin, max_jump, accel, 0.2)
    return j


def test_position_step_beyond_the_velocities_is_refused_with_the_reason():
    j = joints()
    last = j.sample(NAMES, Q0, [1.0, 0.0], 0.0, None)
    good = j.sample(NAMES, Q0 + [1e-3, 0.0], [1.0, 0.0], 1e-3, last)  # 1 rad/s for 1 ms
    with pytest.raises(ImplausibleJointState, match=r'joint1 moved \+0.2 in 1 ms, 0.199 more '
                       r'than its velocities allow \(max_joint_jump 0.01\)'):
        j.sample(NAMES, good.q + [0.2, 0.0], [1.0, 0.0], 2e-3, good)
    # against the last accepted one (the refused one is no reference): the next is fine
    j.sample(NAMES, good.q + [1e-3, 0.0], [1.0, 0.0], 2e-3, good)


def test_fast_consistent_motion_and_a_jump_after_a_gap_are_accepted():
    j = joints()
    last = j.sample(NAMES, Q0, [8.0, -8.0], 0.0, None)
    s = j.sample(NAMES, Q0 + [0.08, -0.08], [8.0, -8.0], 0.01, last)  # 8 rad/s for 10 ms
    j.sample(NAMES, s.q + [0.3, 0.0], [0.0, 0.0], 0.01 + 0.2001, s)  # after the gap


def test_the_position_bound_grows_with_the_gap_as_the_acceleration_allows():
    """
    (J1) max_jump + max_accel dt^2 / 4: a fall onto the surface and its bounce, 80 ms skipped.

    The velocity reversed (0.6 rad/s down, then up): the trapezoid says nothing moved, and the
    fixed bound refused the state and every one after it for 2 state_timeout.
    """
    j, dt = joints(accel=30.0), 0.08  # 0.01 + 30 * 0.08^2 / 4 = 0.058 rad
    last = j.sample(NAMES, Q0, [-0.6, 0.0], 0.0, None)
    j.sample(NAMES, Q0 + [-0.057, 0.0], [0.6, 0.0], dt, last)
    with pytest.raises(ImplausibleJointState, match='joint1 moved -0.059 in 80 ms'):
        j.sample(NAMES, Q0 + [-0.059, 0.0], [0.6, 0.0], dt, last)
    rest = j.sample(NAMES, Q0, [0.0, 0.0], 0.0, None)
    with pytest.raises(ImplausibleJointState):  # 1 ms apart: 0.01 + 7.5e-6
        j.sample(NAMES, Q0 + [-0.0101, 0.0], [0.0, 0.0], 1e-3, rest)


@pytest.mark.parametrize('v', [15.1, -15.1, 100.0])
def test_velocity_beyond_the_urdf_limit_times_the_margin_is_refused(v):
    j = joints()
    with pytest.raises(ImplausibleJointState, match=r"joint2's velocity .* beyond its URDF "
                       r'limit 10 x joint_velocity_margin 1.5'):
        j.sample(NAMES, Q0, [0.0, v], 0.0, None)
    j.sample(NAMES, Q0, [0.0, math.copysign(14.9, v)], 0.0, None)


def test_joints_without_a_urdf_limit_and_zero_settings_are_not_checked():
    j = joints(limits=(np.inf, 0.0))
    j.sample(NAMES, Q0, [1e3, 1e3], 0.0, None)
    j = joints(max_jump=0.0, margin=0.0, accel=0.0)
    last = j.sample(NAMES, Q0, [1e3, 0.0], 0.0, None)
    j.sample(NAMES, Q0 + 1.0, [0.0, 0.0], 1e-3, last)


def test_a_velocity_jump_beyond_max_joint_acceleration_is_refused():
    """A velocity discontinuity (libfranka's reflex): 1000 rad/s^2 allows 1 rad/s per ms."""
    j = joints()
    last = j.sample(NAMES, Q0, [0.2, 0.0], 0.0, None)
    with pytest.raises(ImplausibleJointState, match=r"joint1's velocity changed by \+1.4 in 1 ms "
                       r'\(max_joint_acceleration 1000\)'):
        j.sample(NAMES, Q0 + [8e-4, 0.0], [1.6, 0.0], 1e-3, last)  # x8: a bit of the exponent
    j.sample(NAMES, Q0 + [3e-4, 0.0], [0.4, 0.0], 1e-3, last)  # 200 rad/s^2: accepted


def test_joint_velocity_margin_below_one_is_refused():
    model = RobotModel.from_urdf()
    with pytest.raises(ParameterValidationError, match='joint_velocity_margin must be 0'):
        build_params(model, {'joint_velocity_margin': 0.5})


# ---------------------------------------------------------------- the runtime, closed loop
class Run:
    """
    The paper's scenario (masses 50 % off) through the loop engine, with reception times.

    Every message gets the plant's time of its step as ``t_recv``; the sender's stamps are
    ``offsets`` ahead; ``faults[k]`` (a step) is a function ``(rt, t, msg) -> msg | None``
    that may send extra messages first and returns what is delivered then.
    """

    def __init__(self, model: RobotModel, duration: float, offsets=(0.0, 0.0), faults=None,
                 **overrides) -> None:
        params = build_params(model, overrides)
        self.rt = ControllerRuntime(model, params)
        p0 = model.kinematics(Q0, np.zeros(2)).p_W
        plant = ArmSimulator(model.with_theta(np.array([0.65, 1.35])),
                             ElasticSurface.create(1700.0, p0, params.law.n), Q0, substeps=2)
        self.offsets, self.faults = offsets, dict(faults or {})
        self.log = LoopEngine(self.rt, plant, duration, input_hook=self._deliver).run()
        self.f = -self.log.f_true_W[:, 1]

    def _deliver(self, t: float, msg):
        fault = self.faults.pop(round(t * 1e3), None)
        if fault is not None:
            msg = fault(self.rt, t, msg)
        if msg is not None:
            q, qdot, F_S = msg
            send(lambda: self.rt.on_joint_state(NAMES, q, qdot, t + self.offsets[0], t))
            send(lambda: self.rt.on_wrench('tool0', F_S, t + self.offsets[1], t))
        return None  # delivered here


def send(call) -> None:
    try:
        call()
    except InputError:
        pass  # refused and counted, as the node's guard does


def wrench_at(stamp_offset: float):
    def fault(rt, t, msg):
        send(lambda: rt.on_wrench('tool0', msg[2], t + stamp_offset, t))
        return msg
    return fault


def state_at(stamp_offset: float, dq=(0.0, 0.0), dv=(0.0, 0.0)):
    def fault(rt, t, msg):
        send(lambda: rt.on_joint_state(NAMES, msg[0] + dq, msg[1] + dv, t + stamp_offset, t))
        return msg
    return fault


def glitch(dq):
    """Replace the step's joint state by one with ``dq`` added (an encoder glitch)."""
    return lambda rt, t, msg: (msg[0] + dq, msg[1], msg[2])


@pytest.fixture(scope='module')
def clean(model) -> Run:
    return Run(model, 3.0)


def test_the_issues_faults_leave_the_run_as_the_clean_one(model, clean):
    """
    One run: wrench and joint state an hour and a minute ahead, a velocity beyond the limit.

    All refused, named and counted; the run is the clean one bit for bit.
    """
    faults = {1000: wrench_at(HOUR), 1300: wrench_at(60.0), 1600: state_at(HOUR),
              1900: state_at(60.0), 2200: state_at(0.0, dv=(0.0, 40.0))}
    run = Run(model, 3.0, faults=faults)
    c = run.rt.counters
    assert c['wrench_clock_implausible'] == 2 and c['joint_state_clock_implausible'] == 2
    assert c['joint_state_implausible'] == 1 and c['safe_mode_entries'] == 0
    assert np.array_equal(run.f, clean.f) and np.array_equal(run.log.tau, clean.log.tau)
    assert "joint2's velocity" in run.rt.last_fault and 'URDF limit' in run.rt.last_fault


def test_a_glitch_of_0_2_rad_is_refused_and_the_force_holds(model, clean):
    run = Run(model, 3.0, faults={2000: glitch(np.array([0.2, 0.0]))})
    assert run.rt.counters['joint_state_implausible'] == 1
    assert 'joint1 moved +0.2' in run.rt.last_fault
    assert np.max(np.abs(run.f - clean.f)) < 0.01  # one state lost, no more


def test_without_the_joint_check_the_glitch_reaches_the_law(model, clean):
    """
    Negative control: max_joint_jump 0 and no velocity check.

    The force moves by 0.33 N (0.01 N with the check; more than 0.5 N before the stiffness
    estimate refused spikes of x_n, (S10), which this glitch also is).
    """
    run = Run(model, 2.3, faults={2000: glitch(np.array([0.2, 0.0]))}, max_joint_jump=0.0)
    assert run.rt.counters['joint_state_implausible'] == 0
    assert np.max(np.abs(run.f - clean.f[:run.f.size])) > 0.2


def test_without_the_clock_check_an_hour_ahead_wrench_locks_the_wrench_out(model, clean):
    """
    Negative control (max_clock_skew 0: stamps used as they come), the issue's first fault.

    Every later wrench is older than the hour-ahead one: the force loop runs on that one
    reading, contact is lost (with the check: the clean run, above).
    """
    run = Run(model, 3.0, faults={1000: wrench_at(HOUR)}, max_clock_skew=0.0)
    assert run.rt.counters['wrench_dropped'] >= 1999
    assert 'older than the last' in run.rt.last_fault
    assert run.f[1500:].min() < 0.05  # contact lost
    assert np.sqrt(np.mean((run.f[1000:] - 1.0) ** 2)) > 0.3 > np.sqrt(
        np.mean((clean.f[1000:] - 1.0) ** 2))


def test_without_the_clock_check_an_hour_ahead_joint_state_freezes_the_arm_state(model):
    """Negative control: the law acts on that one state for the rest of the run."""
    run = Run(model, 3.0, faults={1000: state_at(HOUR)}, max_clock_skew=0.0)
    assert run.rt.counters['joint_state_dropped'] >= 1999
    assert run.f[1000:].max() > 10.0


def test_sensor_clocks_two_seconds_off_for_the_whole_run(model, clean):
    """Joint states 2 s ahead, the wrench 2 s behind: the run is the clean one (to rounding)."""
    run = Run(model, 3.0, offsets=(2.0, -2.0))
    assert sum(run.rt.counters[k] for k in ('joint_state_clock_implausible',
                                            'wrench_clock_implausible', 'safe_mode_entries')) == 0
    assert np.max(np.abs(run.f - clean.f)) < 1e-6
    offsets = run.rt.clock_offsets()
    assert offsets == {'joint_state': pytest.approx(2.0), 'wrench': pytest.approx(-2.0)}


def test_a_burst_of_jumped_states_longer_than_state_timeout_is_safe_mode_then_adopted(model):
    """
    The arm moved while the driver restarted: every state 0.2 rad off from 0.5 s on.

    Refused: the inputs go stale after state_timeout (safe mode); 2 state_timeout after the
    last accepted state the new position is adopted, and the runtime leaves safe mode by itself.
    (At 10 rad/s^2 no motion explains 0.2 rad within 0.2 s, (J1); at the default 1000 rad/s^2
    one does after 28 ms, and the burst is then adopted as motion.)
    """
    rt = ControllerRuntime(model, build_params(model, {'max_joint_acceleration': 10.0}))
    kin = model.kinematics(Q0, np.zeros(2))
    F = kin.R_W_ee.T @ np.array([0.0, 1.0, 0.0])  # 1 N into the surface, in tool0
    modes, refused = [], []
    for k in range(1000):
        t = k * 1e-3
        q = Q0 + ([0.2, 0.0] if t >= 0.5 else 0.0)
        try:
            rt.on_joint_state(NAMES, q, np.zeros(2), t, t)
        except ImplausibleJointState:
            refused.append(t)
        rt.on_wrench('tool0', F * (1.0 + 1e-3 * math.sin(k)), t, t)  # not frozen
        modes.append(rt.tick(t).mode.value)
    assert refused[0] == pytest.approx(0.5)
    assert refused[-1] - refused[0] == pytest.approx(0.2, abs=2e-3)
    assert 'safe' not in modes[:600] and set(modes[610:690]) == {'safe'} and modes[-1] != 'safe'
    assert rt.counters['safe_mode_entries'] == 1


def test_clock_offset_warnings_once_per_stream():
    from hybrid_force_controller.ros.controller.diagnostics import clock_offset_warnings
    warned: set = set()
    out = clock_offset_warnings({'joint_state': 1e-4, 'wrench': 2.0}, warned)
    assert len(out) == 1 and 'wrench stamps are 2.000 s ahead of' in out[0]
    out = clock_offset_warnings({'joint_state': -0.3, 'wrench': 2.0}, warned)
    assert len(out) == 1 and 'joint state stamps are 0.300 s behind' in out[0]
    assert clock_offset_warnings({'joint_state': -0.3, 'wrench': math.nan}, warned) == []


def test_joint_sample_is_a_reference_only_when_accepted():
    j = joints()
    a = j.sample(NAMES, Q0, [0.0, 0.0], 0.0, None)
    with pytest.raises(ImplausibleJointState):
        j.sample(NAMES, Q0 + [0.2, 0.0], [0.0, 0.0], 1e-3, a)
    b = j.sample(NAMES, Q0 + [1e-5, 0.0], [0.0, 0.0], 2e-3, a)
    assert isinstance(b, JointSample) and b.t == 2e-3
