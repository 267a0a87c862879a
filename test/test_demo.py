"""
The README's main command end to end: demo -> MCAP bag -> report (real DDS).

Run twice: the default (real time, as the README runs it: loose bounds, the machine may be
loaded; the rates it recorded are printed and handed on, not asserted) and ``--lockstep``
(deterministic: exact message counts and the paper's figures). Both runs are clean: the last
statuses in the bag count no callback error and no safe mode.
"""
import json
import os
from pathlib import Path
import re
import subprocess
import sys

from helpers.bounds import check_bounds
from helpers.figures import current_test, report_figure
from helpers.pins import check_pinned, numbers
from helpers.ros import domain_id, ISOLATED, parse_diagnostics
from helpers.watch import assert_clean_run
from hybrid_force_controller.tools.bag_io import load_run, RECORD_TOPICS
import numpy as np
import pytest
from rosbags.highlevel import AnyReader


REPO = Path(__file__).resolve().parents[1]
DURATION_S = 10.0  # the metrics start at 5 s: 5 s of them
RATE_HZ = 1000.0
TELEMETRY_HZ = 100.0  # telemetry_rate_hz in config/params.yaml
DEMO_DOMAIN_ID = str(domain_id('demo'))


@pytest.fixture(scope='module', params=['real_time', 'lockstep'])
def demo_run(tmp_path_factory, request) -> Path:
    out = tmp_path_factory.mktemp(f'demo_{request.param}')
    mode = ['--lockstep'] if request.param == 'lockstep' else []
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=DEMO_DOMAIN_ID,
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')]),
               **ISOLATED)  # as a user runs it: the cell domain behind the gateway
    proc = subprocess.run([sys.executable, '-m', 'hybrid_force_controller.ros.programs.demo',
                           '--duration', str(DURATION_S), '--out', str(out), *mode],
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert f'bag:     {out / "bag"}' in proc.stdout
    assert 'fig6_stiffness.png' in proc.stdout.splitlines()[-2]  # figures: ... every one
    return out, request.param


RATES = (('/joint_states', RATE_HZ), ('/effort_controller/commands', RATE_HZ),
         ('/hybrid_force_controller/x', TELEMETRY_HZ),
         ('/hybrid_force_controller/wrench', TELEMETRY_HZ),
         ('/sim/contact_wrench', TELEMETRY_HZ))


def test_demo_bag_has_expected_topics_types_and_counts(demo_run):
    out, mode = demo_run
    times: dict[str, list[int]] = {topic: [] for topic, _ in RATES}
    stamps: dict[str, list[int]] = {topic: [] for topic, _ in RATES}
    with AnyReader([out / 'bag']) as reader:
        found = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
        conns = [c for c in reader.connections if c.topic in times]
        for conn, log_ns, raw in reader.messages(connections=conns):
            times[conn.topic].append(log_ns)
            header = getattr(reader.deserialize(raw, conn.msgtype), 'header', None)
            if header is not None:
                stamps[conn.topic].append(header.stamp.sec * 10**9 + header.stamp.nanosec)
    assert set(found) == {topic for topic, _ in RECORD_TOPICS}
    for topic, msgtype in RECORD_TOPICS:
        assert found[topic][0] == msgtype, topic
    # the rate on the recorder's clock is this machine's speed (also in lockstep, which may run
    # slower or faster than real time; in real time a backlog delivered at once shortens the
    # span: 110.8 Hz read for the 100 Hz telemetry in a CI run): printed and handed on; every
    # topic was recorded, no stamped message twice. Lockstep: one joint state per step, over
    # DURATION_S of sim time (the recording may run on past it while it stops); each other
    # topic never more than its share of the steps, and at least half of it: a recorder that
    # the machine cannot run keeps up to its queue and loses the rest, as rosbag2 does (0.80
    # of the commands seen on one CPU)
    rates, shares = {}, {}
    for topic, rate in RATES:
        t = np.array(times[topic]) * 1e-9
        assert t.size > 1, (topic, t.size)
        rates[topic] = (t.size - 1) / (t[-1] - t[0])
        assert len(set(stamps[topic])) == len(stamps[topic]), topic  # nothing recorded twice
        if mode == 'lockstep':
            shares[topic] = share = t.size / len(times['/joint_states']) * RATE_HZ / rate
            assert 0.5 <= share <= 1.05, (topic, share)
    if mode == 'lockstep':
        assert len(times['/joint_states']) >= 0.95 * DURATION_S * RATE_HZ
    print(mode, 'recorded rates', rates, 'shares of the steps', shares)
    report_figure(current_test(), rates_hz=rates, shares=shares)
    # 1 Hz from the controller and from the sim on the wall clock (a lockstep run may be
    # faster than real time); the first and last second may miss
    assert found['/diagnostics'][1] >= (2 * (DURATION_S - 2) if mode == 'real_time' else 2)
    assert found['/sim/link_masses'][1] == 1  # once, transient local: recorded though late


def test_demo_bag_metadata_is_rosbag2_v8_mcap(demo_run):
    meta = (demo_run[0] / 'bag' / 'metadata.yaml').read_text()
    assert 'version: 8' in meta and 'storage_identifier: mcap' in meta
    assert 'offered_qos_profiles' in meta


def _statuses(bag: Path) -> dict[str, list[dict]]:
    """Return the /diagnostics statuses in ``bag`` by hardware_id, with their stamps, in order."""
    out: dict[str, list[dict]] = {}
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == '/diagnostics']
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if msg.status:
                d = parse_diagnostics(msg)
                d['stamp_s'] = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                out.setdefault(msg.status[0].hardware_id, []).append(d)
    return out


