"""
The frozen settings of the stiffness and normal estimates and of the recovery (pure Python).

They are groups of the one schema (schema.py, groups ``stiffness``, ``normal``, ``recovery``
and ``orientation``), built by params.py; the estimators (law/stiffness.py,
law/normal_estimate.py), the episodes (runtime/recovery.py) and the tool's orientation
(law/orientation.py) take them. Each validates itself and raises its typed
error naming the field.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
import math

__all__ = ['NormalConfig', 'NormalConfigError', 'NormalEstimateError', 'ORIENTATION_MODES',
           'ORIENTATION_NAMES', 'OrientationConfig', 'OrientationConfigError', 'RecoveryConfig',
           'RecoveryConfigError', 'StiffnessConfig', 'StiffnessConfigError', 'StiffnessError',
           'TICK_IMPLS', 'TOOL_SPINS']


class StiffnessError(ValueError):
    """The estimator was called with an argument it cannot use (e.g. ``dt <= 0``)."""


class StiffnessConfigError(StiffnessError):
    """A stiffness-estimator setting is rejected; the message names it and says why."""


_POSITIVE = ('k_min', 'k_max', 'k_s0', 'time_constant', 'excitation_window', 'valid_tol',
             'k_s_rate_down', 'k_s_rate_up', 'regularisation', 'force_floor')
_NON_NEGATIVE = ('k_hat0', 'excitation', 'k_s_time_constant', 'change_force',
                 'force_filter_hz')


@dataclass(frozen=True)
class StiffnessConfig:
    """
    Validated settings of :class:`StiffnessEstimator`.

    Symbols of the module docstring; the schema names are in ``params.py``, group ``stiffness``.

    Attributes
    ----------
    enabled : the law uses k_s from (S7) (False: the configured ``k_s0``; the estimate
        still runs and is reported).
    k_min, k_max : bounds of k_hat, N/m (``0 < k_min < k_max``).
    k_s0 : the configured k_s of eq. (11), N/m: the design stiffness of lambda2.
    k_hat0 : prior of k_hat and first k_s command, N/m; 0 means ``k_s0`` (clipped to the
        bounds), see :attr:`prior`.
    time_constant : T_f of (S3), s; at least 20 control periods, else (S6) never holds.
    excitation, excitation_window : delta_f (N) and T_e (s) of (S5).
    valid_tol : tol of (S6).
    k_s_time_constant : T_s of (S7), s (0: no lag, rate limits only).
    k_s_rate_down, k_s_rate_up : rate limits of (S7), 1/s.
    k_max_margin : margin of (S8).
    change_force : delta_c of (S9), N (0: no change test).
    regularisation : rho of (S3)-(S4); force_floor : sigma floor of (S6), N.
    force_filter_hz : cut-off of the caller's force filter, Hz (0: none), for (S0).

    """

    enabled: bool = True
    k_min: float = 50.0
    k_max: float = 6000.0
    k_s0: float = 6000.0
    k_hat0: float = 0.0
    time_constant: float = 2.0
    excitation: float = 0.05
    excitation_window: float = 0.2
    valid_tol: float = 0.05
    k_s_time_constant: float = 0.1
    k_s_rate_down: float = 10.0
    k_s_rate_up: float = 20.0
    k_max_margin: float = 0.2
    change_force: float = 0.2
    regularisation: float = 1e-2
    force_floor: float = 0.01
    force_filter_hz: float = 200.0

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, bool):
            raise StiffnessConfigError(f'enabled must be a bool, got {self.enabled!r}')
        for f in fields(self)[1:]:
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise StiffnessConfigError(f'{f.name} must be a number, got {value!r}')
            if not math.isfinite(value):
                raise StiffnessConfigError(f'{f.name} must be finite, got {value}')
            object.__setattr__(self, f.name, float(value))
        for name in _POSITIVE:
            if not getattr(self, name) > 0.0:
                raise StiffnessConfigError(f'{name} must be > 0, got {getattr(self, name):g}')
        for name in _NON_NEGATIVE:
            if getattr(self, name) < 0.0:
                raise StiffnessConfigError(f'{name} must be >= 0, got {getattr(self, name):g}')
        if not self.k_min < self.k_max:
            raise StiffnessConfigError(
                f'need k_min < k_max, got k_min = {self.k_min:g}, k_max = {self.k_max:g}')
        if self.k_hat0 != 0.0 and not self.k_min <= self.k_hat0 <= self.k_max:
            raise StiffnessConfigError(f'k_hat0 = {self.k_hat0:g} is outside '
                                       f'[k_min, k_max] = [{self.k_min:g}, {self.k_max:g}]')
        if not 0.0 <= self.k_max_margin < 1.0 or not self.valid_tol < 1.0:
            raise StiffnessConfigError('k_max_margin must be in [0, 1) and valid_tol in (0, 1)')

    @property
    def prior(self) -> float:
        """Return the prior of k_hat, N/m: ``k_hat0``, or ``k_s0`` clipped to the bounds if 0."""
        return self.k_hat0 or min(max(self.k_s0, self.k_min), self.k_max)


class RecoveryConfigError(ValueError):
    """An inconsistent recovery configuration."""


@dataclass(frozen=True)
class RecoveryConfig:
    """
    The ``recovery`` group of the schema (module docstring).

    Attributes
    ----------
    enabled : episodes freeze adaptation at the trusted estimate (false: only counted).
    stall_periods : a gap between ticks longer than this many periods is a stall.
    calm_time : calm this long ends an episode and makes theta_hat trusted, s.
    calm_force : calm force error, N.
    calm_error : calm tracking error ``|e|``, m/s.
    transient_force : a force error above this starts an episode, N (0: off).
    transient_error : a tracking error above this starts an episode, m/s (0: off).

    """

    enabled: bool = True
    stall_periods: float = 10.0
    calm_time: float = 0.5
    calm_force: float = 0.2
    calm_error: float = 0.02
    transient_force: float = 3.0
    transient_error: float = 0.25

    def __post_init__(self) -> None:
        values = (self.stall_periods, self.calm_time, self.calm_force, self.calm_error,
                  self.transient_force, self.transient_error)
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise RecoveryConfigError(f'recovery settings must be finite and >= 0: {self}')
        if self.stall_periods < 2.0:
            raise RecoveryConfigError('stall_periods must be >= 2 (a late tick is no stall)')
        for calm, transient, name in ((self.calm_force, self.transient_force, 'force'),
                                      (self.calm_error, self.transient_error, 'error')):
            if transient > 0.0 and not calm < transient:
                raise RecoveryConfigError(f'calm_{name} must be below transient_{name}')


class NormalEstimateError(ValueError):
    """The normal estimator was called with an argument it cannot use (e.g. ``dt <= 0``)."""


class NormalConfigError(NormalEstimateError):
    """A normal-estimator setting is rejected; the message names it and says why."""


@dataclass(frozen=True)
class NormalConfig:
    """
    Validated settings of the surface-normal estimate (law/normal_estimate.py, group ``normal``).

    Attributes
    ----------
    enabled : the controller uses n_hat (``n`` is only the initial guess); False: the paper's
        fixed ``n``.
    rate_limit : largest rotation rate of n_hat, rad/s (docs/design.md, "A moving normal":
        below ``(sqrt(lambda1^2 + 20 sigma) - lambda1) / 10``, ``sigma = lambda1^2 - 2 lambda2
        k_max``, checked by params.py; 0.5 rad/s is 0.6 of the bound without the feed-forward
        of dS/dt for the Panda, 1/12 of the bound with it at the default gains).
    time_constant : time constant with which n_hat follows the measured normal, s.
    force_floor : the measurement is used only above this contact force, N.
    speed_floor : ... and only while sliding faster than this along the surface, m/s.
    friction_removal : remove the kinetic friction mu_hat |f_perp| along the velocity.
    friction_time_constant : time constant of the friction coefficient mu_hat, s of sliding.
    velocity_fusion : weight in [0, 1] of the constraint n_hat perpendicular to the velocity
        (0: off; 1: the measured force's component along the velocity is removed entirely).
    seat_offset : with ``orientation_mode`` moment, the pad counts as seated while its centre
        of pressure lies within this distance of its centre (m; normal_estimate.py (N7));
        its axis is then the measured normal. 0: off.

    """

    enabled: bool = False
    rate_limit: float = 0.5
    time_constant: float = 0.1
    force_floor: float = 0.5
    speed_floor: float = 0.01
    friction_removal: bool = True
    friction_time_constant: float = 0.5
    velocity_fusion: float = 0.5
    seat_offset: float = 0.01

    def __post_init__(self) -> None:
        for name in ('enabled', 'friction_removal'):
            if not isinstance(getattr(self, name), bool):
                raise NormalConfigError(f'{name} must be a bool, got {getattr(self, name)!r}')
        for name in ('rate_limit', 'time_constant', 'force_floor', 'speed_floor',
                     'friction_time_constant', 'velocity_fusion', 'seat_offset'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise NormalConfigError(f'{name} must be a number, got {value!r}')
            if name == 'velocity_fusion' and not 0.0 <= value <= 1.0:
                raise NormalConfigError(f'velocity_fusion must be in [0, 1], got {value}')
            zero_ok = name in ('velocity_fusion', 'seat_offset')
            if not (math.isfinite(value) and (value > 0.0 or (zero_ok and value == 0.0))):
                raise NormalConfigError(f"{name} must be finite and {'>=' if zero_ok else '>'} "
                                        f'0, got {value}')
            object.__setattr__(self, name, float(value))


class OrientationConfigError(ValueError):
    """A setting of the tool's orientation is rejected; the message names it and says why."""


ORIENTATION_MODES = ('free', 'normal', 'moment')
TOOL_SPINS = ('hold', 'path')
#: the law's per-tick arithmetic (law/tick_impl.py): numba kernels or the numpy reference
TICK_IMPLS = ('compiled', 'python')
#: OrientationConfig field -> schema name (the errors name the parameters).
ORIENTATION_NAMES = {'mode': 'orientation_mode', 'tool_axis': 'tool_axis', 'tilt': 'tool_tilt',
                     'spin': 'tool_spin', 'lambda_o': 'orientation_lambda',
                     'k_d': 'orientation_k_d', 'k_d_spin': 'orientation_k_d_spin',
                     'rate_limit': 'orientation_rate_limit',
                     'error_limit': 'orientation_error_limit', 'moment_gain': 'moment_gain'}


@dataclass(frozen=True)
class OrientationConfig:
    """
    Validated settings of the tool's orientation (law/orientation.py, group ``orientation``).

    Attributes
    ----------
    mode : ``free`` (the paper: only the tool's position is controlled), ``normal`` (the
        tool axis held along n_hat, into the surface, or tilted by ``tilt``) or ``moment``
        (the tilt moments about the two tangent axes regulated to their target: the pad
        seats itself; the spin as in ``normal``).
    tool_axis : the tool's axis in the end-effector frame (unit; the way it points at the part).
    tilt : the axis' tilt from n_hat toward the path's direction of travel, rad.
    spin : ``hold`` (the spin about the axis kept from the start) or ``path`` (the end
        effector's x axis turned along the path's direction of travel).
    lambda_o : the orientation error's gain in the angular reference velocity, 1/s.
    k_d : the angular damping about the two axes across the tool axis (the tilt), the
        rotational part of K_D of eq. (5), N m s/rad.
    k_d_spin : the angular damping about the tool axis (the spin), N m s/rad.
    rate_limit : largest rotation rate of the target, rad/s.
    error_limit : the orientation error is saturated to this angle, rad.
    moment_gain : ``moment`` mode's admittance, rad/(s N m).

    """

    mode: str = 'free'
    tool_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    tilt: float = 0.0
    spin: str = 'hold'
    lambda_o: float = 10.0
    k_d: float = 3.0
    k_d_spin: float = 0.3
    rate_limit: float = 0.5
    error_limit: float = 0.3
    moment_gain: float = 5.0

    @property
    def k_w(self) -> tuple[float, float]:
        """Return the angular damping (across the tool axis, about it), N m s/rad."""
        return self.k_d, self.k_d_spin

    def __post_init__(self) -> None:
        if self.mode not in ORIENTATION_MODES:
            raise OrientationConfigError(
                f'orientation_mode must be one of {list(ORIENTATION_MODES)}, got {self.mode!r}')
        if self.spin not in TOOL_SPINS:
            raise OrientationConfigError(
                f'tool_spin must be one of {list(TOOL_SPINS)}, got {self.spin!r}')
        axis = [float(c) for c in self.tool_axis]
        norm = math.sqrt(sum(c * c for c in axis)) if len(axis) == 3 else 0.0
        if not (math.isfinite(norm) and norm > 1e-9):
            raise OrientationConfigError(
                f'tool_axis must be 3 finite numbers, not all 0, got {list(self.tool_axis)}')
        object.__setattr__(self, 'tool_axis', tuple(c / norm for c in axis))
        for name in ('tilt', 'lambda_o', 'k_d', 'k_d_spin', 'rate_limit', 'error_limit',
                     'moment_gain'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value) or value < 0.0:
                raise OrientationConfigError(
                    f'{ORIENTATION_NAMES[name]} must be finite and >= 0, got {value!r}')
            object.__setattr__(self, name, float(value))
        if not self.tilt <= 0.5:
            raise OrientationConfigError(
                f'tool_tilt must be at most 0.5 rad (29 deg), got {self.tilt:g}')

    @property
    def active(self) -> bool:
        """Say whether the tool's orientation is controlled (a 6-D task)."""
        return self.mode != 'free'
