"""BagRecorder over real DDS (localhost only, own domain) and read back with rosbags."""
from __future__ import annotations

import time  # noqa: E402
from typing import Callable  # noqa: E402

from geometry_msgs.msg import PointStamped, WrenchStamped  # noqa: E402
from helpers.ros import domain_id  # noqa: E402
from hybrid_force_controller.ros.programs.recorder_node import BagRecorder, message_class
from hybrid_force_controller.tools.bag_io import (RECORD_TOPICS, TOPIC_CONTACT_WRENCH,
                                                  TOPIC_WRENCH, TOPIC_X, TYPESTORE)
import pytest  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402


DOMAIN_ID = domain_id('recorder')
TIMEOUT_S = 20.0
COUNTS = {TOPIC_X: 5, TOPIC_WRENCH: 3, TOPIC_CONTACT_WRENCH: 2}


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    yield ctx
    ctx.try_shutdown()


def spin_until(executor: SingleThreadedExecutor, condition: Callable[[], bool],
               timeout_s: float = TIMEOUT_S) -> bool:
    """Spin until ``condition()`` holds or ``timeout_s`` elapses; return whether it held."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


def make_msg(topic: str, k: int):
    if topic == TOPIC_X:
        msg = PointStamped()
        msg.point.x, msg.point.y = 1.0 + k, -0.5
    else:
        msg = WrenchStamped()
        msg.wrench.force.y = -1.0 - k
    msg.header.frame_id = 'base_link'
    msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + k, 7
    return msg


def test_message_class_resolves_every_recorded_type():
    for _, msgtype in RECORD_TOPICS:
        assert message_class(msgtype).__name__ == msgtype.rsplit('/', 1)[1]


def test_recorder_writes_what_was_published(context, tmp_path):
    bag = tmp_path / 'recorded'
    recorder = BagRecorder(bag, context=context)
    talker = Node('recorder_test_talker', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(recorder)
    executor.add_node(talker)
    pubs = {t: talker.create_publisher(type(make_msg(t, 0)), t, 10) for t in COUNTS}
    subs = {s.topic_name: s for s in recorder.subscriptions}
    assert set(subs) == {t for t, _ in RECORD_TOPICS}
    matched = spin_until(executor, lambda: all(
        p.get_subscription_count() >= 1 and subs[t].get_publisher_count() >= 1
        for t, p in pubs.items()))
    assert matched, 'recorder and talker did not discover each other'
    for topic, count in COUNTS.items():
        for k in range(count):
            pubs[topic].publish(make_msg(topic, k))
    received = spin_until(executor, lambda: all(
        recorder.writer.counts[t] >= c for t, c in COUNTS.items()))
    assert received, f'recorded {recorder.writer.counts}, expected {COUNTS}'
    executor.remove_node(talker)
    executor.remove_node(recorder)
    talker.destroy_node()
    recorder.destroy_node()  # closes the bag
    assert recorder.record(TOPIC_X, b'late') is False  # logged, not raised
    assert recorder.record('/unknown', b'') is False

    with AnyReader([bag]) as reader:
        topics = reader.topics
        assert {t: i.msgtype for t, i in topics.items()} == dict(RECORD_TOPICS)
        assert {t: i.msgcount for t, i in topics.items() if i.msgcount} == COUNTS
        seen: dict[str, list] = {t: [] for t in COUNTS}
        for conn, log_ns, raw in reader.messages():
            assert log_ns > 0
            seen[conn.topic].append(reader.deserialize(raw, conn.msgtype))
    assert [m.point.x for m in seen[TOPIC_X]] == [1.0 + k for k in range(COUNTS[TOPIC_X])]
    assert [m.header.stamp.sec for m in seen[TOPIC_WRENCH]] == [100, 101, 102]
    assert [m.wrench.force.y for m in seen[TOPIC_CONTACT_WRENCH]] == [-1.0, -2.0]
    assert TYPESTORE.types[topics[TOPIC_X].msgtype].__msgtype__ == \
        'geometry_msgs/msg/PointStamped'


def test_the_bag_begins_with_its_start_topics(context, tmp_path):
    """``start_with``: other topics are dropped until each start topic came once; latched kept."""
    from rclpy.serialization import serialize_message
    from hybrid_force_controller.ros.programs.recorder_node import LATCHED_TOPICS
    latched = next(t for t, _ in RECORD_TOPICS if any(t.endswith(s) for s in LATCHED_TOPICS))
    recorder = BagRecorder(tmp_path / 'gated', context=context,
                           start_with=(TOPIC_WRENCH, TOPIC_CONTACT_WRENCH))
    raw = {t: serialize_message(make_msg(t, 0)) for t in COUNTS}
    try:
        assert recorder.record(TOPIC_X, raw[TOPIC_X]) is False          # before the bag began
        assert recorder.record(TOPIC_WRENCH, raw[TOPIC_WRENCH]) is False  # one start topic of two
        assert recorder.record(latched, b'\x00\x01\x00\x00\x00\x00\x00\x00') is True
        assert recorder.record(TOPIC_CONTACT_WRENCH, raw[TOPIC_CONTACT_WRENCH]) is True
        assert recorder.record(TOPIC_X, raw[TOPIC_X]) is True
        assert recorder.record(TOPIC_WRENCH, raw[TOPIC_WRENCH]) is True
        counts = recorder.writer.counts
        assert {t: counts.get(t, 0) for t in COUNTS} == dict.fromkeys(COUNTS, 1)
    finally:
        recorder.destroy_node()
