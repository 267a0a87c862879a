"""
Faults in real time over real DDS (issue 10): the sim on wall time, the controller beside it.

One sim (link masses 50 % off) and one controller run for the module; this process
watches them and injects faults. In order: a frozen force sensor (the sim's
``sensor_frozen``: it repeats its last reading), a 1 s burst of 1e4 N readings published
between the real ones, a 1 s phase of NaN and partial joint states between the real ones,
and the surface dropping 3 cm (the sim's ``surface_point``). Each case asserts
/diagnostics non-OK because of the fault, no effort beyond the limits, contact kept or
regained, the force back within 0.05 N of f_d after the fault's end, and the controller alive;
the times back and the peaks within 5 times the worst measured (test/realtime_bounds.json).
Times are message stamps (the wall clock here); waits have a wall timeout that only guards
against hangs; the figures are printed and handed on (helpers.figures), the exact ones go to
docs/results.md.
"""
from __future__ import annotations

import math

from geometry_msgs.msg import WrenchStamped
from helpers.bounds import check_bounds
from helpers.figures import current_test, report_figure
from helpers.ros import domain_id, wait_for, wait_future
from helpers.watch import RealTimeRig
from hybrid_force_controller.core.model.robot_model import RobotModel
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState


N_W = np.array([0.0, -1.0, 0.0])
F_D, TOL = 1.0, 0.05
# After a frozen sensor the force came back in 0 s in some runs and in 1.8-2.08 s in others.
# Fixed since: safe mode's hold stepped at entry and the tool could leave the surface, and the
# sine ran on during the hold (effort.py SafeHold; the reference pauses). What remains: the
# force loop is blind for state_timeout (0.1 s) before frozen readings count as stale, and a
# fault early in the run, theta_hat still converging, let the force fall to 0.52 N then: 0 to
# 1.58 s in 8 runs, <= 0.09 s with the sine off (docs/results.md). So the bound stays loose.
EFFORT_LIMIT = 100.0  # N m, the bundled URDF's
CTRL = 'hybrid_force_controller'
P0 = RobotModel.from_urdf().kinematics(np.array([0.657, 0.913]), np.zeros(2)).p_W


class _Injector:
    """A 500 Hz timer on the rig's node that publishes ``self.inject()`` while it is set."""

    def __init__(self, rig: RealTimeRig) -> None:
        node = rig.log.node
        self.node, self.inject, self.injected = node, None, 0
        self.pub_js = node.create_publisher(JointState, 'joint_states', 10)
        self.pub_ft = node.create_publisher(WrenchStamped,
                                            'force_torque_sensor_broadcaster/wrench', 10)
        node.create_timer(0.002, self._on_inject)

    def _on_inject(self) -> None:
        make = self.inject
        if make is not None:
            pub, msg = make(self.node.get_clock().now().to_msg())
            pub.publish(msg)
            self.injected += 1


@pytest.fixture(scope='module')
def rig(tmp_path_factory):
    rig = RealTimeRig(tmp_path_factory.mktemp('realtime_faults'), domain_id('realtime_faults'),
                      efforts=True)
    try:
        rig.injector = _Injector(rig)
        rig.start()
        wait_for(lambda: bool(rig.log.statuses(CTRL)), 'the controller to report',
                 alive=rig.procs)
        yield rig
    finally:
        rig.close()


def now(rig: RealTimeRig) -> float:
    return rig.log.latest_t()


def run_until(rig: RealTimeRig, t: float) -> None:
    wait_for(lambda: now(rig) >= t, f'stamp {t:.2f}', alive=rig.procs)


def settled_at(rig: RealTimeRig, t0: float, hold: float = 0.5) -> float:
    """
    Return the first time after ``t0`` from which the force stays within TOL of f_d ``hold`` s.

    Waits for it; fails after 20 s of stamps.
    """
    def found() -> float | None:
        t, f = rig.log.forces(t0)
        if t.size == 0:
            return None
        bad = np.flatnonzero(np.abs(f - F_D) > TOL)
        start = t0 if bad.size == 0 else t[bad[-1]]
        return start if t[-1] - start >= hold else None
    wait_for(lambda: found() is not None or now(rig) > t0 + 20.0, 'the force to settle',
             alive=rig.procs, poll=0.05)
    t = found()
    assert t is not None, f'the force did not settle within 20 s after {t0:.2f}'
    return t


def set_sim(rig: RealTimeRig, **values) -> None:
    result = wait_future(rig.sim_params.set_parameters(
        [Parameter(k, value=v) for k, v in values.items()]))
    assert all(r.successful for r in result.results), result


