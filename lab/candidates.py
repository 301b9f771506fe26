"""The catalogue's candidates for a fitted model: what else could explain the residual.

A fitted model's residual is judged twice against the catalogue of effects (:mod:`arm.effects`):
by the screening (:mod:`lab.screening`: a pose beyond the rule once the model *and every candidate*
explain what they can is a gross outlier, not a missing effect's largest deviation) and by the
diagnosis (:mod:`lab.diagnosis`: which candidate explains it significantly). Both build the same
candidates here, once per data set:

    full, groups, skipped = candidate_groups(fit.model, data, candidates=None)
    J0, Jc = candidate_columns(fit, full, inputs, p, candidate_indices(full, groups))
    r, k = explained(e, J0, Jc, weights)     # e minus its fit on every column

The columns are held as two tall arrays (the model's identifiable columns, scaled, and every
candidate's), filled block by block (:mod:`lab.blocks`), and reduced through the small Gram
matrix: no copy of the whole catalogue's Jacobian is made.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from arm.effect_api import EffectError, ModelInputs
from arm.effects import (
    EFFECTS,
    Effect,
    JointAngleEffect,
    candidate_effects,
    make_effect,
    missing_inputs,
)
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from lab import blocks as _blocks
from lab.blocks import Blocks
from lab.errors import FitError
from lab.identifiability import Identifiability, gram_factor, lower_inverse
from lab.observations import Observations

__all__ = ["candidate_model"]


class ModelFit(Protocol):
    """What the screening and the diagnosis read of a fitted model (a :class:`lab.FitResult`)."""

    @property
    def model(self) -> ErrorModel: ...
    @property
    def params(self) -> np.ndarray: ...
    @property
    def identifiable(self) -> np.ndarray: ...
    @property
    def identifiability(self) -> Identifiability: ...
    @property
    def inputs(self) -> ModelInputs: ...
    @property
    def residuals(self) -> np.ndarray: ...
    @property
    def row_residuals(self) -> np.ndarray: ...
    @property
    def observations(self) -> Observations | None: ...
    @property
    def n_points(self) -> int: ...
    @property
    def rank(self) -> int: ...


def candidate_model(
    model: ErrorModel, data: MeasurementSet, candidates: Sequence[str] | None = None
) -> tuple[ErrorModel, dict[str, str]]:
    """One model holding the fitted effects (all joints of a per-joint one) and every candidate
    effect the data and the arm allow (default: every registered effect), and the candidates
    skipped with the reason (a column the data lack, no mass model)."""
    skipped: dict[str, str] = {}
    have = {e.name for e in model.effects}
    effects: list[Effect] = []
    for e in model.effects:  # a per-joint effect fitted on some joints: the others are candidates
        whole = e.per_joint and e.joints is not None and not e.scan_only
        effects.append(type(e)() if whole else e)  # a scanned effect's other orders: the scan
    for spec in candidate_effects() if candidates is None else list(candidates):
        if isinstance(spec, str) and spec.strip() in EFFECTS and EFFECTS[spec.strip()].scan_only:
            continue  # its terms are scanned (lab.spectral), not tested whole
        e = make_effect(spec)
        if e.name in have:
            continue
        why = missing_inputs(e, model.robot, list(data.columns))
        if why:
            skipped[e.label] = f"needs {why}"
            continue
        effects.append(e)
    # a candidate that stands in for another where that one cannot be tested (compliance without
    # a mass model) is not tested beside it
    tested = {e.name for e in effects}
    effects = [
        e
        for k, e in enumerate(effects)
        if k < len(model.effects) or not e.stands_in_for or e.stands_in_for not in tested
    ]
    full = ErrorModel(
        model.robot,
        effects,
        targets=model.targets,
        stations=model.stations,
        orientation=model.orientation,
        rehomed=model.rehomed,
    )
    return full, skipped


Columns = Callable[[], Iterator[tuple[slice, np.ndarray]]]


def explained_residual(
    e: np.ndarray, columns: Columns, weights: np.ndarray | None = None, rtol: float = 1e-6
) -> tuple[np.ndarray, int]:
    """``e`` (M,) minus its (weighted) least-squares fit on columns that ``columns()`` gives
    block by block (row slice, (rows, k) block), through the small Gram matrix: the columns'
    numerically independent part (:func:`lab.identifiability.gram_factor`) is fitted, the tall
    matrix is never formed. Returns the residual and the number of columns fitted."""
    G: np.ndarray | None = None
    b: np.ndarray | None = None
    for rows, X in columns():
        Xw = X if weights is None else X * weights[rows, None]
        Gb, bb = Xw.T @ X, Xw.T @ e[rows]
        G, b = (Gb, bb) if G is None else (G + Gb, b + bb)
    r = np.array(e, dtype=float)
    if G is None or b is None:
        return r, 0
    idx, L = gram_factor(G, rtol)
    if not idx.size:
        return r, 0
    Li = lower_inverse(L)
    c = Li.T @ (Li @ b[idx])
    for rows, X in columns():
        r[rows] -= X[:, idx] @ c
    return r, int(idx.size)


@dataclass(frozen=True)
class CandidateGroup:
    """Parameters of a candidate effect tested together: one joint of a per-joint effect, all
    its joints, or a global effect."""

    effect: str
    joints: tuple[int, ...] | None
    names: tuple[str, ...]


def candidate_groups(
    model: ErrorModel,
    data: MeasurementSet,
    candidates: Sequence[str] | None,
) -> tuple[ErrorModel, list[CandidateGroup], dict[str, str]]:
    """One model holding the fitted effects (all joints) and every testable candidate effect, the
    candidate parameter groups, and the effects skipped with the reason."""
    try:
        full, skipped = candidate_model(model, data, candidates)
    except EffectError as exc:
        raise FitError(str(exc)) from None
    base_names = set(model.layout.names)
    groups: list[CandidateGroup] = []
    for e in full.effects:
        new = [n for n in full.layout.names[full.layout.slice(e.name)] if n not in base_names]
        if not new:
            continue
        if isinstance(e, JointAngleEffect):
            per: list[tuple[int, CandidateGroup]] = []
            names = full.layout.names[full.layout.slice(e.name)]
            joint_of = dict(zip(names, e.parameter_joints(full.robot), strict=True))
            for j in e.active_joints():
                js = tuple(n for n in new if joint_of[n] == j)
                if js:
                    per.append((j, CandidateGroup(e.name, (j,), js)))
            groups += [g for _, g in per]
            if len(per) > 1:
                groups.append(CandidateGroup(e.name, tuple(j for j, _ in per), tuple(new)))
        else:
            groups.append(CandidateGroup(e.name, None, tuple(new)))
    return full, groups, skipped


def candidate_indices(full: ErrorModel, groups: list[CandidateGroup]) -> np.ndarray:
    """The indices (in ``full``'s layout) of every candidate parameter, sorted."""
    return np.array(
        sorted({int(i) for g in groups for i in full.layout.indices(g.names)}), dtype=int
    )


def group_label(g: CandidateGroup) -> str:
    return g.effect if g.joints is None else f"{g.effect}[{','.join(map(str, g.joints))}]"


def candidate_columns(
    res: ModelFit, full: ErrorModel, inputs: ModelInputs, p: np.ndarray, cand: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The fitted model's identifiable Jacobian columns, scaled (kN, r0), and the candidate
    columns ``cand`` of the full model at ``p`` (kN, m), block by block; k rows per pose (3, or
    the fit's weighted rows: :mod:`lab.observations`)."""
    free = np.flatnonzero(res.identifiable)
    s = res.identifiability.scale[free]
    N = res.n_points
    obs = res.observations
    k = res.row_residuals.shape[1]
    J0 = np.empty((k * N, free.size))
    Jc = np.empty((k * N, cand.size))
    blocks = Blocks(res.model, res.inputs, observations=obs)
    for sl, _, J in blocks.jacobians(res.params, keep_cache=False):
        J0[k * sl.start : k * sl.stop] = J[:, :, free].reshape(-1, free.size) * s
    for sl, _, J in Blocks(full, inputs, observations=obs).jacobians(p, keep_cache=False):
        Jc[k * sl.start : k * sl.stop] = J[:, :, cand].reshape(-1, cand.size)
    return J0, Jc


def row_blocks(m: int) -> list[slice]:
    step = 3 * _blocks.BLOCK
    return [slice(a, min(a + step, m)) for a in range(0, m, step)]


def compact(A: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The rows ``keep`` of ``A``, moved up in place (a view of the first rows of A)."""
    idx = np.flatnonzero(keep)
    for b in row_blocks(idx.size):  # rows only move up: in order, nothing is overwritten early
        A[b] = A[idx[b]]
    return A[: idx.size]


def project_out(A: np.ndarray, Q: np.ndarray) -> None:
    """``A -= Q (Q^T A)`` in place, block by block."""
    C = Q.T @ A
    for b in row_blocks(A.shape[0]):
        A[b] -= Q[b] @ C


def explained(e: np.ndarray, J0: np.ndarray, Jc: np.ndarray, w: np.ndarray | None):
    """``e`` minus its (weighted) least-squares fit on the columns of the model and of every
    candidate, and the number of columns fitted (:func:`explained_residual`)."""

    def columns():
        for b in row_blocks(e.size):
            yield b, np.hstack([J0[b], Jc[b]])

    return explained_residual(e, columns, w)
