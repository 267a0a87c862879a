"""
The real-time tests' bounds, set from what was measured on the halved machine (issue 31).

``test/realtime_bounds.json`` holds, for each real-time test (its pytest node id) and each
figure it bounds, the worst of the measured runs and the bound, ``multiple`` times that worst.
The runs are the tests themselves under ``taskset -c 0`` (one CPU: this machine halved), each
handing its figures on with :func:`helpers.figures.report_figure` (``HFC_FIGURES=FILE``). A
figure whose worst was 0 (no contact lost in any run) is bounded at 0: any loss fails. Where
the test's earlier bound (``cap``) was tighter than ``multiple`` times the worst, the cap stays
(a figure such as a time to reach a surface is mostly a fixed offset: 1.22-1.23 s in 10 runs),
and the entry says its own multiple.

* :func:`check_bounds`: assert that every figure the file bounds for the running test is within
  its bound (the test hands all its figures; the file says which are bounded);
* :func:`bound`: the bound of one figure of one test;
* ``python -m helpers.bounds FIGURES.jsonl [--multiple M] [--write]`` (from test/): the worst of
  each bounded figure over the runs in FIGURES and the bound it gives, beside the file's; with
  ``--write`` the file takes them (a change of bounds is made on purpose, with its reason in the
  commit). Which figures are bounded is the file's list: a new one is added by hand. An entry
  with ``documented`` keeps its worst when the runs give less (a figure measured before).
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import re
import sys
from typing import Any

from helpers import witness
from helpers.figures import current_test
import pytest

BOUNDS_FILE = Path(__file__).resolve().parents[1] / 'realtime_bounds.json'
_CACHE: dict[str, Any] = {}


def _table() -> dict[str, Any]:
    if not _CACHE:
        _CACHE.update(json.loads(BOUNDS_FILE.read_text()))
    return _CACHE


def bound(test: str, figure: str) -> float:
    """
    Return the bound of ``figure`` (``a.b`` for a figure nested in a dict) of ``test``.

    ``test`` is the node id below ``test/`` as pytest names it (``test_x.py::test_y[p]``).
    """
    tests = _table()['bounds']
    key = _key(test)
    if key not in tests or figure not in tests[key]:
        raise KeyError(f'no measured bound for {figure!r} of {key!r} in {BOUNDS_FILE.name}')
    return float(tests[key][figure]['bound'])


def check_bounds(figures: dict[str, Any], context: Any = '', test: str | None = None,
                 skip: tuple[str, ...] = ()) -> None:
    """
    Assert that each figure the file bounds for ``test`` (default: the running one) is within.

    ``figures`` may nest dicts (``a.b`` names) and need not hold all the test's bounded
    figures (a test may check its figures in parts), but at least one: a name that matches
    none fails. A bounded figure that is not a finite number fails too. ``skip``: bounded
    figures not checked here (a test's own reason, said there). ``context`` is appended to the
    failure's message (logs). A figure out of its bound while the machine itself stalled
    (:mod:`helpers.witness`) skips the test, saying both: it is the machine's figure.
    """
    test = current_test() if test is None else test
    key = _key(test)
    tests = _table()['bounds']
    if key not in tests:
        raise KeyError(f'no measured bounds for {key!r} in {BOUNDS_FILE.name}')
    flat, over = _flat(figures), []
    names = [n for n in tests[key] if n in flat or n in skip]
    assert names, f'none of {sorted(flat)} is bounded for {key!r} in {BOUNDS_FILE.name}'
    for name in names:
        entry = tests[key][name]
        if name in skip:
            continue
        v = flat[name]
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        if not ok or v > entry['bound']:
            mult = entry.get('multiple', _table()['multiple'])
            over.append(f"{name} = {v!r} > {entry['bound']:.4g} ({mult:.3g} x the worst of "
                        f"{entry['runs']} runs, {entry['worst']:.4g})")
    stalled = witness.stalls_text() if over else ''
    if stalled:  # the figures of a stalled machine are not the code's: said, not asserted
        print(f"not asserted ({stalled}): {'; '.join(over)}")
        pytest.skip(f"{stalled}; out of bounds meanwhile: {'; '.join(over)}")
    assert not over, '; '.join(over) + f'\nfigures: {figures}\n{context}'


def _key(test: str) -> str:
    """Return a node id from below test/ (``test_x.py::test_y[p]``, without xdist's ``@group``)."""
    path, sep, rest = test.partition('::')
    return path.split('/')[-1] + sep + re.sub(r'@\w+$', '', rest)


def _flat(figures: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in figures.items():
        if isinstance(v, dict):
            out.update(_flat(v, f'{prefix}{k}.'))
        else:
            out[f'{prefix}{k}'] = v
    return out


def worst_of(lines: list[dict[str, Any]]) -> dict[str, dict[str, tuple[float, int]]]:
    """Return ``{test: {figure: (worst, runs)}}``: each figure's largest value, and its count."""
    out: dict[str, dict[str, tuple[float, int]]] = {}
    for line in lines:
        test = _key(line.get('test', ''))
        for name, v in _flat({k: v for k, v in line.items() if k != 'test'}).items():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                v = math.inf if v in ('nan', 'inf', None) else None  # a failed run is worst
            if v is None:
                continue
            w, n = out.setdefault(test, {}).get(name, (-math.inf, 0))
            out[test][name] = (max(w, float(v)), n + 1)
    return out


def main(argv: list[str] | None = None) -> int:
    """Print (and with ``--write`` store) the bounds that FIGURES gives the file's figures."""
    ap = argparse.ArgumentParser(prog='python -m helpers.bounds', description=main.__doc__)
    ap.add_argument('figures', type=Path, help='the JSON lines of HFC_FIGURES')
    ap.add_argument('--multiple', type=float, default=None, help="default: the file's")
    ap.add_argument('--write', action='store_true', help='store the new bounds in the file')
    args = ap.parse_args(argv)
    table = json.loads(BOUNDS_FILE.read_text())
    multiple = args.multiple or table['multiple']
    lines = [json.loads(s) for s in args.figures.read_text().splitlines() if s.strip()]
    worst = worst_of([line for line in lines if 'test' in line])
    for test, figures in table['bounds'].items():
        for name, entry in figures.items():
            w, n = worst.get(test, {}).get(name, (math.nan, 0))
            if 'documented' in entry and n:  # a worse figure measured before these runs stays
                w = max(w, entry['worst'])
            new = min(multiple * w, entry.get('cap', math.inf))
            print(f'{test} {name}: worst {w:.4g} of {n} runs -> {new:.4g} '
                  f'(now {entry["bound"]:.4g})')
            if args.write and n:
                entry.update(worst=w, runs=n, bound=new)
                if 'cap' in entry:
                    entry['multiple'] = new / w if w else 0.0
    if args.write:
        table['multiple'] = multiple
        BOUNDS_FILE.write_text(json.dumps(table, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
