"""
The stiffness estimate with its per-sample step compiled (``tick_impl: compiled``).

:class:`CompiledStiffnessEstimator` is stiffness.py's :class:`StiffnessEstimator` whose state
lives in one float64 array (stiffness_kernels.STATE: None as NaN, flags as 0 or 1), so that
:meth:`update` and :meth:`k_s_command`, the two calls of every state, run as the kernels of
stiffness_kernels.py (given by the law's tick; this module imports no numba). Every other
method is stiffness.py's Python, reading and writing the same array through :class:`_Slot`.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .stiffness import StiffnessConfig, StiffnessError, StiffnessEstimator

__all__ = ['CompiledStiffnessEstimator']

_OPTIONAL = ('_x_f', '_x_last', '_x_ref')
_FLAGS = ('saturated', '_valid', 'excited')
_COUNTS = ('samples_used', 'samples_rejected', 'restarts', 'changes')


class _Slot:
    """One attribute of the estimator kept in its state array ``_st``."""

    def __init__(self, index: int, kind: str) -> None:
        self.index, self.optional = index, kind == 'optional'
        self.convert = {'flag': bool, 'count': int}.get(kind, float)

    def __get__(self, obj: Any, objtype: Any = None) -> Any:
        if obj is None:
            return self
        value = obj._st.item(self.index)
        if self.optional:
            return None if value != value else value  # NaN: None
        return self.convert(value)

    def __set__(self, obj: Any, value: Any) -> None:
        obj._st[self.index] = math.nan if value is None else float(value)


class _Held:
    """(S10)'s held sample ``(f_n, x_n, dt)`` or None, in four slots of ``_st``."""

    def __init__(self, index: int) -> None:
        self.index = index  # the flag; f_n, x_n and dt follow

    def __get__(self, obj: Any, objtype: Any = None) -> Any:
        if obj is None:
            return self
        i = self.index
        return tuple(obj._st[i + 1:i + 4].tolist()) if obj._st[i] else None

    def __set__(self, obj: Any, value: Any) -> None:
        i = self.index
        obj._st[i] = 0.0 if value is None else 1.0
        if value is not None:
            obj._st[i + 1:i + 4] = value


def _dt_checked(dt: Any) -> float:
    """stiffness.py's check of dt (StiffnessEstimator._factors), before a kernel call."""
    if not (isinstance(dt, (int, float)) and dt > 0.0 and math.isfinite(dt)):
        raise StiffnessError(f'dt must be finite and > 0, got {dt!r}')
    return float(dt)


class CompiledStiffnessEstimator(StiffnessEstimator):
    """StiffnessEstimator with update and k_s_command in ``kernels`` (stiffness_kernels.py)."""

    def __init__(self, config: StiffnessConfig, kernels: Any) -> None:
        _install_slots(kernels.STATE)  # the kernels' layout (once per process)
        self._kn = kernels
        self._st = np.full(len(kernels.STATE), math.nan)
        self._cf = np.zeros(len(kernels.CONFIG))
        super().__init__(config)
        self._load_config()

    def _load_config(self) -> None:
        self._cf[:] = [float(getattr(self.config, name)) for name in self._kn.CONFIG]

    def reconfigure(self, config: StiffnessConfig) -> None:
        """See :meth:`StiffnessEstimator.reconfigure`."""
        super().reconfigure(config)
        self._load_config()

    def update(self, f_n: float, x_n: float, dt: float, in_contact: bool) -> float:
        """See :meth:`StiffnessEstimator.update` (the same step, compiled)."""
        dt = _dt_checked(dt)
        try:
            f_n, x_n = float(f_n), float(x_n)
        except (TypeError, ValueError):
            self.excited, self.excitation_n = False, 0.0
            raise StiffnessError(f'f_n and x_n must be numbers, got {f_n!r}, {x_n!r}') from None
        return self._kn.update(self._st, self._cf, f_n, x_n, dt, bool(in_contact))

    def k_s_command(self, dt: float) -> float:
        """See :meth:`StiffnessEstimator.k_s_command` (the same step, compiled)."""
        return self._kn.k_s_command(self._st, self._cf, _dt_checked(dt))


def _install_slots(layout: dict[str, int]) -> None:
    """Make each attribute of ``layout`` a slot of the state array (idempotent)."""
    if isinstance(CompiledStiffnessEstimator.__dict__.get('_x_f'), _Slot):
        return
    for name, index in layout.items():
        if name.startswith('_held_'):
            continue
        slot = (_Held(index) if name == '_held' else
                _Slot(index, 'optional' if name in _OPTIONAL else 'flag' if name in _FLAGS
                      else 'count' if name in _COUNTS else 'float'))
        setattr(CompiledStiffnessEstimator, name, slot)
