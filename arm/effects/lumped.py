"""Compliance without a mass model (:class:`LumpedCompliance`): the gravity deflection of elastic
joints, from the arm's kinematics alone.

The gravity torque about joint j is linear in the links' first moments. Folding each link's mass
into the links before it (the mass ``m_l`` of every link beyond k hangs at the origin of frame
k+1, a point fixed in frame k), the torque is

    tau_j = |g| sum_{k >= j} U_k . R_k^T (g_hat x z_j),
    U_k = m_k com_k + (sum_{l > k} m_l) p_k          (kg m, in frame k; the payload in link 6)

with ``R_k`` frame k's rotation, ``z_j`` joint j's axis, ``p_k`` the origin of frame k+1 in frame
k: three constant unknowns per link, the same for every joint. An elastic joint turns by
``dq_j = c_j tau_j``, so the deflection is linear in the lumped products ``c_j |g| U_k`` (rad):
parameter ``lc{j}_{x|y|z}{k}`` multiplies ``(R_k^T (g_hat x z_j))_{x|y|z}``. Of the 63 products of
a 6R arm only some change the deflection independently (a vertical joint 1 carries no torque;
parallel axes repeat the same functions); as in the base parameters of dynamic identification,
the effect keeps a base set, chosen by a QR decomposition with column pivoting of the columns on
random poses (:func:`base_columns`), their constant parts left out (the geometric ``dtheta``
holds them). The choice depends on the arm's structure only: its DH angles rounded to the
nearest quarter turn when within 0.02 rad of it, so a calibrated arm keeps the nominal arm's
parameters.

With a mass model, the catalogue's ``compliance`` has one parameter per joint and is tested
instead (:attr:`LumpedCompliance.stands_in_for`); :func:`lumped_values` gives the values of this
effect equivalent to it. A payload that changes from row to row is not in this law (its torque
needs the stiffness alone): fit ``compliance`` with the mass model then.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Sequence
from typing import ClassVar

import numpy as np
import scipy.linalg

from arm.description import RobotDescription, vec3
from arm.effect_api import EffectError, ModelInputs
from arm.effects.base import Effect, JointAngleEffect
from arm.kinematics import Chain, gravity_torques, link_frames

__all__ = ["LumpedCompliance", "base_columns", "first_group", "gravity_columns", "lumped_values"]

AXES = "xyz"
#: DH angles within this of a quarter turn are that quarter turn for the choice of the base set
SNAP = 0.02  # rad
#: random poses (the whole circle of every joint) on which the base set is chosen
_POSES = 240
#: draws of a tilting extra joint's value on which gravity's directions in frame 0 are taken
_TILTS = 24
#: a column whose part independent of those before it is below this, relative to the largest
#: (each column scaled to unit RMS), adds nothing the others do not
_RANK_TOL = 1e-7
#: a link whose next joint lies at least this share of the longest such offset away is one of
#: the arm's long links (:func:`first_group`)
LONG = 0.25
_NAME = re.compile(r"lc([1-6])_([xyz])([1-6])")

Term = tuple[int, int]  # (link k 1..6, axis 0..2)


def gravity_columns(
    robot: RobotDescription, q: np.ndarray, gravity: np.ndarray | None = None
) -> np.ndarray:
    """(N, 6, 6, 3): ``[n, j, k, c] = (R_k^T (g_hat x z_j))_c`` at the joint angles ``q`` (N, 6),
    zero where link k lies before joint j (k < j): the regressor of ``c_j |g| U_k,c`` on the
    deflection of joint j (the module docstring). ``gravity`` (3,) or (N, 3) in frame 0, where
    extra joints turn it (``ModelInputs.gravity``); default the robot's at their defaults."""
    m = robot.to_modified()
    g = np.asarray(robot.frame0_gravity() if gravity is None else gravity, dtype=float)
    norm = float(np.linalg.norm(g.reshape(-1, 3), axis=1).min())
    if not norm > 0:
        raise EffectError(f"robot {robot.name!r}: gravity is zero; no arm sags without it")
    f = link_frames(Chain.from_description(m), np.atleast_2d(np.asarray(q, dtype=float)))
    R = f.R[:, 1:]  # (N, 6, 3, 3), frames 1..6
    g_hat = g / np.linalg.norm(g, axis=-1, keepdims=True)
    w = np.cross(g_hat[:, None, :] if g.ndim == 2 else g_hat, f.z)  # (N, 6, 3): g_hat x z_j
    Y = np.einsum("nkic,nji->njkc", R, w)
    Y *= np.triu(np.ones((6, 6)))[None, :, :, None]  # link k loads joint j where k >= j
    return Y


