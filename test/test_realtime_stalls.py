"""
Recovery from stalls over real DDS, in real time (issue 16).

The sim (masses 50 % off, ``command_timeout`` 0.1 s: zero effort after it, as a torque-
controlled arm's watchdog) and the controller with ``config/params.yaml``. Once the force
has held at f_d, the controller process is frozen (SIGSTOP, then SIGCONT) for 150, 300 and
500 ms, each longer than the watchdog, so the arm falls onto the surface each time; then,
with the surface dropped 3 cm, it is frozen for 300 ms during the approach.

Checks cover the whole run after each release, bounded at 5 times the worst of the measured
runs on one CPU (test/realtime_bounds.json); the exact figures are what ``bench --ros
--freezes 3 --freeze-ms MS`` reports (docs/results.md).
"""
from __future__ import annotations

import time

from helpers.bounds import check_bounds
from helpers.figures import current_test, report_figure
from helpers.ros import domain_id, freeze, wait_for, wait_future
from helpers.watch import assert_clean_run, RealTimeRig
from hybrid_force_controller.tools.bag_io import load_run
from hybrid_force_controller.tools.recovery_figures import recovery_figures
import numpy as np
import pytest
from rclpy.parameter import Parameter


FREEZES_MS = (150.0, 300.0, 500.0)
PEAK_N = 50.0  # issue 30's bound on the approach freeze's peak after SIGCONT
CONTROL_S = 0.2  # the controller has left safe mode this long after its first command back
WINDOW_S = 6.0
F_D = 1.0
P0 = np.array([1.0, 1.6, 0.0])  # the tool at q0 (config/params.yaml), on the surface
N_W = np.array([0.0, -1.0, 0.0])
THETA_TRUE = np.array([0.65, 1.35])  # the sim's link masses (helpers.watch.MASSES_OFF)


def _diag(rig: RealTimeRig, name: str) -> dict:
    return rig.log.fresh_diag(name, rig.procs)


NEAR_S, NEAR_RTOL = 3.0, 0.10  # theta_hat near the sim's masses for this long


def _near(rig: RealTimeRig) -> bool:
    """Say whether every theta_hat row of the last NEAR_S is within NEAR_RTOL of THETA_TRUE."""
    t, theta = rig.log.thetas()
    if t.size < 10 or t[-1] - t[0] < NEAR_S:
        return False
    return bool(np.allclose(theta[t >= t[-1] - NEAR_S], THETA_TRUE, rtol=NEAR_RTOL, atol=0.0))


def _learned(rig: RealTimeRig) -> bool:
    """
    Say whether theta_hat is learned: near the sim's masses, trusted, the force settled.

    Learned is not steady: on the paper's path (x_d = 1 + 0.1 sin t) theta_hat keeps
    swinging around the masses (up to 5 % off, 2-7 % peak to peak over any 2 s, with and
    without two busy loops beside the cell), so a wait for 1 % over 2 s timed out in CI.
    Near for NEAR_S is also not an estimate held by an episode that began before convergence
    (seen under taskset -c 0): that one sits at an early calm stretch's value, off the masses.
    """
    return (rig.settled(F_D, hold_s=1.0) and _near(rig)
            and rig.log.diag('hybrid_force_controller').get('theta_trusted', 'none') != 'none')


def _learning(rig: RealTimeRig) -> str:
    """Say where each condition of :func:`_learned` stands (for a wait that timed out)."""
    t_th, theta = rig.log.thetas()
    return (f'theta_hat learned and trusted: settled {rig.settled(F_D, hold_s=1.0)}, near '
            f'{_near(rig)}, theta_hat {theta[-1] if len(theta) else None} '
            f'(true {THETA_TRUE}), trusted '
            f"{rig.log.diag('hybrid_force_controller').get('theta_trusted', 'none')!r}")


def _run_past(rig: RealTimeRig, t: float) -> None:
    wait_for(lambda: rig.log.latest_t() > t, f'the force log past {t:.1f}', alive=rig.procs)


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    """One real-time run: theta_hat learned, three freezes, a freeze during an approach."""
    tmp = tmp_path_factory.mktemp('stalls')
    rig = RealTimeRig(tmp, domain_id('realtime_stalls'), efforts=True,
                      ctrl_args=['-p', f'flight_recorder_dir:={tmp / "flight"}'])
    try:
        rig.start()  # the masses are learned in about 8 s; then theta_hat holds still
        wait_for(lambda: _learned(rig), lambda: _learning(rig), alive=rig.procs)
        sim0, freezes = _diag(rig, 'sim'), []
        for ms in FREEZES_MS:
            wait_for(lambda: rig.settled(F_D, hold_s=1.0), 'calm before the freeze',
                     alive=rig.procs)
            freezes.append((ms, *freeze(rig.ctrl, ms * 1e-3)))
            _run_past(rig, freezes[-1][2] + WINDOW_S + 0.2)
        sim1, ctrl1 = _diag(rig, 'sim'), _diag(rig, 'hybrid_force_controller')
        drop = rig.sim_params.set_parameters(
            [Parameter('surface_point', value=(P0 + 0.03 * N_W).tolist())])
        assert wait_future(drop).results[0].successful
        t_drop = time.time()
        wait_for(lambda: rig.log.forces(t_drop)[1].size > 50, 'forces after the drop',
                 alive=rig.procs)
        wait_for(lambda: rig.log.latest_t() > t_drop + 0.4, 'into the approach',
                 alive=rig.procs)
        approach = (t_drop, *freeze(rig.ctrl, 0.3))
        _run_past(rig, approach[2] + 3.0)
        yield {'rig': rig, 'freezes': freezes, 'sim0': sim0, 'sim1': sim1, 'ctrl1': ctrl1,
               'approach': approach, 'flight': tmp / 'flight'}
    finally:
        rig.close()


