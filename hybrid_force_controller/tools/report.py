"""
``report BAG --out DIR``: metrics and Figs. 3-5 of a recorded controller run.

Writes ``metrics.json`` (non-finite numbers such as an unknown wall time become ``null``;
``stiffness_estimate_n_per_m`` is the last recorded stiffness estimate, ``null`` when the
bag has no ``~/stiffness_estimate`` or it was unknown at the end; ``rms_path_error_m`` and
``max_path_error_m`` the tool's distance from the desired point in the tangent plane, while a
user's path was running, or over ``t >= T_START`` when none did: ``path_window`` says which)
and three PNGs to ``DIR``, plus ``fig6_stiffness.png`` when the estimate was recorded
(``--k-true``: the surface's true stiffness, drawn for comparison) and ``fig7_path.png``, the
path in the surface plane, desired against actual. With ``~/surface_normal`` and
``/sim/contact_normal`` recorded, ``normal_error_deg`` (the largest angle between the
controller's normal and the true one from 2 s after sliding begins; ``sliding_begins_s``) and
``fig8_normal.png`` (normal_analysis.py), and the force error is the true force along the
true normal. Exit code 0 on success, 2 on an
unreadable bag or invalid run.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
import sys
from typing import Sequence

from .analysis import AnalysisError, compute_metrics, json_safe
from .bag_io import BagError, load_run
from .normal_analysis import normal_metrics
from .orientation_analysis import orientation_metrics
from .path_analysis import path_metrics
from .plots import (write_figures, write_normal_figure, write_orientation_figure,
                    write_path_figure)

__all__ = ['main']


def _parser() -> argparse.ArgumentParser:
    """Command-line interface."""
    parser = argparse.ArgumentParser(
        prog='report', description='Metrics and figures of a hybrid_force_controller bag.')
    parser.add_argument('bag', type=Path, help='rosbag2 directory (MCAP or sqlite3)')
    parser.add_argument('--out', type=Path, required=True, help='output directory')
    parser.add_argument('--t-start', type=float, default=5.0,
                        help='errors use samples with t >= T_START seconds (default 5)')
    parser.add_argument('--contact-threshold', type=float, default=0.05,
                        help='normal force [N] above which the tool is in contact')
    parser.add_argument('--wall-time', type=float, default=float('nan'),
                        help='wall-clock duration of the run [s], copied to metrics.json')
    parser.add_argument('--k-true', type=float, default=None,
                        help='true surface stiffness [N/m], drawn in fig6_stiffness.png')
    parser.add_argument('--tool-tilt', type=float, default=0.0,
                        help="the controller's tool_tilt [rad]: the tilt error is the tool "
                             "axis' angle from the normal less it")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """
    Run the report.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; ``None`` reads ``sys.argv``.

    Returns
    -------
    int
        0 on success, 2 when the bag cannot be used or the output cannot be written
        (message on stderr).

    """
    args = _parser().parse_args(argv)
    try:
        log = load_run(args.bag, contact_threshold_n=args.contact_threshold)
        if args.k_true is not None:
            log = dataclasses.replace(log, k_true=args.k_true)
        metrics = compute_metrics(log, t_start=args.t_start, wall_time_s=args.wall_time)
        metrics.update(path_metrics(log, t_start=args.t_start))
        metrics.update(normal_metrics(log))
        if log.tool_axis_W is not None:  # a tool with an axis (MuJoCo's): how square it was
            metrics.update(orientation_metrics(log, args.tool_tilt))
    except (BagError, AnalysisError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    metrics_path = args.out / 'metrics.json'
    try:
        figures = write_figures(log, args.out)
        figures.append(write_path_figure(log, args.out, args.t_start))
        figures.extend(p for p in [write_normal_figure(log, args.out),
                                   write_orientation_figure(log, args.out, args.tool_tilt)]
                       if p is not None)
        metrics_path.write_text(json.dumps(json_safe(metrics), indent=2) + '\n')
    except OSError as exc:
        print(f'error: cannot write to {args.out}: {exc}', file=sys.stderr)
        return 2
    print(f'metrics: {metrics_path}')
    for path in figures:
        print(f'figure:  {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
