"""
The controller's parameters: validation of the schema's values and the frozen parameters.

Every parameter has a type, a default, a description and bounds in :mod:`.schema` (re-exported
here); the ROS node declares them from :data:`CONTROLLER_SCHEMA` and ``config/*.yaml`` only
overrides values. :func:`build_params` validates a full set once and freezes it into
:class:`ControllerParams`: the control law's gains (:class:`LawGains`, eqs. (5), (11),
(26), (29) of [1]), the runtime's configuration (:class:`RuntimeConfig`: rate, limits,
filter, reference, timeouts, approach, sensor plausibility, tool mass, the sensor's offset, a
user's path) and the online stiffness estimate's (:class:`~.groups.StiffnessConfig`, group
``stiffness``), the recovery from stalls and drops (:class:`~.groups.RecoveryConfig`, group
``recovery``), the surface-normal estimate's (:class:`~.groups.NormalConfig`, group
``normal``) and the tool orientation's (:class:`~.groups.OrientationConfig`, group
``orientation``). Pure Python + numpy.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
import re
from typing import Any, Mapping, Sequence

import numpy as np

from .groups import (NormalConfig, NormalConfigError, OrientationConfig, OrientationConfigError,
                     RecoveryConfig, RecoveryConfigError, StiffnessConfig, StiffnessConfigError,
                     TICK_IMPLS)
from .schema import CONTROLLER_SCHEMA, MODEL_SCHEMA, NORMAL_FIELDS, ORIENTATION_FIELDS, ParamSpec
from .schema import RECOVERY_FIELDS, STIFFNESS_FIELDS

__all__ = ['CONTROLLER_SCHEMA', 'MODEL_SCHEMA', 'ControllerParams', 'LawGains', 'ParamSpec',
           'ParameterValidationError', 'RuntimeConfig', 'build_params', 'check_stability',
           'check_stability_estimated', 'normal_rate_bound', 'schema_defaults',
           'STIFFNESS_FIELDS']


class ParameterValidationError(ValueError):
    """A parameter value (or a combination of them) is rejected; the message says why."""


_SPECS = {s.name: s for s in CONTROLLER_SCHEMA}


@dataclass(frozen=True)
class LawGains:
    """Validated gains of the control law (the ``law`` group of the schema)."""

    lambda1: float
    lambda2: float
    Gamma: np.ndarray
    n: np.ndarray
    f_d: float
    k_d: float
    k_null: float
    k_max: float
    k_s: float
    k_a: float
    adapt_error_limit: float
    adapt_dead_zone: float
    singular_sigma: float
    theta_hat0: np.ndarray
    theta_min: np.ndarray
    theta_max: np.ndarray
    integral_limit: float
    tick_impl: str = 'compiled'


@dataclass(frozen=True)
class RuntimeConfig:
    """Validated configuration of the runtime around the law (the ``runtime`` group)."""

    rate_hz: float
    joints: tuple[str, ...]
    effort_limits: np.ndarray
    max_effort_rate: float
    force_filter_hz: float
    ref_center: np.ndarray
    ref_amplitude: np.ndarray
    ref_omega: float
    ref_blend_time: float
    state_timeout: float
    max_integration_dt: float
    min_delay_margin: float
    approach_speed: float
    approach_limit: float
    wrench_limit: float
    wrench_rate_limit: float
    max_clock_skew: float
    max_joint_jump: float
    max_joint_acceleration: float
    joint_velocity_margin: float
    reject_frozen_wrench: bool
    tool_mass: float
    tool_com: np.ndarray
    wrench_offset: np.ndarray
    tare_time: float
    f_d_rate: float
    path_speed: float
    path_max_accel: float
    path_max_speed: float
    path_max_poses: int
    path_corner_tolerance: float


@dataclass(frozen=True)
class ControllerParams:
    """
    One validated, frozen parameter set.

    The law's gains, the runtime's configuration, the stiffness estimate's, the recovery's, the
    normal estimate's and the tool orientation's.
    """

    law: LawGains
    runtime: RuntimeConfig
    stiffness: StiffnessConfig
    recovery: RecoveryConfig = RecoveryConfig()
    normal: NormalConfig = NormalConfig()
    orientation: OrientationConfig = OrientationConfig()


def schema_defaults() -> dict[str, Any]:
    """Return the default value of every parameter."""
    return {s.name: s.default for s in CONTROLLER_SCHEMA}


def check_stability(lambda1: float, lambda2: float, k_max: float) -> None:
    """
    Eq. (29) of [1]: require ``lambda1^2 > 2 lambda2 k_max``.

    Raises :class:`ParameterValidationError` stating both sides when it fails.
    """
    lhs, rhs = lambda1 ** 2, 2.0 * lambda2 * k_max
    if not lhs > rhs:
        raise ParameterValidationError(
            f'unstable gains, eq. (29) needs lambda1^2 > 2*lambda2*k_max: '
            f'lambda1^2 = {lhs:g} <= 2*lambda2*k_max = {rhs:g}')


def check_stability_estimated(lambda1: float, lambda2: float, k_s: float) -> None:
    """
    Check eq. (29) at the operating point of the stiffness estimate.

    Require ``lambda1^2 > 2 lambda2 k_s``, lambda2 and k_s the configured ones.

    With ``k_s := k_hat`` and ``lambda2 k_s`` held (control_law.py) the normal loop on a
    surface k is ``hddot + (k/k_hat) lambda1 hdot + lambda2 k_s (k/k_hat) h = 0``; (28)
    is negative semi-definite iff ``k_hat / k < lambda1^2 / (2 lambda2 k_s)``. This asks
    it at an exact estimate; the ratio is the overestimate the gains tolerate (1.33 with
    the defaults, against the 5 % standard deviation of a valid estimate).
    """
    lhs, rhs = lambda1 ** 2, 2.0 * lambda2 * k_s
    if not lhs > rhs:
        raise ParameterValidationError(
            f'with stiffness_estimation, eq. (29) at k_s = k_hat needs lambda1^2 > '
            f'2*lambda2*k_s: lambda1^2 = {lhs:g} <= 2*lambda2*k_s = {rhs:g}')


def _scalar(spec: ParamSpec, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterValidationError(f'{spec.name} must be a number, got {value!r}')
    x = float(value)
    if not math.isfinite(x):
        raise ParameterValidationError(f'{spec.name} must be finite, got {x}')
    if spec.positive and not x > 0.0:
        raise ParameterValidationError(f'{spec.name} must be > 0, got {x:g}')
    if (spec.lo is not None and x < spec.lo) or (spec.hi is not None and x > spec.hi):
        raise ParameterValidationError(
            f'{spec.name} = {x:g} is outside [{spec.lo:g}, {spec.hi:g}]')
    return x


def _bool(spec: ParamSpec, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ParameterValidationError(f'{spec.name} must be true or false, got {value!r}')
    return value


def _array(name: str, value: Any, sizes: Sequence[int] | None = None) -> np.ndarray:
    """
    Return ``value`` as a finite float array of one of ``sizes`` elements (default any).

    ``None`` (an empty array as a params file gives it) is empty.
    """
    items = [] if value is None else value
    try:
        items = list(items)
        if any(isinstance(x, bool) for x in items):
            raise TypeError('booleans are not numbers')
        arr = np.asarray(items, dtype=float)
    except (TypeError, ValueError):
        raise ParameterValidationError(
            f'{name} must be an array of numbers, got {value!r}') from None
    if sizes is not None and arr.size not in sizes:
        want = ' or '.join(str(s) for s in sizes)
        raise ParameterValidationError(f'{name} must have {want} elements, got {arr.size}')
    if not np.all(np.isfinite(arr)):
        raise ParameterValidationError(f'{name} must be finite, got {arr.tolist()}')
    return arr


def _gamma(value: Any, p: int) -> np.ndarray:
    g = _array('gamma', value, (1, p, p * p))
    G = np.diag(np.broadcast_to(g, p)) if g.size in (1, p) else g.reshape(p, p)
    if not np.allclose(G, G.T, rtol=0.0, atol=1e-12 * max(1.0, np.abs(G).max())):
        raise ParameterValidationError('gamma must be symmetric')
    if np.linalg.eigvalsh(G).min() <= 0.0:
        raise ParameterValidationError(
            f'gamma must be positive definite, eigenvalues {np.linalg.eigvalsh(G).tolist()}')
    return G


def _normal(value: Any, task_axes: Sequence[int]) -> np.ndarray:
    n = _array('n', value, (3,))
    norm = float(np.linalg.norm(n))
    if norm < 1e-9:
        raise ParameterValidationError('n must not be zero')
    n = n / norm
    off = np.delete(n, list(task_axes))
    if off.size and np.abs(off).max() > 1e-6:
        raise ParameterValidationError(
            f'n = {n.tolist()} leaves the task space of this arm (base axes {list(task_axes)})')
    return n


def _theta(v: Mapping[str, Any], model: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """theta_hat0 and its projection bounds (empty: the parameter set's)."""
    p = len(model.theta_nominal)
    theta0 = _array('theta_hat0', v['theta_hat0'], (0, p))
    theta0 = model.theta_nominal.copy() if theta0.size == 0 else theta0
    lo = _array('theta_min', v['theta_min'], (0, p))
    hi = _array('theta_max', v['theta_max'], (0, p))
    ps = model.parameter_set
    lo = np.asarray(ps.theta_min, dtype=float) if lo.size == 0 else lo
    hi = np.asarray(ps.theta_max, dtype=float) if hi.size == 0 else hi
    if np.any(lo >= hi) or np.any(theta0 < lo) or np.any(theta0 > hi):
        raise ParameterValidationError('need theta_min < theta_max and theta_hat0 inside them')
    return theta0, lo, hi


def _tick_impl(value: Any) -> str:
    if value not in TICK_IMPLS:
        raise ParameterValidationError(
            f'tick_impl must be one of {list(TICK_IMPLS)}, got {value!r}')
    return value


def _law_gains(v: Mapping[str, Any], s: Mapping[str, float], model: Any) -> LawGains:
    check_stability(s['lambda1'], s['lambda2'], s['k_max'])
    theta0, lo, hi = _theta(v, model)
    return LawGains(
        lambda1=s['lambda1'], lambda2=s['lambda2'],
        Gamma=_gamma(v['gamma'], len(model.theta_nominal)),
        n=_normal(v['n'], model.task_axes), f_d=s['f_d'], k_d=s['k_d'], k_null=s['k_null'],
        k_max=s['k_max'], k_s=s['k_s'], k_a=s['k_a'],
        adapt_error_limit=s['adapt_error_limit'], adapt_dead_zone=s['adapt_dead_zone'],
        singular_sigma=s['singular_sigma'], theta_hat0=theta0, theta_min=lo,
        theta_max=hi, integral_limit=s['integral_limit'], tick_impl=_tick_impl(v['tick_impl']))


def _runtime_config(v: Mapping[str, Any], s: Mapping[str, float], model: Any) -> RuntimeConfig:
    n_joints = model.n
    joints = tuple(str(j) for j in v['joints'])
    if len(joints) != n_joints or len(set(joints)) != n_joints:
        raise ParameterValidationError(
            f'joints must name {n_joints} distinct joints, got {joints}')
    unknown = [j for j in joints if j not in model.joint_names]
    if unknown:
        raise ParameterValidationError(f'joints not in the robot model: {unknown}')
    limits = _array('effort_limits', v['effort_limits'], (0, n_joints))
    limits = np.asarray(model.effort_limits, dtype=float) if limits.size == 0 else limits
    if limits.shape != (n_joints,) or np.any(limits <= 0):
        raise ParameterValidationError(f'effort_limits must be {n_joints} values > 0')
    if 0.0 < s['joint_velocity_margin'] < 1.0:
        raise ParameterValidationError(
            f"joint_velocity_margin must be 0 (off) or >= 1, got {s['joint_velocity_margin']:g}:"
            " below 1 it refuses motion within the URDF's velocity limits")
    return RuntimeConfig(
        rate_hz=s['rate_hz'], joints=joints, effort_limits=limits,
        max_effort_rate=s['max_effort_rate'], force_filter_hz=s['force_filter_hz'],
        ref_center=_array('ref_center', v['ref_center'], (3,)),
        ref_amplitude=_array('ref_amplitude', v['ref_amplitude'], (3,)),
        ref_omega=s['ref_omega'], ref_blend_time=s['ref_blend_time'],
        state_timeout=s['state_timeout'], max_integration_dt=s['max_integration_dt'],
        min_delay_margin=s['min_delay_margin'], approach_speed=s['approach_speed'],
        approach_limit=s['approach_limit'],
        wrench_limit=s['wrench_limit'], wrench_rate_limit=s['wrench_rate_limit'],
        max_clock_skew=s['max_clock_skew'], max_joint_jump=s['max_joint_jump'],
        max_joint_acceleration=s['max_joint_acceleration'],
        joint_velocity_margin=s['joint_velocity_margin'],
        reject_frozen_wrench=s['reject_frozen_wrench'], tool_mass=s['tool_mass'],
        tool_com=_array('tool_com', v['tool_com'], (0, 3)).reshape(-1, 3).sum(0),  # []: 0
        wrench_offset=_array('wrench_offset', v['wrench_offset'], (0, 3)).reshape(-1, 3).sum(0),
        tare_time=s['tare_time'], f_d_rate=s['f_d_rate'], **_path_config(v, s))


def _path_config(v: Mapping[str, Any], s: Mapping[str, float]) -> dict[str, Any]:
    """Return the ``path_*`` fields (``path_speed <= path_max_speed``)."""
    if s['path_speed'] > s['path_max_speed']:
        raise ParameterValidationError(
            f"path_speed = {s['path_speed']:g} m/s is above path_max_speed = "
            f"{s['path_max_speed']:g} m/s")
    return {'path_speed': s['path_speed'], 'path_max_accel': s['path_max_accel'],
            'path_max_speed': s['path_max_speed'],
            'path_max_poses': _integer(_SPECS['path_max_poses'], v['path_max_poses']),
            'path_corner_tolerance': s['path_corner_tolerance']}


def _integer(spec: ParamSpec, value: Any) -> int:
    """Return an integer parameter within its bounds."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ParameterValidationError(f'{spec.name} must be an integer, got {value!r}')
    if (spec.lo is not None and value < spec.lo) or (spec.hi is not None and value > spec.hi):
        raise ParameterValidationError(
            f'{spec.name} = {value} is outside [{spec.lo:g}, {spec.hi:g}]')
    return int(value)


def build_params(model: Any, values: Mapping[str, Any] | None = None) -> ControllerParams:
    """
    Validate a set of values against the schema and ``model`` and freeze it.

    Missing values take the defaults; ``model`` is a :class:`~.robot_model.RobotModel` (joints,
    task axes, parameter set, URDF effort limits). Raises :class:`ParameterValidationError`
    with the reason on the first problem.
    """
    values = {} if values is None else values
    unknown = set(values) - set(_SPECS)
    if unknown:
        raise ParameterValidationError(f'unknown parameters: {sorted(unknown)}')
    v = {**schema_defaults(), 'joints': list(model.joint_names), **values}
    s = {name: _scalar(spec, v[name]) for name, spec in _SPECS.items() if spec.kind == 'double'}
    s.update({name: _bool(spec, v[name]) for name, spec in _SPECS.items() if spec.kind == 'bool'})
    return ControllerParams(law=_law_gains(v, s, model), runtime=_runtime_config(v, s, model),
                            stiffness=_stiffness_config(s), recovery=_recovery_config(s),
                            normal=_normal_config(s), orientation=_orientation_config(v, s, model))


def normal_rate_bound(lambda1: float, lambda2: float, k_max: float) -> float:
    """
    Return the largest rotation rate of n, rad/s, that keeps (28) negative definite.

    docs/design.md, "A moving normal": with ``sigma = lambda1^2 - 2 lambda2 k_max`` (the
    margin of eq. 29) the terms dn/dt adds to (19) and (27) are dominated while
    ``5 omega^2 + lambda1 omega < sigma``: ``omega* = (sqrt(lambda1^2 + 20 sigma) - lambda1)/10``
    (5.8 rad/s at the defaults; 0 when (29) fails).
    """
    sigma = lambda1 ** 2 - 2.0 * lambda2 * k_max
    return max(0.0, (math.sqrt(lambda1 ** 2 + 20.0 * sigma) - lambda1) / 10.0) \
        if sigma > 0.0 else 0.0


def _normal_config(s: Mapping[str, Any]) -> NormalConfig:
    """Build the ``normal`` group; errors name the parameter (``n_`` + the field)."""
    if s['n_estimation']:
        bound = normal_rate_bound(s['lambda1'], s['lambda2'], s['k_max'])
        if not s['n_rate_limit'] < bound:
            raise ParameterValidationError(
                f'with n_estimation, n_rate_limit = {s["n_rate_limit"]:g} rad/s must be below '
                f'(sqrt(lambda1^2 + 20 sigma) - lambda1)/10 = {bound:.4g} rad/s, sigma = '
                'lambda1^2 - 2*lambda2*k_max (docs/design.md, "A moving normal")')
    try:
        return NormalConfig(**{f: s[name] for name, f in NORMAL_FIELDS.items()})
    except NormalConfigError as exc:
        msg = re.sub(r'^enabled\b', 'n_estimation', str(exc))
        raise ParameterValidationError(msg if msg != str(exc) else f'n_{exc}') from None


def _orientation_config(v: Mapping[str, Any], s: Mapping[str, Any],
                        model: Any) -> OrientationConfig:
    """Build the ``orientation`` group; ``normal`` and ``moment`` need a 6-D capable arm."""
    values = {f: (s[name] if name in s else v[name]) for name, f in ORIENTATION_FIELDS.items()}
    values['tool_axis'] = tuple(_array('tool_axis', v['tool_axis'], (3,)))
    try:
        cfg = OrientationConfig(**values)
    except OrientationConfigError as exc:
        raise ParameterValidationError(str(exc)) from None
    if cfg.active and (model.m != 3 or model.n < 6):
        raise ParameterValidationError(
            f'orientation_mode {cfg.mode} needs a spatial arm with 6 joints or more (a 6-D '
            f'task); this one has {model.n} joint(s) for a {model.m}-D task: use free')
    return cfg


def _recovery_config(s: Mapping[str, Any]) -> RecoveryConfig:
    """Build the ``recovery`` group (its fields are named as the parameters)."""
    try:
        return RecoveryConfig(**{f: s[name] for name, f in RECOVERY_FIELDS.items()})
    except RecoveryConfigError as exc:
        raise ParameterValidationError(str(exc)) from None


def _stiffness_config(s: Mapping[str, Any]) -> StiffnessConfig:
    """Build the ``stiffness`` group with the shared k_max, k_s and force_filter_hz."""
    if s['stiffness_estimation']:
        check_stability_estimated(s['lambda1'], s['lambda2'], s['k_s'])
    try:
        return StiffnessConfig(k_max=s['k_max'], k_s0=s['k_s'],
                               force_filter_hz=s['force_filter_hz'],
                               **{f: s[name] for name, f in STIFFNESS_FIELDS.items()})
    except StiffnessConfigError as exc:  # name the parameters, not the fields
        msg = str(exc)
        for name, f in sorted(STIFFNESS_FIELDS.items(), key=lambda i: -len(i[1])):
            msg = re.sub(rf'(?<!\w){f}(?!\w)', name, msg)
        raise ParameterValidationError(msg) from None