def _figures(run, k: int) -> dict:
    rig = run['rig']
    ms, t_stop, t_release = run['freezes'][k]
    t, f = rig.log.forces(t_stop - 1.0, t_release + WINDOW_S)
    t_th, th = rig.log.thetas()
    fig = recovery_figures(t, f, t_stop, t_release, F_D, t_th, th, WINDOW_S)
    print(f'freeze {ms:.0f} ms: {fig}')
    report_figure(current_test(), freeze_ms=ms, **fig)
    return fig


def test_every_freeze_drops_the_arm_on_the_plant_watchdog(run):
    timeouts = run['sim1']['command_timeouts'] - run['sim0']['command_timeouts']
    assert timeouts >= len(FREEZES_MS), run['rig'].sim.tail()
    assert run['ctrl1']['episodes_stall'] >= len(FREEZES_MS)  # seen in its own tick times
    assert run['ctrl1']['stalls'] >= len(FREEZES_MS)
    # trusted by then: the freezes held it, none was provisional; the sine stays off full reach
    assert run['ctrl1']['episode_provisional'] is False and run['ctrl1']['singular_ticks'] == 0
    # a frozen controller may find its inputs stale when it resumes (safe mode): not counted
    assert_clean_run(run['ctrl1'], run['sim1'], safe_mode_entries=None,
                     run=run['rig'].log.statuses('hybrid_force_controller'))


@pytest.mark.parametrize('k', range(len(FREEZES_MS)), ids=[f'{m:.0f}ms' for m in FREEZES_MS])
def test_the_force_comes_back_and_theta_hat_holds(run, k):
    """
    Issue 16's targets are 1 s, 10 %, 0.05 N; bounded at 5x the worst measured.

    back_s, theta_change and rms_force_error_n (realtime_bounds.json). The peak is the fall's
    (the arm falls while the torque is off): it must be there, its size is the plant's.
    """
    fig = _figures(run, k)
    assert fig['peak_force_n'] > 3.0, fig  # the arm fell while the torque was off
    check_bounds(fig)


def test_a_freeze_during_an_approach_ends_on_the_surface(run):
    """
    The surface dropped 3 cm; frozen 300 ms into the approach: back in contact, on it at the end.

    The time back in contact is bounded at 5 times the worst measured (realtime_bounds.json).
    The controller's peak is bounded at PEAK_N (issue 30's target; 5 times the worst of the
    42 runs of docs/results.md section 18, 33.7 N, would be looser): the largest true force
    from CONTROL_S after its commands came back after SIGCONT, once it has left safe mode. Before
    that the force is the fall's: the arm fell onto the surface at zero effort during the
    freeze (25-48 N), the controller sends nothing until its inputs are current (catch_up.py,
    (C1)), then holds for 50 ms: printed, not bounded. The bound is for what the runtime did
    before docs/results.md section 16's fixes (426-512 N at the effort limits), and before
    section 30's (420-785 N half a second after SIGCONT in 3 of 5 CI runs, or the arm flung
    off the surface: then the end of the window fails).
    """
    rig = run['rig']
    t_drop, _, t_release = run['approach']
    t, f = rig.log.forces(t_drop)
    assert (f[t < t_release] < 0.05).any(), 'the drop did not break contact'
    back = (t > t_release) & (f > 0.1)
    # back: its 20th command after SIGCONT (the first few can be commands sent before the
    # freeze that the middleware held: 4 ms after SIGCONT, while the runtime sent nothing)
    t_cmd = rig.log.command_after(t_release, k=20)
    assert np.isfinite(t_cmd), 'no command after SIGCONT'
    after = t > t_cmd + CONTROL_S
    tail, peak = float(f[t > t_release].max()), float(f[after].max())
    t_peak = float(t[after][np.argmax(f[after])] - t_release)
    print(f'freeze in an approach: contact {t[np.argmax(back)] - t_release:.3f} s after '
          f"SIGCONT, the fall's tail {tail:.2f} N, commands back at {t_cmd - t_release:.3f} s, "
          f'then peak {peak:.2f} N at {t_peak:.3f} s' if back.any() else 'no contact')
    report_figure(current_test(), contact_back_s=(float(t[np.argmax(back)] - t_release)
                                                  if back.any() else None),
                  tail_force_n=tail, peak_force_n=peak, peak_after_s=t_peak,
                  commands_back_s=float(t_cmd - t_release))
    assert back.any(), 'no contact after SIGCONT'
    check_bounds({'contact_back_s': float(t[np.argmax(back)] - t_release)})
    end = (t > t_release + 2.5) & (t <= t_release + 3.0)
    assert end.any() and np.all(f[end] > 0.1), (  # on the surface at the end, not bounced off
        f'{f[end]} N at 2.5-3 s after SIGCONT; flight logs in {run["flight"]}')
    assert peak <= PEAK_N, f'peak {peak:.1f} N after SIGCONT; flight logs in {run["flight"]}'
    assert run['ctrl1']['lifecycle_state'] == 'active'


def test_the_freezes_leave_readable_flight_logs(run):
    """Each freeze is a stall the flight recorder dumps: bags that load_run reads."""
    bags = sorted(p for p in run['flight'].glob('flight_*') if p.is_dir())
    assert bags, f'no flight log in {run["flight"]}'
    assert any('stall' in p.name or 'safe_mode' in p.name for p in bags), bags
    for bag in bags:
        log = load_run(bag)
        assert 0 < log.t.size <= 2000 and np.all(np.isfinite(log.x_W)), bag  # <= 2 s
