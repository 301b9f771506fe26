"""Inverse kinematics of a 6R arm: every solution in closed form for arms with a spherical wrist,
and a batched damped least-squares (Levenberg-Marquardt) solver for any arm, for full poses, for
tool points, and for the measured point of a calibrated :class:`~arm.errormodel.ErrorModel`.

Closed form (derived here; the seed paper's equations (9)-(20) are not used). The modified-DH rows
``T(i-1 -> i) = RotX(alpha_{i-1}) RotY(beta_{i-1}) TransX(a_{i-1}) RotZ(theta_i) TransZ(d_i)`` must
have this structure, checked at construction:

* a spherical wrist: ``a_4 = a_5 = 0`` and ``d_5 = 0``, so axes 4, 5 and 6 meet at the wrist
  centre ``o_4 = o_6 - d_6 z_6``; ``sin(alpha_4) != 0`` and ``sin(alpha_5) != 0`` (+-90 deg usually);
* ``alpha_1 = +-90 deg`` (shoulder), ``alpha_2 = 0`` or 180 deg (joints 2 and 3 parallel), ``a_2 != 0``;
* ``beta`` zero on rows 2..6. Row 1 (alpha_0, a_0, beta_0, d_1), ``alpha_3``, the shoulder offset
  ``a_1``, the lateral offsets ``d_2, d_3``, the elbow offsets ``a_3, d_4`` and every joint offset
  ``theta_offset`` are free.

Derivation, with ``P = RotX(alpha_0) RotY(beta_0) TransX(a_0) TransZ(d_1)`` and the target pose of
frame 6 written in P's frame (so ``T = RotZ(theta_1) T(1 -> 6)``):

1. The wrist centre in frame 3 is the constant ``w3 = (a_3, -sin(alpha_3) d_4, cos(alpha_3) d_4)``.
   With ``s = cos(alpha_2) = +-1``, in frame 2 it is ``P2 = (a_2 + c3 w3x - s3 w3y,
   s (s3 w3x + c3 w3y), s (w3z + d_3) + d_2)``, whose z part ``Pz`` is a constant.
2. In frame 1, ``o_4 = RotX(alpha_1) (a_1 + X, Y, Pz)`` with ``(X, Y) = RotZ(theta_2) (P2x, P2y)``;
   with ``sin(alpha_1) = e = +-1`` that is ``(a_1 + X, -e Pz, e Y)``.
3. ``RotZ(theta_1)`` maps ``(A, B) = (a_1 + X, -e Pz)`` onto the wrist centre's ``(w_x, w_y)``: so
   ``A = +-sqrt(w_x^2 + w_y^2 - B^2)`` (shoulder left/right) and
   ``theta_1 = atan2(w_y, w_x) - atan2(B, A)``; the height gives ``Y = e w_z``, and ``X = A - a_1``.
4. ``|P2|_xy^2 = X^2 + Y^2 = a_2^2 + rho^2 + 2 a_2 rho cos(theta_3 + phi)`` with
   ``rho, phi`` the polar form of ``(w3x, w3y)``: ``theta_3 = +-acos(.) - phi`` (elbow up/down),
   then ``theta_2 = atan2(Y, X) - atan2(P2y, P2x)``.
5. The wrist: ``M = RotX(alpha_3)^T R_3^T R_6 = RotZ(theta_4) RotX(alpha_4) RotZ(theta_5)
   RotX(alpha_5) RotZ(theta_6)``. Its third column ``W = M e_z`` has
   ``W_z = cos(alpha_4) cos(alpha_5) - sin(alpha_4) sin(alpha_5) cos(theta_5)``: ``theta_5 = +-acos``
   (wrist flip); ``RotZ(theta_4)`` turns ``(u, v) = (sin(theta_5) sin(alpha_5),
   -cos(alpha_4) cos(theta_5) sin(alpha_5) - sin(alpha_4) cos(alpha_5))`` onto ``(W_x, W_y)``, and
   ``theta_6`` is the angle of ``(RotZ(theta_4) RotX(alpha_4) RotZ(theta_5) RotX(alpha_5))^T M``.
   Where ``(u, v) = 0`` (axes 4 and 6 aligned) only ``theta_4 +- theta_6`` is determined: theta_4 is
   then taken from ``q4_hint`` (default 0).

That gives up to 8 solutions; each joint angle ``q_i = theta_i - theta_offset_i`` is then repeated by
``2 pi`` for as long as it stays within the limits (q6 of the seed arm spans +-6.28 rad), so a pose
may have 16 or more solutions. Each branch is polished by two Newton steps on the pose (the acos of
a near-straight elbow loses half the digits otherwise) and every returned solution reproduces the
pose to 1e-9.

A description that is close to this structure (a calibrated arm, whose small errors break it) is
solved on its nearest structured arm, and every branch is then finished by damped least squares on
the true chain. Other arms use damped least squares from several starts; that finds the solutions
its starts lead to, not necessarily all.

It is one module, longer than most, because its derivation is its documentation, and the closed form
and the damped least-squares solver that refines or replaces it share their pose and joint-limit
handling.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from arm.description import RobotDescription
from arm.errors import IKError
from arm.kinematics import Chain, by_joint, link_frames
from arm.so3 import rot_x, rot_y, rot_z, rotation_vector

if TYPE_CHECKING:  # pragma: no cover
    from arm.errormodel import ErrorModel

__all__ = [
    "IKError",
    "IKResult",
    "InverseKinematics",
    "flange_transform",
    "forward_pose",
    "pose_error",
    "singular_directions",
    "singularity",
    "solve_model_point_near",
    "solve_model_pose",
    "solve_point",
    "solve_pose",
    "solve_position",
    "wrist_structure",
]

log = logging.getLogger(__name__)

TWO_PI = 2.0 * math.pi
POSE_TOL = 1e-9  # m and rad: a returned solution reproduces the pose this well
_STRUCTURE_EXACT = 1e-9  # deviations below this count as the exact structure
_STRUCTURE_NEAR = 0.05  # m / rad: closer than this, the closed form seeds a refinement


class IKResult(NamedTuple):
    """Outcome of a damped least-squares solve, one row per pose.

    ``q`` (N, 6) the joint angles reached, ``converged`` (N,) whether the error fell below the
    tolerance, ``error`` (N,) the final error norm (m, or m and rad for a pose), ``iterations``
    (N,) the steps taken.
    """

    q: np.ndarray
    converged: np.ndarray
    error: np.ndarray
    iterations: np.ndarray


def _wrap(x: np.ndarray) -> np.ndarray:
    """Angles to [-pi, pi)."""
    return (np.asarray(x) + math.pi) % TWO_PI - math.pi


def _homogeneous(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.zeros((*R.shape[:-2], 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def _inverse(T: np.ndarray) -> np.ndarray:
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return _homogeneous(Rt, -(Rt @ T[..., :3, 3:4])[..., 0])


# -- poses ---------------------------------------------------------------------------------------
def flange_transform(robot: RobotDescription) -> np.ndarray:
    """4x4 transform modified frame 6 <- flange: the last standard row's ``TransX(a_6)
    RotX(alpha_6)`` for a standard-DH description (see ``to_modified``), frame 6 <- tip link for
    one read from a URDF, the identity for the seed arm (``RobotDescription.flange_matrix``)."""
    return robot.to_modified().flange_matrix


def _tool_matrix(tool: np.ndarray | None) -> np.ndarray:
    """None -> identity; a point (3,) -> a translation; a 4x4 -> itself."""
    if tool is None:
        return np.eye(4)
    tool = np.asarray(tool, dtype=float)
    if tool.shape == (3,):
        T = np.eye(4)
        T[:3, 3] = tool
        return T
    if tool.shape == (4, 4):
        return tool
    raise IKError(f"tool must be None, a point (3,) or a 4x4 transform, got shape {tool.shape}")


def forward_pose(
    robot: RobotDescription,
    q: np.ndarray,
    tool: np.ndarray | None = None,
    chain: Chain | None = None,
) -> np.ndarray:
    """Pose(s) of the tool in the robot base frame: (N, 4, 4), or (4, 4) for q of shape (6,).

    ``tool`` is given in the flange frame (see :func:`flange_transform`): None for the flange
    itself, a point (3,) or a 4x4 transform.
    """
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    chain = Chain.from_description(robot) if chain is None else chain
    f = link_frames(chain, q)
    T = _homogeneous(f.R[:, 6], f.o[:, 6]) @ (flange_transform(robot) @ _tool_matrix(tool))
    return T[0] if single else T


def pose_error(T: np.ndarray, T_target: np.ndarray) -> np.ndarray:
    """(N, 6): position error (m) and rotation vector (rad) taking ``T`` to ``T_target``, both in
    the base frame."""
    dp = T_target[..., :3, 3] - T[..., :3, 3]
    dr = rotation_vector(T_target[..., :3, :3] @ np.swapaxes(T[..., :3, :3], -1, -2))
    return np.concatenate([dp, dr], axis=-1)


# -- damped least squares --------------------------------------------------------------------------
def _dls_step(J: np.ndarray, e: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """``J^T (J J^T + lam^2 I)^-1 e`` for a batch: J (n, m, 6), e (n, m), lam (n,)."""
    m = J.shape[1]
    A = J @ np.swapaxes(J, 1, 2) + (lam**2)[:, None, None] * np.eye(m)
    try:
        y = np.linalg.solve(A, e[..., None])
    except np.linalg.LinAlgError:  # an exactly singular J with vanishing damping
        y = np.linalg.pinv(A) @ e[..., None]
    return (np.swapaxes(J, 1, 2) @ y)[..., 0]


def _levenberg_marquardt(
    residual,
    q0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    tol: float,
    max_iter: int,
    damping: float,
) -> IKResult:
    """Batched LM on ``residual(q, idx) -> (e (n, m), J (n, m, 6))`` with ``e = target - f(q)``
    and ``J = d f / d q``; each pose keeps its own damping, steps are clipped to the limits and
    taken only where they lower the error."""
    q = np.clip(np.array(q0, dtype=float), lower, upper)
    n = q.shape[0]
    idx_all = np.arange(n)
    e, J = residual(q, idx_all)
    err = np.linalg.norm(e, axis=1)
    lam = np.full(n, float(damping))
    iters = np.zeros(n, dtype=int)
    for _ in range(max_iter):
        idx = np.flatnonzero((err > tol) & (lam < 1e4))
        if idx.size == 0:
            break
        qi, Ji = q[idx], J[idx]
        dq = _dls_step(Ji, e[idx], lam[idx])
        # a joint at its limit that the step pushes outwards is held there: solve without it
        held = ((qi <= lower) & (dq < 0)) | ((qi >= upper) & (dq > 0))
        if held.any():
            dq = _dls_step(Ji * ~held[:, None, :], e[idx], lam[idx])
        qn = np.clip(qi + dq, lower, upper)
        en, Jn = residual(qn, idx)
        errn = np.linalg.norm(en, axis=1)
        better = errn < err[idx]
        acc = idx[better]
        q[acc], e[acc], J[acc], err[acc] = qn[better], en[better], Jn[better], errn[better]
        lam[acc] = np.maximum(lam[acc] * 0.1, 1e-7)
        lam[idx[~better]] *= 10.0
        iters[idx] += 1
    return IKResult(q=q, converged=err <= tol, error=err, iterations=iters)


def _batch(x: np.ndarray, n: int, shape: tuple[int, ...], what: str) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.shape == shape:
        return np.broadcast_to(x, (n, *shape)).copy()
    if x.shape != (n, *shape):
        raise IKError(f"{what} must have shape {shape} or {(n, *shape)}, got {x.shape}")
    return x.copy()


def solve_pose(
    robot: RobotDescription,
    T_target: np.ndarray,
    q0: np.ndarray,
    tool: np.ndarray | None = None,
    tol: float = 1e-12,
    max_iter: int = 100,
    damping: float = 1e-2,
    chain: Chain | None = None,
) -> IKResult:
    """Joint angles putting the tool (in the flange frame, as :func:`forward_pose`) at the poses
    ``T_target`` (N, 4, 4) in the robot base frame, by damped least squares from ``q0`` (N, 6),
    within the joint limits. The error is ``|(dp, drot)|`` in m and rad."""
    T_target = np.asarray(T_target, dtype=float)
    single = T_target.ndim == 2
    T_target = T_target.reshape(-1, 4, 4)
    n = T_target.shape[0]
    q0 = _batch(q0, n, (6,), "q0")
    chain = Chain.from_description(robot) if chain is None else chain
    post = flange_transform(robot) @ _tool_matrix(tool)

    def residual(q, idx):
        f = link_frames(chain, q)
        T = _homogeneous(f.R[:, 6], f.o[:, 6]) @ post
        p = T[:, :3, 3]
        J = np.empty((q.shape[0], 6, 6))
        J[:, :3] = np.cross(f.z, p[:, None, :] - f.o[:, 1:]).transpose(0, 2, 1)
        J[:, 3:] = f.z.transpose(0, 2, 1)
        return pose_error(T, T_target[idx]), by_joint(chain, J)

    res = _levenberg_marquardt(residual, q0, robot.lower, robot.upper, tol, max_iter, damping)
    return IKResult(*(x[0] for x in res)) if single else res


def solve_point(
    robot: RobotDescription,
    target_xyz: np.ndarray,
    q0: np.ndarray,
    point: np.ndarray | None = None,
    tol: float = 1e-12,
    max_iter: int = 100,
    damping: float = 1e-2,
) -> IKResult:
    """Joint angles putting ``point`` (in modified frame 6; default the first tool point) at
    ``target_xyz`` (N, 3) in the robot base frame, by damped least squares from ``q0`` (N, 6): the
    minimum-norm steps stay close to ``q0`` in the three redundant directions."""
    target_xyz = np.asarray(target_xyz, dtype=float)
    single = target_xyz.ndim == 1
    target_xyz = target_xyz.reshape(-1, 3)
    n = target_xyz.shape[0]
    q0 = _batch(q0, n, (6,), "q0")
    m = robot.to_modified()
    chain = Chain.from_description(m)
    point = m.tool_points[0] if point is None else np.asarray(point, dtype=float)

    def residual(q, idx):
        f = link_frames(chain, q)
        p = f.point(point)
        J = np.cross(f.z, p[:, None, :] - f.o[:, 1:]).transpose(0, 2, 1)
        return target_xyz[idx] - p, by_joint(chain, J)

    res = _levenberg_marquardt(residual, q0, m.lower, m.upper, tol, max_iter, damping)
    return IKResult(*(x[0] for x in res)) if single else res


def _model_problem(
    columns: Mapping[str, np.ndarray] | None, p: np.ndarray, target_xyz: np.ndarray, q0: np.ndarray
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """The arrays of an inverse-kinematics problem on a calibrated model: the targets (N, 3),
    the starts (N, 6), each column broadcast to (N,), and the parameters."""
    target_xyz = np.asarray(target_xyz, dtype=float).reshape(-1, 3)
    n = target_xyz.shape[0]
    cols = {
        k: np.broadcast_to(np.asarray(v, dtype=float), (n,)) for k, v in (columns or {}).items()
    }
    return target_xyz, _batch(q0, n, (6,), "q0"), cols, np.asarray(p, dtype=float)


def solve_position(
    model: ErrorModel,
    columns: Mapping[str, np.ndarray] | None,
    p: np.ndarray,
    target_xyz: np.ndarray,
    q0: np.ndarray,
    tol: float = 1e-10,
    max_iter: int = 50,
    damping: float = 1e-2,
) -> IKResult:
    """Encoder readings q (N, 6) for which a calibrated model predicts the measured points
    ``target_xyz`` (N, 3) (measurement frame, the pose's target), from ``q0`` (N, 6).

    ``columns`` are the per-pose measured columns the model's effects need (temperature, payload,
    dir1..6, target), as for :meth:`ErrorModel.inputs`. The residual is the model's own
    prediction, so a converged q is exact to ``tol`` (m); the step uses the derivative by the
    effective joint angles, which leaves out the small dependence of joint-angle effects (gravity
    torques, transmission) on q: the iteration still converges, a little more slowly.
    """
    target_xyz, q0, cols, p = _model_problem(columns, p, target_xyz, q0)

    def residual(q, idx):
        inputs = model.inputs(q, {k: v[idx] for k, v in cols.items()})
        xyz, J = model.joint_jacobian(inputs, p)
        return target_xyz[idx] - xyz, J

    robot = model.robot
    return _levenberg_marquardt(residual, q0, robot.lower, robot.upper, tol, max_iter, damping)


def solve_model_pose(
    model: ErrorModel,
    columns: Mapping[str, np.ndarray] | None,
    p: np.ndarray,
    target_xyz: np.ndarray,
    target_R: np.ndarray,
    q0: np.ndarray,
    tol: float = 1e-10,
    max_iter: int = 100,
    damping: float = 1e-2,
) -> IKResult:
    """Encoder readings q (N, 6) for which a calibrated model puts its tool frame at the poses
    ``target_xyz`` (N, 3) and ``target_R`` (N, 3, 3) (measurement frame <- tool frame, as
    :meth:`ErrorModel.predict_pose`), from ``q0`` (N, 6): six equations for six joints, so the
    solution is the one of ``q0``'s branch that the damped steps reach (the nearest, for a start
    as close as a calibration's errors make it). The error is ``|(dp, drot)|`` in m and rad; as
    for :func:`solve_position`, the step uses the derivatives by the effective joint angles."""
    target_xyz, q0, cols, p = _model_problem(columns, p, target_xyz, q0)
    target_R = np.asarray(target_R, dtype=float).reshape(len(target_xyz), 3, 3)

    def residual(q, idx):
        inputs = model.inputs(q, {k: v[idx] for k, v in cols.items()})
        xyz, R, Jp, Jw = model.joint_pose_jacobian(inputs, p)
        dr = rotation_vector(target_R[idx] @ np.swapaxes(R, 1, 2))
        return np.concatenate([target_xyz[idx] - xyz, dr], axis=1), np.concatenate([Jp, Jw], 1)

    robot = model.robot
    return _levenberg_marquardt(residual, q0, robot.lower, robot.upper, tol, max_iter, damping)


# -- singular poses --------------------------------------------------------------------------------
# the smallest singular value of a pose's Jacobian (position rows per metre of its longest lever,
# rotation rows in rad) under this fraction of the largest: a singular pose (a wrist within a few
# degrees of q5 = 0 on a UR or a Puma, an elbow as near its stretch, the two together sooner)
SINGULAR_RATIO = 0.005
_SINGULAR_KIND = ("shoulder", "elbow", "elbow", "wrist", "wrist", "wrist")


def _scaled_svd(Jp: np.ndarray, Jw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The singular values (N, 6) and right singular vectors (N, 6, 6) of ``(Jp / L; Jw)``."""
    Jp, Jw = np.asarray(Jp, dtype=float), np.asarray(Jw, dtype=float)
    lever = np.maximum(np.linalg.norm(Jp, axis=1).max(axis=1), 1e-12)
    _, s, vt = np.linalg.svd(np.concatenate([Jp / lever[:, None, None], Jw], axis=1))
    return s, vt