def gravity_directions(robot: RobotDescription) -> np.ndarray:
    """The directions (G, 3) gravity takes in frame 0: one, unless revolute extra joints tilt
    the arm (a tilting table), then those at :data:`_TILTS` draws of their values (a vertical
    table's turn keeps one direction)."""
    g = robot.frame0_gravity()
    g = g / max(float(np.linalg.norm(g)), 1e-300)
    if not any(j.kind == "revolute" for j in robot.extra_joints):
        return g[None, :]
    rng = np.random.default_rng(0)
    values = np.array(
        [
            rng.uniform(-math.pi, math.pi, _TILTS) if j.kind == "revolute" else np.zeros(_TILTS)
            for j in robot.extra_joints
        ]
    ).T
    G = robot.frame0_gravity(values)
    G /= np.linalg.norm(G, axis=1, keepdims=True)
    if float(np.max(np.linalg.norm(G - g, axis=1))) < SNAP:
        return g[None, :]
    return G


def _structure(robot: RobotDescription) -> tuple:
    """What the base set depends on: the DH angles and the directions of gravity in frame 0
    (:func:`gravity_directions`), each rounded to a quarter turn (gravity's components to zero)
    where within :data:`SNAP` of it."""

    def snap(x: float) -> float:
        k = round(x / (math.pi / 2))
        return k * math.pi / 2 if abs(x - k * math.pi / 2) < SNAP else round(x, 9)

    m = robot.to_modified()
    G = gravity_directions(robot)
    G = np.where(np.abs(G) < SNAP, 0.0, G)
    G /= np.linalg.norm(G, axis=1, keepdims=True)
    return (
        tuple(snap(j.alpha) for j in m.joints),
        tuple(snap(j.beta) for j in m.joints),
        tuple(snap(j.theta_offset) for j in m.joints),
        tuple(tuple(round(float(v), 9) for v in g) for g in G),
    )


def base_columns(robot: RobotDescription) -> dict[int, tuple[Term, ...]]:
    """The base set of each joint: the (link, axis) of its columns whose non-constant parts are
    independent (QR with column pivoting on random poses of the arm's structure, gravity taking
    each of its directions in turn), sorted by link and axis. A joint that gravity never loads
    (a vertical joint 1 on a level base) has none."""
    return _base_columns(_structure(robot))


@functools.lru_cache(maxsize=64)
def _base_columns(structure: tuple) -> dict[int, tuple[Term, ...]]:
    alpha, beta, theta, directions = structure
    from arm.description import Joint  # the structure alone: lengths do not turn any frame

    joints = tuple(
        Joint(alpha=alpha[i], a=0.0, d=0.0, theta_offset=theta[i], beta=beta[i]) for i in range(6)
    )
    G = np.array(directions, dtype=float)
    arm = RobotDescription("structure", joints, gravity=vec3(G[0]))
    q = np.random.default_rng(0).uniform(-math.pi, math.pi, (_POSES, 6))
    Y = gravity_columns(arm, q, G[np.arange(_POSES) % len(G)])
    out: dict[int, tuple[Term, ...]] = {}
    for j in range(6):
        terms = [(k + 1, c) for k in range(j, 6) for c in range(3)]
        X = np.stack([Y[:, j, k - 1, c] for k, c in terms], axis=1)
        X = X - X.mean(axis=0)  # a constant is the geometric dtheta's
        rms = np.sqrt((X**2).mean(axis=0))
        live = np.flatnonzero(rms > 1e-9)
        if not live.size:
            out[j + 1] = ()
            continue
        _, Rq, piv = scipy.linalg.qr(X[:, live] / rms[live], mode="economic", pivoting=True)
        diag = np.abs(np.diag(Rq))
        rank = int(np.sum(diag > _RANK_TOL * diag[0]))
        out[j + 1] = tuple(sorted(terms[int(live[i])] for i in piv[:rank]))
    return out