def test_demo_run_is_clean(demo_run):
    statuses = _statuses(demo_run[0] / 'bag')
    assert {'hybrid_force_controller', 'sim'} <= set(statuses), set(statuses)
    sim = statuses['sim'][-1]
    # the controller's last status while the sim still ran (once the demo stops the sim, the
    # controller's inputs end: its safe mode then is the shutdown's, not the run's)
    ctrl = [d for d in statuses['hybrid_force_controller'] if d['stamp_s'] <= sim['stamp_s']]
    assert ctrl, statuses['hybrid_force_controller']
    # real time: refused inputs and safe modes only where the loop kept up (helpers.ros)
    assert_clean_run(ctrl[-1], sim, run=ctrl if demo_run[1] == 'real_time' else None)


def test_demo_report_outputs(demo_run):
    out, mode = demo_run
    report = out / 'report'
    metrics = json.loads((report / 'metrics.json').read_text())
    report_figure(current_test(), **{k: metrics.get(k) for k in (
        'rms_position_error_m', 'rms_force_error_n', 'contact_lost_s')})
    assert metrics['mode'] == mode
    if mode == 'lockstep':  # and its pins: test_demo_lockstep_figures_are_the_pinned_ones
        assert metrics['rms_position_error_m'] <= 5e-4
        assert metrics['rms_force_error_n'] <= 0.05
        assert metrics['contact_lost_s'] == 0.0
    else:  # real time: rms position, rms force and contact lost (realtime_bounds.json)
        check_bounds(metrics)
    for name in ('fig3_position.png', 'fig4_force.png', 'fig5_parameters.png',
                 'fig6_stiffness.png'):
        assert (report / name).stat().st_size > 5000, name
    # the demo's arm is 50 % off its URDF: Fig. 5 draws the sim's true masses, theta_hat nears them
    log = load_run(out / 'bag')
    np.testing.assert_allclose(log.theta_true, [0.65, 1.35])
    np.testing.assert_allclose(log.theta_hat[-1], [0.65, 1.35], rtol=0.05)


def test_the_wipe_task_tares_and_follows_the_users_path(tmp_path):
    """
    ``demo --task wipe`` on the paper's arm: the biased sensor tared, a script's path followed.

    The paper's planar arm follows the square's part in its task space (along x, there and
    back). Bounds: 5 times the worst of the measured runs (test/realtime_bounds.json): no contact
    lost on the path; over the whole run, the pressing's first swing from the brakes' zero-force
    touch lifted the tool in 2 of 37 runs, both on one CPU (0.040, 0.058 s): 5 times the worst.
    """
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=DEMO_DOMAIN_ID,
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')]),
               **ISOLATED)  # as a user runs it: the cell domain behind the gateway
    proc = subprocess.run([sys.executable, '-m', 'hybrid_force_controller.ros.programs.demo',
                           '--task', 'wipe', '--side', '0.05', '--out', str(tmp_path)],
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    tared = re.search(r'tare: wrench_offset = \[([^\]]+)\] N', proc.stdout)
    assert tared, proc.stdout[-2000:]  # the sim's bias, under 0.02 N of sensor noise
    assert np.allclose([float(v) for v in tared.group(1).split(',')], [1.5, -1.0, 2.5],
                       atol=0.01), tared.group(0)
    assert (tmp_path / 'script.log').read_text().strip().endswith('send_path: done')
    metrics = json.loads((tmp_path / 'report' / 'metrics.json').read_text())
    assert metrics['task'] == 'wipe' and metrics['tared'] is True
    assert metrics['path_window'] == 'path running'
    report_figure(current_test(), **{k: metrics.get(k) for k in (
        'rms_path_error_m', 'max_path_error_m', 'rms_force_error_n', 'contact_lost_s',
        'contact_lost_window_s')})
    check_bounds(metrics)  # path rms and max, force rms, contact lost: whole run and path


@pytest.mark.parametrize('demo_run', ['lockstep'], indirect=True)  # the fixture's lockstep run
def test_demo_lockstep_figures_are_the_pinned_ones(demo_run):
    """
    Compare the lockstep run's report/metrics.json with its pins (test/pinned_figures.json).

    No demo run of its own: the fixture's lockstep run (pytest reuses the module's instance for
    the same param). Not bit-exact: the reference starts at another sim time each run, the
    recording at another step, and under load the sim's 0.2 s watchdog steps without a command;
    three runs gave rms force errors of 1.10e-5 to 3.85e-5 N and max force errors of 1.9e-5 to
    2.3e-4 N, rms position errors within 0.7 %. So each figure is pinned at the median of the
    three within 3 times its largest deviation (pinned_figures.json, not_bit_exact: the figures
    and the note), the offline runs' 1e-6 for those that did not move.
    """
    out, mode = demo_run
    assert mode == 'lockstep'
    metrics = json.loads((out / 'report' / 'metrics.json').read_text())
    check_pinned('demo_lockstep', numbers(metrics))
