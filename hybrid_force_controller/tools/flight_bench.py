"""
What the flight recorder costs the control thread, measured offline (never asserted in tests).

The control thread's part of the recorder per tick (control_loop.py): read the runtime's
joint sample and wrench stamp, :meth:`FlightRecorder.record` (the row and the trigger
check), :meth:`FlightRecorder.note_hold`. :func:`replay_ticks` runs an offline scenario (the
paper's 2-link arm, or the Panda), replays the inputs the controller received into fresh
runtimes and times that part right after each tick, as the loop runs it;
:func:`record_cost_us` times it again over the stored ticks, cycled (their outputs colder
in the cache: an upper bound), call by call and in one untimed loop. Each call is timed with
``time.perf_counter``, less the median cost of two back-to-back reads. Run it with
``python -c "from hybrid_force_controller.tools.flight_bench import main; main()"``.
"""
from __future__ import annotations

import gc
import json
import time
from typing import Any

import numpy as np

from ..core.config.params import build_params
from ..core.model.robot_model import RobotModel
from ..core.offline.arm7 import panda_model, panda_scenario
from ..core.offline.scenario import run_scenario, ScenarioConfig
from ..core.runtime.controller_runtime import ControllerRuntime
from ..core.runtime.flight_recorder import FlightRecorder

__all__ = ['main', 'record_cost_us', 'replay_ticks']


def _stream(model: Any, cfg: ScenarioConfig) -> list[tuple]:
    """Run ``cfg`` and return the (stamp s, q, qdot, F_S) the controller received."""
    stream: list = []
    run_scenario(ScenarioConfig(**{**vars(cfg), 'input_hook': lambda t, msg: stream.append(
        (t, *msg)) or msg}), model)
    return stream


def _runtime(model: Any, cfg: ScenarioConfig) -> ControllerRuntime:
    theta0 = (model.theta_nominal * np.asarray(cfg.theta_hat0_scale)).tolist()
    return ControllerRuntime(model, build_params(model, {**cfg.overrides, 'theta_hat0': theta0}))


def _recorder(runtime: ControllerRuntime) -> FlightRecorder:
    return FlightRecorder(runtime.model.n, runtime.theta_hat.size, 2000, max_force=50.0,
                          stall_s=runtime.params.runtime.state_timeout)


def replay_ticks(model: Any, cfg: ScenarioConfig, rounds: int = 1,
                 ) -> tuple[ControllerRuntime, list[tuple], np.ndarray]:
    """
    Replay the inputs of ``cfg`` ``rounds`` times into fresh runtimes, recording every tick.

    Returns the last runtime, its ticks ``(t, joint_sample, wrench_stamp, TickOutput)`` and
    the recorder's per-tick cost right after each tick (its outputs still in the cache, as on
    the control thread), s, less the cost of reading the clock twice. As the node does at
    configure, the heap is frozen first (``gc.freeze``) and the loop keeps no tick's output
    but the last round's.
    """
    stream, clock = _stream(model, cfg), time.perf_counter
    names, frame = list(model.joint_names), model.end_effector_link
    cost: list[float] = []
    gc.collect()
    gc.freeze()
    for k in range(rounds):
        runtime, ticks, keep = _runtime(model, cfg), [], k == rounds - 1
        rec = _recorder(runtime)
        for t, q, qdot, F_S in stream:
            runtime.on_joint_state(names, q, qdot, t)
            runtime.on_wrench(frame, F_S, t)
            out = runtime.tick(t)
            t0 = clock()
            rec.record(t, runtime.joint_sample, runtime.wrench_stamp, out)
            rec.note_hold(1e-4)
            cost.append(clock() - t0)
            if keep:
                ticks.append((t, runtime.joint_sample, runtime.wrench_stamp, out))
    return runtime, ticks, np.array(cost) - _clock_pair_s()


def _clock_pair_s(calls: int = 100_000) -> float:
    """Return the median cost of two back-to-back perf_counter reads, s."""
    clock, empty = time.perf_counter, np.empty(calls)
    for j in range(calls):
        t0 = clock()
        empty[j] = clock() - t0
    return float(np.median(empty))


def _figures(cost_s: np.ndarray) -> dict[str, float]:
    us = cost_s * 1e6
    return {'median_us': round(float(np.median(us)), 3),
            'p99_us': round(float(np.percentile(us, 99)), 3), 'max_us': round(float(us.max()), 1),
            'calls': int(us.size)}


def record_cost_us(runtime: ControllerRuntime, ticks: list[tuple],
                   calls: int = 100_000) -> dict[str, float]:
    """
    Time the recorder's per-tick work ``calls`` times over stored ``ticks`` (cycled).

    Outputs of earlier ticks are colder in the cache than the tick's own: an upper bound.
    Returns the median, p99 and max per call, us, and the mean of an untimed loop.
    """
    rec, clock, n = _recorder(runtime), time.perf_counter, len(ticks)
    cost = np.empty(calls)
    for j in range(calls):
        t, _, _, out = ticks[j % n]
        t0 = clock()
        rec.record(t, runtime.joint_sample, runtime.wrench_stamp, out)
        rec.note_hold(1e-4)
        cost[j] = clock() - t0
    t0 = clock()
    for j in range(calls):
        t, _, _, out = ticks[j % n]
        rec.record(t, runtime.joint_sample, runtime.wrench_stamp, out)
        rec.note_hold(1e-4)
    bulk = (clock() - t0) / calls
    return {**_figures(cost - _clock_pair_s()), 'mean_untimed_us': round(bulk * 1e6, 3)}


def main(calls: int = 100_000, duration: float = 5.0) -> dict[str, Any]:
    """Print and return the cost on the paper's 2-link arm and on the Panda (JSON)."""
    out: dict[str, Any] = {}
    panda = panda_model()
    cases = (('paper_2link', RobotModel.from_urdf(), ScenarioConfig(duration=duration)),
             ('panda_7dof', panda, panda_scenario(panda, duration=duration)))
    for name, model, cfg in cases:
        rounds = max(1, round(calls / (duration * 1000)))
        runtime, ticks, hot = replay_ticks(model, cfg, rounds)
        out[name] = {'after_each_tick': _figures(hot),
                     'cycled_stored_outputs': record_cost_us(runtime, ticks, calls)}
    print(json.dumps(out, indent=2))
    return out