def first_group(robot: RobotDescription) -> list[str]:
    """The names of the base parameters that carry the load along the arm's long links: for each
    joint, link k's first moment along the axis of the largest component of ``p_k`` (the origin of
    frame k+1 in frame k), for the links whose ``|p_k|`` is at least :data:`LONG` of the longest
    (on a UR: ``lc2_x2``, ``lc2_x3``, ``lc3_x3``, the upper arm and forearm along their length).
    The rest of the base set (the payload's and the wrist's moments off the links' lines) enters
    a fit only where its own data say it helps (:mod:`lab.lumped_choice`)."""
    m = robot.to_modified()
    f = link_frames(Chain.from_description(m), np.zeros((1, 6)))
    R, o = f.R[0], f.o[0]
    p = {k: R[k].T @ (o[k + 1] - o[k]) for k in range(1, 6)}
    longest = max(float(np.linalg.norm(v)) for v in p.values())
    if not longest > 0:
        return []
    along = {
        k: int(np.argmax(np.abs(v))) for k, v in p.items() if np.linalg.norm(v) >= LONG * longest
    }
    base = base_columns(robot)
    return [parameter_name(j, (k, c)) for j in range(1, 7) for k, c in base[j] if along.get(k) == c]


def parameter_name(joint: int, term: Term) -> str:
    """``lc2_x3``: joint 2's deflection from link 3's first moment along x."""
    return f"lc{joint}_{AXES[term[1]]}{term[0]}"


class LumpedCompliance(JointAngleEffect):
    """Elastic joints without a mass model (the module docstring): ``theta_j = q_j + sum
    lc{j}_{c}{k} (R_k^T (g_hat x z_j))_c`` over the base set of joint j, the gravity deflection
    with the stiffnesses and the links' first moments lumped into identifiable products (rad)."""

    name = "lumped_compliance"
    extrapolates = True  # a law of the arm over its whole range, as compliance
    # c_j |g| U_k: a UR5's 3e-6..1e-5 rad/(N m) times 10-50 N m per (kg m) of moment
    typical = {"lc": (1e-4, 1e-3)}
    # a deflection of 50 mrad (as a DH angle's bound) from one product is no arm's
    bounds: ClassVar[dict[str, float | None]] = {"lc": 0.05}
    description = (
        "elastic joints without a mass model: theta_j = q_j + sum_k lc{j}_{xyz}{k} "
        "(R_k^T (g x z_j))_{xyz}, the stiffness times the links' first moments lumped"
    )
    example = "lumped_compliance"
    #: where the arm has a mass model, the diagnosis tests this effect's catalogue twin instead
    stands_in_for: ClassVar[str] = "compliance"

    def __init__(
        self, joints: Sequence[int] | None = None, names: Sequence[str] | None = None
    ) -> None:
        super().__init__(joints)
        self.fixed: tuple[tuple[int, Term], ...] | None = None
        if names is not None:
            fixed = []
            for n in names:
                m = _NAME.fullmatch(n)
                if m is None:
                    raise EffectError(
                        f"{n!r} is not a parameter of the lumped_compliance effect (lc2_x3: joint "
                        "2's deflection from link 3's first moment along x)"
                    )
                j, c, k = int(m.group(1)), AXES.index(m.group(2)), int(m.group(3))
                if k < j:
                    raise EffectError(f"{n!r}: link {k} lies before joint {j}; it loads no joint")
                fixed.append((j, (k, c)))
            self.fixed = tuple(sorted(set(fixed)))

    @classmethod
    def from_parameters(cls, names: Sequence[str]) -> Effect:
        """The effect with exactly these parameters (a calibrated arm's values keep their names,
        whatever the base set of its calibrated DH angles)."""
        return cls(names=list(names))

    def columns_of(self, robot: RobotDescription) -> list[tuple[int, Term]]:
        """(joint, (link, axis)) of each parameter, in the order of :meth:`parameter_names`."""
        if self.fixed is not None:
            chosen = list(self.fixed)
        else:
            base = base_columns(robot)
            chosen = [(j, t) for j in range(1, 7) for t in base[j]]
        return [(j, t) for j, t in chosen if j in self.active_joints()]

    def parameter_names(self, robot: RobotDescription, targets: Sequence[int]) -> list[str]:
        return [parameter_name(j, t) for j, t in self.columns_of(robot)]

    def parameter_joints(self, robot: RobotDescription) -> list[int]:
        return [j for j, _ in self.columns_of(robot)]

    def parameter_terms(self) -> list[tuple[int, str]]:
        raise EffectError(
            "lumped_compliance's terms depend on the arm: use parameter_names(robot, targets)"
        )

    def regressor(self, inputs: ModelInputs) -> np.ndarray:
        """(N, 6, k): each parameter's column on its joint, at the encoder readings."""
        cols = self.columns_of(inputs.robot)
        Y = gravity_columns(inputs.robot, inputs.q, inputs.gravity)
        out = np.zeros((inputs.n, 6, len(cols)))
        for p, (j, (k, c)) in enumerate(cols):
            out[:, j - 1, p] = Y[:, j - 1, k - 1, c]
        return out


