"""
The paced timer (ros/common/paced_timer.py): one callback per expiry of the timer.

The Jazzy EventsExecutor may dispatch a timer twice when two of its checks (one per ``/clock``
jump) run before the first dispatch; each dispatch is ``rcl_timer_call`` and then the
callback. Here a node on a ROS-time clock set by hand runs that sequence itself, on rclpy's
real timers: a plain timer serves the second dispatch at once (the next expiry, a period
early), the paced one skips it and comes back at that expiry.
"""
from __future__ import annotations

from helpers.ros import domain_id
from hybrid_force_controller.ros.common.paced_timer import create_paced_timer, is_repeat
import pytest

P_S = 0.1
P_NS = round(P_S * 1e9)
T0_NS = 5_000_000_000


@pytest.mark.parametrize('until_next_ns, since_served_ns, repeat', [
    (P_NS - 1_000_000, 0, False),              # on time: next call within a period
    (2 * P_NS - 1_000_000, 0, True),           # the same instant again: the next expiry taken
    (P_NS + 4_000_000, 96_000_000, False),     # 4 ms early, a period after the last: served
    (P_NS + 30_000_000, P_NS // 2 - 1, True),  # within half a period of the last served
    (None, 0, False),                          # canceled
])
def test_a_repeat_took_an_expiry_ahead_within_half_a_period(until_next_ns, since_served_ns,
                                                            repeat):
    """A repeat: next call over a period away, and under half a period since the last served."""
    assert is_repeat(until_next_ns, since_served_ns, P_NS) is repeat


@pytest.fixture
def sim_time_node():
    """Yield a node, in a context of its own, whose ROS clock the test sets (as /clock would)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.time import Time
    context = Context()
    rclpy.init(context=context, domain_id=domain_id('paced_timer'))
    node = Node('paced_timer_test', context=context,
                parameter_overrides=[Parameter('use_sim_time', value=True)])

    def set_now(t_ns: int) -> None:
        node.get_clock().set_ros_time_override(Time(nanoseconds=t_ns))
    set_now(T0_NS)
    try:
        yield node, set_now
    finally:
        node.destroy_node()
        context.try_shutdown()


def dispatch(timer) -> None:
    """Do what the EventsExecutor's DispatchTimer does: rcl_timer_call, then the callback."""
    with timer.handle:
        timer.handle.call_timer()
    timer.callback()


@pytest.mark.parametrize('paced', [False, True], ids=['plain', 'paced'])
def test_a_second_dispatch_of_one_expiry_is_skipped(sim_time_node, paced):
    """Two dispatches at one instant: the plain timer runs twice, the paced one once."""
    node, set_now = sim_time_node
    fired: list[int] = []

    def callback() -> None:
        fired.append(node.get_clock().now().nanoseconds)
    make = create_paced_timer if paced else node.create_timer
    timer = make(node, P_S, callback) if paced else make(P_S, callback)
    t1 = T0_NS + P_NS + 1_000_000  # the first expiry, seen 1 ms late
    set_now(t1)
    dispatch(timer)
    dispatch(timer)
    if not paced:
        assert fired == [t1, t1]
        assert timer.time_until_next_call() == 2 * P_NS - 1_000_000  # one expiry lost
        return
    assert fired == [t1]
    assert timer.time_until_next_call() == P_NS  # reset: the expiry it took, a period on
    set_now(t1 + P_NS)
    assert timer.is_ready()
    dispatch(timer)
    assert fired == [t1, t1 + P_NS]
