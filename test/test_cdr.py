"""The CDR readers of the 1 kHz inputs agree with rclpy's own serialization."""
import math

from geometry_msgs.msg import PointStamped, Vector3Stamped, WrenchStamped
from hybrid_force_controller.ros.common.cdr import (CdrError, RawMessage, read_float64_array,
                                                    read_joint_state, read_wrench_stamped)
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension, MultiArrayLayout


@pytest.mark.parametrize('frame, names', [
    ('', ['joint1', 'joint2']), ('base', ['a', 'bb', 'ccc']), ('panda_link0', ['j'] * 7),
    ('odd', []),
])
def test_joint_state_round_trip(frame, names):
    rng = np.random.default_rng(len(names))
    msg = JointState(name=names, position=rng.normal(size=len(names)).tolist(),
                     velocity=rng.normal(size=len(names)).tolist(),
                     effort=rng.normal(size=len(names)).tolist())
    msg.header.frame_id = frame
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1795465910, 684296025
    data = read_joint_state(serialize_message(msg))
    assert data.names == names
    np.testing.assert_array_equal(data.position, msg.position)
    np.testing.assert_array_equal(data.velocity, msg.velocity)
    assert data.stamp_s == 1795465910 + 1e-9 * 684296025


def test_joint_state_without_velocities():
    msg = JointState(name=['joint1'], position=[1.0])
    data = read_joint_state(serialize_message(msg))
    assert data.velocity.size == 0 and data.position.tolist() == [1.0]


@pytest.mark.parametrize('frame', ['', 'tool0', 'a_longer_frame_name'])
def test_wrench_round_trip(frame):
    msg = WrenchStamped()
    msg.header.frame_id = frame
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 5
    msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = 1.5, -math.inf, math.nan
    msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = 9.0, -0.25, 1e-9
    data = read_wrench_stamped(serialize_message(msg))
    assert data.frame_id == frame and data.stamp_s == 12 + 5e-9
    assert data.force[:2] == (1.5, -math.inf) and math.isnan(data.force[2])
    assert data.torque == (9.0, -0.25, 1e-9)


def test_float64_array_round_trip():
    layout = MultiArrayLayout(dim=[MultiArrayDimension(label='m1,m2', size=2, stride=2)],
                              data_offset=3)
    for msg in (Float64MultiArray(data=[1.0, -2.0, 3.5]),
                Float64MultiArray(layout=layout, data=[4.0, 5.0]), Float64MultiArray()):
        assert read_float64_array(serialize_message(msg)).tolist() == list(msg.data)


def test_truncated_or_foreign_bytes_are_refused():
    raw = serialize_message(JointState(name=['joint1'], position=[1.0], velocity=[0.0]))
    for bad in (raw[:-12], raw[:10], b'', b'\x00\x07\x00\x00' + raw[4:]):
        with pytest.raises(CdrError):
            read_joint_state(bad)


@pytest.mark.parametrize('kind, msg_type, field', [
    ('point_stamped', PointStamped, 'point'), ('vector3_stamped', Vector3Stamped, 'vector')])
def test_a_stamped_vector_refilled_in_place_is_the_message_rclpy_would_send(kind, msg_type,
                                                                            field):
    """The telemetry's ~/x, ~/x_desired, ~/error, ~/surface_normal (telemetry.py)."""
    template = msg_type()
    template.header.frame_id = 'panda_link0'
    raw = RawMessage(kind, template)
    raw.set_stamp(1_234_567_890_123)
    raw.arrays[0][:] = (0.1, -2.5, 1e-9)
    msg = deserialize_message(raw.serialized(), msg_type)
    v = getattr(msg, field)
    assert (v.x, v.y, v.z) == (0.1, -2.5, 1e-9)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1234, 567_890_123)
    assert msg.header.frame_id == 'panda_link0'
    expected = msg_type()
    expected.header = msg.header
    setattr(expected, field, v)
    assert raw.serialized() == serialize_message(expected)


def test_a_float64_refilled_in_place_is_the_message_rclpy_would_send():
    """~/stiffness_estimate: NaN while unknown, then the estimate."""
    raw = RawMessage('float64', Float64(data=float('nan')))
    assert math.isnan(deserialize_message(raw.serialized(), Float64).data)
    raw.arrays[0][0] = 2741.5
    assert raw.serialized() == serialize_message(Float64(data=2741.5))