def first_moments(robot: RobotDescription) -> np.ndarray:
    """(6, 3) ``U_k`` of the description's mass model (kg m, frame k; the payload a point mass
    at the first tool point): each link's mass times its centre of mass, plus the mass of every
    link beyond it at the origin of the next frame."""
    m = robot.to_modified()
    chain = Chain.from_description(m)
    f = link_frames(chain, np.zeros((1, 6)))
    R, o = f.R[0], f.o[0]
    masses = m.masses.copy()
    U = masses[:, None] * m.coms
    U[5] += m.payload * m.tool_points[0]
    beyond = np.cumsum((masses + np.eye(6)[5] * m.payload)[::-1])[::-1]  # sum_{l >= k} m_l
    for k in range(5):  # frame k+1's origin, in frame k (constant: theta turns about z_k only)
        U[k] += beyond[k + 1] * (R[k + 1].T @ (o[k + 2] - o[k + 1]))
    return U


def lumped_values(robot: RobotDescription, compliance: Sequence[float]) -> dict[str, float]:
    """The values of :class:`LumpedCompliance` (its base set on ``robot``) that move the joints as
    the catalogue's ``compliance`` of ``c1..c6`` does with ``robot``'s mass model, constants
    aside (the geometric ``dtheta`` holds them): least squares on random poses."""
    c = np.asarray(compliance, dtype=float)
    if c.shape != (6,):
        raise EffectError(f"compliance must be 6 values c1..c6, got shape {c.shape}")
    effect = LumpedCompliance()
    cols = effect.columns_of(robot)
    q = np.random.default_rng(1).uniform(-math.pi, math.pi, (_POSES, 6))
    Y = gravity_columns(robot, q)
    dq = c * gravity_torques(robot, q)
    out: dict[str, float] = {}
    for j in range(1, 7):
        mine = [(p, t) for p, (jj, t) in enumerate(cols) if jj == j]
        if not mine:
            continue
        X = np.stack([Y[:, j - 1, k - 1, ax] for _, (k, ax) in mine], axis=1)
        X = np.hstack([X, np.ones((len(q), 1))])
        sol = np.linalg.lstsq(X, dq[:, j - 1], rcond=None)[0]
        out |= {parameter_name(j, t): float(v) for (_, t), v in zip(mine, sol, strict=False)}
    return out
