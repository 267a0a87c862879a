"""The one parameter schema of the controller, its validation and the frozen dataclass.

Every parameter has a type, a default, a description and bounds here; the ROS node
declares them from :data:`CONTROLLER_SCHEMA` and ``config/*.yaml`` only overrides values.
Pure Python + numpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

__all__ = ['CONTROLLER_SCHEMA', 'MODEL_SCHEMA', 'ControllerParams', 'ParamSpec', 'ParameterValidationError',
           'build_controller_params', 'check_stability', 'schema_defaults']


class ParameterValidationError(ValueError):
    """A parameter value (or a combination of them) is rejected; the message says why."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: ROS type (``double``, ``integer``, ``double_array``, ``string_array``,
    ``string``), default, description and closed bounds (``None``: unbounded)."""

    name: str
    kind: str
    default: Any
    description: str
    lo: float | None = None
    hi: float | None = None
    positive: bool = False
    read_only: bool = False


_S = ParamSpec
CONTROLLER_SCHEMA: tuple[ParamSpec, ...] = (
    _S('rate_hz', 'double', 1000.0, 'Control rate, Hz (timer period 1/rate_hz).', 1.0, 10000.0,
       read_only=True),
    _S('joints', 'string_array', ['joint1', 'joint2'],
       'Controlled joints, in the order of the effort command.', read_only=True),
    _S('lambda1', 'double', 40.0, 'lambda1 of eq. (11), 1/s.', 0.0, 1e4, positive=True),
    _S('lambda2', 'double', 0.1, 'lambda2 of eq. (11), force integral gain, m/(N s^2).', 0.0, 1e4,
       positive=True),
    _S('gamma', 'double_array', [70.0],
       'Gamma of eq. (26) (acting on k_s e): one value (times I), p diagonal entries or a row-major p x p SPD matrix.'),
    _S('n', 'double_array', [0.0, -1.0, 0.0],
       'Contact normal in the base frame (into the surface); normalised on set.'),
    _S('f_d', 'double', 1.0, 'Desired normal force the tool exerts on the surface, N.', 0.0, 1e3),
    _S('k_d', 'double', 200.0, 'K_D of eq. (5), N s/m.', 0.0, 1e5, positive=True),
    _S('k_null', 'double', 2.0,
       'Null-space posture damping of redundant arms, N m s/rad.', 0.0, 1e5),
    _S('k_max', 'double', 6000.0, 'Upper bound of the surface stiffness (eq. 29), N/m.',
       0.0, 1e8, positive=True),
    _S('k_s', 'double', 6000.0,
       'Stiffness scaling the S-part of eq. (11) to a velocity (c = 1/k_s), N/m.',
       0.0, 1e8, positive=True),
    _S('theta_hat0', 'double_array', [],
       'Initial theta_hat (empty: the parameter set nominal, e.g. the URDF masses).',
       read_only=True),
    _S('theta_min', 'double_array', [], 'Lower projection bounds of theta_hat (empty: the parameter set default).'),
    _S('theta_max', 'double_array', [], 'Upper projection bounds of theta_hat (empty: the parameter set default).'),
    _S('effort_limits', 'double_array', [],
       'Per-joint effort limits, N m (empty: from the URDF).'),
    _S('max_effort_rate', 'double', 0.0,
       'Largest effort change per tick, N m (0: no rate limit).', 0.0, 1e6),
    _S('force_filter_hz', 'double', 200.0, 'Cut-off of the force low-pass filter, Hz (0: off).',
       0.0, 1e5),
    _S('integral_limit', 'double', 2.0,
       'Anti-windup bound of |h| (eq. 20), N s.', 0.0, 1e6, positive=True),
    _S('ref_center', 'double_array', [1.0, 1.6, 0.0], 'Reference centre, base frame, m.'),
    _S('ref_amplitude', 'double_array', [0.1, 0.0, 0.0], 'Reference sine amplitude, m.'),
    _S('ref_omega', 'double', 1.0, 'Reference sine frequency, rad/s.', 0.0, 1e3),
    _S('ref_blend_time', 'double', 2.0,
       'Blend from the start position into the reference over this time, s.', 0.0, 60.0),
    _S('state_timeout', 'double', 0.1,
       'Inputs older than this put the controller in safe mode, s.', 0.0, 10.0, positive=True),
)
_SPECS = {s.name: s for s in CONTROLLER_SCHEMA}

# The robot model, read once at start-up (shared by the controller and the sim node).
MODEL_SCHEMA: tuple[ParamSpec, ...] = (
    _S('robot_description', 'string', '',
       "URDF XML (as robot_state_publisher provides it) or a URDF file path; '' = the "
       "paper's 2-link arm.", read_only=True),
    _S('base_link', 'string', '', "Base frame of the task space ('' = the URDF root); must "
       'be fixed to the root.', read_only=True),
    _S('end_effector_link', 'string', 'tool0', 'Frame whose origin is controlled.',
       read_only=True),
    _S('parameter_set', 'string', 'link_masses',
       'Adapted parameters: link_masses, payload or full.', read_only=True),
    _S('gravity', 'double_array', [0.0, -9.81, 0.0],
       'Gravity in the URDF root frame, m/s^2 (z-up robots: [0, 0, -9.81]).', read_only=True),
)


@dataclass(frozen=True)
class ControllerParams:
    """Validated, frozen controller parameters (see :data:`CONTROLLER_SCHEMA`)."""

    rate_hz: float
    joints: tuple[str, ...]
    lambda1: float
    lambda2: float
    Gamma: np.ndarray
    n: np.ndarray
    f_d: float
    k_d: float
    k_null: float
    k_max: float
    k_s: float
    theta_hat0: np.ndarray
    theta_min: np.ndarray
    theta_max: np.ndarray
    effort_limits: np.ndarray
    max_effort_rate: float
    force_filter_hz: float
    integral_limit: float
    ref_center: np.ndarray
    ref_amplitude: np.ndarray
    ref_omega: float
    ref_blend_time: float
    state_timeout: float


def schema_defaults() -> dict[str, Any]:
    """Default value of every parameter."""
    return {s.name: s.default for s in CONTROLLER_SCHEMA}


def check_stability(lambda1: float, lambda2: float, k_max: float) -> None:
    """Eq. (29) of [1]: require ``lambda1^2 > 2 lambda2 k_max``.

    Raises :class:`ParameterValidationError` stating both sides when it fails.
    """
    lhs, rhs = lambda1 ** 2, 2.0 * lambda2 * k_max
    if not lhs > rhs:
        raise ParameterValidationError(
            f'unstable gains, eq. (29) needs lambda1^2 > 2*lambda2*k_max: '
            f'lambda1^2 = {lhs:g} <= 2*lambda2*k_max = {rhs:g}')


def _scalar(spec: ParamSpec, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterValidationError(f'{spec.name} must be a number, got {value!r}')
    x = float(value)
    if not math.isfinite(x):
        raise ParameterValidationError(f'{spec.name} must be finite, got {x}')
    if spec.positive and not x > 0.0:
        raise ParameterValidationError(f'{spec.name} must be > 0, got {x:g}')
    if (spec.lo is not None and x < spec.lo) or (spec.hi is not None and x > spec.hi):
        raise ParameterValidationError(f'{spec.name} = {x:g} is outside [{spec.lo:g}, {spec.hi:g}]')
    return x


def _array(name: str, value: Any, sizes: Sequence[int] | None = None) -> np.ndarray:
    try:
        arr = np.asarray(list(value), dtype=float)
    except (TypeError, ValueError):
        raise ParameterValidationError(f'{name} must be an array of numbers, got {value!r}') from None
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


def build_controller_params(values: Mapping[str, Any], *, p: int, n_joints: int,
                            task_axes: Sequence[int], theta_nominal: np.ndarray,
                            urdf_effort_limits: np.ndarray,
                            theta_bounds: tuple[np.ndarray, np.ndarray] | None = None
                            ) -> ControllerParams:
    """Validate a full set of values against the schema and the model; freeze them.

    ``theta_bounds`` are the default projection bounds (the parameter set's); without
    them ``[0, 10 theta_nominal]``. Raises :class:`ParameterValidationError` with the
    reason on the first problem.
    """
    unknown = set(values) - set(_SPECS)
    if unknown:
        raise ParameterValidationError(f'unknown parameters: {sorted(unknown)}')
    v = {**schema_defaults(), **values}
    s = {name: _scalar(_SPECS[name], v[name]) for name, spec in _SPECS.items()
         if spec.kind == 'double'}
    check_stability(s['lambda1'], s['lambda2'], s['k_max'])
    joints = tuple(str(j) for j in v['joints'])
    if len(joints) != n_joints or len(set(joints)) != n_joints:
        raise ParameterValidationError(f'joints must name {n_joints} distinct joints, got {joints}')
    theta0 = _array('theta_hat0', v['theta_hat0'], (0, p))
    theta0 = theta_nominal.copy() if theta0.size == 0 else theta0
    lo = _array('theta_min', v['theta_min'], (0, p))
    hi = _array('theta_max', v['theta_max'], (0, p))
    lo_0, hi_0 = theta_bounds or (np.zeros(p), 10.0 * np.abs(theta_nominal))
    lo = np.asarray(lo_0, dtype=float) if lo.size == 0 else lo
    hi = np.asarray(hi_0, dtype=float) if hi.size == 0 else hi
    if np.any(lo >= hi) or np.any(theta0 < lo) or np.any(theta0 > hi):
        raise ParameterValidationError('need theta_min < theta_max and theta_hat0 inside them')
    limits = _array('effort_limits', v['effort_limits'], (0, n_joints))
    limits = np.asarray(urdf_effort_limits, dtype=float) if limits.size == 0 else limits
    if limits.shape != (n_joints,) or np.any(limits <= 0):
        raise ParameterValidationError(f'effort_limits must be {n_joints} values > 0')
    return ControllerParams(
        rate_hz=s['rate_hz'], joints=joints, lambda1=s['lambda1'], lambda2=s['lambda2'],
        Gamma=_gamma(v['gamma'], p), n=_normal(v['n'], task_axes), f_d=s['f_d'],
        k_d=s['k_d'], k_null=s['k_null'], k_max=s['k_max'], k_s=s['k_s'], theta_hat0=theta0, theta_min=lo,
        theta_max=hi, effort_limits=limits, max_effort_rate=s['max_effort_rate'],
        force_filter_hz=s['force_filter_hz'], integral_limit=s['integral_limit'],
        ref_center=_array('ref_center', v['ref_center'], (3,)),
        ref_amplitude=_array('ref_amplitude', v['ref_amplitude'], (3,)),
        ref_omega=s['ref_omega'], ref_blend_time=s['ref_blend_time'],
        state_timeout=s['state_timeout'])
