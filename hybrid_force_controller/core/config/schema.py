"""
The parameter schema: every parameter's type, default, description, bounds and group.

The ROS node declares its parameters from :data:`CONTROLLER_SCHEMA` and :data:`MODEL_SCHEMA`;
``config/*.yaml`` only overrides values. Validation and freezing are in :mod:`.params`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .groups import ORIENTATION_NAMES

__all__ = ['CONTROLLER_SCHEMA', 'MODEL_SCHEMA', 'NORMAL_FIELDS', 'ORIENTATION_FIELDS', 'ParamSpec',
           'RECOVERY_FIELDS', 'STIFFNESS_FIELDS']


@dataclass(frozen=True)
class ParamSpec:
    """
    One parameter of the schema.

    Its ROS type (``double``, ``integer``, ``double_array``, ``string_array``, ``string``,
    ``bool``), default, description, closed bounds (``None``: unbounded) and the group it
    configures (``law``, ``runtime``, ``stiffness``, ``normal``, ``recovery`` or
    ``orientation``).
    """

    name: str
    kind: str
    default: Any
    description: str
    lo: float | None = None
    hi: float | None = None
    positive: bool = False
    read_only: bool = False
    group: str = 'runtime'


def _law(*args: Any, **kwargs: Any) -> ParamSpec:
    return ParamSpec(*args, group='law', **kwargs)


def _stf(*args: Any, **kwargs: Any) -> ParamSpec:
    return ParamSpec(*args, group='stiffness', **kwargs)


def _rec(*args: Any, **kwargs: Any) -> ParamSpec:
    return ParamSpec(*args, group='recovery', **kwargs)


def _nrm(*args: Any, **kwargs: Any) -> ParamSpec:
    return ParamSpec(*args, group='normal', **kwargs)


def _ori(*args: Any, **kwargs: Any) -> ParamSpec:
    return ParamSpec(*args, group='orientation', **kwargs)


_S = ParamSpec
CONTROLLER_SCHEMA: tuple[ParamSpec, ...] = (
    _S('rate_hz', 'double', 1000.0, 'Control rate, Hz (timer period 1/rate_hz).', 1.0, 10000.0,
       read_only=True),
    _S('joints', 'string_array', ['joint1', 'joint2'],
       'Controlled joints, in the order of the effort command.', read_only=True),
    _law('lambda1', 'double', 40.0, 'lambda1 of eq. (11), 1/s.', 0.0, 1e4, positive=True),
    _law('lambda2', 'double', 0.1, 'lambda2 of eq. (11), force integral gain, m/(N s^2).',
         0.0, 1e4, positive=True),
    _law('gamma', 'double_array', [70.0],
         'Gamma of eq. (26) (acting on k_a e): one value (times I), p diagonal entries or a '
         'row-major p x p SPD matrix.'),
    _law('n', 'double_array', [0.0, -1.0, 0.0],
         'Contact normal in the base frame (into the surface); normalised on set.'),
    _law('f_d', 'double', 1.0, 'Desired normal force the tool exerts on the surface, N.',
         0.0, 1e3),
    _law('k_d', 'double', 60.0, 'K_D of eq. (5), N s/m.', 0.0, 1e5, positive=True),
    _law('k_null', 'double', 2.0,
         'Null-space posture damping of redundant arms, N m s/rad.', 0.0, 1e5),
    _law('k_max', 'double', 6000.0, 'Upper bound of the surface stiffness (eq. 29), N/m.',
         0.0, 1e8, positive=True),
    _law('k_s', 'double', 6000.0,
         'Stiffness scaling the S-part of eq. (11) to a velocity (c = 1/k_s), N/m.',
         0.0, 1e8, positive=True),
    _law('k_a', 'double', 1500.0,
         'Stiffness converting e to the force-rate units of the adaptation (26), N/m.',
         0.0, 1e8, positive=True),
    _law('adapt_error_limit', 'double', 0.1,
         'The adaptation (26) integrates e saturated to this norm, m/s (transients such as '
         'impacts do not throw theta_hat).', 0.0, 1e3, positive=True),
    _law('adapt_dead_zone', 'double', 0.0,
         'Dead zone of the adaptation (26): it integrates e scaled by max(0, 1 - d/|e|), '
         'so errors below d (sensor noise) do not drift theta_hat, m/s (0: off).', 0.0, 1e3),
    _law('singular_sigma', 'double', 0.1,
         'Near a singularity, where the smallest singular value of the task Jacobian of a '
         'square arm is below this, the law inverts J damped (damped least squares) and '
         'theta_hat holds, m (0: off; the 2-link arm of the paper: 0.21 at the end of its '
         'sine, 0 at full reach).', 0.0, 1e3),
    _law('tick_impl', 'string', 'compiled',
         "compiled: the per-tick arithmetic (the task inverse, eq. (5)'s effort, eq. (26), "
         'the reference, the stiffness estimate) in numba kernels, compiled on the first '
         'start (or at install) and cached; '
         'python: the numpy reference, the same figures to rounding.', read_only=True),
    _law('theta_hat0', 'double_array', [],
         'Initial theta_hat (empty: the parameter set nominal, e.g. the URDF masses).',
         read_only=True),
    _law('theta_min', 'double_array', [],
         'Lower projection bounds of theta_hat (empty: the parameter set default).'),
    _law('theta_max', 'double_array', [],
         'Upper projection bounds of theta_hat (empty: the parameter set default).'),
    _law('integral_limit', 'double', 2.0,
         'Anti-windup bound of |h| (eq. 20), N s.', 0.0, 1e6, positive=True),
    _S('effort_limits', 'double_array', [],
       'Per-joint effort limits, N m (empty: from the URDF).'),
    _S('max_effort_rate', 'double', 0.0,
       'Largest effort change per tick, N m (0: no rate limit).', 0.0, 1e6),
    _S('force_filter_hz', 'double', 200.0, 'Cut-off of the force low-pass filter, Hz (0: off).',
       0.0, 1e5),
    _S('ref_center', 'double_array', [1.0, 1.6, 0.0], 'Reference centre, base frame, m.'),
    _S('ref_amplitude', 'double_array', [0.1, 0.0, 0.0], 'Reference sine amplitude, m.'),
    _S('ref_omega', 'double', 1.0, 'Reference sine frequency, rad/s.', 0.0, 1e3),
    _S('ref_blend_time', 'double', 2.0,
       'Blend from the start position into the reference over this time, s.', 0.0, 60.0),
    _S('state_timeout', 'double', 0.1,
       'Inputs older than this put the controller in safe mode, s.', 0.0, 10.0, positive=True),
    _S('max_integration_dt', 'double', 0.005,
       'Longest time one new state may integrate theta_hat and h (a late sample after a '
       'gap integrates only this much), s.', 0.0, 1.0, positive=True),
    _S('min_delay_margin', 'double', 0.005,
       'Smallest loop delay the gains must tolerate (margin.py, at the current pose); a '
       'set leaving less is refused, s (0: no check).', 0.0, 1.0),
    _S('approach_speed', 'double', 0.025,
       'Out of contact the tool moves into the surface at this speed, m/s (0: no approach, '
       'only the force loop).', 0.0, 1.0),
    _S('approach_limit', 'double', 0.05,
       'Largest approach travel along n; then the arm holds and reports that the surface '
       'was not found, m.', 0.0, 10.0, positive=True),
    _S('wrench_limit', 'double', 100.0,
       'Largest plausible force reading, N; larger readings (or a saturated sensor) are '
       'dropped.', 0.0, 1e6, positive=True),
    _S('wrench_rate_limit', 'double', 20000.0,
       'Largest plausible change of the force reading, N/s; faster changes are dropped.',
       0.0, 1e9, positive=True),
    _S('max_clock_skew', 'double', 10.0,
       "Largest plausible difference between an input's stamp and the controller's clock "
       'when it arrives, s; beyond it the message is refused. Within it the clock offset of '
       'each input stream is measured and removed (sender_clock.py; 0: stamps used as they '
       'come).',
       0.0, 1e9),
    _S('max_joint_jump', 'double', 0.01,
       'Largest plausible position change of a joint beyond what the velocities of two '
       'consecutive joint states explain, rad (m for a prismatic joint), plus '
       'max_joint_acceleration dt^2/4 across a gap dt; a larger one is refused (0: off).',
       0.0, 1e3),
    _S('max_joint_acceleration', 'double', 1000.0,
       'Largest plausible change of a joint velocity between two joint states, per second '
       'between their stamps, rad/s^2 (m/s^2); a faster one is refused (0: off).', 0.0, 1e9),
    _S('joint_velocity_margin', 'double', 1.5,
       "A joint velocity beyond the URDF's velocity limit times this is refused (joints "
       'without a limit are not checked; 0: off, else >= 1).', 0.0, 1e3),
    _S('reject_frozen_wrench', 'bool', True,
       'Treat bit-identical force readings as stale (a frozen sensor leads to safe mode '
       'after state_timeout).'),
    _S('tool_mass', 'double', 0.0,
       'Mass of the tool the wrist sensor carries, kg: its weight is subtracted from the '
       'reading before the law (tool_gravity.py; 0: none).', 0.0, 1e3),
    _S('path_speed', 'double', 0.05,
       'Speed of a path on ~/path whose stamps are all zero, and of the transit to its first '
       'pose, m/s (<= path_max_speed).', 0.0, 10.0, positive=True),
    _S('path_max_accel', 'double', 0.5,
       'Largest acceleration of an untimed path and its transit along the surface; also '
       'bounds the blend into a path and the stop on an empty path, m/s^2.', 0.0, 1e3,
       positive=True),
    _S('path_max_speed', 'double', 0.25,
       'A timed path with a segment faster than this (along the surface) is refused, m/s.',
       0.0, 10.0, positive=True),
    _S('path_max_poses', 'integer', 10000,
       'A path with more poses than this is refused.', 1, 1000000),
    _S('path_corner_tolerance', 'double', 0.001,
       'An untimed path rounds its corners within this distance of the pose (0: it stops '
       'at each corner instead), m.', 0.0, 1.0),
    _S('tool_com', 'double_array', [],
       "The tool's centre of mass in the sensor frame, m (empty: the origin); it moves only "
       'the torque of the weight, which the law does not use.'),
    _S('wrench_offset', 'double_array', [],
       "The force sensor's bias, N, sensor frame: subtracted from every reading (empty: "
       'none). ~/tare measures and sets it; ros2 param dump keeps it.'),
    _S('tare_time', 'double', 1.0,
       '~/tare averages the force reading over this long, s.', 0.0, 10.0, positive=True),
    _S('f_d_rate', 'double', 10.0,
       'A new f_d (parameter or ~/target_wrench) is approached at this rate, N/s, with its '
       'rate fed forward (0: a step).', 0.0, 1e6),
    # the online stiffness estimate (stiffness.py, docs/design.md): symbols (S0)-(S8)
    _stf('stiffness_estimation', 'bool', True,
         'Use the online stiffness estimate as k_s of eq. (11), with lambda2 = lambda2 '
         'k_s/k_hat (false: k_s and lambda2 as set; the estimate is still reported).'),
    _stf('k_min', 'double', 50.0, 'Lower bound of the stiffness estimate, N/m (< k_max).',
         0.0, 1e8, positive=True),
    _stf('stiffness_k_hat0', 'double', 0.0,
         'Prior of the stiffness estimate and first k_s command, N/m (0: k_s).', 0.0, 1e8),
    _stf('stiffness_time_constant', 'double', 2.0,
         'Forgetting time constant T_f of the estimate, s of exciting contact.', 0.01, 1e4),
    _stf('stiffness_excitation', 'double', 0.05,
         'Excitation dead zone delta_f: samples with k_e |x_n - x_bar| below it are not '
         'used, N.', 0.0, 1e3),
    _stf('stiffness_excitation_window', 'double', 0.2,
         'Time constant T_e of the mean x_bar in the excitation test, s.', 0.001, 1e3),
    _stf('stiffness_valid_tol', 'double', 0.05,
         'The estimate is valid (k_s may fall to it) when its standard deviation is below '
         'this fraction of it.', 0.0, 1.0, positive=True),
    _stf('stiffness_k_s_time_constant', 'double', 0.1,
         'Time constant T_s with which k_s follows the estimate, s.', 0.0, 1e3),
    _stf('stiffness_k_s_rate_down', 'double', 10.0,
         'Largest relative decrease rate of k_s, |d ln k_s/dt|, 1/s.', 0.0, 1e3, positive=True),
    _stf('stiffness_k_s_rate_up', 'double', 20.0,
         'Largest relative increase rate of k_s, d ln k_s/dt, 1/s.', 0.0, 1e3, positive=True),
    _stf('stiffness_k_max_margin', 'double', 0.2,
         'Warn when the estimate is >= (1 - margin) k_max.', 0.0, 1.0),
    _stf('stiffness_change_force', 'double', 0.2,
         'Change test: a lasting prediction error above this restarts the estimate and '
         'returns k_s to the configured one, N (0: off).', 0.0, 1e3),
    _stf('stiffness_regularisation', 'double', 1e-2,
         'Weight rho of the prior, in samples of a 1 N excursion.', 0.0, 1e6, positive=True),
    _stf('stiffness_force_floor', 'double', 0.01,
         'Floor of the residual standard deviation in the validity test, N.', 0.0, 1e3,
         positive=True),
    # recovery from stalls and drops (recovery.py, docs/design.md): episodes, trusted theta_hat
    _rec('episode_recovery', 'bool', True,
         'During a fault episode (stall, contact loss, safe mode, force transient, tracking '
         'fault) theta_hat holds the trusted estimate of the last calm stretch (false: '
         'episodes are only counted).'),
    _rec('stall_periods', 'double', 10.0,
         'A gap between ticks longer than this many periods is a stall: nothing integrates '
         'across it and the reference re-blends from the arm.', 2.0, 1e6),
    _rec('calm_time', 'double', 0.5,
         'Calm this long ends an episode and makes theta_hat trusted, s.', 0.0, 60.0),
    _rec('calm_force', 'double', 0.2, 'Calm: |f_n - f_d| below this, N.', 0.0, 1e3,
         positive=True),
    _rec('calm_error', 'double', 0.02, 'Calm: |e| below this, m/s.', 0.0, 1e3, positive=True),
    _rec('transient_force', 'double', 3.0,
         'A force error |f_n - f_d| above this starts an episode (an impact, a fall), N '
         '(0: off).', 0.0, 1e4),
    _rec('transient_error', 'double', 0.25,
         'A tracking error |e| above this starts an episode (an effort the plant did not '
         'apply), m/s (0: off).', 0.0, 1e3),
    # the online estimate of the surface normal (normal_estimate.py, docs/design.md)
    _nrm('n_estimation', 'bool', False,
         'Estimate the surface normal online from the contact force (n is then only the '
         'initial guess); false: the paper, n fixed.'),
    _nrm('n_rate_limit', 'double', 0.5,
         'Largest rotation rate of the estimated normal, rad/s; with n_estimation it must be '
         'below (sqrt(lambda1^2 + 20 sigma) - lambda1)/10, sigma = lambda1^2 - 2 lambda2 '
         'k_max (5.8 rad/s with the defaults; docs/design.md, "A moving normal").',
         0.0, 100.0, positive=True),
    _nrm('n_time_constant', 'double', 0.1,
         'Time constant with which the estimate follows the measured normal, s.', 1e-3, 100.0),
    _nrm('n_force_floor', 'double', 0.5,
         'The normal is measured only with a contact force above this, N.', 0.0, 1e3,
         positive=True),
    _nrm('n_speed_floor', 'double', 0.01,
         'The normal is measured only while sliding faster than this, m/s (at rest it is '
         'held: static friction may lean the force by up to atan(mu)).', 0.0, 10.0,
         positive=True),
    _nrm('n_friction_removal', 'bool', True,
         'Remove the kinetic friction mu_hat |f_perp| along the velocity (mu_hat estimated '
         'online) from the measured force.'),
    _nrm('n_friction_time_constant', 'double', 0.5,
         'Time constant of the friction estimate mu_hat, s of sliding.', 1e-3, 1e3),
    _nrm('n_velocity_fusion', 'double', 0.5,
         'Weight of the constraint n perpendicular to the velocity, 0 (off) to 1 (the '
         "force's whole component along the velocity removed).", 0.0, 1.0),
    _nrm('n_seat_offset', 'double', 0.01,
         'orientation_mode moment: the pad counts as seated while its centre of pressure '
         '(tilt moment error over force) is within this distance of its centre for 0.1 s, m; '
         "a seated pad's axis is then the measured normal, at rest too (0: off).", 0.0, 1.0),
    # the tool's orientation (law/orientation.py, docs/design.md "The tool square to the part")
    _ori('orientation_mode', 'string', 'free',
         'free: only the tool position is controlled (the paper); normal: tool_axis held '
         'along n (into the surface), tilted by tool_tilt; moment: the tilt moments about the '
         'two tangent axes regulated to ~/target_wrench torques (0: the pad seats itself '
         'flat). normal and moment need a spatial arm of 6 joints or more.'),
    _ori('tool_axis', 'double_array', [0.0, 0.0, 1.0],
         "The tool's axis in the end-effector frame, pointing at the part; normalised."),
    _ori('tool_tilt', 'double', 0.0,
         "The tool axis' tilt from n toward the path's direction of travel (its leading edge "
         'lifted), rad.', 0.0, 0.5),
    _ori('tool_spin', 'string', 'hold',
         'The spin about the tool axis: hold (kept from the start) or path (the end '
         "effector's x axis along the direction of travel)."),
    _ori('orientation_lambda', 'double', 10.0,
         'Gain of the orientation error (SO(3) log) in the angular reference velocity, 1/s.',
         0.0, 1e3),
    _ori('orientation_k_d', 'double', 3.0,
         'Angular damping about the two axes across the tool axis (the tilt), the rotational '
         'part of K_D of eq. (5), N m s/rad. A loop of rotational inertia I tolerates a delay of '
         'about (pi/2) I / k: the Panda tilts with 0.14-0.38 kg m^2, 73 ms at 3.', 0.0, 1e4),
    _ori('orientation_k_d_spin', 'double', 0.3,
         'Angular damping about the tool axis (the spin), N m s/rad. The Panda spins its tool '
         'with 0.0066 kg m^2: 35 ms of delay tolerated at 0.3, 3.5 ms at 3.', 0.0, 1e4),
    _ori('orientation_rate_limit', 'double', 0.5,
         "Largest rotation rate of the tool's target orientation, rad/s.", 0.0, 100.0,
         positive=True),
    _ori('orientation_error_limit', 'double', 0.3,
         'The orientation error is saturated to this angle, rad.', 0.0, 3.0, positive=True),
    _ori('moment_gain', 'double', 5.0,
         "orientation_mode moment: the admittance turning the tool with the tilt moment's "
         'error, rad/(s N m).', 0.0, 1e3),
)
#: schema name -> OrientationConfig field.
ORIENTATION_FIELDS = {name: field for field, name in ORIENTATION_NAMES.items()}
#: schema name -> RecoveryConfig field.
RECOVERY_FIELDS = {s.name: 'enabled' if s.name == 'episode_recovery' else s.name
                   for s in CONTROLLER_SCHEMA if s.group == 'recovery'}
#: schema name -> NormalConfig field.
NORMAL_FIELDS = {s.name: 'enabled' if s.name == 'n_estimation' else s.name.removeprefix('n_')
                 for s in CONTROLLER_SCHEMA if s.group == 'normal'}
#: schema name -> StiffnessConfig field (k_max, k_s and force_filter_hz are shared).
STIFFNESS_FIELDS = {s.name: 'enabled' if s.name == 'stiffness_estimation'
                    else s.name.removeprefix('stiffness_')
                    for s in CONTROLLER_SCHEMA if s.group == 'stiffness'}

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
