"""``report`` on real MCAP/sqlite3 bags written with BagWriter / rosbags (no mocks)."""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
import subprocess
import sys

from helpers.bags import (FORCE_AMPLITUDE_N, N_SAMPLES, N_SURF, point_msg, run_report,
                          synthetic_messages, wrench_msg, write_bag)
from hybrid_force_controller.tools.analysis import compute_metrics
from hybrid_force_controller.tools.bag_io import (BAG_VERSION, BagError, BagWriter, load_run,
                                                  RECORD_TOPICS, REQUIRED_TOPICS, TOPIC_THETA_HAT,
                                                  TOPIC_WRENCH, TOPIC_WRENCH_DESIRED, TOPIC_X,
                                                  TOPIC_X_DESIRED, TYPESTORE)
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer


REPO_ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope='module')
def good_bag(tmp_path_factory) -> Path:
    return write_bag(tmp_path_factory.mktemp('bags') / 'run')


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
