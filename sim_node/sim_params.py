"""
The sim node's parameters: one schema (declared with descriptors, validated at the boundary).

:data:`SIM_SCHEMA` lists the plant's, the surface's (settable at run time: :data:`SURFACE`),
the sensor's, MuJoCo's (mujoco_params.py) and the node's own scheduling parameters; those of
:data:`RUNTIME` (the surface's and ``lockstep_watchdog``) are the ones settable at run time.
"""
from __future__ import annotations

from hybrid_force_controller.core.config.params import ParamSpec as _S
from hybrid_force_controller.ros.common.node_params import (CPU_AFFINITY_SPEC, EXECUTOR_SPEC,
                                                            THREAD_PRIORITY_SPEC)

from .mujoco_params import MUJOCO_SCHEMA

__all__ = ['HELP_PARAMETERS', 'RUNTIME', 'SIM_SCHEMA', 'SURFACE', 'UNIT', 'WATCHDOG_ACTIONS']

WATCHDOG_ACTIONS = ('zero', 'brake')

SURFACE = ('stiffness', 'surface_point', 'surface_normal', 'surface_enabled',  # settable
           'surface_shape', 'surface_radius', 'surface_axis', 'sensor_frozen', 'sensor_offset')
UNIT = ('surface_normal', 'surface_axis')  # normalised on set
RUNTIME = SURFACE + ('lockstep_watchdog',)  # settable at run time, each applied on its own
SIM_SCHEMA = tuple(_S(*a, read_only=a[0] not in RUNTIME, **k) for *a, k in (
    ('rate_hz', 'double', 1000.0, 'Plant step rate, Hz (each step is 1/rate_hz).', 1.0, 1e5, {}),
    ('joints', 'string_array', ['joint1', 'joint2'], 'Joint order of states and commands.', {}),
    ('stiffness', 'double', 1700.0, 'Surface stiffness k, N/m.', 1e-6, 1e9, {}),
    ('surface_point', 'double_array', [],
     'Point of the undeformed surface, base frame, m ([] = tool start: touching, 0 N).', {}),
    ('surface_normal', 'double_array', [0.0, -1.0, 0.0], 'Surface normal (into it), base.', {}),
    ('surface_enabled', 'bool', True, 'false: no surface (free motion, e.g. contact loss).', {}),
    ('surface_shape', 'string', 'plane', "'plane', 'cylinder' or 'sphere': a convex workpiece "
     'pressed from outside, touched at surface_point with its normal surface_normal there '
     '(centre surface_radius beyond it, along surface_normal); a spring along the local '
     'normal. physics:=mujoco: fixed at start-up.', {}),
    ('surface_radius', 'double', 0.5, 'Radius of the cylinder or sphere, m.', 1e-3, 1e3, {}),
    ('surface_axis', 'double_array', [], "The cylinder's axis, base frame: perpendicular to "
     'surface_normal (within 1 deg; then made exactly so) ([] = the base axis z, x or y most '
     'perpendicular to it).', {}),
    ('sensor_frozen', 'bool', False, 'true: the F/T sensor repeats its last reading (a frozen '
     'sensor, for fault injection).', {}),
    ('sensor_offset', 'double_array', [], "The F/T sensor's bias, N, sensor frame: added to "
     'every force reading, as a real sensor drifts ([] = none; the controller tares it).', {}),
    ('masses', 'double_array', [], 'True link masses, kg ([] = URDF).', {}),
    ('q0', 'double_array', [0.657, 0.913], 'Initial joint positions (joints order), rad.', {}),
    ('noise_sigma', 'double', 0.0, 'Force sensor noise sigma, N.', 0.0, 1e3, {}),
    ('joint_state_clock_offset', 'double', 0.0, "Added to the joint states' stamps, s: a "
     'driver on a PC whose clock is off (0: none).', -1e6, 1e6, {}),
    ('wrench_clock_offset', 'double', 0.0, "Added to the wrench's stamps, s: an F/T sensor "
     'driver on a PC whose clock is off (0: none).', -1e6, 1e6, {}),
    ('seed', 'integer', 0, 'Noise seed.', 0, 2 ** 31 - 1, {}),
    ('plant_impl', 'string', 'compiled', "physics:=paper: the plant's step compiled (numba, "
     "core/offline/plant_kernels.py) or 'python' (pinocchio's ABA, the reference).", {}),
    ('substeps', 'integer', 2, 'Integration sub-steps per step (the offline scenarios use 2).',
     1, 1000, {}),
    ('command_timeout', 'double', 0.1, 'The watchdog acts after this long without a '
     'command, s (sim time in lockstep).', 1e-6, 60.0, {}),
    ('watchdog_action', 'string', 'zero', "What the arm does after command_timeout: 'zero' "
     "(torque off: it falls, a bare torque interface) or 'brake' (it stops and holds, as a "
     "Franka's reflex or a UR's protective stop; the next valid command releases it).", {}),
    ('lockstep', 'bool', False, 'Own the time: publish /clock, step once per command.', {}),
    ('lockstep_watchdog', 'double', 2.0, 'Lockstep: wall seconds without a command after '
     'which the sim steps anyway, once commands have come (before the first: 0.2 s). Long, '
     'so that a busy machine slows the run instead of changing it; settable at run time (a '
     'test that stops the controller on purpose shortens it meanwhile).', 0.01, 60.0, {}),
    ('max_catch_up', 'integer', 100, 'Real time: most periods a late timer callback '
     'integrates (older time is dropped and counted).', 1, 100000, {}),
    ('telemetry_rate_hz', 'double', 100.0, 'Rate of sim/contact_wrench and '
     'sim/contact_normal, Hz (0: off).',
     0.0, 1e5, {}),
)) + MUJOCO_SCHEMA + (EXECUTOR_SPEC, THREAD_PRIORITY_SPEC, CPU_AFFINITY_SPEC)


HELP_PARAMETERS = (
    ('lockstep', 'true: own /clock and step once per command (deterministic)'),
    ('lockstep_watchdog', 'lockstep: wall s without a command before a step anyway (2)'),
    ('physics', "'paper' (default) or 'mujoco' (tool_*, surface_damping/friction, joint_*)"),
    ('rate_hz', 'plant step rate (default 1000)'),
    ('masses', "true link masses, kg ([] = the URDF's)"),
    ('stiffness, surface_*', 'the elastic surface (settable at run time)'),
    ('surface_shape', "'plane' (default), 'cylinder' or 'sphere' (surface_radius, "
     'surface_axis)'),
    ('sensor_frozen', 'true: the F/T sensor repeats its last reading (settable)'),
    ('sensor_offset', "the F/T sensor's bias, N, sensor frame (settable)"),
    ('noise_sigma, seed', 'force sensor noise'),
    ('joint_state_clock_offset, wrench_clock_offset', 'added to the sensor stamps, s'),
    ('command_timeout', 'the watchdog acts after this long without a command'),
    ('watchdog_action', "'zero' (default: torque off, the arm falls) or 'brake' (it holds)"),
    ('max_catch_up', 'most periods a late timer callback integrates'),
    ('robot_description', "URDF XML, .urdf or .xacro path ('': the paper's 2-link arm)"),
)
