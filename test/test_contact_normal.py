"""
The sim's true surface normal, ``sim/contact_normal``, over real DDS (the sim alone, brakes on).

* paper physics: a plane tilted 0.3 rad that the tool touches at its start publishes the tilted
  normal; a cylinder set at run time with its top 5 cm aside (the tool 0.8 mm in) publishes the
  analytic normal at the tool (9.6 deg off); a bad shape or an axis off the tangent plane is
  refused with the reason and changes nothing; a bad shape or radius stops the sim at start-up
  with the reason;
* MuJoCo: a cylinder, tilted 0.3 rad, publishes the analytic normal at the tool, before and
  after its top is moved aside at run time; a change of shape is refused (fixed at start-up).

Loose tolerances (1 deg): MuJoCo's surface moves on its spring (mujoco_scene.py); the exact
geometry is checked offline (test_surface_shapes.py).
"""
from __future__ import annotations

import math
import threading

from geometry_msgs.msg import Vector3Stamped
from helpers.figures import angle_deg
from helpers.ros import domain_id, NodeProcess, ROOT, SIM_MODULE, Spun, wait_for, wait_future
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.environment import make_surface
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile

CONFIG = ROOT / 'config'
MODEL = RobotModel.from_urdf()
Q0 = np.array([0.657, 0.913])  # config/params.yaml
P0 = MODEL.kinematics(Q0, np.zeros(2)).p_W  # the tool, held by the brakes
TILT = 0.3
N_TILTED = np.array([math.sin(TILT), -math.cos(TILT), 0.0])  # about z: the arm's plane
T_TILTED = np.array([math.cos(TILT), math.sin(TILT), 0.0])  # along it, in the arm's plane
TOL_DEG = 1.0


def _aside(tool_radius: float) -> list[float]:
    """Return a cylinder's top (R 0.3 m) 5 cm aside, 5 mm out: the tool 0.8 mm in, 9.6 deg."""
    return (P0 + (tool_radius - 0.005) * N_TILTED + 0.05 * T_TILTED).tolist()


def _arg(name: str, value) -> list[str]:
    return ['-p', f'{name}:={value}']


class NormalWatcher:
    """The latest ``sim/contact_normal`` and how many have come, and a parameter client."""

    def __init__(self, spun: Spun) -> None:
        node = spun.node('normal_watcher')
        self.lock = threading.Lock()
        self.count, self.latest, self.frame = 0, None, ''
        node.create_subscription(Vector3Stamped, 'sim/contact_normal', self._on_normal,
                                 QoSProfile(depth=10))
        self.client = AsyncParameterClient(spun.node('normal_param_client'), 'sim')

    def _on_normal(self, msg: Vector3Stamped) -> None:
        with self.lock:
            self.count += 1
            self.latest = np.array([msg.vector.x, msg.vector.y, msg.vector.z])
            self.frame = msg.header.frame_id

    def fresh(self, sim: NodeProcess) -> np.ndarray:
        """Wait for three more normals (the sim publishes at 100 Hz); return the latest."""
        with self.lock:
            start = self.count
        wait_for(lambda: self.count >= start + 3, 'new contact normals', alive=[sim])
        with self.lock:
            return self.latest

    def set_params(self, **values):
        """Set sim parameters atomically; return the result."""
        params = [Parameter(k, value=v) for k, v in values.items()]
        return wait_future(self.client.set_parameters_atomically(params)).result


def _sim(tmp_path, name: str, files: list[str], args: list[str]) -> NodeProcess:
    files_args = [a for f in files for a in ('--params-file', str(CONFIG / f))]
    return NodeProcess(SIM_MODULE, tmp_path / f'{name}.log', domain_id('contact_normal'),
                       files_args + args, params_file=None)


def test_paper_physics_tilted_plane_then_a_cylinder_set_at_run_time(tmp_path):
    sim = _sim(tmp_path, 'sim_paper', ['params.yaml'],
               _arg('surface_normal', N_TILTED.tolist()))
    with Spun(domain_id('contact_normal')) as spun, sim:
        watcher = NormalWatcher(spun)
        tilted = watcher.fresh(sim)
        assert watcher.frame == MODEL.base_link, watcher.frame
        point = _aside(0.0)
        result = watcher.set_params(surface_shape='cylinder', surface_radius=0.3,
                                    surface_point=point)
        assert result.successful, result.reason
        on_cylinder = watcher.fresh(sim)
        refused = [watcher.set_params(surface_shape='cone'),
                   watcher.set_params(surface_axis=[0.0, 1.0, 0.0])]  # n is tilted in x-y: z only
        unchanged = watcher.fresh(sim)
    assert angle_deg(tilted, N_TILTED) < TOL_DEG, tilted
    expected = make_surface('cylinder', 1700.0, point, N_TILTED, 0.3).normal_at(P0)
    print('paper: tilted', tilted, 'cylinder', on_cylinder, 'expected', expected)
    assert angle_deg(expected, N_TILTED) > 5.0  # the case is not trivial
    assert angle_deg(on_cylinder, expected) < TOL_DEG, (on_cylinder, expected)
    assert not refused[0].successful and 'surface shape must be one of' in refused[0].reason
    assert not refused[1].successful and 'perpendicular' in refused[1].reason
    assert angle_deg(unchanged, expected) < TOL_DEG


def test_mujoco_tilted_cylinder_and_its_shape_fixed_at_start_up(tmp_path):
    sim = _sim(tmp_path, 'sim_mujoco', ['params.yaml', 'mujoco.yaml'],
               _arg('surface_normal', N_TILTED.tolist()) + _arg('surface_shape', 'cylinder')
               + _arg('surface_radius', 0.3))
    with Spun(domain_id('contact_normal')) as spun, sim:
        watcher = NormalWatcher(spun)
        at_start = watcher.fresh(sim)
        point = _aside(0.01)  # config/mujoco.yaml: a 1 cm tool
        result = watcher.set_params(surface_point=point)
        assert result.successful, result.reason
        aside = watcher.fresh(sim)
        refused = watcher.set_params(surface_shape='plane')
    expected = make_surface('cylinder', 1700.0, point, N_TILTED, 0.3).normal_at(P0)
    print('mujoco: at start', at_start, 'aside', aside, 'expected', expected)
    assert angle_deg(at_start, N_TILTED) < TOL_DEG, at_start
    assert angle_deg(aside, expected) < TOL_DEG, (aside, expected)
    assert not refused.successful and 'fixed at start-up' in refused.reason, refused.reason


@pytest.mark.parametrize('override, words', [
    (_arg('surface_shape', 'cone'), 'surface shape must be one of'),
    (_arg('surface_radius', 0.0), 'surface_radius'),
])
def test_a_bad_shape_stops_the_sim_at_start_up(tmp_path, override, words):
    sim = _sim(tmp_path, 'sim_bad', ['params.yaml'], override)
    log = sim.refused_at_start_up()
    assert 'invalid configuration' in log and words in log, log
