"""Screening the measurements before and during identification: repeated rows and gross outliers.

**Duplicates.** Two rows equal in every column (joint readings, point, every other column) are not
two measurements: a tracker's noise makes two real measurements of one pose differ in the
micrometres. A copied block of a log would otherwise count as evidence twice, shrink every
standard error and move the condition number. :func:`duplicate_rows` finds them; the lab counts
each once and names the copies by line.

**Gross outliers** (a reflector that lost lock, a wrong row pasted in) are found with the fit,
against a robust noise scale, by a stated rule:

* the scale ``s`` is the median absolute deviation of the residual's coordinates (times 1.4826,
  the standard deviation of Gaussian noise), corrected for the degrees of freedom the fit takes
  (``sqrt(3N / (3N - rank))``);
* a pose is an outlier when its 3-D residual exceeds ``r_N * s``, with ``r_N`` the radius that
  Gaussian noise of that scale exceeds anywhere among the N poses with probability
  :data:`OUTLIER_ALPHA` (1 %): ``r_N^2 = chi2.isf(alpha / N, 3)`` (Bonferroni). That is 4.75
  sigma for 200 poses, 5.23 for 2,000, 6.07 for 200,000. On clean data a false flag is that rare
  for a whole data set (measured in ``benchmarks/lab.py outliers``);
* the residual judged is the one left once the model *and every catalogued effect the data
  allow* (:func:`candidate_model`) have explained what they can, to first order: a missing
  effect's largest deviations (its residual has heavy tails) are then not taken for outliers.
  :func:`lab.fit` judges it when the model's own residual flags a pose; :func:`lab.diagnose`
  always (a gross error hidden in a missing effect's spread shows only there);
* the outliers are left out and the model refitted; the residuals of every pose are judged
  again, until the set no longer changes. Gross errors settle in one or two rounds; a set still
  growing after :data:`MAX_ROUNDS` is the spread of an effect the model and the catalogue lack,
  peeled away round by round, and nothing is left out.

A data set whose "outliers" would be more than :data:`MAX_OUTLIER_FRACTION` of its poses does not
have outliers: its model does not fit. Then nothing is left out, and the lab says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.stats import chi2

from arm.effects import EFFECTS, Effect, candidate_effects, make_effect, missing_inputs
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from lab.identifiability import gram_factor, lower_inverse

__all__ = [
    "MAX_OUTLIER_FRACTION",
    "MAX_ROUNDS",
    "OUTLIER_ALPHA",
    "OUTLIER_MODES",
    "Duplicate",
    "Outlier",
    "OutlierScreen",
    "annotate",
    "candidate_model",
    "duplicate_rows",
    "duplicates_text",
    "explained_residual",
    "judge",
    "outlier_radius",
    "robust_sigma",
    "screen_outliers",
]

OUTLIER_MODES = ("auto", "keep")
OUTLIER_ALPHA = 0.01  # the family-wise rate of a false flag on a clean data set
MAX_OUTLIER_FRACTION = 0.1
MAX_ROUNDS = 3  # gross errors settle in one or two rounds
MAD_TO_SIGMA = 1.4826
MIN_DOF = 30  # fewer residual degrees of freedom: no scale to judge by, nothing is flagged
# The scale never goes below 1 nm: far under any instrument, far above the round-off of noise-
# free data (1e-15 m), whose residual is not noise and has no outliers to find.
MIN_SCALE = 1e-9  # m


def outlier_radius(n: int, alpha: float = OUTLIER_ALPHA) -> float:
    """The 3-D radius, in standard deviations of per-axis Gaussian noise, that one of ``n``
    poses exceeds with probability ``alpha`` (Bonferroni over the poses)."""
    return math.sqrt(float(chi2.isf(alpha / max(int(n), 1), 3)))


def robust_sigma(r: np.ndarray) -> float:
    """1.4826 times the median absolute deviation of the coordinates of ``r``: the standard
    deviation of Gaussian noise, unmoved by a few gross errors."""
    r = np.asarray(r, dtype=float).reshape(-1)
    if not r.size:
        return float("nan")
    return float(MAD_TO_SIGMA * np.median(np.abs(r - np.median(r))))


@dataclass(frozen=True)
class Outlier:
    """One pose left out: its index in the data given, its line in the file (if read from one),
    its 3-D residual and how many robust standard deviations that is."""

    index: int
    line: int | None
    residual_mm: float
    sigmas: float
    note: str | None = None  # why the model could not say where it is, when an effect knows

    @property
    def where(self) -> str:
        return f"line {self.line}" if self.line is not None else f"row {self.index + 1}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "row": self.index + 1,
            "line": self.line,
            "residual_mm": self.residual_mm,
            "sigmas": self.sigmas,
            "note": self.note,
        }


@dataclass(frozen=True)
class Duplicate:
    """A row equal in every column to an earlier one (``first``), counted once."""

    index: int
    first: int
    line: int | None
    first_line: int | None

    @property
    def where(self) -> str:
        if self.line is not None and self.first_line is not None:
            return f"line {self.line} repeats line {self.first_line}"
        return f"row {self.index + 1} repeats row {self.first + 1}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "row": self.index + 1,
            "line": self.line,
            "first_row": self.first + 1,
            "first_line": self.first_line,
        }


def _ranges(values: list[int]) -> str:
    """``3-11, 13``: sorted integers as ranges."""
    out: list[str] = []
    start: int | None = None
    prev: int | None = None
    for v in [*sorted(values), None]:
        if start is not None and (v is None or prev is None or v != prev + 1):
            out.append(str(start) if start == prev else f"{start}-{prev}")
            start = None
        if v is not None and start is None:
            start = v
        prev = v
    return ", ".join(out)


def duplicates_text(dups: list[Duplicate], limit: int = 5) -> str:
    """The copies grouped by the row they repeat: ``line 2 (copied on lines 3-11)``."""
    groups: dict[tuple[int, int | None], list[int]] = {}
    for d in dups:
        key = (d.first, d.first_line)
        groups.setdefault(key, []).append(d.line if d.line is not None else d.index + 1)
    word = "line" if all(d.line is not None for d in dups) else "row"
    parts = []
    for (first, first_line), copies in list(groups.items())[:limit]:
        where = f"{word} {first_line if first_line is not None else first + 1}"
        parts.append(f"{where} (copied on {word}s {_ranges(copies)})")
    if len(groups) > limit:
        parts.append(f"... {len(groups) - limit} more rows copied")
    return "; ".join(parts)


def _line(data: MeasurementSet, i: int) -> int | None:
    return None if data.lines is None else int(data.lines[i])


def duplicate_rows(data: MeasurementSet) -> tuple[np.ndarray, list[Duplicate]]:
    """The rows to keep (each distinct row once, first occurrence, in order) and the copies."""
    n = len(data)
    if n < 2:
        return np.arange(n), []
    keys = [*data.q.T, *data.xyz.T, *data.columns.values()]
    order = np.lexsort(keys[::-1])  # equal rows end up side by side, earliest first (stable)
    same = np.ones(n - 1, dtype=bool)
    for k in keys:  # column by column: no copy of the table
        same &= k[order[1:]] == k[order[:-1]]
    if not same.any():
        return np.arange(n), []
    start = np.concatenate([[True], ~same])  # the first row of each run of equal rows
    head = order[np.flatnonzero(start)[np.cumsum(start) - 1]]
    owner = np.empty(n, dtype=int)
    owner[order] = head  # the first row equal to each row
    copies = np.flatnonzero(owner != np.arange(n))
    dups = [
        Duplicate(int(i), int(owner[i]), _line(data, int(i)), _line(data, int(owner[i])))
        for i in copies
    ]
    keep = np.flatnonzero(owner == np.arange(n))
    return keep, dups


@dataclass
class OutlierScreen:
    """The outcome of :func:`screen_outliers`: the poses kept (a mask over the data), the
    outliers, the scale and radius used, and why nothing was left out when that is the case."""

    keep: np.ndarray
    outliers: list[Outlier]
    sigma: float
    radius: float
    rounds: int
    note: str = ""

    @property
    def threshold_mm(self) -> float:
        return 1e3 * self.sigma * self.radius

    def rule(self) -> str:
        if not math.isfinite(self.sigma):
            return self.note or "not screened"
        return (
            f"3-D residual above {self.radius:.2f} robust sigmas ({self.threshold_mm:.4g} mm; "
            f"a false flag on clean data in {100 * OUTLIER_ALPHA:g} % of data sets)"
        )


def annotate(
    outliers: list[Outlier],
    model: ErrorModel,
    data: MeasurementSet,
    effects: Collection[str] | None = None,
) -> list[Outlier]:
    """The outliers (indices into ``data``) with the note of any effect of ``model`` whose law
    cannot say where such a pose is (:meth:`arm.effects.Effect.ambiguity_note`: load-dependent
    backlash at zero load). ``effects``: only the effects of these names speak (those of the
    model fitted or chosen, not every candidate a diagnosis tried)."""
    if not outliers:
        return outliers
    sub = data.subset(np.array([o.index for o in outliers]))
    try:
        inputs = model.inputs(sub.q, sub.columns, source=data.source)
    except ValueError:
        return outliers
    out = []
    for k, o in enumerate(outliers):
        notes = [
            n
            for e in model.effects
            if (effects is None or e.name in effects) and (n := e.ambiguity_note(inputs, k))
        ]
        out.append(replace(o, note="; ".join(notes)) if notes else o)
    return out


def judge(
    residuals: np.ndarray, keep: np.ndarray, rank: int, alpha: float = OUTLIER_ALPHA
) -> tuple[np.ndarray, float, float]:
    """One application of the rule: which poses are beyond the radius, given the residuals of
    every pose (N, 3) and the fit made on ``keep`` with ``rank`` parameters. Returns (mask,
    sigma (m), radius (sigmas))."""
    r = np.asarray(residuals, dtype=float)
    n = len(r)
    m = int(np.sum(keep))
    dof = 3 * m - rank
    if dof < MIN_DOF:
        return np.zeros(n, dtype=bool), float("nan"), float("nan")
    s = max(robust_sigma(r[keep]) * math.sqrt(3 * m / dof), MIN_SCALE)
    radius = outlier_radius(n, alpha)
    if not s > 0:
        return np.zeros(n, dtype=bool), s, radius
    return np.sum(r**2, axis=1) > (radius * s) ** 2, s, radius


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
        effects.append(type(e)() if e.per_joint and e.joints is not None else e)
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
    return ErrorModel(model.robot, effects, targets=model.targets), skipped


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


def screen_outliers(
    data: MeasurementSet,
    first: Any,
    refit: Callable[[np.ndarray], Any],
    residuals: Callable[[Any], np.ndarray],
    rank: Callable[[Any], int],
    explain: Callable[[Any, np.ndarray], tuple[np.ndarray, int]] | None = None,
) -> tuple[Any, OutlierScreen]:
    """Leave gross outliers out, iterating with the fit (see the module docstring).

    ``first``: the fit of every pose of ``data``; ``refit(mask)`` fits the poses of a mask;
    ``residuals(fit)`` gives the residuals (N, 3) of every pose of ``data`` under a fit, m;
    ``rank(fit)`` its number of fitted parameters. ``explain(fit, mask)``, when given, is asked
    once the model's own residual flags a pose: the residual (N, 3) left once every candidate
    effect may explain it too, and the number of columns fitted; the rule then applies to that
    residual, so that a missing effect's largest deviations are not taken for outliers.
    Returns the final fit and the screen."""
    n = len(data)

    def flags(res: Any, keep: np.ndarray) -> tuple[np.ndarray, float, float, np.ndarray]:
        r = residuals(res)
        far, s, radius = judge(r, keep, rank(res))
        if far.any() and explain is not None:
            r_all, k = explain(res, keep)
            far, s, radius = judge(r_all, keep, k)
        return far, s, radius, r

    keep = np.ones(n, dtype=bool)
    res = first
    far, s, radius, r = flags(res, keep)
    if not math.isfinite(s):
        note = "too few poses for the parameters to judge outliers by"
        return first, OutlierScreen(keep, [], s, radius, 0, note)
    rounds = 0
    while far.any() and rounds < MAX_ROUNDS:
        if far.sum() > MAX_OUTLIER_FRACTION * n:
            note = (
                f"{int(far.sum())} of {n} poses lie beyond the outlier radius: the model does "
                "not fit these data (a missing effect, other units, another robot); none left out"
            )
            return first, OutlierScreen(np.ones(n, dtype=bool), [], s, radius, rounds, note)
        if np.array_equal(~far, keep):
            break
        keep = ~far
        res = refit(keep)
        rounds += 1
        far, s, radius, r = flags(res, keep)
    if not far.any():
        if rounds:  # the poses once flagged are back within the radius: every pose is fitted
            return first, OutlierScreen(np.ones(n, dtype=bool), [], s, radius, rounds)
        return res, OutlierScreen(keep, [], s, radius, rounds)
    if not np.array_equal(~far, keep):
        note = (
            f"the poses beyond the rule kept changing with the fit ({int((~keep).sum())}, then "
            f"{int(far.sum())}): the spread of an effect no candidate has, not gross errors; "
            "none left out"
        )
        return first, OutlierScreen(np.ones(n, dtype=bool), [], s, radius, rounds, note)
    d = np.sqrt(np.sum(r**2, axis=1))
    outs = [
        Outlier(int(i), _line(data, int(i)), 1e3 * float(d[i]), float(d[i] / s))
        for i in np.flatnonzero(~keep)
    ]
    return res, OutlierScreen(keep, outs, s, radius, rounds)
