"""
What the tool is asked to do: the reference along the surface, the approach along n (pure numpy).

:class:`Motion` is the runtime's motion side. The modes (controller_runtime.py) decide *when*
the tool approaches, presses or starts again from where it is; this says *what* it tracks:

* along the surface, the reference of a run (law/reference.py ``BlendedReference``: the sine,
  a held point or a user's path (path_run.py, its own clock), blended smoothly on every
  change);
* along n, out of contact, the approach (law/approach.py), and at contact the bumpless
  hand-over of what the approach demanded of r into the force loop;
* the force the tool presses with, f_d, ramped to a new value (law/force_reference.py).

It keeps the last tick's normal part of r and rdot (``r_n``, ``rdot_n``): an approach starts
with the velocity the tool had, and the hand-over fades the gap to the force loop's. Times are
the run's (``tau``, s since its start) or the joint-state stamps (``t``); nothing reads a clock.
"""
from __future__ import annotations

import math

import numpy as np

from .path_run import IDLE, PATH_STOPPED, PathProgress, PathRun
from ..config.params import ControllerParams
from ..law.approach import Approach, Handover
from ..law.control_law import ApproachRef
from ..law.force_reference import ForceRamp
from ..law.path import PathPlan, stop_time
from ..law.reference import BlendedReference, H0_PEAK, Reference, SineReference

__all__ = ['Motion', 'reference_changed']


_REFERENCE_FIELDS = ('ref_center', 'ref_amplitude', 'ref_omega', 'ref_blend_time')


def sine_of(params: ControllerParams) -> SineReference:
    """Return the sine reference of a parameter set (``ref_center``, ``ref_amplitude``, ...)."""
    rt = params.runtime
    return SineReference(rt.ref_center, rt.ref_amplitude, rt.ref_omega)


def reference_changed(old: ControllerParams, new: ControllerParams) -> bool:
    """Say whether a new set changes the reference (a ``ref_*`` parameter or ``n``)."""
    return (any(not np.array_equal(getattr(new.runtime, k), getattr(old.runtime, k))
                for k in _REFERENCE_FIELDS) or not np.array_equal(new.law.n, old.law.n))


