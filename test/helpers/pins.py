"""
The pinned figures of the deterministic runs (issue 31, item 1): test/pinned_figures.json.

One file holds them all: the commit whose code computed them, a note, the tolerance and, per
scenario, its figures (numbers only: what the scenario's metrics function returns, less the
wall time, strings, booleans and NaN). :func:`check_pinned` compares a scenario's figures with
its pins, every figure at ``rel_tol`` (an absolute floor only for a figure pinned at 0), or at
the tolerances the file's ``not_bit_exact`` entry gives a scenario that does not repeat bit for
bit (the lockstep demo; its note says why and how they were measured). With
``HFC_PIN_UPDATE=1`` in the environment it writes the scenario's figures into the file instead,
with ``git rev-parse --short HEAD`` as the commit (``+dirty`` when tracked files differ from
it). A pinned figure changes on purpose only: run the pinning tests with ``HFC_PIN_UPDATE=1``
and commit the file, the reason in the commit message.
"""
from __future__ import annotations

import fcntl
import json
import math
import os
from pathlib import Path
import subprocess
from typing import Any, Mapping

PINS_PATH = Path(__file__).resolve().parents[1] / 'pinned_figures.json'
UPDATE_VAR = 'HFC_PIN_UPDATE'
# The offline runs are deterministic: here every figure repeats bit for bit from process to
# process. With numpy's SIMD dispatch off (NPY_DISABLE_CPU_FEATURES of X86_V3/V4, AVX512_*) and
# OpenBLAS on its Nehalem kernels, 75 of 111 figures moved, by at most 4.5e-8 relative (the max
# force errors: ~1e-5 N differences of ~1 N forces). 1e-6 leaves 20x that for another machine's
# roundoff and still catches any change of the law or the loop, far below its tests' bounds.
REL_TOL = 1e-6
# A figure pinned at 0 (contact_lost_s: no sample out of contact; the lockstep demo's normal
# error: n_hat is n) has no relative scale: it may differ by 1e-12 in its unit (s, deg), an
# exact 0 in practice. Every other figure, however small, is compared at the relative tolerance.
ABS_FLOOR = 1e-12
NOTE = ('Pinned figures of the deterministic runs (test/helpers/pins.py, '
        'test/test_pinned_figures.py, test/test_demo.py). "commit": the code that computed '
        'them. Every figure is compared at rel_tol (abs_floor for a figure pinned at 0), '
        'or at the tolerances of its scenario in not_bit_exact. A change is made on '
        'purpose: HFC_PIN_UPDATE=1 rewrites the figures; the commit that changes this file '
        'says why.')

Figures = dict[str, Any]


def _number(value: Any) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value))


def numbers(metrics: Mapping[str, Any], drop: tuple[str, ...] = ('wall_time_s',)) -> Figures:
    """
    Return the figures of ``metrics``: its finite numbers and lists of them, by name.

    Strings, booleans, None and NaN (an unknown figure) are left out, and so are ``drop``'s
    names (by default the wall time, which is no figure of the run).
    """
    out: Figures = {}
    for name, value in metrics.items():
        if name in drop:
            continue
        if isinstance(value, (list, tuple)) and value and all(_number(v) for v in value):
            out[name] = list(value)
        elif _number(value):
            out[name] = value
    return out


def load() -> dict[str, Any]:
    """Return the pins file's content (empty when there is no file yet)."""
    text = PINS_PATH.read_text() if PINS_PATH.exists() else ''
    return json.loads(text) if text.strip() else {}


def mismatches(scenario: str, pinned: Figures, got: Figures, rel_tol: float = REL_TOL,
               abs_floor: float = ABS_FLOOR,
               rel_tol_by_figure: Mapping[str, float] | None = None) -> list[str]:
    """
    Return one line per figure of ``got`` that is not its pin (or has none), else [].

    A figure is its pin within ``rel_tol * |pin|`` (``abs_floor`` for a pin of 0);
    ``rel_tol_by_figure`` replaces ``rel_tol`` for the figures it names (a run that is not
    bit-exact).
    """
    lines = []
    by_figure = rel_tol_by_figure or {}
    for name in sorted(set(pinned) | set(got)):
        if name not in got:
            lines.append(f'{scenario}: {name}: pinned {pinned[name]!r}, got none')
            continue
        if name not in pinned:
            lines.append(f'{scenario}: {name}: not pinned, got {got[name]!r}')
            continue
        p, g = pinned[name], got[name]
        if isinstance(p, list) != isinstance(g, list) or (
                isinstance(p, list) and len(p) != len(g)):
            lines.append(f'{scenario}: {name}: pinned {p!r}, got {g!r}')
            continue
        pairs = ([(f'{name}[{i}]', a, b) for i, (a, b) in enumerate(zip(p, g))]
                 if isinstance(p, list) else [(name, p, g)])
        rel = by_figure.get(name, rel_tol)
        for label, a, b in pairs:
            tol = rel * abs(a) if a else abs_floor
            if not abs(b - a) <= tol:
                diff = abs(b - a) / abs(a) if a else math.inf
                lines.append(f'{scenario}: {label}: pinned {a!r}, got {b!r} '
                             f'(relative difference {diff:.3g}, tolerance {tol:.3g})')
    return lines


def _commit() -> str:
    """Return ``git rev-parse --short HEAD`` (``+dirty`` when tracked code differs from it)."""
    root = PINS_PATH.parents[1]
    head = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=root, check=True,
                          capture_output=True, text=True).stdout.strip()
    status = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'], cwd=root,
                            check=True, capture_output=True, text=True).stdout.splitlines()
    changed = [line for line in status if not line.endswith(PINS_PATH.name)]
    return head + ('+dirty' if changed else '')


def _update(scenario: str, got: Figures) -> None:
    """Write ``got`` as ``scenario``'s pins (the file locked: workers may write at once)."""
    with open(PINS_PATH, 'a+') as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        fh.seek(0)
        text = fh.read()
        data = json.loads(text) if text.strip() else {}
        scenarios = {**data.get('scenarios', {}), scenario: got}
        data = {'commit': _commit(), 'note': NOTE,
                'rel_tol': data.get('rel_tol', REL_TOL),
                'abs_floor': data.get('abs_floor', ABS_FLOOR),
                **{k: v for k, v in data.items()
                   if k not in ('commit', 'note', 'rel_tol', 'abs_floor', 'scenarios')},
                'scenarios': dict(sorted(scenarios.items()))}
        fh.seek(0)
        fh.truncate()
        fh.write(json.dumps(data, indent=2) + '\n')


def check_pinned(scenario: str, got: Figures) -> None:
    """
    Assert that ``scenario``'s figures are its pins; with HFC_PIN_UPDATE=1 pin them instead.

    Every figure within the file's ``rel_tol``, except those its ``not_bit_exact`` entry of the
    scenario gives a tolerance of their own (measured: see its note).
    """
    if os.environ.get(UPDATE_VAR) == '1':
        _update(scenario, got)
        return
    data = load()
    pinned = data.get('scenarios', {}).get(scenario)
    assert pinned is not None, (f'{scenario}: no pinned figures in {PINS_PATH.name} '
                                f'(pin them with {UPDATE_VAR}=1)')
    own = data.get('not_bit_exact', {}).get(scenario, {}).get('rel_tol')
    lines = mismatches(scenario, pinned, got, data.get('rel_tol', REL_TOL),
                       data.get('abs_floor', ABS_FLOOR), own)
    assert not lines, (f'figures differ from the pins of commit {data.get("commit")} '
                       f'({PINS_PATH.name}):\n' + '\n'.join(lines))
