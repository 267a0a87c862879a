"""
The sim's physics choice and the MuJoCo scene's parameters (schema and validation only).

``physics`` selects the plant: ``paper`` (default: the paper's model, pinocchio ABA against a
frictionless spring, core/offline/simulator.py) or ``mujoco`` (MuJoCo compiled from the same URDF:
mujoco_scene.py, mujoco_plant.py). This module does not import ``mujoco``, so the default
sim declares these parameters without loading it. :func:`mujoco_options` validates the
values once at start-up and raises :class:`ParameterValidationError` naming the bad one.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping

from hybrid_force_controller.core.config.params import ParameterValidationError, ParamSpec as _S

__all__ = ['DISC_HALF_THICKNESS_M', 'MUJOCO_SCHEMA', 'MujocoOptions', 'PHYSICS', 'TOOL_SHAPES',
           'check_physics', 'mujoco_options']

PHYSICS = ('paper', 'mujoco')
TOOL_SHAPES = ('sphere', 'disc')
DISC_HALF_THICKNESS_M = 0.002  # a disc tool is 4 mm thick

MUJOCO_SCHEMA: tuple[_S, ...] = tuple(_S(*a, read_only=True) for a in (
    ('physics', 'string', 'paper', "Plant: 'paper' (pinocchio ABA against the paper's "
     "frictionless spring) or 'mujoco' (MuJoCo from the same URDF, a sphere tool, a plane "
     'with friction, a wrist force/torque sensor).'),
    ('tool_radius', 'double', 0.01, 'mujoco: radius of the sphere tool centred on '
     'end_effector_link, m.', 0.0, 10.0, True),
    ('tool_mass', 'double', 0.0, 'mujoco: mass of the tool, kg (the wrist sensor '
     'feels its weight).', 0.0, 1e3),
    ('tool_shape', 'string', 'sphere', "mujoco: the tool, 'sphere' (tool_radius, centred on "
     "end_effector_link) or 'disc' (a flat pad of tool_radius, 4 mm thick, centred there, "
     "its axis along end_effector_link's z: tilted, it touches on its rim and the wrist "
     'sensor reads the moment).'),
    ('surface_damping', 'double', 0.0, 'mujoco: contact damping of the surface, N s/m.',
     0.0, 1e6),
    ('surface_friction', 'double', 0.0, 'mujoco: Coulomb friction coefficient mu of the '
     'tool on the surface (0: frictionless).', 0.0, 10.0),
    ('joint_damping', 'double', 0.0, 'mujoco: viscous damping of every joint, N m s/rad.',
     0.0, 1e4),
    ('joint_friction', 'double', 0.0, 'mujoco: dry friction (frictionloss) of every joint, '
     'N m.', 0.0, 1e4),
    ('joint_limits', 'bool', True, 'mujoco: enforce the URDF position limits as hard stops '
     '(a real arm has them; physics:=paper has none).'),
))


@dataclass(frozen=True)
class MujocoOptions:
    """Validated MuJoCo scene options (SI units; see :data:`MUJOCO_SCHEMA`)."""

    tool_radius: float = 0.01
    tool_mass: float = 0.0
    tool_shape: str = 'sphere'
    surface_damping: float = 0.0
    surface_friction: float = 0.0
    joint_damping: float = 0.0
    joint_friction: float = 0.0
    joint_limits: bool = True


def check_physics(value: Any) -> str:
    """Return ``value`` if it names a physics; else a ParameterValidationError naming them."""
    if value not in PHYSICS:
        raise ParameterValidationError(f"physics must be one of {list(PHYSICS)}, got '{value}'")
    return value


def mujoco_options(values: Mapping[str, Any]) -> MujocoOptions:
    """Validate the MuJoCo parameters of ``values`` (schema names; missing: defaults)."""
    specs = {s.name: s for s in MUJOCO_SCHEMA if s.kind == 'double'}
    out: dict[str, Any] = {}
    for name, spec in specs.items():
        x = values.get(name, spec.default)
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise ParameterValidationError(f'{name} must be a finite number, got {x!r}')
        if spec.positive and not x > 0.0:
            raise ParameterValidationError(f'{name} must be > 0, got {x:g}')
        if not spec.lo <= x <= spec.hi:
            raise ParameterValidationError(f'{name} = {x:g} is outside [{spec.lo:g}, '
                                           f'{spec.hi:g}]')
        out[name] = float(x)
    shape = values.get('tool_shape', 'sphere')
    if shape not in TOOL_SHAPES:
        raise ParameterValidationError(f'tool_shape must be one of {list(TOOL_SHAPES)}, '
                                       f'got {shape!r}')
    limits = values.get('joint_limits', True)
    if not isinstance(limits, bool):
        raise ParameterValidationError(f'joint_limits must be true or false, got {limits!r}')
    return MujocoOptions(joint_limits=limits, tool_shape=shape, **out)
