"""``report`` on real MCAP/sqlite3 bags written with BagWriter / rosbags (no mocks)."""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
import subprocess
import sys

from hybrid_force_controller.tools import report
from hybrid_force_controller.tools.analysis import compute_metrics
from hybrid_force_controller.tools.bag_io import (BAG_VERSION, BagError, BagWriter, load_run,
                                                  RECORD_TOPICS, REQUIRED_TOPICS,
                                                  TOPIC_CONTACT_WRENCH, TOPIC_THETA_HAT,
                                                  TOPIC_WRENCH, TOPIC_WRENCH_DESIRED, TOPIC_X,
                                                  TOPIC_X_DESIRED, TYPESTORE)
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer


REPO_ROOT = Path(__file__).resolve().parent.parent
T = TYPESTORE.types
T0_NS = 1_700_000_000_000_000_000  # header stamps (e.g. the controller clock)
LOG_OFFSET_NS = 123_456_789  # recorder receive time = stamp + offset
DT_NS = 10_000_000
N_SAMPLES = 1001  # 10 s at 100 Hz
FORCE_AMPLITUDE_N = 0.2
N_SURF = (0.0, -1.0, 0.0)


def _header(ns: int):
    stamp = T['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
    return T['std_msgs/msg/Header'](stamp=stamp, frame_id='base_link')


def point_msg(ns: int, p) -> object:
    point = T['geometry_msgs/msg/Point'](x=float(p[0]), y=float(p[1]), z=float(p[2]))
    return T['geometry_msgs/msg/PointStamped'](header=_header(ns), point=point)


def wrench_msg(ns: int, f) -> object:
    vec = T['geometry_msgs/msg/Vector3']
    wrench = T['geometry_msgs/msg/Wrench'](force=vec(x=float(f[0]), y=float(f[1]),
                                                     z=float(f[2])),
                                           torque=vec(x=0.0, y=0.0, z=0.0))
    return T['geometry_msgs/msg/WrenchStamped'](header=_header(ns), wrench=wrench)


def array_msg(values, label: str) -> object:
    dim = T['std_msgs/msg/MultiArrayDimension'](label=label, size=len(values),
                                                stride=len(values))
    layout = T['std_msgs/msg/MultiArrayLayout'](dim=[dim], data_offset=0)
    return T['std_msgs/msg/Float64MultiArray'](layout=layout,
                                               data=np.asarray(values, dtype=float))


def synthetic_messages(skip=(), true_force=False, header_t0_ns=T0_NS, theta_label='m1,m2'):
    """
    (topic, log_ns, msg) of a run with known errors.

    Tangential error 1 mm (plus a 2 mm error along n, which must not count); normal force
    error ``0.2 sin(2 pi t)`` N; contact lost for t in [2.0, 2.5); theta_hat -> (1.3, 0.5).
    With ``true_force`` the measured wrench carries a large bias and the true one is on
    ``/sim/contact_wrench``. The wrench is published at 200 Hz, the rest at 100 Hz.
    Header stamps start at ``header_t0_ns``; log (receive) times at ``T0_NS``.
    """
    n = np.array(N_SURF)
    for k in range(2 * N_SAMPLES - 1):
        ns = header_t0_ns + k * DT_NS // 2
        log_ns = T0_NS + k * DT_NS // 2 + LOG_OFFSET_NS
        t = k * DT_NS / 2 * 1e-9
        lost = 2.0 <= t < 2.5
        f_W = np.zeros(3) if lost else (1.0 + FORCE_AMPLITUDE_N * np.sin(2 * np.pi * t)) * n
        measured_W = f_W + 5.0 * n if true_force else f_W
        out = [(TOPIC_WRENCH, ns, wrench_msg(ns, measured_W))]
        if true_force:
            out.append((TOPIC_CONTACT_WRENCH, ns, wrench_msg(ns, f_W)))
        if k % 2 == 0:
            x_d = np.array([1.0 + 0.1 * np.sin(t), 0.0, 0.0])
            theta = [1.3, 0.5 + 0.4 * math.exp(-t)]
            out += [(TOPIC_X, ns, point_msg(ns, x_d + [1e-3, 2e-3, 0.0])),
                    (TOPIC_X_DESIRED, ns, point_msg(ns, x_d)),
                    (TOPIC_WRENCH_DESIRED, ns, wrench_msg(ns, n)),
                    (TOPIC_THETA_HAT, ns, array_msg(theta, theta_label))]
        for topic, _, msg in out:
            if topic not in skip:
                yield topic, log_ns, msg


def write_bag(path: Path, drop=(), silence=(), true_force=False, messages=None) -> Path:
    """
    Bag of :func:`synthetic_messages`; ``drop``.

    Topics not even declared, ``silence``: topics declared without messages.
    """
    topics = [(t, typ) for t, typ in RECORD_TOPICS if t not in drop]
    with BagWriter(path, topics) as writer:
        for topic, log_ns, msg in (messages if messages is not None
                                   else synthetic_messages((*drop, *silence), true_force)):
            writer.write_msg(topic, log_ns, msg)
    return path


@pytest.fixture(scope='module')
def good_bag(tmp_path_factory) -> Path:
    return write_bag(tmp_path_factory.mktemp('bags') / 'run')


def run_report(bag: Path, out: Path, capsys, *extra: str) -> tuple[int, str, str]:
    rc = report.main([str(bag), '--out', str(out), *extra])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def test_report_metrics_and_figures(good_bag, tmp_path, capsys):
    rc, out, err = run_report(good_bag, tmp_path / 'out', capsys)
    assert rc == 0, err
    metrics = json.loads((tmp_path / 'out' / 'metrics.json').read_text())
    assert metrics['rms_position_error_m'] == pytest.approx(1e-3, rel=1e-6)
    assert metrics['max_position_error_m'] == pytest.approx(1e-3, rel=1e-6)
    assert metrics['rms_force_error_n'] == pytest.approx(FORCE_AMPLITUDE_N / math.sqrt(2),
                                                         abs=1e-3)
    assert metrics['max_force_error_n'] == pytest.approx(FORCE_AMPLITUDE_N, abs=1e-3)
    assert metrics['contact_lost_s'] == pytest.approx(0.5)
    assert metrics['theta_hat_final'] == pytest.approx([1.3, 0.5 + 0.4 * math.exp(-10.0)])
    assert metrics['sim_time_s'] == pytest.approx(10.0)
    assert metrics['wall_time_s'] is None  # unknown -> null, metrics.json stays valid JSON
    for name in ('fig3_position.png', 'fig4_force.png', 'fig5_parameters.png'):
        png = tmp_path / 'out' / name
        assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
        assert png.stat().st_size > 1000
        assert str(png) in out


def test_load_run_signals(good_bag):
    log = load_run(good_bag)
    assert log.theta_names == ('m1', 'm2')
    assert log.t[0] == 0.0 and log.t.size == N_SAMPLES
    np.testing.assert_allclose(log.n_W, N_SURF)
    assert log.f_true_W is None and log.theta_true is None
    assert np.count_nonzero(~log.in_contact) == 50


def test_sim_time_stamps_with_wall_clock_log_times_and_default_names(tmp_path):
    """
    Header stamps in sim time (from 0) while the recorder logs wall time.

    The headerless theta_hat is aligned on log times, the stamped topics on header stamps.
    """
    bag = write_bag(tmp_path / 'simtime', messages=list(
        synthetic_messages(header_t0_ns=0, theta_label='')))
    log = load_run(bag)
    assert log.theta_names == ('theta_0', 'theta_1')
    np.testing.assert_allclose(log.theta_hat[[0, 500, -1], 1],
                               0.5 + 0.4 * np.exp(-np.array([0.0, 5.0, 10.0])))
    metrics = compute_metrics(log)
    assert metrics['rms_position_error_m'] == pytest.approx(1e-3, rel=1e-6)


def test_true_contact_force_is_used_when_recorded(tmp_path, capsys):
    bag = write_bag(tmp_path / 'sim', true_force=True)
    log = load_run(bag)
    assert log.f_true_W is not None
    rc, _, err = run_report(bag, tmp_path / 'out', capsys, '--wall-time', '3.5')
    assert rc == 0, err
    metrics = json.loads((tmp_path / 'out' / 'metrics.json').read_text())
    assert metrics['rms_force_error_n'] == pytest.approx(FORCE_AMPLITUDE_N / math.sqrt(2),
                                                         abs=1e-3)
    assert metrics['contact_lost_s'] == pytest.approx(0.5)
    assert metrics['wall_time_s'] == 3.5


def test_sqlite3_bag_is_read(tmp_path):
    bag = tmp_path / 'sqlite_run'
    with Writer(bag, version=BAG_VERSION, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conns = {t: writer.add_connection(t, typ, typestore=TYPESTORE)
                 for t, typ in RECORD_TOPICS}
        for topic, log_ns, msg in synthetic_messages():
            writer.write(conns[topic], log_ns, TYPESTORE.serialize_cdr(msg, msg.__msgtype__))
    log = load_run(bag)
    assert log.t.size == N_SAMPLES


def test_bag_writer_metadata_is_jazzy_v8(good_bag):
    import yaml  # noqa: PLC0415 - pyyaml ships with the ROS python packages
    info = yaml.safe_load((good_bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 8 and info['storage_identifier'] == 'mcap'
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert set(topics) == {name for name, _ in RECORD_TOPICS}
    x = topics[TOPIC_X]
    assert x['message_count'] == N_SAMPLES
    assert x['topic_metadata']['type'] == 'geometry_msgs/msg/PointStamped'
    assert x['topic_metadata']['type_description_hash'].startswith('RIHS01_')
    qos = yaml.safe_load(x['topic_metadata']['offered_qos_profiles'])  # v8: a YAML string
    assert qos == [{'history': 1, 'depth': 10, 'reliability': 1, 'durability': 2,
                    'deadline': {'sec': 0, 'nsec': 0}, 'lifespan': {'sec': 0, 'nsec': 0},
                    'liveliness': 0, 'liveliness_lease_duration': {'sec': 0, 'nsec': 0},
                    'avoid_ros_namespace_conventions': False}]
    with AnyReader([good_bag]) as reader:  # definitions are embedded: no default typestore
        assert reader.topics[TOPIC_X].msgcount == N_SAMPLES


def test_bag_writer_rejects_misuse(tmp_path, good_bag):
    with pytest.raises(BagError, match='cannot create bag'):
        BagWriter(good_bag, RECORD_TOPICS)
    with pytest.raises(BagError, match='not in the Jazzy typestore'):
        BagWriter(tmp_path / 'b', [('/a', 'nope_msgs/msg/Nope')])
    writer = BagWriter(tmp_path / 'c', [(TOPIC_X, 'geometry_msgs/msg/PointStamped')])
    with pytest.raises(BagError, match='was not declared'):
        writer.write('/other', 0, b'')
    with pytest.raises(BagError, match='cannot serialize'):
        writer.write_msg(TOPIC_X, 0, wrench_msg(0, N_SURF))
    writer.close()
    writer.close()
    with pytest.raises(BagError, match='is closed'):
        writer.write(TOPIC_X, 0, TYPESTORE.serialize_cdr(point_msg(0, N_SURF),
                                                         'geometry_msgs/msg/PointStamped'))


def _random_file(path: Path) -> Path:
    path.write_bytes(np.random.default_rng(1).bytes(4096))
    return path


@pytest.mark.parametrize('make_bag, message', [
    (lambda d: d / 'does_not_exist', 'bag not found'),
    (lambda d: write_bag(d / 'empty', messages=[]), 'is empty'),
    (lambda d: _random_file(d / 'corrupt.mcap'), 'not a readable rosbag2 bag'),
    (lambda d: _random_file(d / 'corrupt'), 'not a readable rosbag2 bag'),
    (lambda d: write_bag(d / 'nowrench', drop=(TOPIC_WRENCH,)),
     f'required topic {TOPIC_WRENCH} missing'),
    (lambda d: write_bag(d / 'nox_d', drop=(TOPIC_X_DESIRED,)),
     f'required topic {TOPIC_X_DESIRED} missing'),
    (lambda d: write_bag(d / 'notheta', silence=(TOPIC_THETA_HAT,)),
     f'no messages on required topic {TOPIC_THETA_HAT}'),
    (lambda d: write_bag(d / 'zero_fd', messages=[
        (t, ns, wrench_msg(ns, (0, 0, 0)) if t == TOPIC_WRENCH_DESIRED else m)
        for t, ns, m in synthetic_messages()]), 'zero everywhere'),
])
def test_bad_bags_fail_with_a_message(tmp_path, capsys, make_bag, message):
    bag = make_bag(tmp_path)
    rc, out, err = run_report(bag, tmp_path / 'out', capsys)
    assert rc == 2
    assert err.startswith('error: ') and message in err, err
    assert not (tmp_path / 'out' / 'metrics.json').exists()
    assert set(REQUIRED_TOPICS) <= {t for t, _ in RECORD_TOPICS}


def test_report_as_a_subprocess(good_bag, tmp_path):
    env = dict(os.environ, MPLBACKEND='Agg')
    cmd = [sys.executable, '-m', 'hybrid_force_controller.tools.report']
    ok = subprocess.run([*cmd, str(good_bag), '--out', str(tmp_path / 'o')], cwd=REPO_ROOT,
                        env=env, capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert (tmp_path / 'o' / 'metrics.json').is_file()
    bad = subprocess.run([*cmd, str(tmp_path / 'missing'), '--out', str(tmp_path / 'p')],
                         cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2
    assert 'error: bag not found' in bad.stderr
