"""The approach's search along n (core/law/approach.py): its limit, and where it counts from."""
from __future__ import annotations

from hybrid_force_controller.core.law.approach import Approach
import pytest

SPEED, LIMIT, DT = 0.025, 0.05, 1e-3


def _search(x_n: float, x_seen: float | None = None) -> float:
    """Run an approach from ``x_n`` (tool following it) until it ends; return where, m."""
    a = Approach(SPEED, LIMIT)
    a.start(x_n, 0.0) if x_seen is None else a.start(x_n, 0.0, x_seen)
    for _ in range(int(10 * LIMIT / SPEED / DT)):
        a.step(DT, a.x)
        if a.exhausted:
            return a.x
    raise AssertionError('the approach never ended')


def test_without_a_surface_seen_the_search_ends_limit_beyond_the_start():
    assert _search(0.10) == pytest.approx(0.10 + LIMIT, abs=1e-9)


def test_thrown_back_off_the_surface_the_search_counts_from_where_it_was_touched():
    """The tool 7 cm short of where it last touched: it searches to 5 cm beyond that point."""
    assert _search(0.03, x_seen=0.10) == pytest.approx(0.10 + LIMIT, abs=1e-9)


def test_a_surface_seen_behind_the_tool_does_not_shorten_the_search():
    assert _search(0.10, x_seen=0.02) == pytest.approx(0.10 + LIMIT, abs=1e-9)
