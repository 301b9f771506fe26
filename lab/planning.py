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

import numpy as np

from arm.constraints import refuse
from arm.description import RobotDescription, as_robot
from arm.effect_api import EffectError
from arm.effects import Effect
from arm.errormodel import ErrorModel
from arm.noise import noise_law_problems
from arm.sampling import SamplingError, check_count, rng_from, sample_poses
from lab.errors import FitError
from lab.identifiability import Identifiability, analyse_jacobian
from lab.options import CRITERIA
from lab.result import SCHEMA_VERSION

__all__ = ["Plan", "plan"]

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
