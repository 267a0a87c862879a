"""
The sim's surface and sensor faults from its parameter values, validated (start-up and sets).

:func:`surface_from_values` builds the surface of the ``SURFACE`` parameters (sim_params.py):
a plane (default), a cylinder or a sphere (core/offline/environment.py ``make_surface``). With
``surface_point`` empty the surface passes through the tool's start (its centre, offset by the
MuJoCo tool's radius along the normal), touching with zero force; a cylinder or sphere is
touched there with its normal ``surface_normal``, its centre ``surface_radius`` beyond. Every bad
value raises SurfaceError with the reason, which a run-time set returns to the caller.
"""
from __future__ import annotations

from typing import Any, Callable

from hybrid_force_controller.core.offline.environment import (ElasticSurface, make_surface,
                                                              Surface, SurfaceError)
import numpy as np

__all__ = ['sensor_offset', 'surface_from_values']


def sensor_offset(value: Any) -> np.ndarray | None:
    """Return ``sensor_offset`` as a finite 3-vector (None: [] or zero), or raise SurfaceError."""
    offset = np.asarray(value if value else [], dtype=float)
    if offset.size == 0:
        return None
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise SurfaceError(f'sensor_offset must be [] or 3 finite numbers, got {list(value)}')
    return offset if np.any(offset) else None


def surface_from_values(v: dict[str, Any], p0_W: np.ndarray,
                        touch_offset: Callable[[np.ndarray], float],
                        check: Callable[[Surface], None] | None = None
                        ) -> tuple[Surface | None, tuple]:
    """
    Build the surface the values describe (None when disabled) and the sensor's faults.

    ``p0_W`` is the tool's start, ``touch_offset(n_W)`` the tool's reach along a normal
    (plants.py; 0 on the paper's physics),
    ``check`` the plant's own limits (MuJoCo's). The faults are ``sensor_frozen`` and
    ``sensor_offset`` (a 3-vector, N, or None for none). SurfaceError when a value is bad.
    """
    if not isinstance(v['stiffness'], float) or not all(
            isinstance(v[k], bool) for k in ('surface_enabled', 'sensor_frozen')):
        raise SurfaceError('stiffness must be a number, surface_enabled and sensor_frozen '
                           'bools')
    if not isinstance(v['surface_shape'], str) or not isinstance(v['surface_radius'], float):
        raise SurfaceError('surface_shape must be a string and surface_radius a number')
    plane = ElasticSurface.create(v['stiffness'], v['surface_point'] or p0_W, v['surface_normal'])
    offset = touch_offset(plane.n_W)
    if not v['surface_point'] and offset:  # touching the tool (MuJoCo's sphere or disc)
        plane = ElasticSurface.create(plane.k, p0_W + offset * plane.n_W, plane.n_W)
    surface = plane if v['surface_shape'] == 'plane' else make_surface(
        v['surface_shape'], plane.k, plane.x0_W, plane.n_W, v['surface_radius'],
        v['surface_axis'])
    if check is not None:
        check(surface)
    return (surface if v['surface_enabled'] else None), (v['sensor_frozen'],
                                                         sensor_offset(v['sensor_offset']))
