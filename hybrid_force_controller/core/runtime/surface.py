"""
The surface's normal in the runtime: told (the paper), or learnt online (issue 24).

With ``n_estimation`` false the normal is the ``n`` parameter and nothing here runs per tick
(every result is the paper's, bit for bit). With it true, ``n`` is only the initial guess and
the normal of the reference's plane (n_p: a path is planned in its tangent plane). On every new
joint state :meth:`SurfaceNormal.update` feeds the estimator (law/normal_estimate.py,
(N1)-(N6)) with the filtered force the tool exerts, the tool's velocity, the contact state and
the time between the state stamps, and hands the law n_hat with its rate (law/moving_normal.py,
(M2)). S = n_hat n_hat^T then sets the force loop's direction, the tangential projector, the
approach's direction (motion.py) and the desired force ``f_d n_hat``; the reference is carried
onto n_hat's tangent plane along n_p (:meth:`project`, (M1)). For an arm whose task space is a
plane (the paper's) the force and velocity are taken in that plane, so n_hat stays in it.

**Far from the guess.** The projection (M1) divides by ``n_hat^T n_p``; beyond
:data:`MAX_TILT_RAD` (60 deg) from n the normal the law uses stays on that cone (the estimate
itself goes on) and :attr:`limited` says so: a workpiece tilted that far from what the user
said is a wrong ``n``, not a detail to learn.

**Stiffness** (stiffness_loop.py fits ``f_n = k (x_n - x0)`` along the normal). Along n_hat,
``x_n = n_hat^T p`` jumps whenever n_hat turns (``dn^T p``: 0.5 mm per mrad half a metre from
the base), and while the tool slides it drifts at ``sin(delta) v`` with the estimate's error
delta: 0.1 mm/s at 0.08 deg and 7 cm/s, against the micrometres by which a force loop holding
5 N moves the depth (3000 N/m). Integrating ``n_hat^T pdot`` instead (exact for the true normal
on a plane, a cylinder and a sphere) drifts alike: on the Panda's tilted plane the fit fell
from 3000 to 183 N/m within 0.5 s of sliding, on the cylinder and sphere to 50 N/m. So the
fit learns only while the tool is still along the surface (``|v - (v^T n_hat) n_hat|`` below
a fifth of ``n_speed_floor`` for 50 ms) and n_hat stays (the force holds it at rest; a seated
pad's axis, normal_estimate.py (N7), may turn it), and it is re-anchored each time
it resumes: the regression restarts from the current k_hat (kept, as its prior), with the
origin of x_n at the next sample (stiffness_loop.py ``learn``)::

    x_n = n_hat^T p,  learnt only while still; re-anchored when learning resumes          (M3)

While it slides k_hat, and the k_s it sets, hold. Pure Python on floats and small numpy arrays;
times are arguments.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from .latest_inputs import LatestInputs
from .motion import Motion
from ..config.params import ControllerParams
from ..law.control_law import HybridForceController
from ..law.moving_normal import MovingNormal, project_rows
from ..law.normal_estimate import NormalEstimator
from ..law.reference import Reference
from ..law.stiffness_loop import StiffnessLoop
from ..model.robot_model import TaskKinematics

__all__ = ['MAX_TILT_RAD', 'NormalStatus', 'SurfaceNormal']

MAX_TILT_RAD = math.pi / 3.0  # the largest angle between the normal in use and n
PROPAGATE_RAD = 1e-4  # n_W (contact, f_d n, approach) follows n_hat once it moved this far
STILL_FRACTION = 0.2  # the tool is still below this fraction of n_speed_floor across n_hat
STILL_S = 0.05  # ... for this long: the stiffness fit may learn (M3)
STILL_TURN_RAD = 1e-6  # ... while n_hat turns by at most this per state (a seated pad's (N7))
_COS_MAX = math.cos(MAX_TILT_RAD)
_ZERO = (0.0, 0.0, 0.0)


def _dot(a: Sequence[float], b: Sequence[float]) -> float:
    """Return the dot product of two 3-tuples (floats: the tick's small vectors)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


class NormalStatus(NamedTuple):
    """What /diagnostics reports of the normal (base frame)."""

    enabled: bool            # n_estimation: the law uses n_hat
    n_hat: tuple             # the normal in use (the told n when disabled)
    angle_from_n_deg: float  # between it and the told n
    mu_hat: float            # the estimated friction coefficient
    state: str               # what the last sample did (normal_estimate.py)
    samples_used: int
    samples_rejected: int
    limited: bool            # held on the MAX_TILT_RAD cone about n


class SurfaceNormal:
    """The normal one runtime uses: n, or n_hat and its rate (module docstring)."""

    def __init__(self, params: ControllerParams, task_axes: Sequence[int]) -> None:
        self._ax = list(task_axes)
        self._full = tuple(task_axes) == (0, 1, 2)
        self.estimator = NormalEstimator(params.normal, params.law.n)
        self.enabled = False
        self.n_p_W, self._n_p = params.law.n, tuple(params.law.n.tolist())
        self.n_W = params.law.n  # the normal in use, base frame (never mutated)
        self.limited = False
        self.n = tuple(params.law.n.tolist())
        self._still_s = 0.0  # how long the tool has been still along the surface, s
        self.still = False  # ... at least STILL_S: the stiffness fit may learn (along n)
        self._moving: MovingNormal | None = None

    def configure(self, params: ControllerParams, ctrl: HybridForceController,
                  motion: Motion) -> None:
        """
        Install a validated set; hand the normal to the law and the motion.

        The estimate is kept unless the estimation is switched on or ``n`` changes (it
        restarts from ``n``); switched off, the law returns to ``n``.
        """
        cfg, n_p = params.normal, params.law.n
        restart = not (self.enabled and np.array_equal(n_p, self.n_p_W))
        self.estimator.reconfigure(cfg)
        self.n_p_W, self._n_p = n_p, tuple(n_p.tolist())
        if not cfg.enabled:
            self.enabled, self.n_W, self._moving = False, n_p, None
            ctrl.set_normal(None)
            return
        if restart:
            self.estimator.reset(n_p)
            self.n_W, self.n, self.limited = n_p, tuple(n_p.tolist()), False
            self._n_given = self._n_est = self.n  # the n_W given out (_turn), n_hat seen
        self.enabled = True
        self._still_speed2 = (STILL_FRACTION * cfg.speed_floor) ** 2
        self._moving = MovingNormal(self.n, _ZERO, self._n_p, self._kappa(self.n),
                                    None if self._full else self._ax)
        ctrl.set_normal(self._moving)
        motion.set_normal(self.n_W)

    def update(self, f_W: np.ndarray, kin: TaskKinematics, dt: float, touching: bool,
               motion: Motion, axis_W: np.ndarray | None = None) -> None:
        """
        Feed one new state (``dt`` > 0, s): n_hat and its rate to the law; :attr:`still` (M3).

        ``f_W`` the filtered force the tool exerts (base frame), ``kin`` the state's kinematics
        (the task velocity), ``touching`` the contact state, ``axis_W`` a seated pad's axis
        (normal_estimate.py (N7); None: none). The tool is still only while n_hat stays.
        """
        est = self.estimator
        f, v = f_W.tolist(), kin.xdot.tolist()
        if not self._full:
            f, v = self._in_plane(f), self._embed(v)
        est.update(f, v, dt, touching, None if axis_W is None else axis_W.tolist())
        n = est.n_hat
        if n is not self._n_est:  # it turned (a new tuple)
            self._n_est = n
            self.limited = _dot(n, self._n_p) < _COS_MAX
            self._turn(self._limit(n) if self.limited else n, dt, motion)
        elif self._moving.ndot is not _ZERO:
            self._moving.ndot = _ZERO
        n0, n1, n2 = self.n
        v0, v1, v2 = v
        v_n = v0 * n0 + v1 * n1 + v2 * n2
        if (v0 * v0 + v1 * v1 + v2 * v2 - v_n * v_n < self._still_speed2
                and est.last_angle <= STILL_TURN_RAD):
            self._still_s += dt
            self.still = self._still_s >= STILL_S
        else:
            self._still_s, self.still = 0.0, False

    def _turn(self, n: tuple, dt: float, motion: Motion) -> None:
        """Hand the law the new normal ``n`` and its rate; n_W and the motion once it moved."""
        n_old, self.n = self.n, n
        mn, rate = self._moving, 1.0 / dt
        mn.kappa = self._kappa(n)
        mn.n, mn.ndot = n, ((n[0] - n_old[0]) * rate, (n[1] - n_old[1]) * rate,
                            (n[2] - n_old[2]) * rate)
        m = self._n_given
        d0, d1, d2 = n[0] - m[0], n[1] - m[1], n[2] - m[2]
        if d0 * d0 + d1 * d1 + d2 * d2 > PROPAGATE_RAD ** 2:  # numpy costs: not every time
            self.n_W, self._n_given = np.array(n), n
            motion.set_normal(self.n_W)

    def _kappa(self, n: tuple) -> float:
        """Return kappa = 1 / (n_hat^T n_p) of (M1) for ``n``, and keep kappa n_p for project."""
        q = self._n_p
        kappa = 1.0 / _dot(n, q)
        self._kq = (kappa * q[0], kappa * q[1], kappa * q[2])
        return kappa

    def _in_plane(self, f: list) -> list:
        """Zero the components of ``f`` outside the task space (a planar arm)."""
        return [f[i] if i in self._ax else 0.0 for i in range(3)]

    def _embed(self, v: list) -> list:
        """Return the task velocity ``v`` as a base-frame 3-vector (a planar arm)."""
        out = [0.0, 0.0, 0.0]
        for i, a in zip(self._ax, v):
            out[i] = a
        return out

    def _limit(self, n: tuple) -> tuple:
        """Return ``n``, more than MAX_TILT_RAD from the told n, held on that cone."""
        p = self._n_p
        c = _dot(n, p)
        e = [a - c * b for a, b in zip(n, p)]  # across n_p, towards n
        s = math.sqrt(sum(a * a for a in e)) or 1.0
        sin_max = math.sin(MAX_TILT_RAD)
        return tuple(_COS_MAX * b + sin_max * a / s for a, b in zip(e, p))

    def reference(self, motion: Motion, tau: float, inputs: LatestInputs) -> Reference:
        """Return the motion's reference at ``tau``; on n_hat's tangent plane through the tool."""
        if not self.enabled or inputs.state is None:
            return motion(tau)
        return self.project(motion.rows(tau), inputs.kin().p_W)

    def position(self, motion: Motion, tau: float, inputs: LatestInputs) -> np.ndarray:
        """Return :meth:`reference`'s x_d_W alone (the offline log's, at every plant step)."""
        if not self.enabled or inputs.state is None:
            return motion.rows(tau)[0]
        return self.reference(motion, tau, inputs).x_d_W

    def feed_stiffness(self, loop: StiffnessLoop, ctrl: HybridForceController, f_n: float,
                       p_W: np.ndarray, dt_state: float, dt_int: float, touching: bool) -> None:
        """Feed the stiffness estimate: along n, or n_hat and only with the tool still (M3)."""
        if self.enabled:
            loop.update(ctrl, f_n, p_W, dt_state, dt_int, touching, self.n, self.still)
        else:
            loop.update(ctrl, f_n, p_W, dt_state, dt_int, touching)

    def project(self, rows_W: np.ndarray, p_W: np.ndarray) -> Reference:
        """Return the reference rows (3, 3) carried onto n_hat's tangent plane at ``p_W`` (M1)."""
        mn = self._moving
        mn.rows = rows = project_rows(rows_W, p_W, self.n, self._kq)
        a = np.array(rows)
        mn.ref = ref = Reference(a[0], a[1], a[2])
        return ref

    def status(self) -> NormalStatus:
        """Return the snapshot /diagnostics reports."""
        est, n = self.estimator, self.n
        cos = _dot(n, self._n_p)
        angle = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
        return NormalStatus(self.enabled, n, angle, est.mu_hat,
                            est.state if self.enabled else 'off', est.samples_used,
                            est.samples_rejected, self.limited)
