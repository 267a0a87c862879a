"""
Rigid-body model of the arm on pinocchio: task-space terms and the regressor.

Everything here is pure numpy + pinocchio. Reference [1] is Jafari et al., "An Adaptive
Hybrid Force/Motion Control Design for Robot Manipulators Interacting in Constrained
Motion with Unknown Non-Rigid Environments" (the paper in ``shared/seeds``).

Frames: ``_W`` is ``base_link``, the world of the task space (by default the URDF root),
in which every position, force and normal of the controller is expressed; ``_root`` is
the URDF root (pinocchio's world: gravity, ``T_root_ee``). The task coordinates are the
translational coordinates of the end-effector frame origin along the base axes that the
arm can actually move in (``task_axes``: ``(0, 1)`` for a planar arm in the x-y plane,
``(0, 1, 2)`` for a spatial arm).
"""
from __future__ import annotations

from importlib import resources
import math
from pathlib import Path
from typing import NamedTuple, Sequence

import numpy as np
import pinocchio as pin

from .parameter_sets import make_parameter_set, ParameterSetError

__all__ = ['ModelError', 'RobotModel', 'TaskKinematics', 'default_urdf_path']

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
_POLARISE = np.array(((1.0, 0.125), (math.sqrt(2.0), -math.sqrt(2.0) / 8.0)))  # (R2)


class ModelError(ValueError):
    """The robot description cannot be used (bad URDF, unknown link or joint, bad chain)."""


def default_urdf_path() -> Path:
    """Path of the bundled URDF of the paper's 2-link planar arm (section V of [1])."""
    return Path(str(resources.files('hybrid_force_controller') / 'robots'
                    / 'two_link_planar.urdf'))


class TaskKinematics(NamedTuple):
    """
    End-effector kinematics at one state.

    Attributes
    ----------
    p_W : (3,) end-effector position in the base frame, m.
    R_W_ee : (3, 3) rotation of the end-effector frame in the base frame.
    x : (m,) task coordinates, eq. (30) of [1].
    xdot : (m,) task velocity, x_dot = J q_dot.
    J_ee : (m, n) task Jacobian, eq. (31) of [1].
    Jdot_ee : (m, n) its time derivative along q_dot.
    J_w : (3, n) angular Jacobian, ``omega_W = J_w q_dot`` (the 6-D task, orientation.py).
    Jdot_w : (3, n) its time derivative along q_dot.
    J6, Jdot6 : (6, n) the linear rows over the angular ones, W (J_w, Jdot_w are views).

    """

    p_W: np.ndarray
    R_W_ee: np.ndarray
    x: np.ndarray
    xdot: np.ndarray
    J_ee: np.ndarray
    Jdot_ee: np.ndarray
    J_w: np.ndarray | None = None
    Jdot_w: np.ndarray | None = None
    J6: np.ndarray | None = None
    Jdot6: np.ndarray | None = None


