"""helpers.bounds: a real-time test's figures checked against the measured bounds file."""
from __future__ import annotations

import json

from helpers import bounds
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
