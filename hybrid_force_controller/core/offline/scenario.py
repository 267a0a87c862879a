"""
Closed loop of controller and plant, offline: the paper's scenario (section V of [1]).

Pure numpy + pinocchio. The runtime (the node's own logic) runs against the simulated arm
through the one loop engine (engine.py) with a timing model: by default the ideal
lockstep loop with ``delay_steps`` periods of sensor-to-actuation delay (a ROS loop
between two processes adds 1-2); ``timing`` replays a real-time loop instead.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from .engine import COMMAND_TIMEOUT_S, Event, LoopLog, run_loop
from .environment import ElasticSurface, make_surface
from .simulator import ArmSimulator
from .timing import TimingModel
from ..config.params import build_params
from ..model.robot_model import RobotModel
from ..runtime.contact import in_contact
from ..runtime.controller_runtime import ControllerRuntime

__all__ = ['PAPER_Q0', 'ScenarioConfig', 'ScenarioResult', 'run_scenario']

PAPER_Q0 = (0.657, 0.913)


@dataclass(frozen=True)
class ScenarioConfig:
    """
    The paper's scenario by default: k = 1700 N/m, 20 s, q(0) = (0.657, 0.913).

    The surface passes through the tool's start position (touching, zero force), with
    normal ``n`` (into the surface). ``theta_hat0_scale`` (one factor or one per
    parameter) multiplies the true parameters to give the initial estimate; ``overrides``
    are controller parameter values; ``timing`` (default: lockstep with ``delay_steps``),
    ``events`` (parameter sets, surface moves at given times) and ``input_hook`` (faults
    on the messages the controller receives) and the plant's ``command_timeout`` (its
    watchdog, s) go to the engine. ``surface_normal`` (None: the controller's ``n``),
    ``surface_shape``, ``surface_radius`` and ``surface_axis`` describe the workpiece as the
    sim's parameters do (environment.py ``make_surface``): touched at the tool's start, its
    normal there ``surface_normal``; the controller is told only ``n``. ``plant_impl``: the
    plant's step compiled (plant_kernels.py) or its Python reference (simulator.py).
    """

    k: float = 1700.0
    duration: float = 20.0
    q0: tuple[float, ...] = PAPER_Q0
    delay_steps: int = 0
    noise_sigma: float = 0.0
    seed: int = 0
    theta_hat0_scale: float | tuple[float, ...] = 1.0
    substeps: int = 2
    overrides: dict[str, Any] = field(default_factory=dict)
    timing: TimingModel | None = None
    events: Sequence[Event] = ()
    input_hook: Callable[[float, Any], Any] | None = None
    command_timeout: float = COMMAND_TIMEOUT_S
    surface_normal: tuple[float, ...] | None = None
    surface_shape: str = 'plane'
    surface_radius: float = 0.5
    surface_axis: tuple[float, ...] | None = None
    plant_impl: str = 'compiled'


@dataclass(kw_only=True)
class ScenarioResult(LoopLog):
    """
    The engine's log of one run plus what the analysis needs.

    Contact (the one predicate on the true force), the normal, the true parameters, the simulated
    surface's k (``k_true``; the log's ``k_hat`` is the controller's estimate, NaN while unknown),
    the runtime and the surface's true normal nearest the tool at every sample (``n_true_W``;
    the log's ``n_hat_W`` is the controller's).
    """

    in_contact: np.ndarray
    n_W: np.ndarray
    theta_true: np.ndarray
    theta_names: tuple[str, ...]
    runtime: ControllerRuntime
    k_true: float
    n_true_W: np.ndarray | None = None

    @property
    def log(self) -> LoopLog:
        return self


def run_scenario(cfg: ScenarioConfig, model: RobotModel | None = None,
                 clock_ns: Callable[[], int] | None = None) -> ScenarioResult:
    """
    Run the closed loop for ``cfg.duration`` seconds and return its time series.

    ``clock_ns``: see :func:`~.engine.run_loop`.
    """
    model = RobotModel.from_urdf() if model is None else model
    theta0 = model.theta_nominal * np.asarray(cfg.theta_hat0_scale, dtype=float)
    params = build_params(model, {'theta_hat0': theta0.tolist(), **cfg.overrides})
    runtime = ControllerRuntime(model, params)
    q0 = np.array(cfg.q0, dtype=float)
    p0 = model.kinematics(q0, np.zeros(model.n)).p_W
    told = cfg.surface_normal is None and cfg.surface_shape == 'plane'
    surface = (ElasticSurface.create(cfg.k, p0, params.law.n) if told else
               make_surface(cfg.surface_shape, cfg.k, p0, cfg.surface_normal or params.law.n,
                            cfg.surface_radius, cfg.surface_axis))
    plant = ArmSimulator(model, surface, q0, substeps=cfg.substeps,
                         noise_sigma=cfg.noise_sigma, seed=cfg.seed, impl=cfg.plant_impl)
    timing = TimingModel.lockstep(cfg.delay_steps) if cfg.timing is None else cfg.timing
    log = run_loop(runtime, plant, cfg.duration, timing, cfg.events, clock_ns=clock_ns,
                   input_hook=cfg.input_hook, command_timeout=cfg.command_timeout)
    n_W = params.law.n
    n_true = (np.tile(n_W, (len(log.t), 1)) if told else
              np.array([surface.normal_at(x) for x in log.x_W]))
    contact = np.array([in_contact(float(n @ f)) for n, f in zip(n_true, log.f_true_W)])
    return ScenarioResult(**vars(log), in_contact=contact, n_W=n_W.copy(),
                          theta_true=model.theta_nominal.copy(),
                          theta_names=model.theta_names, runtime=runtime, k_true=float(cfg.k),
                          n_true_W=n_true)
