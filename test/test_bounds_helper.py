"""helpers.bounds: a real-time test's figures checked against the measured bounds file."""
from __future__ import annotations

import json
import os
import re
import signal
import time

from helpers import bounds, witness
from helpers.ros import wait_for
from helpers.watch import assert_clean_run
import pytest

TABLE = {'multiple': 5.0, 'measured': 'a test', 'bounds': {
    'test_x.py::test_y[a]': {'rms': {'worst': 0.01, 'runs': 10, 'bound': 0.05},
                             'lost_s': {'worst': 0.0, 'runs': 10, 'bound': 0.0},
                             'inner.peak': {'worst': 2.0, 'runs': 10, 'bound': 10.0},
                             'doc': {'worst': 0.5, 'runs': 10, 'bound': 2.5,
                                     'documented': 'measured before'}}}}


@pytest.fixture
def table(tmp_path, monkeypatch):
    path = tmp_path / 'realtime_bounds.json'
    path.write_text(json.dumps(TABLE))
    monkeypatch.setattr(bounds, 'BOUNDS_FILE', path)
    monkeypatch.setattr(bounds, '_CACHE', {})
    return path


def test_figures_within_their_bounds_pass_and_one_over_fails_saying_which(table):
    test = 'test/test_x.py::test_y[a]'
    bounds.check_bounds({'rms': 0.05, 'lost_s': 0.0, 'inner': {'peak': 9.9}}, test=test)
    with pytest.raises(AssertionError, match=r'rms = 0.051 > 0.05 \(5 x the worst of 10'):
        bounds.check_bounds({'rms': 0.051}, test=test)
    with pytest.raises(AssertionError, match='lost_s'):  # a worst of 0 bounds at 0
        bounds.check_bounds({'lost_s': 0.001}, test=test)
    with pytest.raises(AssertionError, match='inner.peak'):
        bounds.check_bounds({'inner': {'peak': 10.5}}, test=test)
    assert bounds.bound(test, 'inner.peak') == 10.0
    assert bounds.bound(test + '@ros', 'rms') == 0.05  # the node id under xdist's loadgroup


def test_not_a_number_fails_a_skip_is_not_checked_and_a_stray_name_fails(table):
    test = 'test_x.py::test_y[a]'
    for bad in (float('nan'), None, 'nan', True):
        with pytest.raises(AssertionError, match='rms'):
            bounds.check_bounds({'rms': bad}, test=test)
    bounds.check_bounds({'rms': 0.01, 'lost_s': 3.0}, test=test, skip=('lost_s',))
    with pytest.raises(AssertionError, match='none of'):
        bounds.check_bounds({'other': 1.0}, test=test)
    with pytest.raises(KeyError, match='no measured bounds'):
        bounds.check_bounds({'rms': 0.01}, test='test_x.py::test_z')


def test_the_worst_of_the_runs_makes_the_bound(table, tmp_path, capsys):
    lines = [{'test': 'test/test_x.py::test_y[a]', 'rms': r, 'lost_s': 0.0, 'doc': 0.1,
              'inner': {'peak': p}} for r, p in ((0.02, 1.0), (0.03, 3.0))]
    lines.append({'test': 'test/test_x.py::test_y[a]', 'rms': 'nan'})  # a failed run: worst
    figures = tmp_path / 'figures.jsonl'
    figures.write_text('\n'.join(json.dumps(d) for d in lines[:2]) + '\n{"round": 1}\n')
    assert bounds.main([str(figures), '--write']) == 0
    got = json.loads(table.read_text())['bounds']['test_x.py::test_y[a]']
    assert got['rms'] == {'worst': 0.03, 'runs': 2, 'bound': pytest.approx(0.15)}
    assert got['inner.peak']['bound'] == pytest.approx(15.0) and got['lost_s']['bound'] == 0.0
    assert got['doc']['worst'] == 0.5 and got['doc']['bound'] == pytest.approx(2.5)
    assert bounds.worst_of(lines)['test_x.py::test_y[a]']['rms'] == (float('inf'), 3)


def test_a_stall_of_the_machine_skips_a_figure_out_of_bounds_and_says_so(table):
    """
    The witness writes down a stall (its own process stopped 0.1 s stands for the machine's).

    Within the test's window a figure out of its bound skips the test, naming the stall; a
    figure within passes; after the window ends the same figure fails as before.
    """
    test = 'test/test_x.py::test_y[a]'
    witness.start_test()
    try:
        proc, cpu = witness._PROCS[0], min(os.sched_getaffinity(0))  # the first CPU's
        # its own file's header: the other's may come first (s52g, s52j: this one was still
        # starting when it was stopped, and wrote down no gap)
        own_file = witness._STATE['dir'] / f'cpu{cpu}.txt'
        wait_for(lambda: own_file.exists() and '# cpu' in own_file.read_text(), 'the witness')
        if 'fifo' not in own_file.read_text():
            pytest.skip('SCHED_FIFO is not permitted here: the witness counts no stall')
        os.kill(proc.pid, signal.SIGSTOP)
        try:
            time.sleep(0.1)  # the stall itself, not a wait on a condition
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        # the machine's own stalls may be written down beside it (s52g: both CPUs 30 ms)
        own = re.compile(rf'CPU {cpu} [1-9]\d\d ms at -?\d+\.\d\d s into the test \(fifo\)')
        wait_for(lambda: own.search(witness.stalls_text()),
                 lambda: f'the stall written down: {witness.stalls_text()!r}')
        assert witness.stalls_text().startswith('the machine stalled: CPU ')
        bounds.check_bounds({'rms': 0.05}, test=test)
        with pytest.raises(pytest.skip.Exception, match=r'the machine stalled: CPU .*; out of '
                           r'bounds meanwhile: rms = 0.051 > 0.05'):
            bounds.check_bounds({'rms': 0.051}, test=test)
        witness.end_test()
        assert witness.stalls_text() == ''
        with pytest.raises(AssertionError, match='rms = 0.051 > 0.05'):
            bounds.check_bounds({'rms': 0.051}, test=test)
    finally:
        witness.end_test()
        witness.stop()


def _status(implausible: int, startup: int, errors: int) -> dict:
    return {'joint_state_clock_implausible': implausible,
            'joint_state_clock_startup_refusals': startup,
            'callback_errors_joint_states': errors, 'safe_mode_entries': 0}


def test_a_clean_run_excuses_only_stamps_refused_in_their_clocks_first_second():
    """All refused in the stream's first second (the middleware's start-up) pass; no other."""
    assert_clean_run(_status(1, 1, 1))
    assert_clean_run(_status(3, 3, 3))
    for bad in (_status(2, 1, 2), _status(1, 0, 1), _status(1, 1, 2)):
        with pytest.raises(AssertionError, match='inputs refused'):
            assert_clean_run(bad)
