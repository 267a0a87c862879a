"""
``demo --physics mujoco`` / ``--arm panda``: the node arguments it builds (no processes started).

The MuJoCo runs add config/mujoco.yaml and one ``tool_mass`` for both nodes; the Panda gets its
parameter files and bundled URDF; options that need MuJoCo are refused without it.
"""
from __future__ import annotations

import argparse

from hybrid_force_controller.core.offline.arm7 import panda_urdf_path
from hybrid_force_controller.ros.programs.demo import (_orientation_args, _scenario_args,
                                                       _tool_args, main, TILT_N_TIME_CONSTANT)
from hybrid_force_controller.ros.programs.send_path import square_poses
import numpy as np
import pytest


def _args(**kwargs):
    base = {'arm': 'paper', 'physics': 'paper', 'friction': None, 'tool_mass': None}
    return argparse.Namespace(**{**base, **kwargs})


def _files(ros_args):
    return [ros_args[i + 1].rsplit('/', 1)[-1] for i, a in enumerate(ros_args)
            if a == '--params-file']


def test_paper_physics_is_todays_demo():
    ros_args, mu, mass = _scenario_args(_args())
    assert _files(ros_args) == ['params.yaml'] and len(ros_args) == 2
    assert (mu, mass) == (0.0, 0.0)


def test_mujoco_on_the_paper_arm_adds_the_overlay_and_a_massless_tool():
    ros_args, mu, mass = _scenario_args(_args(physics='mujoco', friction=0.3))
    assert _files(ros_args) == ['params.yaml', 'mujoco.yaml']
    assert ros_args[-2:] == ['-p', 'tool_mass:=0.0'] and (mu, mass) == (0.3, 0.0)


def test_the_panda_on_mujoco_has_its_table_friction_and_tool():
    ros_args, mu, mass = _scenario_args(_args(arm='panda', physics='mujoco'))
    assert _files(ros_args) == ['panda_params.yaml', 'panda_table.yaml', 'mujoco.yaml']
    assert f'robot_description:={panda_urdf_path()}' in ros_args
    assert 'tool_mass:=0.1' in ros_args and (mu, mass) == (0.3, 0.1)


@pytest.mark.parametrize('argv', [['--friction', '0.3'], ['--tool-mass', '0.1'],
                                  ['--physics', 'mujoco', '--friction', '-1'],
                                  ['--tool', 'disc'], ['--tool-radius', '0.02']])
def test_mujoco_options_need_mujoco(argv, capsys):
    assert main([*argv, '--out', '/nonexistent/never']) == 2
    assert 'needs --physics mujoco' in capsys.readouterr().err


@pytest.mark.parametrize('argv', [['--surface', 'tilted'],
                                  ['--surface', 'sphere', '--task', 'wipe'],
                                  ['--arm', 'panda', '--surface', 'cylinder']])
def test_a_surface_needs_the_pandas_wipe(argv, capsys):
    assert main([*argv, '--out', '/nonexistent/never']) == 2
    assert '--surface needs --task wipe and --arm panda' in capsys.readouterr().err


def test_the_wipes_square_centred_in_the_told_plane():
    """Demo --surface: send_path --centred --normal 0 0 -1 gives a square around the tool."""
    start = np.array([0.48, 0.0, 0.41])
    corners = square_poses(start, np.array([0.0, 0.0, -1.0]), 0.1, centred=True)
    assert corners.shape == (5, 3) and np.allclose(corners[0], corners[-1])
    assert np.allclose(corners[:4].mean(axis=0), start)  # centred on the tool
    assert np.allclose(corners[:, 2], start[2])  # in the told plane
    sides = np.linalg.norm(np.diff(corners, axis=0), axis=1)
    assert np.allclose(sides, 0.1)
    assert np.allclose(square_poses(start, np.array([0.0, 0.0, -1.0]), 0.1)[0], start)


def test_a_node_parameter_is_name_colon_equals_value(capsys):
    assert main(['--sim-param', 'surface_normal=[0, 1, 0]', '--out', '/nonexistent/never']) == 2
    assert "a parameter is NAME:=VALUE, got 'surface_normal=[0, 1, 0]'" in capsys.readouterr().err


def test_the_pad_is_the_sims_tool_shape_and_radius():
    args = argparse.Namespace(tool='disc', tool_radius=0.025)
    assert _tool_args(args) == ['-p', 'tool_shape:=disc', '-p', 'tool_radius:=0.025']
    assert _tool_args(argparse.Namespace(tool=None, tool_radius=None)) == []


def test_a_tilted_pad_slows_the_normals_estimate():
    """--tool-tilt: the controller's tool_tilt and n_time_constant 1 s; no tilt, neither."""
    tilt = argparse.Namespace(orientation='normal', tool='disc', arm='panda', tool_tilt=0.15)
    assert _orientation_args(tilt) == ['-p', 'orientation_mode:=normal', '-p', 'tool_tilt:=0.15',
                                       '-p', 'n_time_constant:=1.0']
    assert TILT_N_TIME_CONSTANT == 1.0
    flat = argparse.Namespace(orientation=None, tool='disc', arm='panda', tool_tilt=0.0)
    assert _orientation_args(flat) == ['-p', 'orientation_mode:=moment']
