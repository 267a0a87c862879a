"""
A timer that runs its callback once per expiry, whatever the executor.

The Jazzy :func:`rclpy.experimental.EventsExecutor` checks its timers on every jump of the
clock (every ``/clock`` message with ``use_sim_time``), and queues a dispatch for each check
that finds a timer due. When two checks run before the first dispatch (the executor was
busy while ``/clock`` came), the timer is dispatched twice: ``rcl_timer_call`` moves its next
call a period on each time, so the second dispatch serves the next expiry at once, a period
early, and that expiry then never comes. The CI saw it as two ``/diagnostics`` statuses with
one stamp and a gap of two periods after them (docs/results.md section 31).

:func:`create_paced_timer` serves a dispatch unless it is such a repeat: one that took
an expiry ahead of now (the time to the next call, read in the callback after rcl moved it
on, is over a period) less than half a period after the last dispatch it served. A repeat is
skipped and the timer reset, so its next call is a period from now: the expiry it took. A
dispatch that took an expiry ahead later than that (the executor's check ran a little before
the expiry) is served, as rclpy would.
"""
from __future__ import annotations

from typing import Any, Callable

from rclpy.node import Node
from rclpy.timer import Timer

__all__ = ['create_paced_timer', 'is_repeat']


def is_repeat(until_next_ns: int | None, since_served_ns: int, period_ns: int) -> bool:
    """
    Say whether a dispatch repeats the last one served (see the module).

    ``until_next_ns``: the timer's time to its next call, read in the callback; None when it
    was canceled. ``since_served_ns``: the clock's time since the last dispatch served.
    """
    return (until_next_ns is not None and until_next_ns > period_ns
            and 2 * since_served_ns < period_ns)


def create_paced_timer(node: Node, period_s: float, callback: Callable[[], Any],
                       **kwargs: Any) -> Timer:
    """
    ``node.create_timer(period_s, callback, **kwargs)``, with repeated dispatches skipped.

    A repeat resets the timer (its next call a period from now) instead of running
    ``callback``. One clock reading per dispatch.
    """
    period_ns = round(period_s * 1e9)
    timer: Timer | None = None
    served = [-period_ns]  # the clock's time at the last dispatch served, ns

    def paced() -> None:
        now_ns = timer.clock.now().nanoseconds
        if is_repeat(timer.time_until_next_call(), now_ns - served[0], period_ns):
            timer.reset()
            return
        served[0] = now_ns
        callback()

    timer = node.create_timer(period_s, paced, **kwargs)
    return timer
