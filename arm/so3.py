"""Rotations in numpy: the elementary rotations, skew matrices, rotation vectors and the left
Jacobian of SO(3).

The one home of these helpers for the arm model, the lab and the plant (the CasADi versions the
MPC differentiates live in :mod:`agents.tool_model`). Every function takes a single value or a
batch along the leading axes.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "left_jacobian",
    "left_jacobian_inverse",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_matrix",
    "rotation_vector",
    "skew",
]

_SMALL = 1e-8  # rad: below this the left Jacobian's series is exact to rounding


def _elementary(angle: float | np.ndarray, axis: int) -> np.ndarray:
    """The rotation about coordinate axis ``axis`` by every angle (...,) -> (..., 3, 3)."""
    i, j = (axis + 1) % 3, (axis + 2) % 3
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((*np.shape(angle), 3, 3))
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    R[..., j, j] = c
    return R


def rot_x(a: float | np.ndarray) -> np.ndarray:
    """RotX of every angle in ``a`` (...,) -> (..., 3, 3)."""
    return _elementary(a, 0)


def rot_y(b: float | np.ndarray) -> np.ndarray:
    """RotY of every angle in ``b`` (...,) -> (..., 3, 3)."""
    return _elementary(b, 1)


def rot_z(t: float | np.ndarray) -> np.ndarray:
    """RotZ of every angle in ``t`` (...,) -> (..., 3, 3)."""
    return _elementary(t, 2)


def skew(v: np.ndarray) -> np.ndarray:
    """[v]x, the cross-product matrix (``skew(v) @ u == cross(v, u)``), of vectors (..., 3) ->
    (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    K = np.zeros((*v.shape[:-1], 3, 3))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -z, y, -x
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = z, -y, x
    return K


def rotation_matrix(r: np.ndarray) -> np.ndarray:
    """The exponential map: rotation vector(s) (..., 3) -> matrices (..., 3, 3) (scipy's
    :class:`~scipy.spatial.transform.Rotation`)."""
    from scipy.spatial.transform import Rotation

    r = np.asarray(r, dtype=float)
    return Rotation.from_rotvec(r.reshape(-1, 3)).as_matrix().reshape(*r.shape[:-1], 3, 3)


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """The logarithm map: rotation matrices (..., 3, 3) -> rotation vectors (..., 3), of norm at
    most pi (scipy's :class:`~scipy.spatial.transform.Rotation`)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(*R.shape[:-2], 3)


def left_jacobian(r: np.ndarray) -> np.ndarray:
    """The left Jacobian J_l(r) of SO(3) at one rotation vector (3,): exp(r + dr) = exp(J_l(r) dr)
    exp(r) to first order in dr."""
    r = np.asarray(r, dtype=float)
    th = math.sqrt(float(r @ r))
    K = skew(r)
    if th < _SMALL:
        return np.eye(3) + 0.5 * K
    return np.eye(3) + (1 - math.cos(th)) / th**2 * K + (th - math.sin(th)) / th**3 * (K @ K)


def left_jacobian_inverse(r: np.ndarray) -> np.ndarray:
    """The inverse of the left Jacobian at rotation vectors (..., 3) -> (..., 3, 3): where
    ``e = log(R R_0^T)``, a small rotation ``w`` of R changes e by ``J_l(e)^-1 w`` (to first
    order), ``J_l^-1 = I - K/2 + (1/th^2 - (1 + cos th) / (2 th sin th)) K^2``, K = [r]x."""
    r = np.asarray(r, dtype=float)
    th = np.linalg.norm(r, axis=-1)
    K = skew(r)
    small = th < 1e-4
    t = np.where(small, 1.0, th)
    c = np.where(
        small, 1.0 / 12.0 + th**2 / 720.0, 1.0 / t**2 - (1 + np.cos(t)) / (2 * t * np.sin(t))
    )
    return np.eye(3) - 0.5 * K + c[..., None, None] * (K @ K)
