"""Batched kinematics of a modified-DH 6R chain, in numpy: no Python loop over poses.

Row i of the chain is ``RotX(alpha_{i-1}) RotY(beta_{i-1}) TransX(a_{i-1}) RotZ(theta_i) TransZ(d_i)``
with ``theta_i = q_i + theta_offset_i`` (``beta`` is Hayati's parameter, zero on a nominal arm).
Every function takes joint angles ``q`` of shape (N, 6) (or (6,)) and broadcasts the chain's
arrays, which are (6,) or, for per-pose lengths such as thermal growth, (N, 6).

The tool-point FK transforms the point backwards through the six rows (about 15 flops a row, one
``sin``/``cos`` per joint per batch); :func:`link_frames` builds all frames for Jacobians.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from envs.description import RobotDescription

__all__ = [
    "Chain",
    "Frames",
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

    @classmethod
    def from_description(cls, robot: RobotDescription) -> Chain:
        m = robot.to_modified()
        return cls(
            alpha=m.column("alpha"),
            a=m.column("a"),
            beta=m.column("beta"),
            d=m.column("d"),
            theta_offset=m.column("theta_offset"),
        )

    def replace(self, **kw) -> Chain:
        return replace(self, **kw)


def _rows(x: np.ndarray) -> np.ndarray:
    """A (6,) or (N, 6) chain array as (6, 1) or (6, N), so row i broadcasts against (N,)."""
    x = np.asarray(x, dtype=float)
    return x[:, None] if x.ndim == 1 else np.ascontiguousarray(x.T)


def _angles(chain: Chain, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    th = np.ascontiguousarray(np.atleast_2d(q).T) + _rows(chain.theta_offset)
    return np.cos(th), np.sin(th)


def tool_points(chain: Chain, q: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Positions (N, 3) in the base frame of ``point`` ((3,) or (N, 3)) given in the last frame."""
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    c, s = _angles(chain, q)
    n = c.shape[1]
    pt = np.asarray(point, dtype=float)
    if pt.ndim == 1:
        x, y, z = (np.full(n, v) for v in pt)
    else:
        x, y, z = (np.array(pt[:, k]) for k in range(3))
    ca, sa = np.cos(_rows(chain.alpha)), np.sin(_rows(chain.alpha))
    beta = _rows(chain.beta)
    cb, sb = np.cos(beta), np.sin(beta)
    a, d = _rows(chain.a), _rows(chain.d)
    for i in range(5, -1, -1):
        z = z + d[i]
        x, y = c[i] * x - s[i] * y, s[i] * x + c[i] * y
        x = x + a[i]
        if np.any(sb[i]):
            x, z = cb[i] * x + sb[i] * z, cb[i] * z - sb[i] * x
        y, z = ca[i] * y - sa[i] * z, sa[i] * y + ca[i] * z
    out = np.stack((x, y, z), axis=-1)
    return out[0] if single else out


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


def link_frames(chain: Chain, q: np.ndarray) -> Frames:
    """Frames 0..6 for a batch of joint angles (N, 6)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    c, s = _angles(chain, q)
    alpha, beta = _rows(chain.alpha), _rows(chain.beta)
    a, d = _rows(chain.a), _rows(chain.d)
    R = np.empty((n, 7, 3, 3))
    o = np.empty((n, 7, 3))
    y_beta = np.empty((n, 6, 3))
    x_a = np.empty((n, 6, 3))
    R[:, 0] = np.eye(3)
    o[:, 0] = 0.0
    for i in range(6):
        ca, sa = np.cos(alpha[i]), np.sin(alpha[i])
        cb, sb = np.cos(beta[i]), np.sin(beta[i])
        Rp = R[:, i]
        # P = RotX(alpha) RotY(beta); columns of Q = R_{i-1} P
        if alpha.shape[1] == 1 and beta.shape[1] == 1:
            P = np.array(
                [
                    [cb[0], 0.0, sb[0]],
                    [sa[0] * sb[0], ca[0], -sa[0] * cb[0]],
                    [-ca[0] * sb[0], sa[0], ca[0] * cb[0]],
                ]
            )
            Q = Rp @ P
            y_beta[:, i] = Rp @ np.array([0.0, ca[0], sa[0]])
        else:
            P = np.stack(
                [
                    np.stack([cb, 0 * cb, sb], -1),
                    np.stack([sa * sb, ca + 0 * sb, -sa * cb], -1),
                    np.stack([-ca * sb, sa + 0 * sb, ca * cb], -1),
                ],
                -2,
            ).reshape(-1, 3, 3)
            Q = Rp @ P
            y_beta[:, i] = np.einsum(
                "nij,nj->ni", Rp, np.stack([0 * ca, ca, sa], -1).reshape(-1, 3)
            )
        x_a[:, i] = Q[:, :, 0]
        ci, si = c[i][:, None], s[i][:, None]
        Ri = R[:, i + 1]
        Ri[:, :, 0] = Q[:, :, 0] * ci + Q[:, :, 1] * si
        Ri[:, :, 1] = Q[:, :, 1] * ci - Q[:, :, 0] * si
        Ri[:, :, 2] = Q[:, :, 2]
        o[:, i + 1] = o[:, i] + a[i][:, None] * Q[:, :, 0] + d[i][:, None] * Q[:, :, 2]
    return Frames(R=R, o=o, y_beta=y_beta, x_a=x_a)


def geometric_jacobian(chain: Chain, q: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The geometric Jacobian (N, 6, 6) of ``point`` (in the last frame): rows (v; omega).

    ``J[:, :3, i] = z_i x (p - o_i)``, ``J[:, 3:, i] = z_i``, all in the base frame.
    """
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    f = link_frames(chain, q)
    p = f.point(point)
    z = f.z
    J = np.empty((z.shape[0], 6, 6))
    J[:, :3, :] = np.cross(z, p[:, None, :] - f.o[:, 1:]).transpose(0, 2, 1)
    J[:, 3:, :] = z.transpose(0, 2, 1)
    return J[0] if single else J


def gravity_torques(
    robot: RobotDescription,
    q: np.ndarray,
    payload: float | np.ndarray | None = None,
    chain: Chain | None = None,
) -> np.ndarray:
    """Torques (N, 6) that gravity exerts about each joint axis (SPEC section 2, compliance).

    ``tau_i = z_i . sum_{k>=i} (c_k - o_i) x (m_k g)``, the payload a point mass at the first tool
    point; this is minus the torque a motor must hold. ``payload`` overrides the description's, and
    may be one value per pose.
    """
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    m = robot.to_modified()
    if chain is None:
        chain = Chain.from_description(m)
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
    g = np.asarray(m.gravity, dtype=float)
    lever = MC - M[:, :, None] * f.o[:, 1:]
    tau = np.einsum("nki,nki->nk", f.z, np.cross(lever, g))
    return tau[0] if single else tau
