"""
``~/surface_normal`` over real DDS, in real time (issue 24): the learnt normal turns to the truth.

One sim (paper physics, config/params.yaml) whose line is turned 0.3 rad about z, and one
controller told n = [0, -1, 0] with ``n_estimation``, holding the tool where it starts
(``ref_center`` there, ``ref_amplitude`` 0). The controller publishes the normal it uses on
``~/surface_normal`` (base frame): the told n, 17 deg off the sim's ``sim/contact_normal``,
as long as the tool rests; once a 10 cm sine makes it slide (``ref_amplitude`` set at run time),
within a few degrees of the truth; /diagnostics says the estimate is on and has used samples,
and the run is clean (no callback error, no safe mode).
Loose bound (5 deg; offline it is within 1 deg: test_normal_closed_loop.py, docs/results.md).
About 15 s.
"""
from __future__ import annotations

import math
import threading

from geometry_msgs.msg import Vector3Stamped
from helpers.figures import angle_deg, current_test, report_figure
from helpers.ros import domain_id, wait_for, wait_future
from helpers.watch import assert_clean_run, RealTimeRig
import numpy as np
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile

TILT = -0.3
N_TRUE = [math.sin(TILT), -math.cos(TILT), 0.0]
N_TOLD = np.array([0.0, -1.0, 0.0])
P0 = [0.79262435, 1.6107438, 0.0]  # the tool at config/params.yaml's start pose
NEAR_DEG = 5.0
CTRL = 'hybrid_force_controller'


class Normals:
    """The controller's latest normal (and how many came) and the sim's, on the rig's node."""

    def __init__(self, rig: RealTimeRig) -> None:
        node = rig.log.node
        self.lock = threading.Lock()
        self.latest = self.true = None
        self.frame, self.count = '', 0
        q = QoSProfile(depth=100)
        node.create_subscription(Vector3Stamped, f'{CTRL}/surface_normal', self._on_normal, q)
        node.create_subscription(Vector3Stamped, 'sim/contact_normal', self._on_true, q)

    def _on_normal(self, msg: Vector3Stamped) -> None:
        v = np.array([msg.vector.x, msg.vector.y, msg.vector.z])
        with self.lock:
            self.latest, self.frame = v, msg.header.frame_id
            self.count += 1

    def _on_true(self, msg: Vector3Stamped) -> None:
        with self.lock:
            self.true = np.array([msg.vector.x, msg.vector.y, msg.vector.z])

    def near_truth(self) -> bool:
        with self.lock:
            return (self.latest is not None and self.true is not None
                    and angle_deg(self.latest, self.true) < NEAR_DEG)


def test_the_published_normal_starts_told_and_turns_to_the_sims_plane(tmp_path):
    rig = RealTimeRig(tmp_path, domain_id('surface_normal_ros'),
                      # a sensor's noise (seeded): at rest a noise-free sim can read the same
                      # bits for 0.1 s, the frozen-sensor check's safe mode (2 of 5 runs on one
                      # CPU); a real sensor never does
                      sim_args=['-p', f'surface_normal:={N_TRUE}', '-p', 'noise_sigma:=0.002',
                                '-p', 'seed:=7'],
                      ctrl_args=['-p', 'n_estimation:=true', '-p', f'ref_center:={P0}',
                                 '-p', 'ref_amplitude:=[0.0, 0.0, 0.0]'])
    normals = Normals(rig)
    try:
        for p in rig.procs:
            p.start()
        wait_for(lambda: normals.count > 10 and normals.true is not None,
                 'the first ~/surface_normal', alive=rig.procs)
        with normals.lock:
            resting, true, frame = normals.latest, normals.true, normals.frame
        slide = [Parameter('ref_amplitude', value=[0.1, 0.0, 0.0])]
        result = wait_future(rig.params.set_parameters(slide)).results[0]
        assert result.successful, result.reason
        wait_for(normals.near_truth, f'~/surface_normal within {NEAR_DEG} deg of the truth',
                 alive=rig.procs)
        wait_for(lambda: rig.log.diag(CTRL).get('normal_samples_used', 0) > 0,
                 '/diagnostics with the estimate', alive=rig.procs)
        with normals.lock:
            latest = normals.latest
        diag, sim = rig.log.fresh_diag(CTRL, rig.procs), rig.log.fresh_diag('sim', rig.procs)
    finally:
        rig.close()
    figures = {'resting_from_told_deg': angle_deg(resting, N_TOLD),
               'resting_from_true_deg': angle_deg(resting, true),
               'latest_from_true_deg': angle_deg(latest, true)}
    print('surface normal', figures)
    report_figure(current_test(), **figures)
    assert frame == 'base_link', frame
    assert figures['resting_from_told_deg'] < 2.0, resting  # the told n while the tool rests
    assert figures['resting_from_true_deg'] > 15.0, (resting, true)  # so the test can fail
    # what the wait above waited for (within NEAR_DEG): 5 times the worst of 10 runs (4.99 deg)
    # would be looser than that condition, so the condition is the bound
    assert figures['latest_from_true_deg'] < NEAR_DEG, (latest, true)
    assert abs(np.linalg.norm(latest) - 1.0) < 1e-9
    assert diag['normal_estimation'] is True, diag
    assert diag['normal_state'] in ('sliding', 'at_rest'), diag
    assert_clean_run(diag, sim, run=rig.log.statuses(CTRL))
