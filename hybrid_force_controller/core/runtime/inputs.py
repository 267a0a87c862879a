"""
The controller's inputs as typed records, checked at the boundary (pure numpy).

:class:`JointInput` maps a joint state by name onto the model's joints (the index map is
cached per name list, so a steady stream costs no lookups) and refuses a state that cannot be
physical (:class:`ImplausibleJointState`): a joint velocity beyond the URDF's limit times
``joint_velocity_margin``, a position further from the last accepted state than the two
states' velocities explain (trapezoidal rule) plus ``max_joint_jump``, or a velocity that
changed faster than ``max_joint_acceleration`` (libfranka's position and velocity
discontinuity reflexes), within a gap after it
(the runtime uses 2 ``state_timeout``: a burst of jumped states is first stale, safe mode;
after the gap any position is accepted, as the arm may really have been moved meanwhile).
A refused state is never the one later states are compared against. :class:`WrenchGate` decides
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

__all__ = ['ImplausibleJointState', 'ImplausibleWrench', 'InputError', 'JointInput',
           'JointSample', 'WrenchGate', 'WrenchSample']


NO_FORCE_N = 1e-9  # a reading this small is no force (exempt from the frozen-sensor check)


class InputError(ValueError):
    """A message the controller cannot use; the text names the problem."""


class ImplausibleWrench(InputError):
    """
    A well-formed wrench reading that cannot be physical (too large, or changing too fast).

    A saturated sensor looks the same.
    """


class ImplausibleJointState(InputError):
    """
    A well-formed joint state that cannot be physical (a jump, a velocity beyond the limit).

    An encoder glitch or a message corrupted in a driver looks the same.
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
    """Joint states by name -> :class:`JointSample` in ``model_joints`` order, checked."""

    def __init__(self, model_joints: Sequence[str], controlled: Sequence[str]) -> None:
        self.model_joints, self.controlled = tuple(model_joints), tuple(controlled)
        self._names: tuple[str, ...] | None = None
        self._idx: list[int] = []
        self._in_order = False  # the names are the model's joints in its order
        self._last: JointSample | None = None  # the last sample returned, as lists
        self._last_lists: tuple[list[float], list[float]] = ([], [])
        self.configure_checks(np.full(len(self.model_joints), np.inf), 0.0, 0.0, 0.0, 0.0)

    def configure_checks(self, v_limit: np.ndarray, margin: float, max_jump: float,
                         max_accel: float, gap: float) -> None:
        """
        Set the plausibility bounds (model order; 0: that check is off).

        ``v_limit`` the URDF's velocity limits (0 or inf: none), ``margin`` the factor
        on them, ``max_jump`` the position bound, ``max_accel`` the largest velocity change
        per second and ``gap`` the time within which these two apply.
        """
        v_limit = np.asarray(v_limit, dtype=float)
        limited = np.isfinite(v_limit) & (v_limit > 0.0)
        self._v_max = np.full(v_limit.shape, np.inf)
        self._v_max[limited] = v_limit[limited] * margin
        self._v_limit, self._margin = v_limit, margin
        self._check_v = bool(margin > 0.0 and limited.any())
        self._v_max_list = self._v_max.tolist()
        self.max_jump, self.max_accel, self.gap = max_jump, max_accel, gap

    def _index(self, names: Sequence[str]) -> list[int]:
        key = tuple(names)
        if key != self._names:
            pos = {n: i for i, n in enumerate(key)}
            missing = [j for j in self.controlled if j not in pos]
            if missing:
                raise InputError(f'joint state lacks controlled joint(s) {missing}')
            self._idx = [pos[j] for j in self.model_joints]
            self._in_order = self._idx == list(range(len(key)))  # a copy, not an index
            self._names = key
        return self._idx

    def sample(self, names: Sequence[str], q: Sequence[float],
               qdot: Sequence[float] | None, t: float,
               last: JointSample | None) -> JointSample:
        """Check and map one joint state; ``last`` is the last accepted one (or None)."""
        t_last = -math.inf if last is None else last.t
        if t < t_last:
            raise InputError(f'joint state stamp {t:.6f} is older than the last one '
                             f'{t_last:.6f}')
        if len(q) != len(names) or (qdot is not None and len(qdot) not in (0, len(names))):
            raise InputError('joint state: names, positions and velocities differ in length')
        idx = self._index(names)
        if qdot is None or not len(qdot):
            raise InputError('joint state has no velocities')
        if self._in_order:  # the model's joints, in its order: a copy (0.2 us, an index 0.6)
            q_arr, v_arr = np.array(q, dtype=float), np.array(qdot, dtype=float)
        else:
            q_arr, v_arr = np.asarray(q, dtype=float)[idx], np.asarray(qdot, dtype=float)[idx]
        qs, vs = q_arr.tolist(), v_arr.tolist()  # a few joints: floats beat numpy calls
        if not (math.isfinite(sum(qs)) and math.isfinite(sum(vs))):
            raise InputError('joint state holds NaN/Inf')
        if self._check_v:
            for v, v_max in zip(vs, self._v_max_list):
                if v > v_max or -v > v_max:
                    self._too_fast(v_arr)
        if (self.max_jump or self.max_accel) and t - t_last <= self.gap:
            self._check_step(qs, vs, t - t_last, last)
        sample = JointSample(t, q_arr, v_arr)
        self._last, self._last_lists = sample, (qs, vs)
        return sample

    def _check_step(self, qs: list[float], vs: list[float], dt: float,
                    last: JointSample) -> None:
        """
        Refuse a step from ``last`` that the velocities do not explain, or a velocity jump.

        Position: further than the trapezoidal rule explains with the velocity changing at
        most max_accel on the way, plus max_jump; velocity: a change beyond max_accel dt (a
        joint velocity discontinuity)::

            |q1 - q0 - (v0 + v1) dt / 2| <= max_jump + max_accel dt^2 / 4              (J1)

        (the trapezoid's largest error for a velocity of slope at most max_accel). Between
        two states 1 ms apart this adds 0.25 mrad at 1000 rad/s^2; across a gap it grows,
        as an arm's motion can: behind a 300 ms freeze of the controller the arm fell onto the
        surface and bounced (its velocity reversed), the first state after a skipped 80-100 ms
        moved 0.01-0.03 rad more than its two velocities said, and the fixed bound refused it
        and every state after it for 2 state_timeout: the hold ran on a stale state while the
        arm was flung off the surface (docs/results.md section 30).
        """
        lq, lv = (self._last_lists if last is self._last else
                  (last.q.tolist(), last.qdot.tolist()))
        h = 0.5 * dt
        bound = ((self.max_jump + 0.25 * self.max_accel * dt * dt) if self.max_jump
                 else math.inf)
        dv_max = self.max_accel * dt if self.max_accel else math.inf
        for i, (a, b, c, d) in enumerate(zip(qs, lq, vs, lv)):
            if abs(a - b - h * (c + d)) > bound:
                e = np.array(qs) - last.q - h * (np.array(vs) + last.qdot)
                self._jumped(e, np.array(qs) - last.q, dt)
            if abs(c - d) > dv_max:
                raise ImplausibleJointState(
                    f"implausible joint state: {self.model_joints[i]}'s velocity changed by "
                    f'{c - d:+.4g} in {dt * 1e3:.4g} ms (max_joint_acceleration '
                    f'{self.max_accel:g})')

    def _too_fast(self, v: np.ndarray) -> None:
        i = int(np.argmax(np.abs(v) - self._v_max))
        raise ImplausibleJointState(
            f"implausible joint state: {self.model_joints[i]}'s velocity {v[i]:.4g} is beyond "
            f'its URDF limit {self._v_limit[i]:g} x joint_velocity_margin {self._margin:g}')

    def _jumped(self, e: np.ndarray, dq: np.ndarray, dt: float) -> None:
        i = int(np.argmax(np.abs(e)))
        raise ImplausibleJointState(
            f'implausible joint state: {self.model_joints[i]} moved {dq[i]:+.4g} in '
            f'{dt * 1e3:.4g} ms, {abs(e[i]):.4g} more than its velocities allow '
            f'(max_joint_jump {self.max_jump:g})')


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
        fx, fy, fz = float(force[0]), float(force[1]), float(force[2])
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
