"""
Closed-form model of the 2-link planar arm of section V of [1], eqs. (30)-(37).

Pure numpy test oracle for ``hybrid_force_controller.core.model.robot_model``. Reference [1] is
Jafari et al., "An Adaptive Hybrid Force/Motion Control Design for Robot Manipulators
Interacting in Constrained Motion with Unknown Non-Rigid Environments".

The arm has links ``l1``, ``l2`` (m), point masses ``m1``, ``m2`` (kg) at the link tips,
joints about the base z axis, and gravity ``g0`` (m/s^2) along the base -y axis. Joint
angles are measured from the base x axis (``q1``) and from link 1 (``q2``). All task
quantities are expressed in the base frame W.

Errata (see ``docs/errata.md``): eqs. (32), (33), (35) and (36) contain typos; the plain
functions below are corrected, and the printed forms are kept as ``*_as_printed`` so the
tests can show that they disagree with the rigid-body model.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


__all__ = ['TwoLinkArm']


@dataclass(frozen=True)
class TwoLinkArm:
    """
    The paper's 2-link planar arm with point masses at the link tips.

    Attributes
    ----------
    l1, l2 : float
        Link lengths, m.
    m1, m2 : float
        Point masses at the tips of links 1 and 2, kg (``theta = [m1, m2]``).
    g0 : float
        Gravity magnitude along -y of the base frame, m/s^2.

    """

    l1: float = 1.0
    l2: float = 1.0
    m1: float = 1.3
    m2: float = 0.9
    g0: float = 9.81

    @property
    def theta(self) -> np.ndarray:
        """Dynamic parameters ``theta = [m1, m2]`` of section V of [1], kg."""
        return np.array([self.m1, self.m2])

    # ------------------------------------------------------------------ kinematics
    def fk(self, q: np.ndarray) -> np.ndarray:
        """
        Task position ``x_W = [x, y]`` of the end effector, eq. (30) (as printed, correct).

        Parameters
        ----------
        q : (2,) ndarray
            Joint angles, rad.

        Returns
        -------
        (2,) end-effector position in the base frame, m.

        """
        q1, q2 = q
        return np.array([self.l1 * np.cos(q1) + self.l2 * np.cos(q1 + q2),
                         self.l1 * np.sin(q1) + self.l2 * np.sin(q1 + q2)])

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """
        Task Jacobian ``J_W = d x_W / d q``, eq. (31) (as printed, correct).

        Parameters
        ----------
        q : (2,) ndarray
            Joint angles, rad.

        Returns
        -------
        (2, 2) Jacobian, m/rad.

        """
        q1, q2 = q
        s1, c1 = np.sin(q1), np.cos(q1)
        s12, c12 = np.sin(q1 + q2), np.cos(q1 + q2)
        return np.array([[-(self.l1 * s1 + self.l2 * s12), -self.l2 * s12],
                         [self.l1 * c1 + self.l2 * c12, self.l2 * c12]])

    def jacobian_dot(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """
        Time derivative ``Jdot_W`` of eq. (31) along ``qdot`` (not printed in [1]).

        Parameters
        ----------
        q : (2,) ndarray
            Joint angles, rad.
        qdot : (2,) ndarray
            Joint velocities, rad/s.

        Returns
        -------
        (2, 2) Jacobian derivative, m/(rad s).

        """
        q1, q2 = q
        w1, w12 = qdot[0], qdot[0] + qdot[1]
        s1, c1 = np.sin(q1), np.cos(q1)
        s12, c12 = np.sin(q1 + q2), np.cos(q1 + q2)
        l1, l2 = self.l1, self.l2
        return np.array([[-(l1 * c1 * w1 + l2 * c12 * w12), -l2 * c12 * w12],
                         [-(l1 * s1 * w1 + l2 * s12 * w12), -l2 * s12 * w12]])

    # ------------------------------------------------------------------ joint space
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """
        Joint inertia matrix M_q, eq. (32), corrected.

        Corrected: the off-diagonal entry is ``M12 = m2 l2 (l2 + l1 cos q2)``; [1] prints
        ``m2 l2 (l2 + 2 l1 cos q2)`` (the factor 2 belongs to M11 only).

        Parameters
        ----------
        q : (2,) ndarray
            Joint angles, rad.

        Returns
        -------
        (2, 2) symmetric positive-definite inertia matrix, kg m^2.

        """
        c2 = np.cos(q[1])
        l1, l2, m1, m2 = self.l1, self.l2, self.m1, self.m2
        m11 = (m1 + m2) * l1 ** 2 + m2 * l2 * (l2 + 2.0 * l1 * c2)
        m12 = m2 * l2 * (l2 + l1 * c2)
        return np.array([[m11, m12], [m12, m2 * l2 ** 2]])

    def mass_matrix_as_printed(self, q: np.ndarray) -> np.ndarray:
        """
        Eq. (32) exactly as printed in [1]: ``M12 = m2 l2 (l2 + 2 l1 cos q2)`` (wrong).

        Differs from :meth:`mass_matrix` by ``m2 l1 l2 cos q2`` in both off-diagonal
        entries.
        """
        c2 = np.cos(q[1])
        l1, l2, m1, m2 = self.l1, self.l2, self.m1, self.m2
        m11 = (m1 + m2) * l1 ** 2 + m2 * l2 * (l2 + 2.0 * l1 * c2)
        m12 = m2 * l2 * (l2 + 2.0 * l1 * c2)
        return np.array([[m11, m12], [m12, m2 * l2 ** 2]])

    def coriolis(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """
        Coriolis/centrifugal matrix C_q(q, qdot), eq. (33), corrected (Christoffel form).

        Corrected: ``C_q = m2 l1 l2 sin q2 [[-qdot2, -(qdot1 + qdot2)], [qdot1, 0]]``, the
        Christoffel-symbol matrix, for which ``Mdot_q - 2 C_q`` is skew-symmetric. [1]
        prints ``[[-2 qdot2, -qdot2], [0, qdot2]]``: its first row is a valid but
        non-Christoffel factorisation, its second row gives ``qdot2^2`` instead of the
        centrifugal term ``qdot1^2`` (wrong C_q qdot).

        Parameters
        ----------
        q : (2,) ndarray
            Joint angles, rad.
        qdot : (2,) ndarray
            Joint velocities, rad/s.

        Returns
        -------
        (2, 2) matrix, kg m^2/s.

        """
        h = self.m2 * self.l1 * self.l2 * np.sin(q[1])
        qd1, qd2 = qdot
        return h * np.array([[-qd2, -(qd1 + qd2)], [qd1, 0.0]])

    def coriolis_as_printed(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """Eq. (33) exactly as printed: ``m2 l1 l2 sin q2 [[-2 qd2, -qd2], [0, qd2]]`` (wrong)."""
        h = self.m2 * self.l1 * self.l2 * np.sin(q[1])
        qd2 = qdot[1]
        return h * np.array([[-2.0 * qd2, -qd2], [0.0, qd2]])

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """
        Gravity torques g_q(q), eq. (34) (as printed, correct; 9.81 replaced by g0).

        Parameters
        ----------
        q : (2,) ndarray
            Joint angles, rad.

        Returns
        -------
        (2,) joint torques, N m.

        """
        c1, c12 = np.cos(q[0]), np.cos(q[0] + q[1])
        l1, l2, m1, m2 = self.l1, self.l2, self.m1, self.m2
        return self.g0 * np.array([(m1 + m2) * l1 * c1 + m2 * l2 * c12, m2 * l2 * c12])

    # ------------------------------------------------------------------ task space
    def task_terms(self, q: np.ndarray,
                   qdot: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        Task-space M_x, C_x, g_x, eqs. (35)-(37), corrected.

        ``M_x = J^-T M_q J^-1`` (35; [1] prints ``J^T M_q J^-1``),
        ``C_x = J^-T (C_q - M_q J^-1 Jdot) J^-1`` (36; [1] ends in ``J``),
        ``g_x = J^-T g_q`` (37, as printed). M_q and C_q are the corrected (32)-(33).

        Parameters
        ----------
        q : (2,) ndarray
            Joint angles, rad.
        qdot : (2,) ndarray
            Joint velocities, rad/s.

        Returns
        -------
        M_x : (2, 2) kg; C_x : (2, 2) kg/s; g_x : (2,) N.

        """
        J_inv = np.linalg.inv(self.jacobian(q))
        M_q = self.mass_matrix(q)
        M_x = J_inv.T @ M_q @ J_inv
        C_x = J_inv.T @ (self.coriolis(q, qdot) - M_q @ J_inv @ self.jacobian_dot(q, qdot)) @ J_inv
        return M_x, C_x, J_inv.T @ self.gravity(q)

    def task_inertia_as_printed(self, q: np.ndarray) -> np.ndarray:
        """
        Eq. (35) exactly as printed: ``M_x = J^T M_q J^-1`` (wrong; not symmetric).

        Uses the corrected M_q so that only the typo of (35) is exercised.
        """
        J = self.jacobian(q)
        return J.T @ self.mass_matrix(q) @ np.linalg.inv(J)

    def task_coriolis_as_printed(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """
        Eq. (36) exactly as printed: ``C_x = J^-T (C_q - M_q J^-1 Jdot) J`` (wrong).

        Uses the corrected M_q and C_q so that only the typo of (36) is exercised.
        """
        J = self.jacobian(q)
        J_inv = np.linalg.inv(J)
        M_q = self.mass_matrix(q)
        return J_inv.T @ (self.coriolis(q, qdot) - M_q @ J_inv @ self.jacobian_dot(q, qdot)) @ J

    def regressor_q(self, q: np.ndarray, qdot: np.ndarray, qdot_r: np.ndarray,
                    qddot_r: np.ndarray) -> np.ndarray:
        """
        Joint-space regressor for ``theta = [m1, m2]``, derived by hand from (32)-(34).

        ``Y_q theta = M_q qddot_r + C_q(q, qdot) qdot_r + g_q`` with the corrected M_q, C_q.
        Column 1 (m1): ``[l1^2 a1 + g0 l1 c1, 0]``. Column 2 (m2): the remaining terms.

        Parameters
        ----------
        q, qdot : (2,) ndarray
            Joint state, rad and rad/s.
        qdot_r, qddot_r : (2,) ndarray
            Reference joint velocity and acceleration.

        Returns
        -------
        (2, 2) regressor, rows joints, columns ``[m1, m2]``.

        """
        l1, l2, g0 = self.l1, self.l2, self.g0
        c1, c12 = np.cos(q[0]), np.cos(q[0] + q[1])
        s2, c2 = np.sin(q[1]), np.cos(q[1])
        qd1, qd2 = qdot
        v1, v2 = qdot_r
        a1, a2 = qddot_r
        k = l1 * l2
        y11 = l1 ** 2 * a1 + g0 * l1 * c1
        y12 = ((l1 ** 2 + l2 ** 2 + 2.0 * k * c2) * a1 + (l2 ** 2 + k * c2) * a2
               + k * s2 * (-qd2 * v1 - (qd1 + qd2) * v2) + g0 * (l1 * c1 + l2 * c12))
        y22 = (l2 ** 2 + k * c2) * a1 + l2 ** 2 * a2 + k * s2 * qd1 * v1 + g0 * l2 * c12
        return np.array([[y11, y12], [0.0, y22]])

    def regressor_x(self, q: np.ndarray, qdot: np.ndarray, r: np.ndarray,
                    rdot: np.ndarray) -> np.ndarray:
        """
        Task-space regressor of eqs. (4)/(6): ``Y_x theta = M_x rdot + C_x r + g_x``.

        With ``qdot_r = J^-1 r`` and ``qddot_r = J^-1 (rdot - Jdot qdot_r)``,
        ``Y_x = J^-T Y_q(q, qdot, qdot_r, qddot_r)`` (substitute (35)-(37) corrected).

        Parameters
        ----------
        q, qdot : (2,) ndarray
            Joint state, rad and rad/s.
        r, rdot : (2,) ndarray
            Task reference velocity (m/s) and its derivative (m/s^2).

        Returns
        -------
        (2, 2) regressor, rows task axes, columns ``[m1, m2]``.

        """
        J = self.jacobian(q)
        qdot_r = np.linalg.solve(J, r)
        qddot_r = np.linalg.solve(J, rdot - self.jacobian_dot(q, qdot) @ qdot_r)
        return np.linalg.solve(J.T, self.regressor_q(q, qdot, qdot_r, qddot_r))
