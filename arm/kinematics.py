"""Batched kinematics of a modified-DH 6R chain, in numpy: no Python loop over poses.

Row i of the chain is ``RotX(alpha_{i-1}) RotY(beta_{i-1}) TransX(a_{i-1}) RotZ(theta_i) TransZ(d_i)``
with ``theta_i = q_i + theta_offset_i`` (``beta`` is Hayati's parameter, zero on a nominal arm).
Every function takes joint angles ``q`` of shape (N, 6) (or (6,)) and broadcasts the chain's
arrays, which are (6,) or, for per-pose lengths such as thermal growth, (N, 6). The angles are the
controller's: where the arm's joints are coupled (FANUC's J3 measured from the horizon), the
chain's ``coupling`` turns them into the DH table's, ``theta = C q + theta_offset``.

The tool-point FK transforms the point backwards through the six rows (about 15 flops a row, one
``sin``/``cos`` per joint per batch); :func:`link_frames` builds all frames for Jacobians.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, replace

import numpy as np

from arm.description import RobotDescription

__all__ = [
    "Chain",
    "ColumnFrames",
    "Frames",
    "Workspace",
    "by_joint",
    "column_frames",
    "cross_columns",
    "geometric_jacobian",
    "gravity_torques",
    "link_frames",
    "tool_points",
]


@dataclass(frozen=True)
class Chain:
    """The numeric arrays of a modified-DH chain (lengths in m, angles in rad)."""

    alpha: np.ndarray
    a: np.ndarray
    beta: np.ndarray
    d: np.ndarray
    theta_offset: np.ndarray
    # the joints' linear coupling (6, 6): theta_DH = coupling @ q + theta_offset, q the
    # controller's angles (RobotDescription.coupling_matrix); None where each joint is its own
    coupling: np.ndarray | None = None

    @classmethod
    def from_description(cls, robot: RobotDescription) -> Chain:
        m = robot.to_modified()
        return cls(
            alpha=m.column("alpha"),
            a=m.column("a"),
            beta=m.column("beta"),
            d=m.column("d"),
            theta_offset=m.column("theta_offset"),
            coupling=m.coupling_matrix if m.couplings else None,
        )

    def replace(self, **kw) -> Chain:
        return replace(self, **kw)


def _rows(x: np.ndarray) -> np.ndarray:
    """A (6,) or (N, 6) chain array as (6, 1) or (6, N), so row i broadcasts against (N,)."""
    x = np.asarray(x, dtype=float)
    return x[:, None] if x.ndim == 1 else np.ascontiguousarray(x.T)


def _angles(chain: Chain, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    qt = np.atleast_2d(q).T
    if chain.coupling is not None:  # the controller's angles to the DH table's
        qt = chain.coupling @ qt
    th = np.ascontiguousarray(qt) + _rows(chain.theta_offset)
    return np.cos(th), np.sin(th)


def tool_points(chain: Chain, q: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Positions (N, 3) in the base frame of ``point`` ((3,) or (N, 3)) given in the last frame.

    The point is carried backwards through the six rows, in place in three (N,) vectors: no 4x4
    products, one ``cos``/``sin`` per joint angle, no temporaries per row, and terms whose
    parameter is exactly zero (a, d, alpha, beta) skipped.
    """
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    c, s = _angles(chain, q)
    n = c.shape[1]
    pt = np.asarray(point, dtype=float)
    xyz = np.empty((3, n))
    xyz[:] = pt[:, None] if pt.ndim == 1 else pt.T
    x, y, z = xyz
    t1, t2 = np.empty(n), np.empty(n)
    alpha, beta = _rows(chain.alpha), _rows(chain.beta)
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    a, d = _rows(chain.a), _rows(chain.d)

    def rotate(u, v, cos, sin):  # (u, v) <- (cos u - sin v, sin u + cos v), in place
        np.multiply(v, sin, out=t1)
        np.multiply(v, cos, out=t2)
        np.multiply(u, sin, out=v)
        v += t2
        u *= cos
        u -= t1

    for i in range(5, -1, -1):
        if np.any(d[i]):
            z += d[i]
        rotate(x, y, c[i], s[i])
        if np.any(a[i]):
            x += a[i]
        if np.any(sb[i]):
            rotate(z, x, cb[i], sb[i])  # RotY(beta): x' = cb x + sb z, z' = cb z - sb x
        if np.any(alpha[i]):
            rotate(y, z, ca[i], sa[i])
    out = xyz.T
    return out[0].copy() if single else out


