r"""
The tool's orientation: the angular half of the 6-D task (``orientation_mode`` normal|moment).

The translation keeps the paper's law (control_law.py). Here the angular reference velocity
``omega_r`` and its rate come from the target orientation, the way eq. (11)'s free part
``xdot_d - lambda1 dx`` comes from the path; the law stacks them under r and rdot, inverts the
6-D Jacobian, and eq. (26) adapts theta_hat on the whole 6-D ``s = qdot - qdot_r``
(docs/design.md, "The tool square to the part").

Frames: ``_W`` the base frame, ``_ee`` the end-effector frame; ``R = R_W_ee``; ``a_ee`` the
tool axis (``tool_axis``), ``a_W = R a_ee``; ``n_hat`` points into the surface. Every angular
velocity is in W.

Target (``normal`` and ``moment``). The target axis ``a* = cos(beta) n_hat + sin(beta) t``
(``beta = tool_tilt``; ``t`` the path's direction of travel in the tangent plane, its last
one kept when the path is still, turned about n so that the axis moves along the tilt's cone
at ``orientation_rate_limit`` at most through a corner); the axis in use ``a_d`` turns toward
``a*`` at ``orientation_rate_limit`` at most (it starts at the tool's own axis: no jump at
activation).
The target rotation moves the orientation held at the start ``R_0`` by the shortest turn from
its axis onto ``a_d``, ``R_d = align(R_0 a_ee, a_d) R_0`` (``tool_spin`` hold), or, with
``tool_spin`` path, also turns it about ``a_d`` until the end effector's x axis lies along t.

Error on SO(3), eq. (O1): ``phi = log(R_d R^T)`` (the rotation vector taking the tool onto the
target, W), saturated to ``orientation_error_limit``, and ``omega_d`` the target's own rate
(the log of its change over the tick, divided by dt). Then::

    normal:  omega_r    = omega_d + lambda_o phi                                     (O2)
             omegadot_r = lambda_o (omega_d - omega)
    moment:  omega_r    = P_n (omega_d + lambda_o phi) - g_m P_t (m_W - m_d)          (O3)
             omegadot_r = P_n lambda_o (omega_d - omega)

with ``P_n = n n^T``, ``P_t = I - P_n``, ``m_W`` the moment the tool exerts on the part about the
sensor (the pad's centre), ``m_d`` its target, ``g_m = moment_gain``. With ``e_w = omega -
omega_r`` driven to 0 by the law, (O2) gives ``phidot = -lambda_o phi`` to first order: the
tool turns onto its target exponentially at ``lambda_o`` (the same first-order tracking as the
translation's ``lambda1``). In (O3) the tool turns with the moment the part exerts on it, an
admittance: a pad on its rim rotates until the moment about its centre is ``m_d``. omegadot_r
omits ``omegadot_d`` (the target turns at most ``orientation_rate_limit``) and, in moment mode,
the moment's rate. Pure numpy; time is an argument.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pinocchio as pin

from ..config.groups import OrientationConfig
from ..model.rotations import align, angle_between, so3_log, tangent_unit, turn_toward

__all__ = ['OrientationRef', 'ToolOrientation']

_ZERO3 = np.zeros(3)
MIN_TRAVEL_SPEED = 1e-3  # m/s: slower than this along the surface, t keeps its last direction
SEAT_S = 0.1  # s: the pad counts as seated after this long with its centre of pressure near


class OrientationRef(NamedTuple):
    """
    One tick's angular reference, W.

    omega_r and its rate, the moment fed forward (N m), the error phi of (O1) (rad), the
    tool's angular velocity omega (rad/s) and its axis a_W (unit) it was computed at.
    """

    omega_r: np.ndarray
    omegadot_r: np.ndarray
    m_W: np.ndarray
    phi: np.ndarray
    omega_W: np.ndarray
    a_W: np.ndarray


class ToolOrientation:
    """The target orientation and the angular reference velocity of (O2)/(O3)."""

    def __init__(self, cfg: OrientationConfig) -> None:
        self.m_d_W = np.zeros(3)  # the tilt moments' target (set_moment_target; kept by reset)
        self.configure(cfg)
        self.reset()

    def configure(self, cfg: OrientationConfig) -> None:
        """Install validated settings; the target goes on from where it is."""
        self.cfg = cfg
        self._a_ee = np.array(cfg.tool_axis)

    def reset(self) -> None:
        """Forget the target: the next call holds the tool's orientation of then (its start)."""
        self.R_0: np.ndarray | None = None  # the orientation held at the start
        self.a_d: np.ndarray | None = None  # the target axis in use (rate-limited)
        self.R_d: np.ndarray | None = None
        self.t_W: np.ndarray | None = None  # the last direction of travel
        self._tilt_dir: np.ndarray | None = None  # the tilt's direction (rate-limited)
        self._omega_d = np.zeros(3)
        self._seated_s = 0.0  # how long the pad has been seated (seated_axis), s

    def set_moment_target(self, m_d_W: np.ndarray) -> None:
        """Use the tilt-moment target ``m_d_W`` (N m, W; its part along n is unused)."""
        self.m_d_W = np.array(m_d_W, dtype=float)

    def axis_W(self, R_W_ee: np.ndarray) -> np.ndarray:
        """Return the tool axis in W at ``R_W_ee``."""
        return R_W_ee.dot(self._a_ee)

    def reference(self, R_W_ee: np.ndarray, omega_W: np.ndarray, n_W: np.ndarray,
                  xdot_d_W: np.ndarray, m_W: np.ndarray, dt: float,
                  touching: bool = True) -> OrientationRef:
        """
        Return (O2) or (O3) at this tick; the target moves by ``dt`` (s, >= 0; 0: it stays).

        ``n_W`` the normal in use (unit, into the surface), ``xdot_d_W`` the reference velocity
        (its part along the surface gives the direction of travel), ``m_W`` the moment the tool
        exerts on the part (N m, W). ``moment`` mode applies (O3) only while ``touching``
        (otherwise (O2)).
        """
        cfg = self.cfg
        if self.R_0 is None:  # the start: the target is where the tool is
            self.R_0, self.a_d, self.R_d = R_W_ee.copy(), self.axis_W(R_W_ee), R_W_ee.copy()
            self._a_0 = self.a_d.copy()  # R_0's axis
        if dt > 0.0:
            self._advance(n_W, xdot_d_W, dt)
        phi = so3_log(self.R_d.dot(R_W_ee.T)).tolist()  # 3-vectors as floats from here
        size = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
        if size > cfg.error_limit:
            phi = [p * (cfg.error_limit / size) for p in phi]
        lam, w_d = cfg.lambda_o, self._omega_d.tolist()
        omega_r = [w + lam * p for w, p in zip(w_d, phi)]
        omegadot_r = [lam * (w - o) for w, o in zip(w_d, omega_W.tolist())]
        if cfg.mode == 'moment' and touching:
            n = n_W.tolist()
            dm = [a - b for a, b in zip(m_W.tolist(), self.m_d_W.tolist())]
            k_r, k_a, k_m = _dot(n, omega_r), _dot(n, omegadot_r), _dot(n, dm)
            g = cfg.moment_gain
            omega_r = [c * k_r - g * (d - c * k_m) for c, d in zip(n, dm)]
            omegadot_r = [c * k_a for c in n]
        return OrientationRef(np.array(omega_r), np.array(omegadot_r), m_W, np.array(phi),
                              omega_W, self.axis_W(R_W_ee))

    def _advance(self, n_W: np.ndarray, xdot_d_W: np.ndarray, dt: float) -> None:
        """Turn a_d toward a* (rate-limited), rebuild R_d and its rate omega_d."""
        cfg = self.cfg
        target, t_W = n_W, None
        if cfg.tilt > 0.0 or cfg.spin == 'path':  # the direction of travel matters
            moving = tangent_unit(xdot_d_W, n_W, MIN_TRAVEL_SPEED)
            if moving is not None:
                self.t_W = moving
            t_W = None if self.t_W is None else tangent_unit(self.t_W, n_W)
        if cfg.tilt > 0.0 and t_W is not None:
            target = math.cos(cfg.tilt) * n_W + math.sin(cfg.tilt) * self._tilt_toward(
                n_W, t_W, cfg.rate_limit * dt / math.sin(cfg.tilt))
        a_d = turn_toward(self.a_d, target, cfg.rate_limit * dt)
        spin = cfg.spin == 'path' and t_W is not None
        if not spin and a_d.tolist() == self.a_d.tolist():  # the target did not move
            self._omega_d = _ZERO3  # never written in place
            return
        self.a_d = a_d
        R_d = align(self._a_0, a_d).dot(self.R_0)
        if spin:
            R_d = self._spin_along(R_d, t_W, cfg.rate_limit * dt)
        self._omega_d = so3_log(R_d.dot(self.R_d.T)) / dt
        self.R_d = R_d

    def _tilt_toward(self, n_W: np.ndarray, t_W: np.ndarray, max_angle: float) -> np.ndarray:
        """
        Return the tilt's direction (tangent, unit) turned about n toward t by ``max_angle``.

        The axis then stays on the cone ``tool_tilt`` around n_hat while the direction of
        travel turns (a corner): a turn straight across would cut the tilt short midway. The
        caller's ``max_angle``, ``orientation_rate_limit dt / sin(tool_tilt)``, moves the axis
        along the cone at the rate limit.
        """
        t_d = None if self._tilt_dir is None else tangent_unit(self._tilt_dir, n_W)
        self._tilt_dir = turn_toward(t_W if t_d is None else t_d, t_W, max_angle)
        return self._tilt_dir

    def _spin_along(self, R_d: np.ndarray, t_W: np.ndarray, max_angle: float) -> np.ndarray:
        """
        Turn R_d about a_d so the end effector's x axis lies along t (tool_spin path).

        The spin held from the last tick is the start (``R_0`` then carries it on), so the spin
        also turns at most ``max_angle`` per tick.
        """
        x, t = tangent_unit(R_d[:, 0], self.a_d), tangent_unit(t_W, self.a_d)
        if x is None or t is None:
            return R_d
        angle = min(angle_between(x, t), max_angle)
        sign = 1.0 if float(np.cross(x, t).dot(self.a_d)) >= 0.0 else -1.0
        R_spin = pin.exp3(sign * angle * self.a_d)
        self.R_0 = R_spin.dot(R_d)  # the new spin is held from here on
        self._a_0 = self.a_d.copy()
        return self.R_0.copy()

    def seated_axis(self, R_W_ee: np.ndarray, n_W: np.ndarray, f_W: np.ndarray,
                    m_W: np.ndarray | None, dt: float, touching: bool,
                    offset: float) -> np.ndarray | None:
        """
        Return the tool axis in W while the pad is seated (the normal's (N7)), else None.

        ``moment`` mode only. Seated: touching, with a measured moment ``m_W`` (None: no
        torque yet), and the tilt part of its error ``P_t (m_W - m_d)`` (``P_t = I - n n^T``,
        ``n_W`` the normal in use) below ``offset |f_W|`` (the centre of pressure within
        ``offset`` m of the pad's centre: a pad on its rim has it at its radius) for
        :data:`SEAT_S` of ``dt`` steps (s).
        """
        if self.cfg.mode != 'moment' or not touching or m_W is None or not offset > 0.0:
            self._seated_s = 0.0
            return None
        n, f = n_W.tolist(), f_W.tolist()
        dm = [a - b for a, b in zip(m_W.tolist(), self.m_d_W.tolist())]
        k = _dot(n, dm)
        tilt = [d - c * k for c, d in zip(n, dm)]
        if _dot(tilt, tilt) > offset * offset * _dot(f, f):
            self._seated_s = 0.0
            return None
        self._seated_s += dt
        return self.axis_W(R_W_ee) if self._seated_s >= SEAT_S else None

    def tilt_error(self, R_W_ee: np.ndarray) -> float:
        """Return the angle between the tool axis and its target axis a_d, rad."""
        return 0.0 if self.a_d is None else angle_between(self.axis_W(R_W_ee), self.a_d)


def _dot(a: list, b: list) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
