"""
Samples of a recorded topic and their alignment on the position topic's samples (pure numpy).

bag_io.py reads a bag into :class:`Series` (header stamps, log times, values) and puts every
topic on the samples of ``~/x`` by zero-order hold (:func:`on_x_time`); the helpers here turn
the optional topics into the :class:`~.analysis.RunLog` fields (None when not recorded).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .analysis import align

__all__ = ['Series', 'on_x_time', 'path_running', 'sorted_by_stamp', 'stamp_ns', 'stiffness',
           'true_masses', 'unit_vectors']


@dataclass
class Series:
    """Samples of one topic: header stamps (or log times), log times and values."""

    stamp_ns: list[int] = field(default_factory=list)
    log_ns: list[int] = field(default_factory=list)
    values: list[Any] = field(default_factory=list)
    has_header: bool = True


def stamp_ns(msg: Any, log_ns: int) -> int:
    """Header stamp of ``msg`` in ns, or the bag log time for headerless types."""
    header = getattr(msg, 'header', None)
    if header is None:
        return log_ns
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def sorted_by_stamp(series: Series) -> Series:
    """``series`` ordered by header stamp (stable; log order breaks ties)."""
    order = np.argsort(np.asarray(series.stamp_ns, dtype=np.int64), kind='stable')
    return Series([series.stamp_ns[i] for i in order], [series.log_ns[i] for i in order],
                  [series.values[i] for i in order], series.has_header)


def on_x_time(series: Series, x: Series) -> np.ndarray:
    """
    Zero-order hold ``series`` onto the samples of the position topic.

    Stamped topics align header stamps; headerless ones (``Float64MultiArray``) align
    bag log times against the position topic's log times, so a sim-time header clock and
    a wall-clock recorder never get mixed.
    """
    t_src, t_query = ((series.stamp_ns, x.stamp_ns) if series.has_header
                      else (series.log_ns, x.log_ns))
    src_ns = np.asarray(t_src, dtype=np.int64)
    query_ns = np.asarray(t_query, dtype=np.int64)
    ref_ns = query_ns.min()  # float64 of epoch ns only resolves ~256 ns: subtract first
    order = np.argsort(src_ns, kind='stable')
    values = np.asarray(series.values, dtype=float)
    return align((query_ns - ref_ns).astype(float), (src_ns[order] - ref_ns).astype(float),
                 values[order])


def stiffness(series: Series | None, x: Series) -> np.ndarray | None:
    """
    Return the stiffness estimate on the position samples (NaN before its first message).

    None when the bag has no message on the topic.
    """
    if series is None or not series.values:
        return None
    k_hat = on_x_time(series, x)
    first_ns = min(series.stamp_ns if series.has_header else series.log_ns)
    query_ns = np.asarray(x.stamp_ns if series.has_header else x.log_ns, dtype=np.int64)
    k_hat[query_ns < first_ns] = np.nan
    return k_hat


def path_running(series: Series | None, x: Series) -> np.ndarray | None:
    """Return whether a path was ``running`` at each position sample (None: no status)."""
    if series is None or not series.values:
        return None
    running = on_x_time(series, x)
    running[np.asarray(x.log_ns) < min(series.log_ns)] = 0.0  # before the first status
    return running > 0.5


def true_masses(series: Series | None, theta_hat: np.ndarray) -> np.ndarray | None:
    """Return the sim's true link masses when they match theta_hat's size (else None)."""
    if series is None or not series.values:
        return None
    masses = series.values[-1]
    return masses if masses.shape == (theta_hat.shape[1],) else None


def unit_vectors(series: Series | None, x: Series) -> np.ndarray | None:
    """Return a normal topic on the position samples, unit length (None: not recorded)."""
    if series is None or not series.values:
        return None
    v = on_x_time(series, x)
    norms = np.linalg.norm(v, axis=1)
    return v / norms[:, None] if np.all(norms > 1e-12) else None