@dataclass(frozen=True)
class Frames:
    """All link frames of a batch, and the intermediate axes of each row for error Jacobians.

    ``R[:, i]`` and ``o[:, i]`` (i = 0..6) are frame i's rotation and origin in the base frame
    (frame 0 is the identity). For row i (index i-1 here) ``x_alpha`` is the axis of alpha_{i-1}
    (x of frame i-1), ``y_beta`` the axis of beta_{i-1}, ``x_a`` the direction of a_{i-1}.
    """

    R: np.ndarray  # (N, 7, 3, 3)
    o: np.ndarray  # (N, 7, 3)
    y_beta: np.ndarray  # (N, 6, 3)
    x_a: np.ndarray  # (N, 6, 3)

    @property
    def z(self) -> np.ndarray:
        """Joint axes z_1..z_6, (N, 6, 3)."""
        return self.R[:, 1:, :, 2]

    @property
    def x_alpha(self) -> np.ndarray:
        return self.R[:, :6, :, 0]

    def point(self, p_last: np.ndarray) -> np.ndarray:
        """A point (3,) or (N, 3) given in the last frame, in the base frame."""
        return self.o[:, 6] + np.einsum(
            "nij,nj->ni", self.R[:, 6], np.broadcast_to(p_last, self.o[:, 6].shape)
        )


