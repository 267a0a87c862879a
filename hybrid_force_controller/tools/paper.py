"""
``paper`` executable: the scenario of section V of [1] offline, Figs. 3-5 + metrics.

``ros2 run hybrid_force_controller paper --out DIR`` runs 20 s of the paper's scenario
(lambda1 = 40, lambda2 = 0.1, Gamma = 70 I, k = 1700 N/m, q(0) = (0.657, 0.913),
x_d = 1 + 0.1 sin t, f_d = 1 N) on the offline simulator and writes fig3_position.png,
fig4_force.png, fig5_parameters.png, fig6_stiffness.png (the online stiffness estimate and
the true k) and metrics.json into DIR. ``--stiffness-estimation`` /
``--no-stiffness-estimation`` set whether the law uses the estimate (default: the
parameter's default); metrics.json holds the final estimate either way
(``stiffness_estimate_n_per_m``, null if it never became valid).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import time
from typing import Sequence

from .analysis import compute_metrics, json_safe, RunLog
from ..core.offline.scenario import run_scenario, ScenarioConfig


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='paper', description=__doc__.splitlines()[0])
    ap.add_argument('--out', type=Path, default=Path('out/paper'), help='output directory')
    ap.add_argument('--duration', type=float, default=20.0, help='simulated time, s')
    ap.add_argument('--k', type=float, default=1700.0, help='surface stiffness, N/m')
    ap.add_argument('--delay-steps', type=int, default=0,
                    help='sensor-to-actuation delay in control periods')
    ap.add_argument('--noise-sigma', type=float, default=0.0, help='force noise sigma, N')
    ap.add_argument('--seed', type=int, default=0, help='noise seed')
    ap.add_argument('--theta-scale', type=float, default=0.5,
                    help='initial theta_hat = scale * true masses (default 0.5: 50 %% low, as '
                    "in the paper's Fig. 5)")
    ap.add_argument('--stiffness-estimation', action=argparse.BooleanOptionalAction,
                    default=None, help='use the online stiffness estimate as k_s (default: '
                    'the stiffness_estimation parameter default)')
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Run the scenario, write the figures and metrics.json; 0 on success."""
    args = _parser().parse_args(argv)
    if args.duration <= 5.0 or args.k <= 0 or args.delay_steps < 0 or args.noise_sigma < 0:
        print('error: need --duration > 5, --k > 0, --delay-steps >= 0, --noise-sigma >= 0',
              file=sys.stderr)
        return 2
    overrides = ({} if args.stiffness_estimation is None
                 else {'stiffness_estimation': args.stiffness_estimation})
    cfg = ScenarioConfig(k=args.k, duration=args.duration, delay_steps=args.delay_steps,
                         noise_sigma=args.noise_sigma, seed=args.seed,
                         theta_hat0_scale=args.theta_scale, overrides=overrides)
    t0 = time.perf_counter()
    log = RunLog.from_result(run_scenario(cfg))
    wall = time.perf_counter() - t0
    from .plots import write_figures  # matplotlib only when plotting
    args.out.mkdir(parents=True, exist_ok=True)
    metrics = compute_metrics(log, wall_time_s=wall)
    paths = write_figures(log, args.out)
    text = json.dumps(json_safe(metrics), indent=2)
    (args.out / 'metrics.json').write_text(text + '\n')
    print(text)
    for path in [*paths, args.out / 'metrics.json']:
        print(f'wrote {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
