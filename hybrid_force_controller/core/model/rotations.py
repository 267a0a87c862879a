"""
Rotations of the 1 kHz path: the SO(3) logarithm and the shortest rotation between two axes.

Pure Python + numpy on 3 x 3 arrays (``math`` on scalars: these run every tick, where numpy's
per-call overhead on 3-vectors costs more than the arithmetic). Frames are the caller's: a
rotation ``R_A_B`` maps B's coordinates to A's.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['align', 'angle_between', 'so3_log', 'tangent_unit', 'turn_toward']


def so3_log(R: np.ndarray) -> np.ndarray:
    r"""
    Return the rotation vector ``phi`` of ``R`` (``R = exp([phi]_x)``, ``|phi| <= pi``).

    .. math::

        \cos\vartheta = \frac{\operatorname{tr} R - 1}{2}, \qquad
        w = \operatorname{vee}(R - R^T) = 2 \sin\vartheta \, u, \qquad
        \phi = \vartheta u = \frac{\vartheta}{2 \sin\vartheta} w

    with ``atan2`` for the angle (accurate at both ends) and ``phi = w / 2`` below 1e-8 rad.
    Near pi, where ``w`` vanishes, the axis comes from the largest diagonal entry of
    ``(R + I) / 2 = u u^T`` (its sign from ``w``, else arbitrary: +-pi u are the same turn).
    """
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    wx, wy, wz = h - f, c - g, d - b
    s = 0.5 * math.sqrt(wx * wx + wy * wy + wz * wz)
    cos = max(-1.0, min(1.0, 0.5 * (a + e + i - 1.0)))
    angle = math.atan2(s, cos)
    if angle < 1e-8:
        return np.array((0.5 * wx, 0.5 * wy, 0.5 * wz))
    if angle < math.pi - 1e-6:
        k = angle / (2.0 * s)
        return np.array((k * wx, k * wy, k * wz))
    B = 0.5 * (R + np.eye(3))
    j = int(np.argmax(np.diag(B)))
    u = B[:, j] / math.sqrt(B[j, j])
    w = np.array((wx, wy, wz))
    if float(u.dot(w)) < 0.0:
        u = -u
    return angle * u


def align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    r"""
    Return the shortest rotation taking the unit vector ``a`` onto the unit vector ``b``.

    Rodrigues' formula with ``v = a x b``, ``c = a . b``:
    :math:`R = I + [v]_\times + [v]_\times^2 / (1 + c)`, exact for ``c > -1``. Raises
    ``ValueError`` for opposite vectors (``c <= -1 + 1e-9``), whose turn has no shortest axis.
    """
    ax, ay, az = a.tolist()
    bx, by, bz = b.tolist()
    c = ax * bx + ay * by + az * bz
    if c <= -1.0 + 1e-9:
        raise ValueError('the axes are opposite: no shortest rotation between them')
    vx, vy, vz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    k = 1.0 / (1.0 + c)
    return np.array((
        (1.0 - k * (vy * vy + vz * vz), k * vx * vy - vz, k * vx * vz + vy),
        (k * vx * vy + vz, 1.0 - k * (vx * vx + vz * vz), k * vy * vz - vx),
        (k * vx * vz - vy, k * vy * vz + vx, 1.0 - k * (vx * vx + vy * vy))))


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Return the angle between two 3-vectors, rad (``atan2(|a x b|, a . b)``: exact near 0)."""
    ax, ay, az = a.tolist()
    bx, by, bz = b.tolist()
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ax * bx + ay * by + az * bz)


def turn_toward(a: np.ndarray, b: np.ndarray, max_angle: float) -> np.ndarray:
    """
    Return the unit vector ``a`` turned toward the unit vector ``b`` by at most ``max_angle``.

    Along the great circle through them (``b`` itself when it is within ``max_angle``; for
    opposite vectors, about an axis perpendicular to ``a``).
    """
    angle = angle_between(a, b)
    if angle <= max_angle:
        return b.copy()
    ax, ay, az = a.tolist()
    bx, by, bz = b.tolist()
    c = ax * bx + ay * by + az * bz
    ux, uy, uz = bx - c * ax, by - c * ay, bz - c * az  # the turn's direction, tangent at a
    norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    if norm < 1e-12:
        ux, uy, uz = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))]).tolist()
        norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    cos, sin = math.cos(max_angle), math.sin(max_angle) / norm
    out = (cos * ax + sin * ux, cos * ay + sin * uy, cos * az + sin * uz)
    k = 1.0 / math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
    return np.array((k * out[0], k * out[1], k * out[2]))


def tangent_unit(v: np.ndarray, n: np.ndarray, floor: float = 1e-9) -> np.ndarray | None:
    """Return ``v``'s part across the unit ``n``, made unit; None when shorter than ``floor``."""
    t = v - n * float(n.dot(v))
    norm = math.sqrt(float(t.dot(t)))
    return t / norm if norm > floor else None