def singular_directions(Jp: np.ndarray, Jw: np.ndarray, k: int = 2) -> np.ndarray:
    """The ``k`` joint-space directions (N, k, 6) in which a pose moves least (unit vectors, the
    least first): at a singular pose those the arm cannot move in to first order, along which
    its solutions split (a stretched elbow bent either way, q5 either side of 0)."""
    return _scaled_svd(Jp, Jw)[1][:, ::-1][:, :k]


def singularity(Jp: np.ndarray, Jw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How near each pose is to a singularity, from its joint Jacobians: the position's Jp
    (N, 3, 6) and the rotation's Jw (N, 3, 6) (as :meth:`ErrorModel.joint_pose_jacobian`).

    Returns the ratio of the smallest to the largest singular value of ``(Jp / L; Jw)`` (N,)
    (``L`` the pose's longest lever, so that both rows are per radian), and each pose's kind
    (N,) of str: ``""`` where the ratio is at least :data:`SINGULAR_RATIO`, else the
    singularities of every direction below it, joined by ``+``, each named by the joint that
    dominates the direction the arm cannot move in: joint 1 the shoulder, joints 2-3 the elbow
    (the arm stretched or folded), joints 4-6 the wrist (axes 4 and 6 aligned)."""
    s, vt = _scaled_svd(Jp, Jw)
    ratio = s[:, -1] / np.maximum(s[:, 0], 1e-300)
    kinds = np.full(len(s), "", dtype=object)
    for i in np.flatnonzero(ratio < SINGULAR_RATIO):
        low = np.flatnonzero(s[i] < SINGULAR_RATIO * s[i, 0])
        names = {_SINGULAR_KIND[int(np.argmax(np.abs(vt[i, k])))] for k in low}
        kinds[i] = "+".join(n for n in ("shoulder", "elbow", "wrist") if n in names)
    return ratio, kinds


def _kkt_step(
    Jp: np.ndarray, Jw: np.ndarray, ep: np.ndarray, eo: np.ndarray, d: np.ndarray, weight: float
) -> np.ndarray:
    """The step dq (n, 6) minimising ``|d + dq|^2 + weight |eo - Jw dq|^2`` subject to
    ``Jp dq = ep``: the point's equations exactly, the joints' change from the start and the
    orientation's deviation balanced (a KKT system per pose; least squares where it is
    singular)."""
    n = len(Jp)
    K = np.zeros((n, 9, 9))
    K[:, :6, :6] = np.eye(6) + weight * np.swapaxes(Jw, 1, 2) @ Jw
    K[:, :6, 6:] = np.swapaxes(Jp, 1, 2)
    K[:, 6:, :6] = Jp
    rhs = np.concatenate([-d + weight * (np.swapaxes(Jw, 1, 2) @ eo[..., None])[..., 0], ep], 1)
    try:
        x = np.linalg.solve(K, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:
        x = np.stack([np.linalg.lstsq(k, r, rcond=None)[0] for k, r in zip(K, rhs, strict=True)])
    return x[:, :6]


def solve_model_point_near(
    model: ErrorModel,
    columns: Mapping[str, np.ndarray] | None,
    p: np.ndarray,
    target_xyz: np.ndarray,
    target_R: np.ndarray,
    q0: np.ndarray,
    weight: float = 1.0,
    tol: float = 1e-10,
    max_iter: int = 50,
    start: np.ndarray | None = None,
) -> IKResult:
    """Encoder readings q (N, 6) for which a calibrated model predicts the points
    ``target_xyz`` (N, 3) exactly, nearest ``q0`` (N, 6) in a balance of the joints' change and
    the tool frame's turn from ``target_R`` (N, 3, 3): the minimum of ``|q - q0|^2 + weight *
    |turn|^2`` (rad) on the point's three equations, by Newton steps on its KKT system.

    This is the compensation of a singular pose. There the six equations of the pose have
    solutions only far from ``q0`` (a wrist singularity turns joints 4 and 6 a long way, in
    opposite senses, for a small turn across them; a stretched elbow bends by the square root of
    the point's move), while the point alone is reached by a change of the order of the
    correction, the orientation held to the same order. ``converged`` is the point's error
    within ``tol`` (m); ``error`` is that error. The steps start at ``start`` (N, 6) (default
    ``q0``): at a singular pose, a start off it on either side of its split
    (:func:`singular_directions`) reaches the solution that Newton's steps from the pose itself,
    where the point cannot move first-order, do not."""
    target_xyz, q0, cols, p = _model_problem(columns, p, target_xyz, q0)
    target_R = np.asarray(target_R, dtype=float).reshape(len(target_xyz), 3, 3)
    robot = model.robot
    q = np.clip(
        q0.copy() if start is None else _batch(start, len(q0), (6,), "start"),
        robot.lower,
        robot.upper,
    )
    iters = np.zeros(len(q), dtype=int)
    active = np.arange(len(q))
    err = np.full(len(q), np.inf)
    for _ in range(max_iter):
        inputs = model.inputs(q[active], {k: v[active] for k, v in cols.items()})
        xyz, R, Jp, Jw = model.joint_pose_jacobian(inputs, p)
        ep = target_xyz[active] - xyz
        err[active] = np.linalg.norm(ep, axis=1)
        eo = rotation_vector(target_R[active] @ np.swapaxes(R, 1, 2))
        dq = _kkt_step(Jp, Jw, ep, eo, q[active] - q0[active], weight)
        done = (err[active] <= tol) & (np.abs(dq).max(axis=1) < 1e-12)
        active = active[~done]
        if not active.size:
            break
        step = dq[~done]
        # a step the first-order model cannot be trusted for (a stretched elbow: the point's
        # move goes with the square of the bend) is cut to 0.1 rad
        step *= np.minimum(1.0, 0.1 / np.maximum(np.abs(step).max(axis=1), 1e-300))[:, None]
        q[active] = np.clip(q[active] + step, robot.lower, robot.upper)
        iters[active] += 1
    if active.size:  # the last step's rows, at the joints returned
        inputs = model.inputs(q[active], {k: v[active] for k, v in cols.items()})
        err[active] = np.linalg.norm(target_xyz[active] - model.predict(inputs, p), axis=1)
    return IKResult(q=q, converged=err <= tol, error=err, iterations=iters)


# -- the closed form ---------------------------------------------------------------------------
@dataclass(frozen=True)
class WristStructure:
    """The constants of the closed form of an arm with the structure of the module docstring."""

    pre: np.ndarray  # 4x4: P = RotX(alpha_0) RotY(beta_0) TransX(a_0) TransZ(d_1)
    e1: float  # sin(alpha_1) = +-1
    s2: float  # cos(alpha_2) = +-1
    a1: float
    a2: float
    pz: float  # the constant z of the wrist centre in frame 2, plus d_2
    w3: np.ndarray  # wrist centre in frame 3
    d6: float
    alpha: np.ndarray  # (6,)
    offset: np.ndarray  # (6,) theta offsets
    uncouple: np.ndarray | None = None  # (6, 6) the coupling's inverse: q = C^-1 (theta - offset)


def _deviations(chain: Chain) -> dict[str, float]:
    """How far a chain is from the closed-form structure, per condition (0 when it holds)."""
    al, a, d, be = chain.alpha, chain.a, chain.d, chain.beta
    return {
        "a_4 (row 5 a)": abs(a[4]),
        "a_5 (row 6 a)": abs(a[5]),
        "d_5": abs(d[4]),
        "alpha_1 = +-90 deg": abs(math.cos(al[1])),
        "alpha_2 = 0 or 180 deg": abs(math.sin(al[2])),
        "beta on rows 2..6": float(np.max(np.abs(be[1:]))),
    }


def wrist_structure(robot: RobotDescription, tol: float = _STRUCTURE_EXACT) -> tuple[bool, str]:
    """Whether the closed form applies to ``robot`` exactly, and why not if it does not."""
    chain = Chain.from_description(robot)
    bad = [k for k, v in _deviations(chain).items() if v > tol]
    if abs(math.sin(chain.alpha[4])) < 1e-3 or abs(math.sin(chain.alpha[5])) < 1e-3:
        bad.append("sin(alpha_4), sin(alpha_5) != 0")
    if abs(chain.a[2]) < 1e-6:
        bad.append("a_2 != 0")
    if math.hypot(chain.a[3], math.sin(chain.alpha[3]) * chain.d[3]) < 1e-6:
        bad.append("the wrist centre off axis 3")
    return (
        not bad,
        "" if not bad else "not a spherical-wrist arm of the supported form: " + ", ".join(bad),
    )


def _snap(chain: Chain) -> Chain:
    """The nearest chain with the exact closed-form structure."""
    al = chain.alpha.copy()
    al[1] = math.copysign(math.pi / 2, math.sin(al[1]))
    al[2] = 0.0 if math.cos(al[2]) > 0 else math.pi
    a, d, be = chain.a.copy(), chain.d.copy(), chain.beta.copy()
    a[4] = a[5] = d[4] = 0.0
    be[1:] = 0.0
    return chain.replace(alpha=al, a=a, d=d, beta=be)


def _structure(chain: Chain) -> WristStructure:
    al, a, d = chain.alpha, chain.a, chain.d
    pre = np.eye(4)
    pre[:3, :3] = rot_x(al[0]) @ rot_y(chain.beta[0])
    pre[:3, 3] = pre[:3, :3] @ np.array([a[0], 0.0, 0.0]) + pre[:3, 2] * d[0]
    s2 = 1.0 if math.cos(al[2]) > 0 else -1.0
    w3 = np.array([a[3], -math.sin(al[3]) * d[3], math.cos(al[3]) * d[3]])
    return WristStructure(
        pre=pre,
        e1=1.0 if math.sin(al[1]) > 0 else -1.0,
        s2=s2,
        a1=float(a[1]),
        a2=float(a[2]),
        pz=float(s2 * (w3[2] + d[2]) + d[1]),
        w3=w3,
        d6=float(d[5]),
        alpha=np.array(al, dtype=float),
        offset=np.array(chain.theta_offset, dtype=float),
        uncouple=None if chain.coupling is None else np.linalg.inv(chain.coupling),
    )


def _branches(
    ws: WristStructure,
    T6: np.ndarray,
    q4_hint: np.ndarray,
    slack: float = 1e-9,
    spread: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """All 8 branches: joint angles q (N, 8, 6) (wrapped to [-pi, pi)) and whether each exists
    (N, 8), for poses T6 (N, 4, 4) of modified frame 6 in the robot base frame. ``slack`` lets a
    cosine exceed 1 by that much (clipped): a pose just outside the reach of a snapped arm is
    still a start for the refinement on the true one; ``spread`` keeps the cosines of the elbow
    and the wrist that far from +-1, so that the two branches of a near-stretched elbow or a
    near-singular wrist start on either side and the refinement finds both true solutions."""
    n = T6.shape[0]
    Tp = _inverse(ws.pre) @ T6
    R6 = Tp[:, :3, :3]
    w = Tp[:, :3, 3] - ws.d6 * R6[:, :, 2]
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    al = ws.alpha
    Rx1, Rx2, Rx3t = rot_x(al[1]), rot_x(al[2]), rot_x(al[3]).T
    Rx4, Rx5 = rot_x(al[4]), rot_x(al[5])
    ca4, sa4, ca5, sa5 = math.cos(al[4]), math.sin(al[4]), math.cos(al[5]), math.sin(al[5])
    rho = math.hypot(ws.w3[0], ws.w3[1])
    phi = math.atan2(ws.w3[1], ws.w3[0])
    B = -ws.e1 * ws.pz
    A2 = wx**2 + wy**2 - B**2
    theta = np.zeros((n, 8, 6))
    ok = np.zeros((n, 8), dtype=bool)
    k = 0
    for sA in (1.0, -1.0):
        A = sA * np.sqrt(np.maximum(A2, 0.0))
        okA = A2 >= -slack * (wx**2 + wy**2 + B**2)
        th1 = np.arctan2(wy, wx) - np.arctan2(np.full(n, B), A)
        X, Y = A - ws.a1, ws.e1 * wz
        c3 = (X**2 + Y**2 - ws.a2**2 - rho**2) / (2.0 * ws.a2 * rho)
        okC = np.abs(c3) <= 1.0 + slack
        for sC in (1.0, -1.0):
            th3 = sC * np.arccos(np.clip(c3, spread - 1.0, 1.0 - spread)) - phi
            px = ws.a2 + np.cos(th3) * ws.w3[0] - np.sin(th3) * ws.w3[1]
            py = ws.s2 * (np.sin(th3) * ws.w3[0] + np.cos(th3) * ws.w3[1])
            th2 = np.arctan2(Y, X) - np.arctan2(py, px)
            R3 = rot_z(th1) @ Rx1 @ rot_z(th2) @ Rx2 @ rot_z(th3)
            M = Rx3t @ np.swapaxes(R3, 1, 2) @ R6
            W = M[:, :, 2]
            c5 = (ca4 * ca5 - W[:, 2]) / (sa4 * sa5)
            ok5 = np.abs(c5) <= 1.0 + slack
            for s5 in (1.0, -1.0):
                th5 = s5 * np.arccos(np.clip(c5, spread - 1.0, 1.0 - spread))
                u = np.sin(th5) * sa5
                v = -ca4 * np.cos(th5) * sa5 - sa4 * ca5
                singular = u**2 + v**2 < 1e-20
                th4 = np.where(
                    singular,
                    q4_hint + ws.offset[3],
                    np.arctan2(W[:, 1], W[:, 0]) - np.arctan2(v, u),
                )
                Mw = rot_z(th4) @ Rx4 @ rot_z(th5) @ Rx5
                Nz = np.swapaxes(Mw, 1, 2) @ M
                th6 = np.arctan2(Nz[:, 1, 0], Nz[:, 0, 0])
                theta[:, k] = np.stack([th1, th2, th3, th4, th5, th6], axis=-1)
                ok[:, k] = okA & okC & ok5
                k += 1
    if ws.uncouple is not None:  # the DH table's angles to the controller's
        return _wrap((theta - ws.offset) @ ws.uncouple.T), ok
    return _wrap(theta - ws.offset), ok


def _aliases(
    q: np.ndarray, owner: np.ndarray, lower: np.ndarray, upper: np.ndarray, tol: float = 1e-12
) -> tuple[np.ndarray, np.ndarray]:
    """Every ``q + 2 pi k`` (per joint) within the limits, for rows q (M, 6) of pose ``owner``."""
    for j in range(6):
        kmax = math.ceil(max(abs(lower[j]), abs(upper[j])) / TWO_PI) + 1
        shifts = TWO_PI * np.arange(-kmax, kmax + 1)
        cand = q[:, j : j + 1] + shifts  # (M, K)
        inside = (cand >= lower[j] - tol) & (cand <= upper[j] + tol)
        row, col = np.nonzero(inside)
        q = q[row].copy()
        q[:, j] = np.clip(cand[row, col], lower[j], upper[j])
        owner = owner[row]
    return q, owner


def _distinct(q: np.ndarray, ok: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """``ok`` (N, B) with every branch that repeats an earlier one of its pose (all joint angles
    equal to ``tol`` modulo 2 pi: coincident branches at singular poses) switched off."""
    d = np.max(np.abs(_wrap(q[:, :, None, :] - q[:, None, :, :])), axis=-1)  # (N, B, B)
    same = (d < tol) & ok[:, :, None] & ok[:, None, :]
    earlier = np.tril(same, k=-1).any(axis=2)  # branch b equals some b' < b
    return ok & ~earlier


class InverseKinematics:
    """Every inverse-kinematics solution of a 6R arm within its joint limits.

    ``method`` is ``"closed_form"`` (the exact structure of the module docstring),
    ``"closed_form+dls"`` (close to it: closed form on the nearest structured arm, finished by damped
    least squares) or ``"dls"`` (any other arm: damped least squares from several starts).
    ``reason`` says why the closed form does not apply. Poses are in the robot base frame; ``tool``
    (in the flange frame, see :func:`forward_pose`) is the frame whose pose is asked for.

        ik = InverseKinematics(seed_robot())
        sols = ik.solve(forward_pose(robot, q))      # (k, 6), every solution of one pose
        q_near = ik.nearest(T, q_ref).q              # the solution nearest q_ref, per pose
    """

    def __init__(
        self,
        robot: RobotDescription,
        tool: np.ndarray | None = None,
        n_starts: int = 16,
        seed: int = 0,
    ) -> None:
        self.robot = robot
        self.chain = Chain.from_description(robot)
        self.lower, self.upper = robot.lower, robot.upper
        self._post_inv = _inverse(flange_transform(robot) @ _tool_matrix(tool))
        exact, reason = wrist_structure(robot)
        near = exact or wrist_structure(robot, _STRUCTURE_NEAR)[0]
        self.reason = reason
        self._ws: WristStructure | None
        if exact:
            self.method = "closed_form"
            self._ws = _structure(self.chain)
        elif near:
            self.method = "closed_form+dls"
            self._ws = _structure(_snap(self.chain))
        else:
            self.method = "dls"
            self._ws = None
        self.tool = tool
        rng = np.random.default_rng(seed)
        mid = 0.5 * (self.lower + self.upper)
        self._starts = np.vstack([mid, rng.uniform(self.lower, self.upper, (n_starts - 1, 6))])
        log.debug("IK for %s: %s %s", robot.name, self.method, reason)

    @property
    def closed_form(self) -> bool:
        return self.method != "dls"

    def _frame6(self, T: np.ndarray) -> np.ndarray:
        return T @ self._post_inv

    def _pose_residual(self, q: np.ndarray, T6: np.ndarray) -> np.ndarray:
        f = link_frames(self.chain, q)
        return pose_error(_homogeneous(f.R[:, 6], f.o[:, 6]), T6)

    def _refine(
        self, q: np.ndarray, T6: np.ndarray, max_iter: int, tol: float, damping: float = 1e-7
    ) -> IKResult:
        """Newton / LM steps on frame 6's pose for rows q (M, 6) with targets T6 (M, 4, 4)."""
        chain = self.chain
        big = np.full(6, 1e3)  # limits are applied after aliasing, not while polishing

        def residual(qq, idx):
            f = link_frames(chain, qq)
            J = np.empty((qq.shape[0], 6, 6))
            J[:, :3] = np.cross(f.z, f.o[:, 6:7] - f.o[:, 1:]).transpose(0, 2, 1)
            J[:, 3:] = f.z.transpose(0, 2, 1)
            return pose_error(_homogeneous(f.R[:, 6], f.o[:, 6]), T6[idx]), by_joint(chain, J)

        return _levenberg_marquardt(residual, q, -big, big, tol, max_iter, damping)

    def solve_flat(
        self, T: np.ndarray, q4_hint: np.ndarray | float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every solution of a batch of poses T (N, 4, 4) as one array q (M, 6) and the index of
        each row's pose (M,), sorted by pose."""
        T = np.asarray(T, dtype=float).reshape(-1, 4, 4)
        n = T.shape[0]
        T6 = self._frame6(T)
        if self._ws is None:  # damped least squares from every start
            b = self._starts.shape[0]
            qb = np.broadcast_to(self._starts, (n, b, 6))
            ok = np.ones((n, b), dtype=bool)
            max_iter, tol = 200, 1e-12
        else:
            hint = np.broadcast_to(np.asarray(q4_hint, dtype=float), (n,))
            exact = self.method == "closed_form"
            qb, ok = _branches(
                self._ws, T6, hint, *((1e-9, 0.0) if exact else (_STRUCTURE_NEAR, 1e-4))
            )
            b = 8
            max_iter, tol = (3, 1e-13) if exact else (100, 1e-12)
        owner = np.repeat(np.arange(n), b)[ok.ravel()]
        damping = 1e-2 if self._ws is None else 1e-7
        res = self._refine(qb.reshape(-1, 6)[ok.ravel()], T6[owner], max_iter, tol, damping)
        qb = np.array(qb)
        qb[ok] = _wrap(res.q)
        if self._ws is None:
            ok[ok] = res.converged
        ok = _distinct(qb, ok)
        owner = np.repeat(np.arange(n), b)[ok.ravel()]
        q, owner = _aliases(qb[ok], owner, self.lower, self.upper)
        if q.shape[0]:
            err = np.abs(self._pose_residual(q, T6[owner])).max(axis=1)
            good = err <= POSE_TOL
            if not np.all(good):
                log.debug(
                    "IK: %d solution(s) missed the pose (max error %.3g)", (~good).sum(), err.max()
                )
            q, owner = q[good], owner[good]
        return q, owner

    def solve(
        self, T: np.ndarray, q4_hint: np.ndarray | float = 0.0
    ) -> np.ndarray | list[np.ndarray]:
        """Every solution within the limits: (k, 6) for one pose (4, 4); a list of such arrays for
        poses (N, 4, 4). An unreachable pose has none (k = 0)."""
        T = np.asarray(T, dtype=float)
        q, owner = self.solve_flat(T, q4_hint)
        if T.ndim == 2:
            return q
        bounds = np.searchsorted(owner, np.arange(T.reshape(-1, 4, 4).shape[0] + 1))
        return [q[bounds[i] : bounds[i + 1]] for i in range(len(bounds) - 1)]

    def nearest(self, T: np.ndarray, q_ref: np.ndarray) -> IKResult:
        """Per pose, the solution nearest ``q_ref`` (N, 6) (max-norm over joints); at a wrist
        singularity joint 4 stays at ``q_ref``'s. ``converged`` is False where no solution exists
        (then ``q`` is ``q_ref``)."""
        T = np.asarray(T, dtype=float)
        single = T.ndim == 2
        T = T.reshape(-1, 4, 4)
        n = T.shape[0]
        q_ref = _batch(q_ref, n, (6,), "q_ref")
        q, owner = self.solve_flat(T, q4_hint=q_ref[:, 3])
        out = q_ref.copy()
        found = np.zeros(n, dtype=bool)
        if q.shape[0]:
            dist = np.max(np.abs(q - q_ref[owner]), axis=1)
            order = np.lexsort((dist, owner))
            first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
            out[owner[first]] = q[first]
            found[owner[first]] = True
        err = np.where(found, 0.0, np.inf)
        res = IKResult(q=out, converged=found, error=err, iterations=np.zeros(n, dtype=int))
        return IKResult(*(x[0] for x in res)) if single else res