class Workspace:
    """Named scratch arrays kept between calls, per thread: repeated evaluations of one batch size
    then reuse memory instead of faulting in fresh pages each call (a freed large numpy array goes
    back to the operating system, and touching a new one costs about as much as the arithmetic
    done on it). Like Pinocchio's ``Data``, but allocated on first use. Arrays from a workspace are
    overwritten by the next call that asks for the same name: never return them to a caller.
    Requests above ``limit_bytes`` get plain fresh arrays."""

    def __init__(self, limit_bytes: int = 64 << 20) -> None:
        self.limit_bytes = limit_bytes
        self._local = threading.local()

    def __call__(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        arrays = self._local.__dict__.setdefault("arrays", {})
        a = arrays.get(name)
        if a is None or a.shape != shape:
            if 8 * math.prod(shape) > self.limit_bytes:
                return np.empty(shape)
            a = arrays[name] = np.empty(shape)
        return a

    def __reduce__(self):  # picklable (sweeps ship models to workers): scratch is not state
        return (Workspace, (self.limit_bytes,))


def _fresh(name: str, shape: tuple[int, ...]) -> np.ndarray:
    return np.empty(shape)


@dataclass(frozen=True)
class ColumnFrames:
    """Frames in component-major layout, pose index last, for the error model's inner loops:
    ``axes[i, k]`` (3, N) is axis k (x, y, z) of frame i, ``o[i]`` (3, N) its origin, ``x_a[i]`` and
    ``y_beta[i]`` (3, N) the directions of a_{i} and beta_{i} of row i+1. Every slice is a
    contiguous block, so a row's update is a handful of vector operations over the batch."""

    axes: np.ndarray  # (7, 3, 3, N)
    o: np.ndarray  # (7, 3, N)
    x_a: np.ndarray  # (6, 3, N)
    y_beta: np.ndarray  # (6, 3, N)

    def frames(self) -> Frames:
        """The same frames in :class:`Frames` layout (views, no copy)."""
        return Frames(
            R=self.axes.transpose(3, 0, 2, 1),
            o=self.o.transpose(2, 0, 1),
            y_beta=self.y_beta.transpose(2, 0, 1),
            x_a=self.x_a.transpose(2, 0, 1),
        )


def column_frames(
    chain: Chain,
    q: np.ndarray,
    base_R: np.ndarray | None = None,
    base_t: np.ndarray | None = None,
    work: Workspace | None = None,
) -> ColumnFrames:
    """Frames 0..6 of a batch (N, 6) in component-major layout; frame 0 is ``(base_R, base_t)``
    (default the identity), so everything comes out in that outer frame directly: one base (3, 3)
    and (3,), or one per pose (N, 3, 3) and (N, 3) (a campaign measured from several tracker
    stations). With a ``work`` space the arrays are its scratch (valid until the next call using
    it)."""
    new = _fresh if work is None else work
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    c, s = _angles(chain, q)
    alpha, beta = _rows(chain.alpha), _rows(chain.beta)
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    a, d = _rows(chain.a), _rows(chain.d)
    axes = new("frames.axes", (7, 3, 3, n))
    o = new("frames.o", (7, 3, n))
    x_a = new("frames.x_a", (6, 3, n))
    y_beta = new("frames.y_beta", (6, 3, n))
    R0 = np.eye(3) if base_R is None else np.asarray(base_R, dtype=float)
    if R0.ndim == 3:  # one base per pose: axis k of pose n's frame 0 is column k of R0[n]
        axes[0] = R0.transpose(2, 1, 0)
    else:
        axes[0] = R0.T[:, :, None]  # axis k of frame 0 is column k of R0
    t0 = None if base_t is None else np.asarray(base_t, dtype=float)
    o[0] = 0.0 if t0 is None else (t0.T if t0.ndim == 2 else t0[:, None])
    for i in range(6):  # terms whose parameter is exactly zero in every pose are skipped
        X, Y, Z = axes[i]
        # Q = R_i RotX(alpha) RotY(beta): columns (Q0, Q1, Q2); y' = Q1 is beta's axis
        Q1 = y_beta[i]
        if not np.any(alpha[i]):
            Q1[:] = Y
            Zp = Z
        else:
            np.multiply(Y, ca[i], out=Q1)
            Q1 += Z * sa[i]
            Zp = Z * ca[i]
            Zp -= Y * sa[i]
        if np.any(sb[i]):
            Q0 = X * cb[i]
            Q0 -= Zp * sb[i]
            Q2 = X * sb[i]
            Q2 += Zp * cb[i]
        else:
            Q0, Q2 = X, Zp
        x_a[i] = Q0
        ci, si = c[i], s[i]
        nX, nY = axes[i + 1, 0], axes[i + 1, 1]
        np.multiply(Q0, ci, out=nX)
        nX += Q1 * si
        np.multiply(Q1, ci, out=nY)
        nY -= Q0 * si
        axes[i + 1, 2] = Q2
        on = o[i + 1]
        on[:] = o[i]
        if np.any(a[i]):
            on += Q0 * a[i]
        if np.any(d[i]):
            on += Q2 * d[i]
    return ColumnFrames(axes=axes, o=o, x_a=x_a, y_beta=y_beta)


def link_frames(chain: Chain, q: np.ndarray) -> Frames:
    """Frames 0..6 for a batch of joint angles (N, 6)."""
    return column_frames(chain, q).frames()


def cross_columns(u: np.ndarray, v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """u x v for component-major stacks (..., 3, N), broadcasting the leading axes."""
    u0, u1, u2 = u[..., 0, :], u[..., 1, :], u[..., 2, :]
    v0, v1, v2 = v[..., 0, :], v[..., 1, :], v[..., 2, :]
    if out is None:
        out = np.empty(np.broadcast_shapes(u.shape, v.shape))
    for k, (a, b, c, d) in enumerate(((u1, v2, u2, v1), (u2, v0, u0, v2), (u0, v1, u1, v0))):
        np.multiply(a, b, out=out[..., k, :])
        out[..., k, :] -= c * d
    return out


def geometric_jacobian(chain: Chain, q: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The geometric Jacobian (N, 6, 6) of ``point`` (in the last frame): rows (v; omega).

    ``J[:, :3, i] = z_i x (p - o_i)``, ``J[:, 3:, i] = z_i``, all in the base frame; by the
    controller's angles where joints are coupled (:func:`by_joint`).
    """
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    f = link_frames(chain, q)
    p = f.point(point)
    z = f.z
    J = np.empty((z.shape[0], 6, 6))
    J[:, :3, :] = np.cross(z, p[:, None, :] - f.o[:, 1:]).transpose(0, 2, 1)
    J[:, 3:, :] = z.transpose(0, 2, 1)
    J = by_joint(chain, J)
    return J[0] if single else J


def by_joint(chain: Chain, J: np.ndarray) -> np.ndarray:
    """Derivatives by the DH angles (..., 6 columns) as derivatives by the controller's angles:
    ``J C`` where the chain's joints are coupled, ``J`` itself otherwise."""
    return J if chain.coupling is None else J @ chain.coupling


TORQUE_BLOCK = 4096  # poses per block of gravity_torques


def gravity_torques(
    robot: RobotDescription,
    q: np.ndarray,
    payload: float | np.ndarray | None = None,
    chain: Chain | None = None,
    gravity: np.ndarray | None = None,
) -> np.ndarray:
    """Torques (N, 6) that gravity exerts about each joint axis (docs/format.md, compliance).

    ``tau_i = z_i . sum_{k>=i} (c_k - o_i) x (m_k g)``, the payload a point mass at the first tool
    point; this is minus the torque a motor must hold. ``payload`` overrides the description's, and
    may be one value per pose; ``gravity`` (3,) or (N, 3), in frame 0, the robot's
    (:meth:`~arm.description.RobotDescription.frame0_gravity`: extra joints at their defaults).
    """
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    m = robot.to_modified()
    if chain is None:
        chain = Chain.from_description(m)
    if q.ndim == 2 and len(q) > TORQUE_BLOCK and np.ndim(chain.a) == 1:
        # block by block: the seven frames of 200k poses take 130 MB, their torques 10 MB
        out = np.empty((len(q), 6))
        pay = None if payload is None else np.broadcast_to(np.asarray(payload, float), len(q))
        grav = None if gravity is None else np.asarray(gravity, dtype=float)
        per_row = grav is not None and grav.ndim == 2
        for a in range(0, len(q), TORQUE_BLOCK):
            b = slice(a, a + TORQUE_BLOCK)
            gb = grav[b] if per_row and grav is not None else grav
            out[b] = gravity_torques(robot, q[b], None if pay is None else pay[b], chain, gb)
        return out
    f = link_frames(chain, q)
    n = f.o.shape[0]
    masses = np.broadcast_to(m.masses, (n, 6)).astype(float)
    coms = f.o[:, 1:] + np.einsum("nkij,kj->nki", f.R[:, 1:], m.coms)
    mp = np.broadcast_to(np.asarray(m.payload if payload is None else payload, dtype=float), (n,))
    tool = f.point(m.tool_points[0])
    # suffix sums of m_k and m_k c_k, payload included at the last link
    mc = masses[:, :, None] * coms
    mc[:, 5] += mp[:, None] * tool
    msum = masses.copy()
    msum[:, 5] += mp
    M = np.cumsum(msum[:, ::-1], axis=1)[:, ::-1]
    MC = np.cumsum(mc[:, ::-1], axis=1)[:, ::-1]
    g = np.asarray(robot.frame0_gravity() if gravity is None else gravity, dtype=float)
    if g.ndim == 2:
        g = g[:, None, :]  # one per pose
    lever = MC - M[:, :, None] * f.o[:, 1:]
    tau = np.einsum("nki,nki->nk", f.z, np.cross(lever, g))
    return tau[0] if single else tau