class RobotModel:
    """
    A serial arm from a URDF, with an adaptive parameter set (parameter_sets.py).

    The default set is the paper's ``link_masses``: one mass per link, each link keeping
    its nominal geometry; for the paper's arm ``theta = [m1, m2]``. Task coordinates are
    expressed in ``base_link`` (default: the URDF root), which must be fixed to the root.
    """

    def __init__(self, model: pin.Model, end_effector_link: str, gravity_root: np.ndarray, *,
                 parameter_set: str = 'link_masses', base_link: str | None = None) -> None:
        if not model.existFrame(end_effector_link):
            raise ModelError(f"end-effector link '{end_effector_link}' is not in the model")
        if model.nq != model.nv:
            raise ModelError('only revolute and prismatic joints are supported (nq != nv)')
        model.gravity.linear = np.asarray(gravity_root, dtype=float)
        self.model = model
        self.data = model.createData()
        self.frame_id = model.getFrameId(end_effector_link)
        self.end_effector_link = end_effector_link
        self.root_link = model.frames[1].name if len(model.frames) > 1 else 'universe'
        self.base_link = base_link or self.root_link
        self._R_W_root = self._base_rotation(self.base_link)
        self.joint_names = tuple(model.names[i] for i in range(1, model.njoints))
        self.n = model.nv
        try:
            ps = make_parameter_set(model, parameter_set, model.frames[self.frame_id].parentJoint)
        except ParameterSetError as exc:
            raise ModelError(str(exc)) from None
        self.parameter_set = ps
        self._P, self._pi_0 = ps.P, ps.pi_0
        self._has_pi_0 = bool(np.any(ps.pi_0))
        self._P_pi_0 = np.column_stack((ps.P, ps.pi_0))
        # (P, known): theta's map of regressor_affine (known: with pi_0 as its last column)
        self.regressor_map = (self._P_pi_0, True) if self._has_pi_0 else (self._P, False)
        self.theta_names, self.theta_nominal = ps.theta_names, ps.theta_nominal
        self.task_axes = self._detect_task_axes()
        self.m = len(self.task_axes)
        a0, a1 = self.task_axes[0], self.task_axes[-1]
        contiguous = self.task_axes == tuple(range(a0, a1 + 1))
        # a slice gives views (no copy) on the hot path; fancy indexing otherwise
        self.task_index = slice(a0, a1 + 1) if contiguous else list(self.task_axes)
        self.redundant = self.n > self.m
        self.effort_limits = model.effortLimit.copy()
        self.velocity_limits = model.velocityLimit.copy()  # inf or 0: the URDF gives none
        self._zero = np.zeros(self.n)
        self._frame_ids: dict[str, int] = {}

    @classmethod
    def from_urdf(cls, urdf: str | Path | None = None, *, end_effector_link: str = 'tool0',
                  base_link: str | None = None, joints: Sequence[str] | None = None,
                  gravity_root: Sequence[float] | None = None,
                  parameter_set: str = 'link_masses') -> 'RobotModel':
        """
        Load a URDF file path or URDF XML string (``None``: the paper's 2-link arm).

        ``joints`` selects the controlled joints (the others are locked at their neutral
        position clipped into their limits). ``gravity_root`` is in the URDF root frame; the
        default, 9.81 m/s^2 along -y, is the paper's (a z-up robot needs (0, 0, -9.81)).
        """
        src = default_urdf_path() if urdf is None else urdf
        model = _parse(src)
        if joints:
            model = _reduce(model, joints)
        gravity_root = (0.0, -9.81, 0.0) if gravity_root is None else gravity_root
        return cls(model, end_effector_link, np.asarray(gravity_root, dtype=float),
                   parameter_set=parameter_set, base_link=base_link)

    @classmethod
    def from_parameters(cls, values: dict, joints: Sequence[str] | None = None) -> 'RobotModel':
        """Build from MODEL_SCHEMA values (params.py) and the controlled ``joints``."""
        gravity = np.asarray(values.get('gravity', (0.0, -9.81, 0.0)), dtype=float)
        if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
            raise ModelError(f'gravity must be 3 finite numbers, got {gravity.tolist()}')
        return cls.from_urdf(values.get('robot_description') or None,
                             end_effector_link=values.get('end_effector_link') or 'tool0',
                             base_link=values.get('base_link') or None, joints=joints,
                             gravity_root=gravity,
                             parameter_set=values.get('parameter_set') or 'link_masses')

    # ------------------------------------------------------------------ set-up helpers
    def _base_rotation(self, base_link: str) -> np.ndarray | None:
        """Rotation base <- root of a base frame fixed to the root (None: it is the root)."""
        if not self.model.existFrame(base_link):
            raise ModelError(f"base link '{base_link}' is not in the model")
        frame = self.model.frames[self.model.getFrameId(base_link)]
        if frame.parentJoint != 0:
            raise ModelError(f"base link '{base_link}' moves with joint "
                             f"'{self.model.names[frame.parentJoint]}'; it must be fixed")
        self._p_root_W = frame.placement.translation.copy()
        R = frame.placement.rotation
        identity = np.allclose(R, np.eye(3)) and np.allclose(self._p_root_W, 0.0)
        return None if identity else R.T.copy()

    def _detect_task_axes(self) -> tuple[int, ...]:
        """Return the base axes along which the end effector can move (planar arms give 2 axes)."""
        rng = np.random.default_rng(0)
        lo, hi = self.model.lowerPositionLimit, self.model.upperPositionLimit
        span = np.zeros(3)
        for _ in range(8):
            q = rng.uniform(np.maximum(lo, -np.pi), np.minimum(hi, np.pi))
            J = pin.computeFrameJacobian(self.model, self.data, q, self.frame_id,
                                         _LWA).reshape(6, -1)[:3]
            J = J if self._R_W_root is None else self._R_W_root @ J
            span += np.abs(J).sum(axis=1)
        axes = tuple(int(i) for i in np.flatnonzero(span > 1e-9 * max(span.max(), 1.0)))
        if not axes or len(axes) > self.n:
            raise ModelError(f'{self.n} joint(s) cannot control the {len(axes)}-D translational '
                             f'task space of {self.end_effector_link}: fewer joints than the '
                             'task needs')
        return axes

    # ------------------------------------------------------------------ per-tick terms
    def kinematics(self, q: np.ndarray, qdot: np.ndarray) -> TaskKinematics:
        """
        Task position, velocity, Jacobian and its derivative, eqs. (30)-(31) of [1].

        Uses pinocchio's ``computeJointJacobiansTimeVariation`` in the LOCAL_WORLD_ALIGNED
        frame, whose linear rows are d p_W / dq and their time derivative, and whose angular
        rows give ``J_w`` and ``Jdot_w``. Every array is new (the simulator shares this model's
        pinocchio data).
        """
        ax = self.task_index
        p_W, R, J6, Jdot6 = self.frame_kinematics(q, qdot)
        R_W_root = self._R_W_root
        if R_W_root is not None:  # express everything in base_link
            p_W, R, _ = self.base_from_root(p_W, R, J6[:3])
            J6 = np.vstack((R_W_root.dot(J6[:3]), R_W_root.dot(J6[3:])))
            Jdot6 = np.vstack((R_W_root.dot(Jdot6[:3]), R_W_root.dot(Jdot6[3:])))
        J = J6[ax]
        return TaskKinematics(p_W, R, p_W[ax], J.dot(qdot), J, Jdot6[ax], J6[3:], Jdot6[3:],
                              J6, Jdot6)

    def frame_kinematics(self, q: np.ndarray, qdot: np.ndarray) -> tuple[np.ndarray, ...]:
        """
        Return the tool's p, R and its LOCAL_WORLD_ALIGNED J6, J6dot, in the root frame.

        Four pinocchio calls, each array new (p and R views of a new placement).
        :meth:`kinematics` takes its terms from them (in base_link), and so does the runtime's
        steady tick (steady_tick.py, base_link the root).
        """
        model, data, fid = self.model, self.data, self.frame_id
        pin.computeJointJacobiansTimeVariation(model, data, q, qdot)
        T_root_ee = pin.updateFramePlacement(model, data, fid)
        return (T_root_ee.translation, T_root_ee.rotation, pin.getFrameJacobian(
            model, data, fid, _LWA), pin.getFrameJacobianTimeVariation(model, data, fid, _LWA))

    def regressor_q(self, q: np.ndarray, qdot: np.ndarray, qdot_r: np.ndarray,
                    qddot_r: np.ndarray) -> np.ndarray:
        """
        Joint-space regressor: Y_q theta = M(q) qddot_r + C(q, qdot) qdot_r + g(q).

        Eq. (4) of [1] in joint space with a reference velocity (Slotine-Li form), mapped to
        theta by P; see :meth:`regressor_affine`.
        """
        return self.regressor_affine(q, qdot, qdot_r, qddot_r)[0]

    def regressor_affine(self, q: np.ndarray, qdot: np.ndarray, qdot_r: np.ndarray,
                         qddot_r: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """
        ``(Y_q, tau_0)`` with ``Y_q theta + tau_0 = M qddot_r + C qdot_r + g``.

        Two calls of pinocchio's ``computeJointTorqueRegressor`` R, with ``R(q, v, a) pi =
        M a + b(v, v) + g``. C is the Christoffel matrix, so ``C(q, v) w = b(v, w)`` with b
        the symmetric bilinear velocity term of the RNEA. By polarisation, ``2 b(v + w/8,
        v + w/8) - 2 b(v - w/8, v - w/8) = b(v, w)`` (the b(v, v) and b(w, w) terms cancel)
        while M a and g appear 2 - 1 = 1 times, so (v = qdot, w = qdot_r, a = qddot_r)::

            Y = (2 R(q, v + w/8, a) - R(q, sqrt2 (v - w/8), a)) P                   (R2)

        gives ``Y theta = M a + C(q, v) w + g``. ``tau_0 = R pi_0`` is the torque of the known
        part of the model (None when the set has no known part, e.g. ``link_masses``).
        """
        model, data = self.model, self.data
        V = _POLARISE.dot((qdot, qdot_r))  # rows v + w/8 and sqrt2 (v - w/8)
        R = pin.computeJointTorqueRegressor(model, data, q, V[0], qddot_r)  # a new array
        R *= 2.0  # in place: bit for bit 2 R1 - R2, two temporaries fewer (2 us on the Panda)
        R -= pin.computeJointTorqueRegressor(model, data, q, V[1], qddot_r)
        if not self._has_pi_0:
            return R.dot(self._P), None
        Y_tau_0 = R.dot(self._P_pi_0)  # [P, pi_0]: Y and tau_0 in one product
        return Y_tau_0[:, :-1], Y_tau_0[:, -1]

    def regressor_pair(self, q: np.ndarray, V: np.ndarray,
                       qddot_r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return pinocchio's regressors ``R(q, V[0], qddot_r)``, ``R(q, V[1], qddot_r)`` (R2)."""
        model, data = self.model, self.data
        return (pin.computeJointTorqueRegressor(model, data, q, V[0], qddot_r),
                pin.computeJointTorqueRegressor(model, data, q, V[1], qddot_r))

    def inertia_inverse(self, q: np.ndarray) -> np.ndarray:
        """M(q)^-1 of the URDF (nominal) model, by pinocchio's ``computeMinverse``."""
        return pin.computeMinverse(self.model, self.data, q)

    def joint_terms(self, q: np.ndarray, qdot: np.ndarray,
                    theta: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        M(q), C(q, qdot) (Christoffel) and g(q), eqs. (32)-(34) of [1] (corrected).

        Computed from the regressor so that they hold for any theta (default nominal):
        column k of C is b(qdot, e_k).
        """
        theta = self.theta_nominal if theta is None else np.asarray(theta, dtype=float)
        z, eye = self._zero, np.eye(self.n)

        def tau(v, w, a):
            Y, tau_0 = self.regressor_affine(q, v, w, a)
            return Y @ theta + (0.0 if tau_0 is None else tau_0)
        g = tau(z, z, z)
        M = np.column_stack([tau(z, z, eye[k]) - g for k in range(self.n)])
        C = np.column_stack([tau(qdot, eye[k], z) - g for k in range(self.n)])
        return M, C, g

    def task_terms(self, q: np.ndarray, qdot: np.ndarray,
                   theta: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        M_x, C_x and g_x of eqs. (35)-(37) of [1], corrected.

        ``M_x = J^-T M J^-1``, ``C_x = J^-T (C - M J^-1 Jdot) J^-1``, ``g_x = J^-T g``.
        (The paper prints J^T in (35) and ends (36) in J; see docs/errata.md.)
        """
        self._require_square()
        kin = self.kinematics(q, qdot)
        M, C, g = self.joint_terms(q, qdot, theta)
        J_inv = np.linalg.inv(kin.J_ee)
        M_x = J_inv.T @ M @ J_inv
        C_x = J_inv.T @ (C - M @ J_inv @ kin.Jdot_ee) @ J_inv
        return M_x, C_x, J_inv.T @ g

    def regressor_x(self, q: np.ndarray, qdot: np.ndarray, r: np.ndarray,
                    rdot: np.ndarray) -> np.ndarray:
        """
        Task-space regressor of eq. (6): Y_x theta = M_x rdot + C_x r + g_x.

        With qdot_r = J^-1 r and qddot_r = J^-1 (rdot - Jdot qdot_r):
        ``Y_x = J^-T Y_q(q, qdot, qdot_r, qddot_r)``.
        """
        self._require_square()
        kin = self.kinematics(q, qdot)
        qdot_r = np.linalg.solve(kin.J_ee, r)
        qddot_r = np.linalg.solve(kin.J_ee, rdot - kin.Jdot_ee @ qdot_r)
        return np.linalg.solve(kin.J_ee.T, self.regressor_q(q, qdot, qdot_r, qddot_r))

    def base_from_root(self, p: np.ndarray, R: np.ndarray, J: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        Express the position, rotation and (3 x n) Jacobian of a frame in ``base_link``.

        The inputs are in the URDF root frame.
        """
        if self._R_W_root is None:
            return p, R, J
        R_W_root = self._R_W_root
        return R_W_root @ (p - self._p_root_W), R_W_root @ R, R_W_root @ J

    def root_in_base(self) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(R, p)`` of :meth:`base_from_root`'s ``R (x - p)`` (identity, 0: none)."""
        if self._R_W_root is None:
            return np.eye(3), np.zeros(3)
        return self._R_W_root.copy(), self._p_root_W.copy()

    def _require_square(self) -> None:
        if self.redundant:
            raise ModelError('task-space terms (35)-(37) need a square Jacobian; '
                             f'this arm has {self.n} joints for a {self.m}-D task')

    def frame_rotation(self, q: np.ndarray, frame: str) -> np.ndarray:
        """Rotation of a model frame in ``base_link`` at ``q``; ModelError if unknown."""
        fid = self._frame_ids.get(frame)
        if fid is None:
            if not self.model.existFrame(frame):
                raise ModelError(f"unknown frame '{frame}'")
            fid = self._frame_ids[frame] = self.model.getFrameId(frame)
        pin.forwardKinematics(self.model, self.data, q)
        R = pin.updateFramePlacement(self.model, self.data, fid).rotation
        return R.copy() if self._R_W_root is None else self._R_W_root @ R

    def forward_dynamics(self, q: np.ndarray, qdot: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Joint accelerations from pinocchio's ABA (uses the model's true inertias)."""
        return pin.aba(self.model, self.data, q, qdot, tau)

    def with_theta(self, theta: np.ndarray) -> 'RobotModel':
        """Return a copy with inertias ``pi = P theta + pi_0`` (a plant with other parameters)."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != self.theta_nominal.shape or not np.all(np.isfinite(theta)):
            raise ModelError(f'theta must be {len(self.theta_nominal)} finite values')
        if self.parameter_set.name == 'link_masses' and np.any(theta <= 0):
            raise ModelError(f'theta must be {len(self.theta_nominal)} positive masses')
        model = self.model.copy()
        pi = self._P @ theta + self._pi_0
        for j in range(1, model.njoints):
            seg = pi[10 * (j - 1):10 * j]
            if seg[0] > 0:
                model.inertias[j] = pin.Inertia.FromDynamicParameters(seg)
        return RobotModel(model, self.end_effector_link, model.gravity.linear.copy(),
                          parameter_set=self.parameter_set.name, base_link=self.base_link)


def _parse(src: str | Path) -> pin.Model:
    """Build the pinocchio model of a URDF path or XML string; ModelError on failure."""
    try:
        if isinstance(src, Path) or not str(src).lstrip().startswith('<'):
            if not Path(src).is_file():
                raise ModelError(f'URDF file not found: {src}')
            return pin.buildModelFromUrdf(str(src))
        return pin.buildModelFromXML(str(src))
    except ModelError:
        raise
    except Exception as exc:  # pinocchio raises plain RuntimeError/ValueError
        raise ModelError(f'cannot parse URDF: {exc}') from exc


def _reduce(model: pin.Model, joints: Sequence[str]) -> pin.Model:
    """Keep ``joints`` (in URDF order), lock every other joint at a neutral position."""
    names = list(model.names)[1:]
    unknown = [j for j in joints if j not in names]
    if unknown:
        raise ModelError(f'joints not in the URDF: {unknown}')
    lock = [model.getJointId(n) for n in names if n not in joints]
    if not lock:
        return model
    q_ref = np.clip(pin.neutral(model), model.lowerPositionLimit, model.upperPositionLimit)
    return pin.buildReducedModel(model, lock, q_ref)
