"""The README's main command end to end: demo -> MCAP bag -> report (real DDS, lockstep)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from hybrid_force_controller.tools.bag_io import RECORD_TOPICS
from ros_helpers import domain_id

REPO = Path(__file__).resolve().parents[1]
DURATION_S = 6.0
RATE_HZ = 1000.0
DEMO_DOMAIN_ID = str(domain_id('demo'))


@pytest.fixture(scope='module')
def demo_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp('demo')
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=DEMO_DOMAIN_ID,
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')]))
    proc = subprocess.run([sys.executable, '-m', 'hybrid_force_controller.ros.demo',
                           '--duration', str(DURATION_S), '--out', str(out)],
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert f'bag:     {out / "bag"}' in proc.stdout
    return out


def test_demo_bag_has_expected_topics_types_and_counts(demo_run):
    with AnyReader([demo_run / 'bag']) as reader:
        found = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
    assert set(found) == {topic for topic, _ in RECORD_TOPICS}
    for topic, msgtype in RECORD_TOPICS:
        assert found[topic][0] == msgtype, topic
    expected = DURATION_S * RATE_HZ  # lockstep: one message per control period
    for topic in ('/joint_states', '/effort_controller/commands', '/hybrid_force_controller/x',
                  '/hybrid_force_controller/wrench', '/sim/contact_wrench'):
        assert 0.95 * expected <= found[topic][1] <= 1.05 * expected, (topic, found[topic])
    assert found['/diagnostics'][1] >= DURATION_S - 2  # 1 Hz, first and last second may miss


def test_demo_bag_metadata_is_rosbag2_v8_mcap(demo_run):
    meta = (demo_run / 'bag' / 'metadata.yaml').read_text()
    assert 'version: 8' in meta and 'storage_identifier: mcap' in meta
    assert 'offered_qos_profiles' in meta


def test_demo_report_outputs(demo_run):
    report = demo_run / 'report'
    metrics = json.loads((report / 'metrics.json').read_text())
    assert metrics['rms_position_error_m'] <= 5e-4
    assert metrics['rms_force_error_n'] <= 0.05
    assert metrics['contact_lost_s'] == 0.0
    for name in ('fig3_position.png', 'fig4_force.png', 'fig5_parameters.png'):
        assert (report / name).stat().st_size > 5000, name
