"""Pose planning: choose the calibration poses that identify the most, so a user measures less.

    p = plan(30, robot, "geometric")          # 30 poses out of 2,000 random candidates
    p.q                                       # (30, 6) joint angles to measure
    p.o1, p.random_o1                         # vs. as many random poses

Candidates are random within the joint limits with the tool point above the floor
(:func:`arm.sampling.sample_poses`), or given. Their identification Jacobian at the nominal
parameters is column-scaled once, by each column's RMS per pose over all candidates, so that
pose sets of one size compare on one scale; only the parameters identifiable from the candidates
(:mod:`lab.identifiability`) count. A set's information matrix is ``M = sum_i A_i^T A_i`` over its
poses' (3, L) scaled blocks (6 rows with an orientation measured), whose eigenvalues are the squared singular values:

* ``o1`` (Borm & Menq): ``(s_1 ... s_L)^(1/L) / sqrt(N)``, i.e. D-optimality, ``log det M``;
* ``o4`` (Nahvi & Hollerbach, noise amplification): ``s_min^2 / s_max``.

The search is Mitchell's DETMAX with excursions of one pose: a sequential D-optimal start (each
pose the one that raises ``log det (M + eps I)`` most, by the determinant lemma), then repeated
exchanges: add the candidate that raises the criterion most, remove the pose whose loss lowers it
least, until the pose removed is the one just added. For ``o4`` the candidates to add are screened
by the first-order gain of the smallest eigenvalue, ``|A_i v_min|^2``, and the best few evaluated
exactly.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arm.constraints import refuse
from arm.description import RobotDescription, as_robot
from arm.effect_api import EffectError
from arm.effects import Effect
from arm.errormodel import ErrorModel
from arm.noise import noise_law_problems
from arm.params import BASE_NAMES
from arm.sampling import SamplingError, check_count, rng_from, sample_poses
from lab.errors import FitError
from lab.identifiability import Identifiability, analyse_jacobian
from lab.options import CRITERIA
from lab.registration import tool_indices
from lab.result import SCHEMA_VERSION
from lab.uncertainty import least_spread

__all__ = ["Plan", "UpdatePlan", "plan", "plan_update"]

log = logging.getLogger(__name__)

_SCREEN = 24  # o4: candidates evaluated exactly per addition
#: the most random candidates a plan draws: their identification Jacobian takes 80 MB for the
#: geometric model's 33 parameters at 100,000
MAX_CANDIDATES = 100_000


@dataclass
class Plan:
    """Chosen poses ``q`` (N, 6) (rows of ``candidates`` at ``indices``) and their quality, beside
    the mean over random sets of as many candidates."""

    q: np.ndarray
    indices: np.ndarray
    candidates: np.ndarray
    criterion: str
    o1: float
    o4: float
    random_o1: float
    random_o4: float
    identifiability: Identifiability
    exchanges: int

    @property
    def n_poses(self) -> int:
        return len(self.q)

    @property
    def condition_number(self) -> float:
        return self.identifiability.condition_number

    def to_dict(self) -> dict:
        return {
            "schema_version": SCHEMA_VERSION,
            "criterion": self.criterion,
            "n_poses": self.n_poses,
            "n_candidates": len(self.candidates),
            "o1": self.o1,
            "o4": self.o4,
            "random_o1": self.random_o1,
            "random_o4": self.random_o4,
            "condition_number": self.condition_number,
            "rank": self.identifiability.rank,
            "unidentifiable": self.identifiability.unidentifiable,
            "q": self.q.tolist(),
        }

    def summary(self) -> str:
        return (
            f"{self.n_poses} poses chosen from {len(self.candidates)} by {self.criterion}: "
            f"O1 {self.o1:.4g} (random {self.random_o1:.4g}), O4 {self.o4:.4g} "
            f"(random {self.random_o4:.4g}), condition number {self.condition_number:.3g}"
        )


def _eig(M: np.ndarray) -> np.ndarray:
    return np.clip(np.linalg.eigvalsh(M), 0.0, None)


def observability(M: np.ndarray, n_poses: int, criterion: str) -> float:
    """O1 or O4 of an information matrix ``M`` (L, L) of ``n_poses`` poses."""
    ev = _eig(M)
    if ev[0] <= 0:
        return 0.0
    if criterion == "o1":
        return float(math.exp(0.5 * np.mean(np.log(ev))) / math.sqrt(n_poses))
    return float(ev[0] / math.sqrt(ev[-1]))


def plan(
    n: int,
    robot: RobotDescription | str | Path | None = None,
    effects: str | Sequence[str | Effect] = "geometric",
    *,
    criterion: str = "o1",
    candidates: np.ndarray | int = 2000,
    columns: Mapping[str, np.ndarray] | None = None,
    noise_mm: float | None = 0.015,
    seed: int | np.random.Generator = 0,
    max_exchanges: int = 1000,
    noise_mrad: float | None = None,
    near: np.ndarray | None = None,
) -> Plan:
    """Choose ``n`` poses from ``candidates`` (an (M, 6) array, or how many random ones to draw)
    that maximise ``criterion`` (``o1`` or ``o4``) for identifying ``effects`` of ``robot``.
    ``columns`` gives the candidates' other inputs (payload...) for effects that need them.
    ``noise_mm`` (the instrument's per-axis noise; None: structure only) leaves out parameters
    that ``n`` such poses could not determine better than their typical size (a tool a millimetre
    off joint 6's axis makes dalpha6 barely separable from dd5): chasing them would spend the
    poses on directions no calibration resolves.

    ``near``: the joints (P, 6) of a program the calibration must hold for: the random candidates
    are drawn from its joint region (:func:`arm.sampling.region_of`: the range of each joint, a
    little wider), so the poses chosen are the ones that identify the most *there*, the poses to
    measure for updating a calibration before it is used in another part of the workspace.

    ``noise_mrad``: the instrument measures the tool frame's orientation too, with this
    per-axis noise: each pose gives six rows, the orientation's weighted against the position's
    by ``noise_mm / noise_mrad`` (:mod:`lab.observations`), and the tool frame's rotation is a
    parameter."""
    if criterion not in CRITERIA:
        raise FitError(f"criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    refuse(noise_law_problems(noise_mm, 0.0, noise_mrad), FitError)
    robot = as_robot(robot)
    try:
        rng = rng_from(seed, "seed")
        if isinstance(candidates, int | np.integer):
            count = check_count(candidates, "candidates", MAX_CANDIDATES)
            cand = sample_poses(robot, count, rng, near=near)
        elif near is not None:
            raise FitError("give candidates as a count with near=: they are drawn from its region")
        else:
            cand = np.asarray(candidates, dtype=float).reshape(-1, 6)
    except SamplingError as exc:
        raise FitError(str(exc)) from None
    turn = noise_mrad is not None
    if turn and noise_mm is None:
        raise FitError("noise_mrad (orientations) needs noise_mm too: the rows are weighed by both")
    try:
        model = ErrorModel(robot, effects, orientation=turn)
        inputs = model.inputs(cand, columns, source="candidate poses")
    except EffectError as exc:
        raise FitError(f"{exc}; give them for every candidate with columns=") from None
    if n > len(cand):
        raise FitError(f"cannot choose {n} poses from {len(cand)} candidates")
    if turn:
        assert noise_mm is not None and noise_mrad is not None
        _, _, JP, JW = model.predict_pose(inputs, model.nominal(), jacobian=True)
        J = np.concatenate([JP, JW * (1e-3 * noise_mm / (1e-3 * noise_mrad))], axis=1)
    else:
        _, J = model.predict(inputs, model.nominal(), jacobian=True)
    k = J.shape[1]  # rows per pose
    # a parameter's effect grows with sqrt(poses): judged for n poses, not for all candidates
    noise = None if noise_mm is None else 1e-3 * noise_mm * math.sqrt(len(cand) / n)
    ident = analyse_jacobian(model, J, noise=noise, warn=False)
    L = ident.rank
    if k * n < L:
        raise FitError(
            f"{n} poses give {k * n} equations for the {L} identifiable parameters of "
            f"{','.join(model.effect_names)}; at least {math.ceil(L / k)} poses are needed"
        )
    free = ident.identifiable
    A = J[:, :, free] * ident.scale[free]  # (M, 3, L), columns of RMS 1 per pose over candidates

    chosen = _sequential(A, n)
    chosen, exchanges = _exchange(A, chosen, criterion, max_exchanges)
    M = np.einsum("nai,naj->ij", A[chosen], A[chosen])
    o1, o4 = observability(M, n, "o1"), observability(M, n, "o4")
    r1, r4 = [], []
    for _ in range(20):
        idx = rng.choice(len(cand), n, replace=False)
        Mr = np.einsum("nai,naj->ij", A[idx], A[idx])
        r1.append(observability(Mr, n, "o1"))
        r4.append(observability(Mr, n, "o4"))
    idx = np.sort(chosen)
    final = analyse_jacobian(
        model,
        J[idx],
        scale=ident.scale,
        noise=None if noise_mm is None else 1e-3 * noise_mm,
        warn=False,
    )
    result = Plan(
        q=cand[idx],
        indices=idx,
        candidates=cand,
        criterion=criterion,
        o1=o1,
        o4=o4,
        random_o1=float(np.mean(r1)),
        random_o4=float(np.mean(r4)),
        identifiability=final,
        exchanges=exchanges,
    )
    log.info("%s", result.summary())
    return result


def _sequential(A: np.ndarray, n: int) -> np.ndarray:
    """Greedy D-optimal start: each pose maximises det(I + A_i M^-1 A_i^T) with M = eps I + ..."""
    m, _, L = A.shape
    eps = 1e-6 * float(np.mean(np.einsum("nai,nai->n", A, A)))
    Minv = np.eye(L) / eps
    taken = np.zeros(m, dtype=bool)
    chosen = []
    for _ in range(n):
        W = A @ Minv  # (m, k, L)
        S = np.eye(A.shape[1]) + np.einsum("nai,nbi->nab", W, A)
        gain = np.linalg.slogdet(S)[1]
        gain[taken] = -np.inf
        i = int(np.argmax(gain))
        chosen.append(i)
        taken[i] = True
        # Woodbury: (M + A^T A)^-1 = Minv - Minv A^T (I + A Minv A^T)^-1 A Minv
        Wi = W[i]
        Minv = Minv - Wi.T @ np.linalg.solve(S[i], Wi)
    return np.array(chosen)


def _exchange(A, chosen, criterion, max_exchanges) -> tuple[np.ndarray, int]:
    """DETMAX excursions of one pose, on the exact criterion."""
    n = len(chosen)
    chosen = list(chosen)
    taken = np.zeros(A.shape[0], dtype=bool)
    taken[chosen] = True
    M = np.einsum("nai,naj->ij", A[chosen], A[chosen])
    best = observability(M, n, criterion)
    exchanges = 0
    for _ in range(max_exchanges):
        # add the candidate that raises the criterion most
        if criterion == "o1":
            Minv = np.linalg.inv(M)
            S = np.eye(A.shape[1]) + np.einsum("nai,ij,nbj->nab", A, Minv, A)
            gain = np.linalg.slogdet(S)[1]
            gain[taken] = -np.inf
            add = int(np.argmax(gain))
        else:
            _, V = np.linalg.eigh(M)
            g = np.sum((A @ V[:, 0]) ** 2, axis=1)
            g[taken] = -np.inf
            top = np.argsort(g)[-_SCREEN:]
            vals = [observability(M + A[i].T @ A[i], n + 1, "o4") for i in top]
            add = int(top[int(np.argmax(vals))])
        M1 = M + A[add].T @ A[add]
        trial = [*chosen, add]
        # remove the pose whose loss lowers it least
        vals = [observability(M1 - A[j].T @ A[j], n, criterion) for j in trial]
        k = int(np.argmax(vals))
        if trial[k] == add or vals[k] <= best * (1 + 1e-12):
            break
        taken[trial[k]] = False
        taken[add] = True
        chosen = [j for j in trial if j != trial[k]]
        M = M1 - A[trial[k]].T @ A[trial[k]]
        best = vals[k]
        exchanges += 1
    return np.array(chosen), exchanges


# -- poses for an update ----------------------------------------------------------------------------
@dataclass(frozen=True)
class UpdatePlan:
    """Poses ``q`` (n, 6) chosen to update a calibration where a program runs, and the RMS (mm,
    3-D) the update is expected to err on the program's poses with them (``predicted_mm``: its
    posterior through the program's Jacobian, the model's discrepancy added) beside the mean of
    as many random poses of the program's region (``random_mm``); ``free``: the parameters
    the update fits without a prior; ``indices``: the candidates chosen."""

    q: np.ndarray
    predicted_mm: float
    random_mm: float
    free: tuple[str, ...]
    indices: np.ndarray  # rows of the candidates chosen

    def to_dict(self) -> dict:
        return {
            "schema_version": SCHEMA_VERSION,
            "n_poses": len(self.q),
            "criterion": "update",
            "predicted_mm": self.predicted_mm,
            "random_mm": self.random_mm,
            "free": list(self.free),
            "q": self.q.tolist(),
        }

    def summary(self) -> str:
        return (
            f"{len(self.q)} poses for the update: expected RMS {self.predicted_mm:.4f} mm on the "
            f"program (random poses of its region: {self.random_mm:.4f} mm)"
        )


def plan_update(
    n: int,
    calibration: Any,
    near: np.ndarray,
    *,
    candidates: np.ndarray | int = 2000,
    seed: int | np.random.Generator = 0,
    remount: bool = False,
    noise_mm: float | None = None,
) -> UpdatePlan:
    """Choose ``n`` poses of a program's region (``near``, its joints (P, 6)) that make the update
    of ``calibration`` (anything :func:`lab.update.prior_of` takes) err least on the program's
    poses: Bayesian I-optimality. The update frees the new session's base (and with ``remount``
    the tool) and re-estimates the rest within the calibration's prior (its covariance widened by
    the spread between sessions and the least spread, as :func:`lab.update.update` does); a pose
    set's posterior precision is the prior's plus its rows' (each in units of the noise,
    ``noise_mm``, default the calibration's residual), and the criterion is the mean variance of
    the program's predicted points, ``trace(G M^-1)`` (``G`` the program's information per pose).
    The poses are added greedily, each the candidate that lowers it most (the Woodbury update of
    ``M^-1``), from ``candidates`` random poses of the program's region (or those given: an
    (M, 6) array)."""
    from lab.update import prior_of

    prior = prior_of(calibration)
    u = prior.uncertainty
    rng = rng_from(seed, "seed")
    try:
        if isinstance(candidates, int | np.integer):
            count = check_count(candidates, "candidates", MAX_CANDIDATES)
            cand = sample_poses(prior.nominal, count, rng, near=near)
        else:
            cand = np.asarray(candidates, dtype=float).reshape(-1, 6)
    except SamplingError as exc:
        raise FitError(str(exc)) from None
    if n > len(cand):
        raise FitError(f"cannot choose {n} poses from {len(cand)} candidates")
    model = ErrorModel(prior.nominal, list(prior.effects))
    lay = model.layout
    p = model.nominal()
    for name, v in u.values.items():
        if name in lay:
            p[lay.index(name)] = v
    free = [str(x) for x in BASE_NAMES if x in lay]
    if remount:
        free += [str(lay.names[i]) for i in tool_indices(model)]
    names = [x for x in u.names if x in lay and x not in free]
    keep = [u.names.index(x) for x in names]
    cov = u.prior_covariance(least_spread(u.names))[np.ix_(keep, keep)]
    sigma = u.sigma if noise_mm is None else 1e-3 * noise_mm
    active = lay.indices(free + names)
    A = _rows_of(model, cand, p, active) / sigma
    Ap = _rows_of(model, np.asarray(near, dtype=float), p, active) / sigma
    scale = np.sqrt(np.einsum("nai,nai->i", A, A) / len(cand))
    scale[scale == 0] = 1.0
    A, Ap = A / scale, Ap / scale
    G = np.einsum("nai,naj->ij", Ap, Ap) / len(Ap)
    L = len(active)
    prec = np.zeros((L, L))
    s = scale[len(free) :]
    # the prior's precision in the scaled parameters (the rows in units of the noise): C^-1 / s s^T
    prec[len(free) :, len(free) :] = np.linalg.pinv(cov, hermitian=True) / np.outer(s, s)
    prec += 1e-9 * np.eye(L)  # the free base: nothing before the poses
    chosen = _i_optimal(A, G, np.linalg.inv(prec), n)

    def expected(idx: np.ndarray) -> float:
        M = prec + np.einsum("nai,naj->ij", A[idx], A[idx])
        # the posterior through the program's poses, and the discrepancy (3 sigma^2 a pose)
        return 1e3 * sigma * math.sqrt(float(np.trace(G @ np.linalg.inv(M))) + 3.0)

    random = [expected(rng.choice(len(cand), n, replace=False)) for _ in range(20)]
    idx = np.sort(chosen)
    return UpdatePlan(cand[idx], expected(idx), float(np.mean(random)), tuple(free), idx)


def _rows_of(model: ErrorModel, q: np.ndarray, p: np.ndarray, active: np.ndarray) -> np.ndarray:
    """The Jacobian (n, 3, L) of the parameters ``active`` at the poses ``q``, every column an
    effect reads at a typical value (20 degC, no payload, each joint approached from +)."""
    n = len(q)
    cols = {"temperature": np.full(n, 20.0), "payload": np.zeros(n)}
    cols |= {f"dir{j}": np.ones(n) for j in range(1, 7)}
    need = model.required_columns()
    try:
        inputs = model.inputs(q, {k: v for k, v in cols.items() if k in need}, "planned poses")
    except EffectError as exc:
        raise FitError(str(exc)) from None
    _, J = model.predict(inputs, p, jacobian=True)
    return J[:, :, active]


def _i_optimal(A: np.ndarray, G: np.ndarray, Minv: np.ndarray, n: int) -> np.ndarray:
    """Greedy I-optimal poses: each the candidate that lowers ``trace(G M^-1)`` most, by the
    Woodbury update ``(M + A_i^T A_i)^-1 = M^-1 - W_i^T (I + A_i M^-1 A_i^T)^-1 W_i``,
    ``W_i = A_i M^-1``."""
    taken = np.zeros(len(A), dtype=bool)
    chosen = []
    eye = np.eye(A.shape[1])
    for _ in range(n):
        W = A @ Minv  # (m, k, L)
        S = eye + np.einsum("nai,nbi->nab", W, A)
        X = np.einsum("nai,ij,nbj->nab", W, G, W)
        gain = np.trace(np.linalg.solve(S, X), axis1=1, axis2=2)
        gain[taken] = -np.inf
        i = int(np.argmax(gain))
        chosen.append(i)
        taken[i] = True
        Minv = Minv - W[i].T @ np.linalg.solve(S[i], W[i])
    return np.array(chosen)
