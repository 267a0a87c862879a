"""
What the tests measure and hand on: angles between vectors, and the real-time figures.

* :func:`angle_deg`: the angle between two vectors, in degrees;
* :func:`report_figure`: one JSON line of a test's measured figures appended to the file that
  ``HFC_FIGURES`` names (nothing when it is unset), so that bounds can be set from the
  distributions of many runs rather than from one;
* :func:`needs_cpus`: a mark that skips a test the machine cannot make meaningful (a real-time
  run whose result depends on a CPU of its own for the loop), saying why.
"""
from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np
import pytest


FIGURES_VAR = 'HFC_FIGURES'


def angle_deg(a, b) -> float:
    """Return the angle between vectors ``a`` and ``b``, degrees (0 to 180)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c = float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _plain(value: Any) -> Any:
    """Return ``value`` as JSON can hold it: numpy scalars and arrays as numbers and lists."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # 'nan', 'inf': strict JSON has no such numbers
    return value


def report_figure(test_name: str, **figures: Any) -> None:
    """
    Append ``{"test": test_name, **figures}`` as one JSON line to the file ``$HFC_FIGURES``.

    A no-op when the variable is unset or empty. The tests call it with the figures they assert
    on (RMS errors, peaks, times back in band, ...), before asserting, so a failing run is
    counted too.
    """
    path = os.environ.get(FIGURES_VAR, '')
    if not path:
        return
    line = json.dumps({'test': test_name, **_plain(figures)}, sort_keys=False)
    with open(path, 'a') as f:  # one write of one line: runs may append side by side
        f.write(line + '\n')


def current_test() -> str:
    """Return the running test's node id (``PYTEST_CURRENT_TEST`` without its phase)."""
    return os.environ.get('PYTEST_CURRENT_TEST', '').rsplit(' ', 1)[0]


def needs_cpus(n: int, why: str):
    """Return a mark that skips a test when this process may run on fewer than ``n`` CPUs."""
    have = len(os.sched_getaffinity(0))
    return pytest.mark.skipif(have < n, reason=f'needs {n} CPUs ({have} here): {why}')
