"""
tools/cell_trial_figures.py on a synthetic MCAP bag (BagWriter, helpers.bags' messages).

10 s at 100 Hz, the path running from 2 to 8 s, f_d 1 N along n. The true force is 1.05 N,
zero from 4.0 to 4.5 s (a whole-cell stall from 4.0 to 4.3 s, then 0.2 s to touch again) and
3 N once at 4.6 s. The Panda's joints move at 1 rad/s, joint 7 at 2 rad/s once (its limit is
2.61 rad/s).
"""
from __future__ import annotations

from helpers.bags import DT_NS, N_SURF, path_messages, T0_NS, wrench_msg, write_bag
from hybrid_force_controller.tools.bag_io import (TOPIC_CONTACT_WRENCH, TOPIC_JOINT_STATES,
                                                  TOPIC_X, TYPESTORE)
from hybrid_force_controller.tools.cell_trial_figures import (trial_figures,
                                                              urdf_velocity_limits)
import numpy as np
import pytest

STALL = (T0_NS * 1e-9 + 4.0, T0_NS * 1e-9 + 4.3)
JOINTS = [f'panda_joint{i}' for i in range(1, 8)]


def _force(t: float) -> float:
    if 4.0 <= t < 4.5:
        return 0.0
    return 3.0 if abs(t - 4.6) < 1e-6 else 1.05


def _messages():
    js = TYPESTORE.types['sensor_msgs/msg/JointState']
    header = TYPESTORE.types['std_msgs/msg/Header']
    stamp = TYPESTORE.types['builtin_interfaces/msg/Time']
    k = 0
    for topic, log_ns, msg in path_messages():
        yield topic, log_ns, msg
        if topic != TOPIC_X:
            continue
        ns, t = T0_NS + k * DT_NS, k * DT_NS * 1e-9
        yield TOPIC_CONTACT_WRENCH, log_ns, wrench_msg(ns, _force(t) * np.array(N_SURF))
        v = np.ones(7)
        v[6] = 2.0 if k == 300 else 1.0
        yield TOPIC_JOINT_STATES, log_ns, js(
            header=header(stamp=stamp(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=''),
            name=JOINTS, position=np.zeros(7), velocity=v, effort=np.zeros(7))
        k += 1


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    return write_bag(tmp_path_factory.mktemp('trial') / 'run', messages=list(_messages()))


def test_the_panda_urdf_gives_each_joint_its_velocity_limit():
    limits = urdf_velocity_limits()
    assert [limits[j] for j in JOINTS] == [2.175] * 4 + [2.61] * 3


def test_figures_of_a_stall_in_the_path(bag):
    fig = trial_figures(bag, STALL)
    assert fig['fastest_joint'] == 'panda_joint7'
    assert fig['max_joint_speed_ratio'] == pytest.approx(2.0 / 2.61, abs=1e-3)
    assert fig['stall_in_path'] is True
    assert fig['path_s'] == pytest.approx(6.0, abs=0.02)
    assert fig['back_s'] == pytest.approx(0.2, abs=0.011)  # in contact again at 4.5 s
    assert fig['settle_s'] == pytest.approx(0.31, abs=0.011)  # after the 3 N sample
    assert fig['peak_force_n'] == pytest.approx(3.0)
    # outside [4.0, 6.3] the error is 0.05 N and the tool never off the surface
    assert fig['rms_force_error_n'] == pytest.approx(0.05, abs=1e-4)
    assert fig['contact_lost_s'] == 0.0


def test_without_a_stall_the_whole_path_counts(bag):
    fig = trial_figures(bag)
    assert 'back_s' not in fig
    assert fig['contact_lost_s'] == pytest.approx(0.5, abs=0.011)
    assert fig['rms_force_error_n'] > 0.2  # the 0.5 s at zero and the 3 N sample
