"""
Offline speed figures of the ``bench`` executable (never asserted in tests).

- ``controller_step_us_median`` / ``_p99``: one ``ControllerRuntime.tick`` (inputs already
  stored: filter, reference, control law (5)-(11), adaptation (26), limits) of the 2-DOF
  arm along the paper trajectory, driven by the loop engine;
- ``controller_step_7dof_us_median`` / ``_p99``: the same for the 7-DOF Panda (redundant);
- ``path_tick_7dof_us_median`` / ``_p99`` and ``hold_tick_7dof_us_median`` / ``_p99``: the
  Panda's tick while it follows a 4 cm square (``~/path``) and, in the same window of the
  same run without the path, while it holds its point (the reference's cost: the spline's
  evaluation against a held point);
- ``normal_tick_7dof_us_median_off`` / ``_on`` and ``normal_tick_ratio``: the Panda's tick
  without and with the surface-normal estimate (``n_estimation``), told n = [0, 0, -1] on
  its plane tilted 0.3 rad while it follows a 4 cm square: one recorded input stream replayed
  into two runtimes, tick by tick in alternation (the machine's load falls on both alike),
  three times: the medians' medians and the median ratio of the medians (issue 24: at most
  1.1);
- ``orientation_tick_7dof_us_median_free`` / ``_moment`` and ``orientation_tick_ratio``: the
  same paired replay, ``orientation_mode`` free against moment (the 6-D task; issue 32);
- ``idle_tick_{paper,7dof}_us_median_hot`` / ``_idle`` and ``_idle_over_hot``: one recorded
  stream replayed into a runtime, its states back to back and then 0.9 ms asleep before each
  (a 1 kHz node's idle between messages, which leaves the tick's caches cold);
- ``plant_step_{paper,7dof}_us_median_{python,compiled}`` and ``_compiled_over_python``: one
  plant step (2 sub-steps, efforts held, the tool 1 mm into the plane) with ``plant_impl``
  python (pinocchio's ABA) and compiled (plant_kernels.py), alternated twice;
- ``sim_realtime_factor`` and ``paper_wall_time_s``: the 20 s paper scenario offline;
- with ``old_tree`` (a checkout of commit 34ec57e, the code before the round that made the
  tick dearer): its controller step timed in a subprocess, alternating three times with
  this tree's tick in this process, and ``tick_median_over_old`` (this / that, medians).
``bench --ros`` adds the ROS loop in real time (ros/lab/bench.py).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
import subprocess
import sys
import time

import numpy as np

from ..core.config.params import build_params
from ..core.model.robot_model import RobotModel
from ..core.offline.arm7 import panda_model, PANDA_Q0, panda_scenario, square_path_event
from ..core.offline.environment import make_surface
from ..core.offline.scenario import PAPER_Q0, run_scenario, ScenarioConfig
from ..core.offline.simulator import ArmSimulator
from ..core.runtime.controller_runtime import ControllerRuntime


def _tick_us(cfg: ScenarioConfig, model=None) -> np.ndarray:
    """Wall time of every runtime tick of one offline run, us."""
    result = run_scenario(cfg, model, clock_ns=time.perf_counter_ns)
    return result.log.tick_ns / 1e3


_OLD_STEP = ('import json, sys; sys.path.insert(0, sys.argv[1]); import numpy as np; '
             'from hybrid_force_controller.bench import controller_step_times_us as f; '
             'print(json.dumps(float(np.median(f(5000)))))')


def old_tree_step_us(old_tree: str) -> float:
    """Median controller step of the tree at ``old_tree`` (commit 34ec57e's bench), us."""
    out = subprocess.run([sys.executable, '-c', _OLD_STEP, str(Path(old_tree).resolve())],
                         capture_output=True, text=True, check=True, cwd='/')
    return json.loads(out.stdout)


def tick_ratio(old_tree: str, rounds: int = 3) -> dict[str, float]:
    """Time this tree's tick against the old tree's step (medians), alternating ``rounds``."""
    new, old = [], []
    for _ in range(rounds):
        old.append(old_tree_step_us(old_tree))
        new.append(float(np.median(_tick_us(ScenarioConfig(duration=5.0)))))
    return {'tick_us_median_this': round(float(np.median(new)), 2),
            'tick_us_median_34ec57e': round(float(np.median(old)), 2),
            'tick_median_over_old': round(float(np.median(new) / np.median(old)), 3)}


def path_tick_figures(model=None) -> dict[str, float]:
    """Return the Panda's tick with and without a path over the path's window, us."""
    model = panda_model() if model is None else model
    still = {'overrides': {'ref_amplitude': [0.0, 0.0, 0.0]}}
    sent: dict = {}
    path = run_scenario(panda_scenario(model, 5.0, events=[square_path_event(0.5, 0.04, sent)],
                                       **still), model, clock_ns=time.perf_counter_ns)
    hold = run_scenario(panda_scenario(model, 5.0, **still), model,
                        clock_ns=time.perf_counter_ns)
    out = {}
    for name, result in (('path', path), ('hold', hold)):
        us = result.log.tick_ns[result.t >= sent['t'] + 0.1] / 1e3  # one tick per step
        out[f'{name}_tick_7dof_us_median'] = round(float(np.median(us)), 2)
        out[f'{name}_tick_7dof_us_p99'] = round(float(np.percentile(us, 99)), 2)
    return out


def recorded_stream(model, cfg: ScenarioConfig, path: bool = True) -> tuple[list, dict]:
    """
    Run ``cfg`` and return the (stamp s, q, qdot, F_S) the controller received, and the path.

    ``path`` False: no path (the paper's planar arm; ``sent`` is then empty).
    """
    stream: list = []
    sent: dict = {}
    events = [square_path_event(0.5, 0.04, sent)] if path else cfg.events
    cfg = ScenarioConfig(**{**vars(cfg), 'events': events,
                            'input_hook': lambda t, msg: stream.append((t, *msg)) or msg})
    run_scenario(cfg, model)
    return stream, sent


def normal_tick_figures(model=None, duration: float = 4.0, rounds: int = 3) -> dict[str, float]:
    """Return the Panda's tick without and with the normal estimate, paired (us, ratio)."""
    off, on, ratio = _paired_medians(model, duration, rounds, {'n_estimation': False},
                                     {'n_estimation': True})
    return {'normal_tick_7dof_us_median_off': off, 'normal_tick_7dof_us_median_on': on,
            'normal_tick_ratio': ratio}


def orientation_tick_figures(model=None, duration: float = 4.0,
                             rounds: int = 3) -> dict[str, float]:
    """Return the Panda's tick with orientation_mode free and moment, paired (us, ratio)."""
    free, moment, ratio = _paired_medians(model, duration, rounds,
                                          {'orientation_mode': 'free'},
                                          {'orientation_mode': 'moment'})
    return {'orientation_tick_7dof_us_median_free': free,
            'orientation_tick_7dof_us_median_moment': moment, 'orientation_tick_ratio': ratio}


def tick_impl_figures(model=None, duration: float = 4.0, rounds: int = 3) -> dict[str, float]:
    """Return the Panda's tick with tick_impl python and compiled, free and moment, paired."""
    out = {}
    for mode in ('free', 'moment'):
        py, nb, ratio = _paired_medians(model, duration, rounds,
                                        {'orientation_mode': mode, 'tick_impl': 'python'},
                                        {'orientation_mode': mode, 'tick_impl': 'compiled'})
        out.update({f'tick_7dof_{mode}_us_median_python': py,
                    f'tick_7dof_{mode}_us_median_compiled': nb,
                    f'tick_7dof_{mode}_compiled_over_python': ratio})
    return out


def _paired_medians(model, duration: float, rounds: int, a: dict,
                    b: dict) -> tuple[float, float, float]:
    """
    Return the tick's medians with settings ``a`` and ``b`` (us) and their median ratio.

    One recorded input stream (told n = [0, 0, -1] on the plane tilted 0.3 rad, learning it,
    a 4 cm square) replayed into two runtimes tick by tick in alternation, ``rounds`` times.
    """
    model = panda_model() if model is None else model
    tilt = (0.0, math.sin(0.3), -math.cos(0.3))
    cfg = panda_scenario(model, duration, surface_normal=tilt, overrides={
        'n': [0.0, 0.0, -1.0], 'n_estimation': True, 'ref_amplitude': [0.0, 0.0, 0.0]})
    stream, sent = recorded_stream(model, cfg)
    theta0 = (model.theta_nominal * np.asarray(cfg.theta_hat0_scale)).tolist()
    k_path = next(k for k, msg in enumerate(stream) if msg[0] >= sent['t'])
    medians = []
    for _ in range(rounds):
        runtimes = [ControllerRuntime(model, build_params(
            model, {**cfg.overrides, 'theta_hat0': theta0, **setting})) for setting in (a, b)]
        ticks = _paired_ticks(model, runtimes, stream, k_path, sent['plan'])
        medians.append([float(np.median(np.array(v[len(v) // 4:]))) / 1e3 for v in ticks])
    med_a, med_b = np.median(np.array(medians), axis=0)
    return (round(float(med_a), 2), round(float(med_b), 2),
            round(float(np.median([y / x for x, y in medians])), 3))


def _paired_ticks(model, runtimes: list, stream: list, k_path: int, plan) -> list[list[int]]:
    """Replay ``stream`` into both runtimes, tick by tick in alternation; each tick's ns."""
    names, frame = list(model.joint_names), model.end_effector_link
    ticks: list[list[int]] = [[], []]
    clock = time.perf_counter_ns
    for k, (t, q, qdot, F_S) in enumerate(stream):
        for i in ((0, 1) if k % 2 else (1, 0)):
            rt = runtimes[i]
            if k == k_path:
                rt.on_path(plan, 1)
            rt.on_joint_state(names, q, qdot, t)
            rt.on_wrench(frame, F_S, t)
            t0 = clock()
            rt.tick(t)
            ticks[i].append(clock() - t0)
    return ticks


def idle_tick_figures(idle_s: float = 0.0009, rounds: int = 2) -> dict[str, float]:
    """
    Return each arm's tick back to back and after ``idle_s`` of sleep, medians (us) and ratio.

    One recorded stream (the paper's scenario; the Panda's, with its 4 cm square) replayed into
    a runtime: first every state at once (caches warm: the figures above), then with the
    loop's idle between states, as a 1 kHz node sleeps between messages. What the tick costs
    in the node follows the second (docs/results.md section 36).
    """
    out = {}
    panda = panda_model()
    for arm, model, cfg in (('paper', None, ScenarioConfig(duration=4.0)),
                            ('7dof', panda, panda_scenario(panda, 4.0))):
        stream, sent = recorded_stream(model, cfg, path=model is not None)
        runs = {name: [] for name in ('hot', 'idle')}
        for _ in range(rounds):
            for name, idle in (('hot', 0.0), ('idle', idle_s)):
                runs[name].append(_replayed_tick_us(model, cfg, stream, sent, idle))
        hot, idle = (float(np.median(v)) for v in runs.values())
        out.update({f'idle_tick_{arm}_us_median_hot': round(hot, 2),
                    f'idle_tick_{arm}_us_median_idle': round(idle, 2),
                    f'idle_tick_{arm}_idle_over_hot': round(idle / hot, 3)})
    return out


def plant_impl_figures(steps: int = 2000, rounds: int = 2) -> dict[str, float]:
    """Return each arm's plant step with either ``plant_impl``, medians (us), and the ratio."""
    out = {}
    for arm, model, n_W in (('paper', RobotModel.from_urdf(), (0.0, -1.0, 0.0)),
                            ('7dof', panda_model(), (0.0, 0.0, -1.0))):
        q0 = np.array(PAPER_Q0 if arm == 'paper' else PANDA_Q0)
        p0 = model.kinematics(q0, np.zeros(model.n)).p_W
        surface = make_surface('plane', 3000.0, p0 - 1e-3 * np.asarray(n_W), n_W)
        runs = {'python': [], 'compiled': []}
        for _ in range(rounds):
            for impl, times in runs.items():
                plant = ArmSimulator(model, surface, q0, substeps=2, impl=impl)
                tau, ns = np.zeros(model.n), []
                for _ in range(steps):
                    t0 = time.perf_counter_ns()
                    plant.step(tau, 1e-3)
                    ns.append(time.perf_counter_ns() - t0)
                times.append(float(np.median(ns)) / 1e3)
        py, comp = (float(np.median(v)) for v in runs.values())
        out.update({f'plant_step_{arm}_us_median_python': round(py, 2),
                    f'plant_step_{arm}_us_median_compiled': round(comp, 2),
                    f'plant_step_{arm}_compiled_over_python': round(comp / py, 3)})
    return out


def _replayed_tick_us(model, cfg: ScenarioConfig, stream: list, sent: dict,
                      idle_s: float) -> float:
    """Replay ``stream`` into a new runtime, ``idle_s`` asleep before each state; median tick."""
    model = RobotModel.from_urdf() if model is None else model
    theta0 = (model.theta_nominal * np.asarray(cfg.theta_hat0_scale)).tolist()
    rt = ControllerRuntime(model, build_params(model, {**cfg.overrides, 'theta_hat0': theta0}))
    names, frame, clock = list(model.joint_names), model.end_effector_link, time.perf_counter_ns
    ticks, path = [], sent.get('plan')
    for t, q, qdot, F_S in stream:
        if path is not None and t >= sent['t']:
            rt.on_path(path, 1)
            path = None
        if idle_s:
            time.sleep(idle_s)
        rt.on_joint_state(names, q, qdot, t)
        rt.on_wrench(frame, F_S, t)
        t0 = clock()
        rt.tick(t)
        ticks.append(clock() - t0)
    return float(np.median(ticks[len(ticks) // 4:])) / 1e3


def offline_figures(old_tree: str | None = None) -> dict[str, float]:
    """Measure the controller step percentiles and the paper scenario's real-time factor."""
    ratio = {} if old_tree is None else tick_ratio(old_tree)
    step_us = _tick_us(ScenarioConfig(duration=20.0))
    panda = panda_model()
    panda_us = _tick_us(panda_scenario(panda, duration=5.0), panda)
    t0 = time.perf_counter()
    run_scenario(ScenarioConfig())
    wall = time.perf_counter() - t0
    return {'controller_step_us_median': round(float(np.median(step_us)), 2),
            'controller_step_us_p99': round(float(np.percentile(step_us, 99)), 2),
            'controller_step_7dof_us_median': round(float(np.median(panda_us)), 2),
            'controller_step_7dof_us_p99': round(float(np.percentile(panda_us, 99)), 2),
            **path_tick_figures(panda), **normal_tick_figures(panda),
            **orientation_tick_figures(panda), **tick_impl_figures(panda),
            **idle_tick_figures(), **plant_impl_figures(),
            'paper_wall_time_s': round(wall, 3),
            'sim_realtime_factor': round(20.0 / wall, 2), **ratio}