def fault_case(rig: RealTimeRig, start, stop, duration: float, counter: str) -> dict:
    """Settle, play a fault for ``duration`` s of stamps, and check the common outcome."""
    settled_at(rig, now(rig))
    before = rig.log.statuses(CTRL)[-1]
    t0 = now(rig)
    start()
    try:
        run_until(rig, t0 + duration)
    finally:
        stop()
    t1 = now(rig)
    t_ok = settled_at(rig, t1)
    wait_for(lambda: bool(rig.log.statuses(CTRL, t1 + 0.05)), 'a status after the fault',
             alive=rig.procs)
    during = rig.log.statuses(CTRL, t0, t1 + 1.2)
    after = rig.log.statuses(CTRL, t1 + 0.05)[0]
    _, f_fault = rig.log.forces(t0, t1)
    figures = {'back_s': t_ok - t1, 'f_min': float(f_fault.min()), 'f_max': float(f_fault.max()),
               'f_dev_max': float(np.abs(f_fault - F_D).max()),
               'max_effort': rig.log.max_effort(t0, t_ok), 'levels': [d['level'] for d in during]}
    print(f'{counter}: {figures}')
    report_figure(current_test(), **figures)
    check_bounds(figures, rig.tails())  # back_s, f_dev_max (realtime_bounds.json)
    assert any(d['level'] >= 1 for d in during), during
    assert after[counter] > before[counter], (counter, before, after)
    assert figures['max_effort'] <= EFFORT_LIMIT, figures
    assert all(p.alive for p in rig.procs), rig.tails()
    return after


def test_frozen_force_sensor(rig):
    """1.2 s of one repeated reading: the wrench is stale, the arm holds in safe mode."""
    after = fault_case(rig, lambda: set_sim(rig, sensor_frozen=True),
                       lambda: set_sim(rig, sensor_frozen=False), 1.2, 'safe_mode_entries')
    assert 'frozen' in after['last_safe_reason'], after


def test_burst_of_1e4_newton_between_the_real_readings(rig):
    def burst(stamp):
        msg = WrenchStamped()
        msg.header.stamp, msg.header.frame_id = stamp, 'tool0'
        msg.wrench.force.y = 1e4
        return rig.injector.pub_ft, msg
    after = fault_case(rig, lambda: setattr(rig.injector, 'inject', burst),
                       lambda: setattr(rig.injector, 'inject', None), 1.0, 'wrench_implausible')
    # a reading beyond wrench_limit is refused as such whatever its stamp (an injected
    # stamp may fall behind a real one): the statuses of the burst give that reason
    faults = [d.get('last_input_fault', '') for d in rig.log.statuses(CTRL)]
    assert any('wrench_limit' in f for f in faults), (after, faults[-5:])
    assert not any('older than the last' in f and 'wrench' in f for f in faults), faults


def test_nan_and_partial_joint_states_between_the_real_ones(rig):
    def bad_state(stamp):
        k = rig.injector.injected
        msg = (JointState(name=['joint1', 'joint2'], position=[math.nan, 0.9],
                          velocity=[0.0, 0.0]) if k % 2 else
               JointState(name=['joint1'], position=[0.7], velocity=[0.0]))
        msg.header.stamp = stamp
        return rig.injector.pub_js, msg
    fault_case(rig, lambda: setattr(rig.injector, 'inject', bad_state),
               lambda: setattr(rig.injector, 'inject', None), 1.0, 'joint_state_dropped')


def test_surface_drop_of_3_cm(rig):
    """
    Contact regained by the approach (2.5 cm/s: 1.2 s for 3 cm), impact below 5 f_d.

    Last: the surface stays lower.
    """
    settled_at(rig, now(rig))
    set_sim(rig, surface_point=(P0 + 0.03 * N_W).tolist())
    t_drop = now(rig)
    run_until(rig, t_drop + 0.3)
    t, f = rig.log.forces(t_drop)
    lost = t[f <= 0.05]
    assert lost.size, 'the drop did not break contact'
    wait_for(lambda: (rig.log.forces(lost[0])[1] > 0.1).any() or now(rig) > t_drop + 5.0,
             'contact again', alive=rig.procs)
    t, f = rig.log.forces(lost[0])
    t_back = t[np.argmax(f > 0.1)]
    t_ok = settled_at(rig, t_back) if f.max() > 0.1 else math.nan
    peak = rig.log.forces(t_back, t_back + 1.0)[1].max()
    levels = [d['level'] for d in rig.log.statuses(CTRL, t_drop, t_back + 1.2)]
    figures = {'contact_back_s': t_back - t_drop, 'peak_force_n': peak,
               'settled_after_back_s': t_ok - t_back,
               'max_effort': rig.log.max_effort(t_drop, t_ok)}
    print(f'surface drop: {figures}')
    report_figure(current_test(), **figures)
    assert f.max() > 0.1, 'no contact after the drop'
    check_bounds(figures, rig.tails())  # contact_back_s, settled_after_back_s, peak_force_n
    assert any(level >= 1 for level in levels), levels
    assert figures['max_effort'] <= EFFORT_LIMIT, figures