class Motion:
    """The reference along the surface and the approach along n of one runtime."""

    def __init__(self, params: ControllerParams, task_index: np.ndarray) -> None:
        self.task_index = task_index
        self.ref = BlendedReference(sine_of(params), params.law.n, params.runtime.ref_blend_time)
        self.approach = Approach(0.0, 0.0)
        self.handover = Handover()
        self.r_n = self.rdot_n = 0.0  # the last tick's normal r (m/s) and rdot term (m/s^2)
        self.x_seen = -math.inf  # where the tool last touched the surface, m along n
        self.path: PathRun | None = None
        self._last = IDLE  # the progress of the last path released
        self.force = ForceRamp(params.law.f_d, params.runtime.f_d_rate)  # f_d(t)
        self.configure(params)

    def configure(self, params: ControllerParams) -> None:
        """Install a validated set's approach and normal (the reference: :meth:`replan`)."""
        rt = params.runtime
        self.n_W = params.law.n
        self.n_task, self._n_moved = params.law.n[self.task_index], False
        self.approach.configure(rt.approach_speed, rt.approach_limit)
        self.path_max_accel = rt.path_max_accel
        self.force.configure(params.law.f_d, rt.f_d_rate)  # a new f_d is ramped to
        self.f_d_W = self.force.value * params.law.n  # the desired force, base frame

    def set_normal(self, n_W: np.ndarray) -> None:
        """Use the normal ``n_W`` (an estimate, runtime/surface.py) for the approach and f_d n."""
        self.n_W, self._n_moved = n_W, True
        self.f_d_W = self.force.value * n_W

    @property
    def force_ramping(self) -> bool:
        """Say whether f_d is still on its way to a new value."""
        return self.force.value != self.force.target

    def force_step(self, dt: float) -> tuple[float, float]:
        """Advance f_d ``dt`` s toward its target (law/force_reference.py): f_d, its rate."""
        f_d = self.force.step(dt)
        self.f_d_W = f_d * self.n_W
        return f_d, self.force.fdot

    def replan(self, params: ControllerParams, tau: float) -> None:
        """Take a new reference (``ref_*``, ``n``): release a held point or a path, blend."""
        self._release()
        self.ref.switch(tau, sine=sine_of(params), release=True, n_W=params.law.n,
                        t_blend=params.runtime.ref_blend_time)

    def hold(self, tau: float, x_W: np.ndarray, blend_s: float | None = None) -> None:
        """Hold the point ``x_W`` (base frame) from ``tau`` on, blended in (a path ends)."""
        self._release()
        self.ref.switch(tau, x_hold_W=x_W, blend_s=blend_s)

    # ------------------------------------------------------------------ a user's path
    def follow(self, tau: float, plan: PathPlan, seq: int) -> None:
        """
        Follow ``plan`` from ``tau`` on (its clock starts at rest), blended from the reference.

        The plan starts where the reference, planned from, would stop (law/path.py): the
        blend is that monotone stop (``stop_time``), lengthened so that a residual offset r
        (the reference moved on while the plan was made) adds at most ``a_max / 2``.
        """
        a_max = self.path_max_accel
        run = PathRun(plan, seq, a_max)
        now, start = self.ref(tau), run.rows()
        dv_W = self.ref.P_t @ now.xdot_d_W
        T = stop_time(float(np.linalg.norm(dv_W)), a_max)
        r = float(np.linalg.norm(self.ref.P_t @ (now.x_d_W - start[0]) + 0.5 * T * dv_W))
        blend = max(T, float(np.sqrt(2.0 * H0_PEAK * r / a_max)))
        self._release()
        self.path = run
        self.ref.switch(tau, path=run, blend_s=blend)

    def stop(self, tau: float) -> None:
        """
        Stop the motion smoothly and hold (an empty path): no jump, no coming back.

        It holds ``x + v T / 2``, blended over T = ``stop_time`` (law/path.py): the velocity
        falls monotonically, decelerating at most ``path_max_accel``.
        """
        now = self.ref(tau)
        v_W = self.ref.P_t @ now.xdot_d_W
        T = stop_time(float(np.linalg.norm(v_W)), self.path_max_accel)
        self.hold(tau, now.x_d_W + 0.5 * T * v_W, blend_s=T)

    def _release(self) -> None:
        """Forget the path being followed (its progress says ``stopped`` unless done)."""
        run, self.path = self.path, None
        if run is not None:
            p = run.progress()
            self._last = p if run.done else p._replace(state=PATH_STOPPED)

    def advance_path(self, dt: float, go: bool) -> None:
        """Advance the path's clock by ``dt`` (``go``: running in contact)."""
        if self.path is not None:
            self.path.advance(dt, go)

    def pause_path(self) -> None:
        """Stand the path still (safe mode)."""
        if self.path is not None:
            self.path.pause()

    def path_progress(self) -> PathProgress:
        """Return the current (or the last) path's progress."""
        return self._last if self.path is None else self.path.progress()

    def __call__(self, tau: float) -> Reference:
        """Return the reference along the surface at ``tau``."""
        return self.ref(tau)

    def rows(self, tau: float) -> np.ndarray:
        """Return the reference at ``tau`` as rows x_d, xdot_d, xddot_d (a new (3, 3) array)."""
        return self.ref.rows(tau)

    def start_from(self, tau: float, p_W: np.ndarray, pdot_W: np.ndarray,
                   correct: bool = False) -> None:
        """
        Blend the reference from the tool's position and velocity (an approach goes on).

        ``correct``: back onto the reference as it goes on (BlendedReference.correct_from).
        """
        (self.ref.correct_from if correct else self.ref.start_from)(tau, p_W, pdot_W)
        self.r_n = float(self.n_W @ pdot_W)

    @property
    def can_approach(self) -> bool:
        """Say whether an approach is configured (``approach_speed`` > 0)."""
        return self.approach.speed > 0.0

    def _n_of_task(self) -> np.ndarray:
        """Return n in task coordinates (an estimate's after set_normal, computed when asked)."""
        if self._n_moved:
            self.n_task, self._n_moved = self.n_W[self.task_index], False
        return self.n_task

    def note_contact(self, x_task: np.ndarray) -> None:
        """Note the tool's task position while it touches (an approach's limit counts on)."""
        self.x_seen = float(self._n_of_task() @ x_task)

    def enter_approach(self, x_task: np.ndarray) -> None:
        """Begin an approach from the tool's task position, with its normal velocity."""
        self.approach.start(float(self._n_of_task() @ x_task), self.r_n, self.x_seen)

    def approach_step(self, dt: float, x_task: np.ndarray) -> ApproachRef:
        """Advance the approach ``dt`` seconds with the tool at ``x_task``; what the law tracks."""
        return self.approach.step(dt, float(self._n_of_task() @ x_task))

    def start_handover(self, t: float, r_f: float, rdot_f: float) -> None:
        """Contact found at ``t``: fade the approach's normal r, rdot into the force loop's."""
        self.handover.start(t, self.r_n - r_f, self.rdot_n - rdot_f)

    def handover_bias(self, t: float) -> tuple[float, float]:
        """Return the approach's part of r and rdot along n still fading at ``t``."""
        return self.handover.bias(t)
