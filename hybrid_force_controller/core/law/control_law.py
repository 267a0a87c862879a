"""
The adaptive hybrid force/motion control law of [1], eqs. (5)/(6), (8), (11) and (26).

[1] Jafari et al., "An Adaptive Hybrid Force/Motion Control Design for Robot Manipulators
Interacting in Constrained Motion with Unknown Non-Rigid Environments".

Pure numpy + pinocchio (through :class:`RobotModel`). Time is an argument: the caller
passes ``dt``; nothing here reads a clock.

Well-posed eq. (11). The literal error vector adds force-rate terms (N/s) to velocity
terms (m/s). Here the S-part is scaled by a compliance ``c = 1/k_s`` (m/N), the force rate
is the model-based estimate ``fdot_hat = k_s n^T xdot`` (no differentiated force), and
lambda2 is read in m/(N s^2), the units in which eqs. (21) and (29) are consistent:

    e = (I - S)(dxdot + lambda1 dx) + n (c dfdot_hat + c lambda1 df_n + lambda2 h)

so with ``r = xdot - e`` (eq. 8) the normal part of r holds no velocity and ``rdot``
needs no acceleration:

    r    = (I - S)(xdot_d - lambda1 dx) + n (c fdot_d - c lambda1 df_n - lambda2 h)
    rdot = (I - S)(xddot_d - lambda1 dxdot) - n (lambda1 (n^T xdot - c fdot_d) + lambda2 df_n)

Along n this is a PI force loop on a velocity reference. With e = 0 its closed loop is
``hddot + (k/k_s) lambda1 hdot + lambda2 k h = 0``; eq. (29), ``lambda1^2 > 2 lambda2
k_max``, is then dimensionally consistent and (with k_s = k_max) says this loop is damped
better than 1/sqrt(2) at the stiffest surface.

Adaptation units. Eq. (26) is applied to e expressed in the paper's force-rate units,
``k_a e`` (N/s), i.e. ``theta_hat_dot = -Gamma^-1 Y_x^T (k_a e)``. That is (26) in SI units
with ``Gamma/k_a``, so the Lyapunov function (27) keeps its form; with the paper's
Gamma = 70 I it makes the estimates converge in seconds instead of minutes.

Time-varying k_s (the online stiffness estimate, stiffness.py). ``set_k_s`` changes k_s
in O(1) without a new gain set: ``c = 1/k_s``, ``lambda2 = lambda2_0 k_s0 / k_s`` (lambda2_0,
k_s0 the gains'), so that at ``k_s = k`` the normal loop is ``hddot + lambda1 hdot +
lambda2_0 k_s0 h = 0``, the user's loop at the design stiffness k_s0 whatever the surface;
h is rescaled so that ``lambda2 h`` (a velocity in r) is continuous, the anti-windup bound
of h scales alike (``|lambda2 h| <= lambda2_0 integral_limit``), and rdot gains the term of
the varying compliance, ``-cdot lambda1 df_n n`` with ``cdot = -c d(ln k_s)/dt``.

Approach. Out of contact the runtime may replace the force loop along n by a position
reference moving toward the surface (``ApproachRef``): the normal part of r becomes
``v_n - lambda1 (n^T x - x_n)``, the same first-order tracking the tangential part uses.
(26) integrates e saturated to ``adapt_error_limit`` (0.1 m/s): tracking errors of a wrong
model are millimetres per second, while an impact or a jump of the surface stiffness
(with the force loop's compliance c = 1/k_s set for the old surface) makes e metres per
second for a few ticks and threw theta_hat to 2.7 times the truth; the saturation keeps
the direction of each update and bounds its size. Meanwhile an approach adapts on the
tangential part of e only: the normal error then measures
how far the lag-limited approach reference leads the tool, not a model error, and
adapting on it swung theta_hat past the truth (6 N impacts with the masses 50 % high).

Moving normal. With the normal estimated (runtime/surface.py), ``set_normal`` makes the law use
n_hat (and its rate) in place of the gains' n: r and rdot then come from moving_normal.py (M2),
the derivative of r with S moving fed forward (docs/design.md, "A moving normal"); without it,
nothing here changes.

Time is an argument: ``dt`` is the time the newest state integrates theta_hat and h over
(0 when no new state arrived since the last tick: the command is recomputed, nothing
integrates). Effort limits are the runtime's (:class:`~.effort.EffortLimiter`).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .adaptation import adapt_theta
from .law_io import ApproachRef, ControlError, ControlOutput
from .moving_normal import MovingNormal
from .orientation import OrientationRef
from .reference import Reference
from .task_inverse import angular_damping
from .tick_impl import make_tick
from ..config.params import LawGains
from ..model.linalg import small_inverse
from ..model.robot_model import RobotModel, TaskKinematics

__all__ = ['ApproachRef', 'ControlError', 'ControlOutput', 'HybridForceController',
           'adapt_theta', 'small_inverse']


class _Derived(NamedTuple):
    """What a gain set fixes for every tick (computed once in ``set_gains``)."""

    gains: LawGains
    n: np.ndarray          # the normal in task coordinates
    G: np.ndarray          # [r; rdot] = G z + force terms (see _linear_part)
    Gamma_inv: np.ndarray


class _Compliance:
    """The k_s in use and what it fixes (updated in place by ``set_k_s``)."""

    __slots__ = ('k_s', 'c', 'lambda2', 'h_limit', 'c_rate', 'override')

    def __init__(self) -> None:
        self.k_s = self.c = self.lambda2 = self.h_limit = self.c_rate = 0.0
        self.override: float | None = None  # k_s set by set_k_s (None: the gains')


class HybridForceController:
    """
    Adaptive hybrid force/motion controller for one arm model.

    ``set_gains`` swaps the gains atomically (the next ``step`` uses the new set);
    ``step`` computes one command from the latest state.
    """

    def __init__(self, model: RobotModel, gains: LawGains) -> None:
        self.model = model
        self._project = model.parameter_set.project
        self._tick = make_tick(gains.tick_impl, model.n)  # compiled: loaded here, at configure
        self._tick.warm_up(model)  # and each kernel's first call made: never in a tick
        self._d: _Derived | None = None
        self._k = _Compliance()
        self._moving: MovingNormal | None = None  # a moving normal (set_normal), else d.n
        self.h = 0.0
        self.damped = False  # the last step used a damped inverse (a pose near a singularity)
        self.e_w: np.ndarray | None = None  # the last step's angular error (the 6-D task), rad/s
        self._r6 = (np.zeros(6), np.zeros(6))  # the 6-D task's r and rdot, filled in place
        self.set_gains(gains)
        self.reset()

    @property
    def tick_note(self) -> str:
        """Say which per-tick arithmetic runs (tick_impl.py), and how it loaded."""
        return self._tick.note

    @property
    def reference_kernel(self):
        """Return the compiled reference's kernel (tick_impl.py; None: numpy computes it)."""
        return self._tick.reference_rows

    @property
    def stiffness_kernels(self):
        """Return the stiffness estimate's kernels (tick_impl.py; None: stiffness.py's Python)."""
        return self._tick.stiffness_kernels

    @property
    def gains(self) -> LawGains:
        return self._d.gains

    @property
    def k_s(self) -> float:
        """Return the k_s in use, N/m (the gains' unless ``set_k_s`` set one)."""
        return self._k.k_s

    @property
    def lambda2(self) -> float:
        """Return the lambda2 in use, ``lambda2_0 k_s0 / k_s``, m/(N s^2)."""
        return self._k.lambda2

    def set_gains(self, gains: LawGains) -> None:
        """
        Install a validated gain set; derived matrices are computed here, once.

        A k_s set by ``set_k_s`` stays in use (lambda2 follows the new gains' lambda2_0, k_s0).
        """
        self.f_d, self.fdot_d = gains.f_d, 0.0  # the desired force, N, and its rate, N/s
        ax = list(self.model.task_axes)
        n = gains.n[ax]
        if self._d is not None and not np.array_equal(gains.n, self._d.gains.n):
            self.h = 0.0  # the force integral belongs to the old normal
        m = len(ax)
        P_t = np.eye(m) - np.outer(n, n)
        self._d = _Derived(gains, n, self._linear_part(P_t, n, gains.lambda1),
                           np.linalg.inv(gains.Gamma))
        # z of _linear_part, filled in place each tick through views of its parts
        self._z = z = np.zeros(2 * m + 11)
        self._z_parts = tuple(z[i:j] for i, j in ((0, m), (m, 2 * m), (2 * m, 2 * m + 3),
                                                  (2 * m + 3, 2 * m + 6), (2 * m + 6, 2 * m + 9)))
        self._set_compliance(self._k.override, 0.0, rescale_h=False)

    @property
    def n(self) -> np.ndarray:
        """Return the normal in use, task coordinates: the gains' n, or the moving n_hat."""
        mn = self._moving
        return self._d.n if mn is None else np.array(
            mn.n if mn.axes is None else [mn.n[i] for i in mn.axes])

    def set_normal(self, moving: MovingNormal | None) -> None:
        """
        Use a moving normal n_hat (moving_normal.py, (M2)) from the next step on; None: the gains'.

        The reference passed to :meth:`step` must then be the projected one (M1): it has no
        part along n_hat. The force integral h goes on (it integrates along the current normal).
        """
        self._moving = moving

    def set_k_s(self, k_s: float | None, log_rate: float = 0.0) -> None:
        """
        Use ``k_s`` (N/m, finite > 0; None: the gains' k_s) from the next step on, O(1).

        ``lambda2 = lambda2_0 k_s0 / k_s``; h is rescaled so that ``lambda2 h`` is
        continuous; ``log_rate = d(ln k_s)/dt`` (1/s) adds the rdot term of the varying
        compliance (module docstring). Raises :class:`ControlError` on a bad value.
        """
        if k_s is not None and not (isinstance(k_s, (int, float)) and k_s > 0.0
                                    and math.isfinite(k_s)):
            raise ControlError(f'k_s must be finite and > 0, got {k_s!r}')
        if not math.isfinite(log_rate):
            raise ControlError(f'log_rate must be finite, got {log_rate!r}')
        self._set_compliance(k_s, log_rate, rescale_h=True)

    def _set_compliance(self, k_s: float | None, log_rate: float, rescale_h: bool) -> None:
        g, k = self._d.gains, self._k
        k.override = k_s
        k_s = g.k_s if k_s is None else float(k_s)
        ratio = g.k_s / k_s  # exactly 1.0 at the gains' own k_s
        lambda2 = g.lambda2 * ratio
        if rescale_h and k.lambda2 > 0.0:
            self.h *= k.lambda2 / lambda2
        k.k_s, k.c, k.lambda2 = k_s, 1.0 / k_s, lambda2
        k.h_limit = g.integral_limit / ratio
        k.c_rate = k.c * log_rate

    def _linear_part(self, P_t: np.ndarray, n: np.ndarray, l1: float) -> np.ndarray:
        """
        Return G with ``G z = [r; rdot]``, eqs. (8) and (11): one product per tick.

        Here ``z = (x, xdot, x_d, xdot_d, xddot_d, r_n, rdot_n)`` (x, xdot in task coordinates,
        the reference 3-D; r_n and rdot_n the normal terms of the mode, :meth:`force_loop_r_n`).
        """
        m = len(n)
        A = np.eye(3)[list(self.model.task_axes)]  # base frame -> task coordinates
        Z, Z3, z1, n1 = np.zeros((m, m)), np.zeros((m, 3)), np.zeros((m, 1)), n[:, None]
        r_row = np.hstack([-l1 * P_t, Z, l1 * P_t @ A, P_t @ A, Z3, n1, z1])
        rdot_row = np.hstack([Z, -l1 * P_t - l1 * np.outer(n, n), Z3, l1 * P_t @ A, P_t @ A,
                              z1, n1])
        return np.vstack([r_row, rdot_row])

    def reset(self, theta_hat: np.ndarray | None = None) -> None:
        """Restart the adaptation (``theta_hat0`` by default) and the force integral."""
        g = self.gains
        self.theta_hat = (g.theta_hat0 if theta_hat is None else np.asarray(theta_hat)).copy()
        self.h = 0.0

    def reference_velocity(self, kin: TaskKinematics, ref: Reference, f: np.ndarray,
                           approach: ApproachRef | None = None,
                           r_bias: tuple[float, float] = (0.0, 0.0)
                           ) -> tuple[np.ndarray, np.ndarray, float, float, float]:
        """
        Compute r and rdot from eqs. (8) and (11) (scaled form, module docstring).

        Returns r, rdot, df_n, the normal part of r and the mode-specific part of rdot's. With
        ``approach`` the normal part tracks that reference instead of the force loop; otherwise
        ``r_bias`` (m/s, m/s^2) is added to them (the runtime's hand-over from an approach).
        """
        d, mn = self._d, self._moving
        g, n = d.gains, (d.n if mn is None else mn.n)
        f_n = float(n.dot(f)) if mn is None else mn.dot(f)
        if approach is None:
            r_n, rdot_n = self.force_loop_r_n(f_n)
            r_n, rdot_n = r_n + r_bias[0], rdot_n + r_bias[1]
        else:
            r_n, rdot_n = self._approach_r_n(approach, float(n.dot(kin.x)) if mn is None
                                             else mn.dot(kin.x))
        if mn is not None:  # (M2) of moving_normal.py
            dr_n = -g.lambda1 * (mn.dot(kin.x, rate=True) if approach is not None
                                 else self._k.c * mn.dot(f, rate=True))
            r, rdot = mn.r_rdot(kin.x, kin.xdot, ref, g.lambda1, r_n, rdot_n, dr_n)
            return r, rdot, f_n - self.f_d, r_n, rdot_n
        x, xdot, x_d, xdot_d, xddot_d = self._z_parts  # z of _linear_part, in place
        x[...], xdot[...] = kin.x, kin.xdot
        x_d[...], xdot_d[...], xddot_d[...] = ref
        z = self._z
        z[-2], z[-1] = r_n, rdot_n
        r_rdot = d.G.dot(z)
        m = len(n)
        return r_rdot[:m], r_rdot[m:], f_n - self.f_d, r_n, rdot_n

    def _approach_r_n(self, approach: ApproachRef, x_n: float) -> tuple[float, float]:
        """Return the normal part of r and rdot's mode term in an approach (at ``x_n = n^T x``)."""
        l1 = self._d.gains.lambda1
        return approach.v_n - l1 * (x_n - approach.x_n), approach.a_n + l1 * approach.v_n

    def force_loop_r_n(self, f_n: float) -> tuple[float, float]:
        """
        Return the normal part of r in the force loop and the mode-specific part of rdot's.

        The normal part of r is ``c fdot_d - (c lambda1 (f_n - f_d) + lambda2 h)``, the
        mode-specific part of rdot's ``lambda1 c fdot_d + (c_rate lambda1 - lambda2) (f_n - f_d)``
        (``c_rate``: the rate of change of the compliance, set_k_s; ``fdot_d``: a ramped f_d,
        set_force_setpoint).
        """
        g, k = self._d.gains, self._k
        df_n = f_n - self.f_d
        r_n = -(k.c * g.lambda1 * df_n + k.lambda2 * self.h)
        rdot_n = (k.c_rate * g.lambda1 - k.lambda2) * df_n
        if self.fdot_d:  # a ramp of f_d: its rate enters (11) (never with a constant f_d)
            r_n += k.c * self.fdot_d
            rdot_n += g.lambda1 * k.c * self.fdot_d
        return r_n, rdot_n

    def set_force_setpoint(self, f_d: float, fdot_d: float = 0.0) -> None:
        """
        Use ``f_d`` (N) and its rate ``fdot_d`` (N/s) from the next step on, O(1).

        The runtime ramps f_d (law/force_reference.py); ``set_gains`` sets the gains' f_d
        and rate 0.
        """
        self.f_d, self.fdot_d = f_d, fdot_d

    def step(self, q: np.ndarray, qdot: np.ndarray, f_W: np.ndarray, ref: Reference,
             dt: float, *, in_contact: bool = True, approach: ApproachRef | None = None,
             r_bias: tuple[float, float] = (0.0, 0.0),
             kin: TaskKinematics | None = None, adapt: bool = True,
             rot: OrientationRef | None = None,
             k_w: tuple[float, float] = (0.0, 0.0)) -> ControlOutput:
        """
        One control tick: eqs. (5)/(6) with (8), (11) and the adaptation (26).

        Parameters
        ----------
        q, qdot : numpy.ndarray
            Joint positions and velocities, in ``model.joint_names`` order.
        f_W : numpy.ndarray, shape (3,)
            Force the tool exerts on the surface, base frame, N (filtered).
        ref : Reference
            Desired motion at this tick.
        dt : float
            Time theta_hat and h integrate over, s (>= 0; 0: nothing integrates).
        in_contact : bool
            The runtime's contact state (anti-windup of h).
        approach : ApproachRef, optional
            Normal reference of an approach (None: the force loop).
        r_bias : tuple of float
            Added to the normal part of r and rdot in the force loop (m/s, m/s^2).
        kin : TaskKinematics, optional
            ``model.kinematics(q, qdot)`` when the caller has it already.
        adapt : bool
            False freezes theta_hat (a fault episode); h still integrates. It also holds
            near a singularity (``damped``: the smallest singular value of J below
            ``singular_sigma``), where J is inverted damped (linalg.damped_inverse).
        rot : OrientationRef, optional
            The angular reference of the 6-D task (orientation.py): omega_r and its rate are
            stacked under r and rdot, J_w under J; None: the translational task of [1].
        k_w : tuple of float
            With ``rot``: the angular damping across the tool axis and about it (the tilt's
            and the spin's), N m s/rad: ``K_w = k_t (I - a a^T) + k_s a a^T``, a = rot.a_W.

        Returns
        -------
        ControlOutput
            With ``tau = Y_q theta_hat + tau_0 + J^T (f - K_D e) [+ J_w^T (m - K_w e_w)]``
            (eq. 5 in joint space).

        """
        if not (dt >= 0.0 and math.isfinite(dt)):
            raise ControlError(f'dt must be finite and >= 0, got {dt}')
        g, model = self._d.gains, self.model
        kin = model.kinematics(q, qdot) if kin is None else kin
        f = f_W[model.task_index]
        if self._tick.fused and rot is None and approach is None and self._moving is None:
            return self._steady_step(q, qdot, f, ref, dt, kin, in_contact, r_bias, adapt)
        r, rdot, df_n, r_n, rdot_n = self.reference_velocity(kin, ref, f, approach, r_bias)
        e = kin.xdot - r
        J, Jdot = (kin.J_ee, kin.Jdot_ee) if rot is None else (kin.J6, kin.Jdot6)
        if rot is not None:  # the 6-D task: [r; omega_r], [rdot; omegadot_r]
            r6, rdot6 = self._r6
            r6[:3], r6[3:], rdot6[:3], rdot6[3:] = r, rot.omega_r, rdot, rot.omegadot_r
            r, rdot = r6, rdot6
        J_pinv, N, qdot_r, qddot_r, self.damped = self._tick.joint_reference(
            lambda: model.inertia_inverse(q), J, Jdot, r, rdot, g.singular_sigma)
        Y_q, tau_0 = model.regressor_affine(q, qdot, qdot_r, qddot_r)
        s = qdot - qdot_r  # = J^-1 e for a square J
        self.e_w = None if rot is None else rot.omega_W - rot.omega_r
        tau, finite = self._tick.effort(
            Y_q, self.theta_hat, tau_0, kin.J_ee, f - g.k_d * e, None if rot is None else kin.J_w,
            None if rot is None else rot.m_W - angular_damping(self.e_w, rot.a_W, k_w), N, s,
            g.k_null)
        if not finite:
            raise ControlError('control law produced a non-finite effort')
        if dt > 0.0:
            if approach is not None:  # adapt on the motion along the surface only
                n = self.n
                e_t = e - n * float(n @ e)
                s = J_pinv @ (e_t if rot is None else np.concatenate((e_t, self.e_w)))
            self._integrate(Y_q, s if adapt and not self.damped else None, e, df_n, dt,
                            in_contact and approach is None)
        return ControlOutput(tau, e, kin, self.theta_hat, self.h, r_n, rdot_n)

    def _steady_step(self, q: np.ndarray, qdot: np.ndarray, f: np.ndarray, ref: Reference,
                     dt: float, kin: TaskKinematics, in_contact: bool,
                     r_bias: tuple[float, float], adapt: bool) -> ControlOutput:
        """:meth:`step` in the force loop along the gains' n, in two kernels (tick_impl.py)."""
        d = self._d
        f_n = float(d.n.dot(f))
        r_n, rdot_n = self.force_loop_r_n(f_n)
        r_n, rdot_n = r_n + r_bias[0], rdot_n + r_bias[1]
        tau, e, theta, self.damped = self._tick.law_step(
            self.model, q, qdot, kin, ref, f, d.G, (r_n, rdot_n), d.gains, d.Gamma_inv,
            self.theta_hat, dt, adapt)
        self.e_w = None
        if tau is None:
            raise ControlError('control law produced a non-finite effort')
        if dt > 0.0:
            if theta is not None:
                self.theta_hat = theta if self._project is None else self._project(theta)
            self._integrate_h(f_n - self.f_d, dt, in_contact)
        return ControlOutput(tau, e, kin, self.theta_hat, self.h, r_n, rdot_n)

    def _integrate(self, Y_q: np.ndarray, s: np.ndarray | None, e: np.ndarray, df_n: float,
                   dt: float, force_loop: bool) -> None:
        """
        Integrate eq. (26) in joint space (``Y_x^T e = Y_q^T s`` for a square J) and h, eq. (20).

        ``s`` None: theta_hat is frozen (a fault episode, recovery.py). The force integral h is
        frozen out of contact (anti-windup) and never holds a retreat (h > 0) there.
        """
        d = self._d
        g = d.gains
        if s is not None:
            theta = self._tick.adapt(self.theta_hat, d.Gamma_inv, Y_q, s, e, g.k_a,
                                     g.adapt_error_limit, g.adapt_dead_zone, dt, g.theta_min,
                                     g.theta_max)
            self.theta_hat = theta if self._project is None else self._project(theta)
        self._integrate_h(df_n, dt, force_loop)

    def _integrate_h(self, df_n: float, dt: float, force_loop: bool) -> None:
        """Integrate h, eq. (20): frozen out of the force loop, never a retreat (h > 0) there."""
        if force_loop:
            limit = self._k.h_limit
            self.h = min(max(self.h + df_n * dt, -limit), limit)
        else:
            self.h = min(self.h, 0.0)
