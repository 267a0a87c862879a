"""
The controller's inputs as typed records, checked at the boundary (pure numpy).

:class:`JointInput` maps a joint state by name onto the model's joints (the index map is
cached per name list, so a steady stream costs no lookups). :class:`WrenchGate` decides
whether a wrench reading is plausible: finite, in a known frame, not older than the last,
within ``wrench_limit`` and not changing faster than ``wrench_rate_limit`` from the last
accepted reading. A frozen sensor (bit-identical non-zero readings) is flagged so the
runtime can treat its value as stale; (practically) exact zeros are exempt, since that is what
a noise-free simulated sensor reports out of contact, also once its bias is tared away (the
offset, a mean of identical readings, may differ from them in the last bit; a real sensor is
never that close to 0).
Each problem raises :class:`InputError` naming it.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

__all__ = ['ImplausibleWrench', 'InputError', 'JointInput', 'JointSample', 'WrenchGate',
           'WrenchSample']


NO_FORCE_N = 1e-9  # a reading this small is no force (exempt from the frozen-sensor check)


class InputError(ValueError):
    """A message the controller cannot use; the text names the problem."""


class ImplausibleWrench(InputError):
    """
    A well-formed wrench reading that cannot be physical (too large, or changing too fast).

    A saturated sensor looks the same.
    """


class JointSample(NamedTuple):
    """Joint positions and velocities in model order, stamped (s)."""

    t: float
    q: np.ndarray
    qdot: np.ndarray


class WrenchSample(NamedTuple):
    """Force the environment exerts on the tool, in ``frame_id``, stamped (s)."""

    t: float
    frame_id: str
    F_S: np.ndarray


class JointInput:
    """Joint states by name -> :class:`JointSample` in ``model_joints`` order."""

    def __init__(self, model_joints: Sequence[str], controlled: Sequence[str]) -> None:
        self.model_joints, self.controlled = tuple(model_joints), tuple(controlled)
        self._names: tuple[str, ...] | None = None
        self._idx: list[int] = []

    def _index(self, names: Sequence[str]) -> list[int]:
        key = tuple(names)
        if key != self._names:
            pos = {n: i for i, n in enumerate(key)}
            missing = [j for j in self.controlled if j not in pos]
            if missing:
                raise InputError(f'joint state lacks controlled joint(s) {missing}')
            self._idx = [pos[j] for j in self.model_joints]
            self._names = key
        return self._idx

    def sample(self, names: Sequence[str], q: Sequence[float],
               qdot: Sequence[float] | None, t: float, t_last: float) -> JointSample:
        """Check and map one joint state; ``t_last`` is the stamp of the last good one."""
        if t < t_last:
            raise InputError(f'joint state stamp {t:.6f} is older than the last one '
                             f'{t_last:.6f}')
        if len(q) != len(names) or (qdot is not None and len(qdot) not in (0, len(names))):
            raise InputError('joint state: names, positions and velocities differ in length')
        idx = self._index(names)
        if qdot is None or not len(qdot):
            raise InputError('joint state has no velocities')
        q_arr, v_arr = np.asarray(q, dtype=float)[idx], np.asarray(qdot, dtype=float)[idx]
        if not (math.isfinite(q_arr.sum()) and math.isfinite(v_arr.sum())):
            raise InputError('joint state holds NaN/Inf')
        return JointSample(t, q_arr, v_arr)


class WrenchGate:
    """Plausibility of wrench readings (see the module docstring)."""

    def __init__(self, frame_exists, wrench_limit: float, wrench_rate_limit: float) -> None:
        self._frame_exists = frame_exists
        self.configure(wrench_limit, wrench_rate_limit)
        self.last: WrenchSample | None = None
        self.frozen_since: float | None = None
        self._last_xyz = (0.0, 0.0, 0.0)

    def configure(self, wrench_limit: float, wrench_rate_limit: float) -> None:
        self.wrench_limit, self.wrench_rate_limit = wrench_limit, wrench_rate_limit

    def reset(self) -> None:
        self.last, self.frozen_since = None, None
        self._last_xyz = (0.0, 0.0, 0.0)

    def check(self, frame_id: str, force: Sequence[float], t: float) -> WrenchSample:
        """Accept one reading or raise :class:`InputError` saying why not."""
        if len(force) != 3:
            raise InputError(f'wrench is not 3-D: {list(force)}')
        fx, fy, fz = (float(c) for c in force)
        if not math.isfinite(fx + fy + fz):
            raise InputError(f'wrench holds NaN/Inf: {[fx, fy, fz]}')
        if not self._frame_exists(frame_id or ' '):
            raise InputError(f"wrench frame '{frame_id}' is not a frame of the robot model")
        size = math.hypot(fx, fy, fz)  # out of range whatever its stamp: say so first
        if size > self.wrench_limit:
            raise ImplausibleWrench(f'implausible wrench: |F| = {size:.4g} N > wrench_limit '
                                    f'{self.wrench_limit:g} N')
        last = self.last
        if last is not None and t < last.t:
            raise InputError(f'wrench stamp {t:.6f} is older than the last one {last.t:.6f}')
        same_frame = last is not None and frame_id == last.frame_id
        if same_frame and t > last.t:
            lx, ly, lz = self._last_xyz
            rate = math.hypot(fx - lx, fy - ly, fz - lz) / (t - last.t)
            if rate > self.wrench_rate_limit:
                raise ImplausibleWrench(f'implausible wrench: changes at {rate:.4g} N/s > '
                                        f'wrench_rate_limit {self.wrench_rate_limit:g} N/s')
        frozen = same_frame and size > NO_FORCE_N and (fx, fy, fz) == self._last_xyz
        self.frozen_since = (self.frozen_since if self.frozen_since is not None else
                             last.t) if frozen else None
        self._last_xyz = (fx, fy, fz)
        self.last = WrenchSample(t, frame_id, np.array((fx, fy, fz)))
        return self.last
