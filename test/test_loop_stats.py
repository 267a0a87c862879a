"""HoldStats (core/runtime/loop_stats.py): the holds of a whole run, and where the longest went."""
from __future__ import annotations

import math

from hybrid_force_controller.core.runtime.loop_stats import hold_phases, HoldStats
import pytest


def test_summary_counts_every_hold_with_its_exact_max_and_binned_p999():
    holds = HoldStats(('joint_states', 'wrench'))
    for _ in range(999):
        holds.record('joint_states', 0.0002)
    holds.record('joint_states', 0.0123)
    holds.record('wrench', 0.00005)
    s = holds.summary()
    assert s['joint_states_count'] == 1000 and s['wrench_count'] == 1
    assert math.isclose(s['joint_states_max_ms'], 12.3)
    assert math.isclose(s['joint_states_p999_ms'], 0.21)  # the upper edge of the 10 us bin
    assert s['all_count'] == 1001 and math.isclose(s['all_max_ms'], 12.3)


def test_the_mean_hold_is_within_a_bin_and_nan_without_samples():
    """{kind}_mean_ms: what a kind of callback costs the thread per call (count x mean)."""
    holds = HoldStats(('joint_states', 'wrench'))
    for d in (0.00012, 0.00031, 0.00047):
        holds.record('joint_states', d)
    s = holds.summary()
    exact = (0.12 + 0.31 + 0.47) / 3
    assert abs(s['joint_states_mean_ms'] - exact) <= HoldStats.BIN_S * 1e3
    assert math.isclose(s['all_mean_ms'], s['joint_states_mean_ms'])
    assert math.isnan(s['wrench_mean_ms'])


def test_where_names_the_longest_hold_and_its_phases_and_reset_forgets_it():
    holds = HoldStats(('joint_states', 'wrench'))
    assert holds.where() == ''
    holds.longest = (0.0031, 'joint_states', (0.00005, 0.0029, 0.00015))
    assert holds.where() == 'joint_states 3.10 ms: inputs 0.05, tick 2.90, publish 0.15'
    holds.longest = (0.0042, 'wrench', ())
    assert holds.where() == 'wrench 4.20 ms'
    holds.reset()
    assert holds.where() == '' and holds.summary()['all_count'] == 0


def test_hold_phases_of_a_joint_state_and_of_a_timer_that_ticked():
    """A timer tick's hold is split too (a 335 ms one had no phases); no tick, no phases."""
    assert hold_phases('joint_states', 1.0, [1.001, 1.004], 1.006) == \
        pytest.approx((0.001, 0.003, 0.002))
    assert hold_phases('timer', 1.0, [1.0, 1.003], 1.338) == pytest.approx((0.0, 0.003, 0.335))
    assert hold_phases('timer', 1.0, [1.0, 1.0], 1.002) == ()  # the watchdog did not tick
    assert hold_phases('wrench', 1.0, [1.0, 1.0], 1.002) == ()
