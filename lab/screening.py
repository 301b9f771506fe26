"""Screening: which rows of the measurements count, by one stated rule, in one step.

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
  allow* (:func:`lab.candidates.candidate_model`) have explained what they can, to first order:
  a missing effect's largest deviations (its residual has heavy tails) are then not taken for
  outliers. The fit's screening judges it when the model's own residual flags a pose;
* the outliers are left out and the model refitted; the residuals of every pose are judged
  again, until the set no longer changes. Gross errors settle in one or two rounds; a set still
  growing after :data:`MAX_ROUNDS` is the spread of an effect the model and the catalogue lack,
  peeled away round by round, and nothing is left out.

**Heavy contamination.** Least squares follows gross errors: with 40 % of the poses off by
millimetres the fit is dragged so far that the robust scale of its residual grows with it and the
rule flags only a few. So the residual is also judged against a fit that follows the majority: a
least-trimmed-squares fit of the model's own linearisation (the parameters that fit best the
:data:`LTS_SHARE` half of the poses they fit best, by random subsets and concentration steps
with a fixed seed; on at most :data:`LTS_POSES` poses), reweighted once. The half is taken of each
tracker station's poses: a pose is judged through its station's base, which only poses of that
station place (trimmed across stations, the best half of two re-homed sessions is the larger one,
and the other looks a mass of gross errors). No fit of the rule judges poses whose station its
poses do not place; such flags are a station's as a whole, not gross errors. Where it flags more
poses than the stated fraction and more than the least-squares fit did, the rule also starts from
the rows it keeps, and where that settles on poses apart from the rest (below), those are the
gross errors.

**The stated fraction.** Where the rule settles on more than :data:`MAX_OUTLIER_FRACTION` (10 %)
of the poses, and they lie apart from the others (the nearest at least :data:`GROSS_GAP` times as
far as the farthest pose kept: gross errors, not a missing effect's spread, whose largest
deviations continue its smaller ones), the data are not a calibration with a few bad points: the lab refuses them (:class:`lab.errors.FitError`), naming
the fraction, how far the poses lie and the first of them by line; ``outliers="keep"`` fits every
pose if that is what is wanted. Where more than that fraction lie beyond the radius but the set
does not settle (a missing effect's spread, peeled round after round), the model does not fit:
nothing is left out, and the lab says so.

**The tests' rows** (``tests=True``, what :func:`lab.diagnose` needs): a gross error hidden in a
missing effect's spread shows only once the fitted model and every candidate (the diagnosis's
candidates, :mod:`lab.candidates`) explain the residual; the same rule, iterated on that
residual, names the poses the tests leave out besides (``Screen.untested``). With
``outliers="keep"`` and a robust loss, the tests leave out the points that a Huber fit of the
model and every candidate puts beyond :data:`lab.solver.OUTLIER_RADIUS` robust sigmas.

**One step.** :func:`screen` applies all of this once and returns a :class:`Screen`: the model's
fit of the rows that count, what was left out and by which rule. :func:`lab.fit`,
:func:`lab.diagnose`, :func:`lab.discover` and :func:`lab.report.build_report` take a screen (or
make one, once, from the data) and leave nothing more out themselves; ``Screen.refit`` fits
another model to the same rows. The fits are made by :func:`lab.estimation.fit_rows`, called
directly: the rule needs no callbacks.

    s = lab.screen(data, "seed", "geometric", noise_mm=0.015)
    s.kept, s.fit.outlier_list, s.untested     # the rows fitted, the outliers, the tests' too
    lab.diagnose(s)                            # the tests of the same rows, nothing screened again
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, fields, replace
from functools import cached_property
from pathlib import Path
from typing import Unpack

import numpy as np
from scipy.stats import chi2

from arm.description import RobotDescription, as_robot
from arm.effect_api import EffectError
from arm.effects import Effect, parse_effects
from arm.errormodel import ErrorModel
from arm.errors import warn
from arm.measurements import MeasurementSet, as_measurements
from arm.params import parse_parameter_name
from lab.blocks import Blocks
from lab.candidates import (
    ModelFit,
    candidate_columns,
    candidate_groups,
    candidate_indices,
    candidate_model,
    explained,
    explained_residual,
)
from lab.errors import ContaminatedError, FitError, NoiseRefutedError, RowsLeftOutWarning
from lab.estimation import check_plausible, fit_rows
from lab.lumped_choice import held_rest
from lab.observations import Observations, observations_of
from lab.options import DEFAULTS, LabOptions, OptionFields, resolve
from lab.registration import reading_hint
from lab.result import Duplicate, FitResult, Outlier, RowsCounted, inputs_of
from lab.sanity import check_stated_noise
from lab.solver import HUBER_K, OUTLIER_RADIUS, robust_sigma
from lab.text import duplicates_text

__all__ = [
    "MAX_OUTLIER_FRACTION",
    "OUTLIER_ALPHA",
    "Screen",
    "duplicate_rows",
    "outlier_radius",
    "screen",
]

log = logging.getLogger(__name__)

OUTLIER_ALPHA = 0.01  # the family-wise rate of a false flag on a clean data set
MAX_OUTLIER_FRACTION = 0.1  # beyond this share of gross outliers, the data are not a calibration
# The least-trimmed-squares start (module docstring): it fits the best half of the poses (plus
# the parameters' worth), so it holds up to about 40 % of gross errors; its random subsets use a
# fixed seed (the same data give the same screen), on at most LTS_POSES poses drawn from the data.
LTS_SHARE = 0.5
LTS_POSES = 500
LTS_TRIALS = 500
LTS_STEPS = 2  # concentration steps per trial; the best trials are concentrated to convergence
# Gross errors lie apart: the nearest at least this many times as far as the farthest pose kept
GROSS_GAP = 2.0
MAX_ROUNDS = 3  # gross errors settle in one or two rounds
# Refusing a data set as mostly gross errors needs the poses kept to hold this many rows per
# parameter: fewer, and the fit of the rest explains them so well that clean poses look apart
# (on 120 campaigns of 29 poses with a missing effect, 55 were refused before this rule, 0 after)
REFUSE_REDUNDANCY = 3
MIN_DOF = 30  # fewer residual degrees of freedom: no scale to judge by, nothing is flagged
# The scale never goes below 1 nm: far under any instrument, far above the round-off of noise-
# free data (1e-15 m), whose residual is not noise and has no outliers to find.
MIN_SCALE = 1e-9  # m

Effects = str | Sequence[str | Effect]


def outlier_radius(n: int, alpha: float = OUTLIER_ALPHA, per_pose: int = 3) -> float:
    """The 3-D radius (``per_pose``-D: a pose's rows), in standard deviations of per-axis
    Gaussian noise, that one of ``n`` poses exceeds with probability ``alpha`` (Bonferroni over
    the poses)."""
    return math.sqrt(float(chi2.isf(alpha / max(int(n), 1), per_pose)))


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
    n, k = r.shape
    m = int(np.sum(keep))
    if k == 3:
        rows = 3 * m
        s = robust_sigma(r[keep])
    else:  # weighted rows, some not measured (zero): the scale of those measured
        rows = int(np.count_nonzero(r[keep]))
        s = robust_sigma(r[keep][r[keep] != 0])
    dof = rows - rank
    if dof < MIN_DOF:
        return np.zeros(n, dtype=bool), float("nan"), float("nan")
    s = max(s * math.sqrt(rows / dof), MIN_SCALE)
    radius = outlier_radius(n, alpha, k)
    if not s > 0:
        return np.zeros(n, dtype=bool), s, radius
    return np.sum(r**2, axis=1) > (radius * s) ** 2, s, radius


# -- the fit's outliers (the model's own residual, explained by the candidates when it flags) -----
@dataclass(frozen=True)
class _Judged:
    """The outcome of the fit's rule: the poses kept (a mask), the outliers, the scale and
    radius used, and why nothing was left out when that is the case."""

    keep: np.ndarray
    outliers: list[Outlier]
    sigma: float
    radius: float
    rounds: int
    note: str = ""

    def rule(self) -> str:
        if not math.isfinite(self.sigma):
            return self.note or "not screened"
        return (
            f"3-D residual above {self.radius:.2f} robust sigmas "
            f"({1e3 * self.sigma * self.radius:.4g} mm; a false flag on clean data in "
            f"{100 * OUTLIER_ALPHA:g} % of data sets)"
        )


def _explain_with_candidates(
    res: ModelFit, data: MeasurementSet, keep: np.ndarray, obs: Observations
) -> tuple[np.ndarray, int]:
    """The residual rows (N, k) of every pose of ``data`` (its rows ``obs``) that are left once
    the model's parameters *and every candidate effect* (:func:`lab.candidates.candidate_model`)
    have explained what they can, to first order, on the poses of ``keep``; and the number of
    columns fitted."""
    try:
        full, _ = candidate_model(res.model, data)
    except EffectError:  # a user's effect that cannot be built here: the model alone
        full = res.model
    p = full.nominal()
    p[full.layout.indices(res.model.layout.names)] = res.params
    blocks = Blocks(full, inputs_of(full, data), observations=obs)
    k = blocks.per_pose
    # the model's residual: candidates are zero
    e = (blocks.predict(p) - (data.xyz if obs.plain else obs.target)).reshape(-1)

    def columns():
        for sl, _, J in blocks.jacobians(p, keep_cache=False):
            yield slice(k * sl.start, k * sl.stop), J.reshape(-1, J.shape[2])

    r, n = explained_residual(e, columns, np.repeat(keep, k).astype(float))
    return r.reshape(-1, k), n


@dataclass(frozen=True)
class _Model:
    """What a fit of some rows needs: the arm, the effects, the options, the starting values."""

    robot: RobotDescription
    effects: Effects
    options: LabOptions
    start: Mapping[str, float] | None = None
    fixed: tuple[str, ...] = ()

    @cached_property
    def parsed(self) -> list[Effect]:
        """The effects as instances: their specification parsed once, for every fit."""
        try:
            return parse_effects(self.effects)
        except EffectError as exc:
            raise FitError(str(exc)) from None

    def fit(self, data: MeasurementSet, judge_noise: bool = False) -> FitResult:
        return fit_rows(
            data,
            self.robot,
            self.parsed,
            self.options,
            start=self.start,
            fixed=self.fixed + self.held(data),
            judge_noise=judge_noise,
        )

    def held(self, data: MeasurementSet) -> tuple[str, ...]:
        """Parameters held at zero beyond ``fixed``: lumped_compliance's beyond its first group
        where the rows do not say they help (:func:`lab.lumped_choice.held_rest`), decided once,
        on the rows of this model's first fit."""
        if "_held" not in self.__dict__:
            self.__dict__["_held"] = held_rest(
                data, self.robot, self.parsed, self.options, self.fixed
            )
        return self.__dict__["_held"]

    def observations(self, data: MeasurementSet) -> Observations:
        return observations_of(data, self.options.instrument, self.options.measured)


def _flags(
    res: FitResult, data: MeasurementSet, keep: np.ndarray, obs: Observations
) -> tuple[np.ndarray, float, float, np.ndarray]:
    """The rule on the residuals of every pose of ``data`` (its rows ``obs``: weighted where
    the rows' uncertainties differ) under ``res`` (fitted on ``keep``); once the model's own
    residual flags a pose, on the residual every candidate explains too."""
    if obs.plain:
        r = res.residuals_of(data)
    else:
        r = Blocks(res.model, inputs_of(res.model, data), observations=obs).predict(res.params)
        r = r - obs.target
    far, s, radius = judge(r, keep, res.rank)
    if far.any():
        r_all, k = _explain_with_candidates(res, data, keep, obs)
        far, s, radius = judge(r_all, keep, k)
    return far, s, radius, r


def _trimmed_fit(res: FitResult, data: MeasurementSet) -> tuple[np.ndarray, np.ndarray] | None:
    """The residual (N, 3) of every pose of ``data`` under a least-trimmed-squares fit of the
    model's linearisation at ``res`` (module docstring), and the poses it fits (a mask); None
    where there are too few poses for it."""
    free = np.flatnonzero(res.identifiable)
    n, P = len(data), free.size
    rng = np.random.default_rng(0)  # a fixed seed: the same data, the same screen
    sub = np.arange(n) if n <= LTS_POSES else np.sort(rng.choice(n, LTS_POSES, replace=False))
    m = len(sub)
    k0 = -(-P // 3) + 1  # poses in a random start: a few equations more than parameters
    h = math.ceil(LTS_SHARE * (m + k0))
    if not P or 3 * h - P < MIN_DOF or h >= m:
        return None
    part = data.subset(sub)
    pred, J = res.model.predict(inputs_of(res.model, part), res.params, jacobian=True)
    e = (pred - part.xyz).reshape(m, 3)
    A = J[:, :, free]
    norms = np.linalg.norm(A.reshape(-1, P), axis=0)
    norms[norms == 0] = 1.0
    A = A / norms
    # each pose's normal equations once: a subset's fit is then a sum of (P, P) blocks
    G = np.einsum("nai,naj->nij", A, A).reshape(m, P * P)
    b = -np.einsum("nai,na->ni", A, e)
    ridge = 1e-12 * float(np.sum(A**2)) / P * np.eye(P)
    Af = A.transpose(0, 1, 2).reshape(m * 3, P)
    ef = e.reshape(-1)

    def solve(W: np.ndarray) -> np.ndarray:
        """The least-squares steps (T, P) on the poses weighted by each row of ``W`` (T, m)."""
        M = (W @ G).reshape(-1, P, P) + ridge
        return np.linalg.solve(M, (W @ b)[:, :, None])[:, :, 0]

    def misses(D: np.ndarray) -> np.ndarray:
        """Each pose's squared miss (T, m) under each step of ``D`` (T, P)."""
        return np.sum(((ef[:, None] + Af @ D.T).reshape(m, 3, -1)) ** 2, axis=1).T

    groups = _stations_of(part)

    def concentrate(D: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
        """Concentration steps: refit each on its h best poses (each station's share of them);
        (trimmed sums (T,), steps)."""
        for _ in range(steps):
            D = solve(_best(misses(D), groups, h, m).astype(float))
        d2 = misses(D)
        return np.sum(np.where(_best(d2, groups, h, m), d2, 0.0), axis=1), D

    W0 = np.zeros((LTS_TRIALS, m))
    picks = np.argsort(rng.random((LTS_TRIALS, m)), axis=1)[:, :k0]  # random starting subsets
    W0[np.arange(LTS_TRIALS)[:, None], picks] = 1.0
    starts = np.vstack([np.zeros((1, P)), solve(W0)])  # and the least-squares fit itself
    cost, D = concentrate(starts, LTS_STEPS)
    order = np.argsort(cost, kind="stable")[:10]
    cost, D = concentrate(D[order], 20)
    best = (float(cost.min()), D[int(np.argmin(cost))])
    p = res.params.copy()
    p[free] += best[1] / norms
    r = Blocks(res.model, inputs_of(res.model, data)).predict(p) - data.xyz
    d2 = np.sum(r**2, axis=1)
    core = _best(d2[None, :], _stations_of(data), h, m)[0]
    return r, core


def _stations_of(data: MeasurementSet) -> list[np.ndarray]:
    """The rows of each tracker station of ``data`` (one group where there is no station
    column)."""
    station = data.columns.get("station")
    if station is None:
        return [np.arange(len(data))]
    return [np.flatnonzero(station == v) for v in np.unique(station)]


def _best(d2: np.ndarray, groups: Sequence[np.ndarray], h: int, m: int) -> np.ndarray:
    """The poses (a mask (T, N)) that each row of squared misses ``d2`` (T, N) fits best: ``h``
    of every ``m`` poses *of each station* (``groups``: their rows), so that a trimmed fit
    places every station's base. Trimmed across stations, the best half of two re-homed
    sessions is the larger session alone, and the other, its base placed by a couple of its
    poses, looks a mass of gross errors."""
    T = len(d2)
    out = np.zeros(d2.shape, dtype=bool)
    rows = np.arange(T)[:, None]
    for g in groups:
        k = min(len(g), -(-h * len(g) // m))  # ceil(h * len(g) / m), at least one
        out[rows, g[np.argpartition(d2[:, g], k - 1, axis=1)[:, :k]]] = True
    return out


def _masked(res: FitResult, data: MeasurementSet, far: np.ndarray) -> np.ndarray | None:
    """The poses a trimmed fit flags where least squares, dragged by many gross errors, hid
    them (more than the stated fraction, and more than ``far``); None where it sees no such
    thing."""
    trimmed = _trimmed_fit(res, data)
    if trimmed is None:
        return None
    r, core = trimmed
    flagged, s, _ = judge(r, core, res.rank)
    if not math.isfinite(s):
        return None
    flagged, s, _ = judge(r, ~flagged, res.rank)  # reweighted: the scale of every pose kept
    n = len(data)
    if flagged.sum() > MAX_OUTLIER_FRACTION * n and flagged.sum() > far.sum():
        return flagged
    return None


def _places_stations(
    first: FitResult, res: FitResult, data: MeasurementSet, keep: np.ndarray
) -> bool:
    """Whether the fit ``res`` of the poses ``keep`` of ``data`` places every tracker station's
    base as ``first`` (the fit of every pose) does: each station keeps the poses to
    over-determine its base :data:`REFUSE_REDUNDANCY` times (6 parameters, 3 rows a pose: 6
    poses), and every base parameter ``first`` identified is identified. A pose is judged by its
    residual through its station's base: where the poses kept do not place that base (a trimmed
    fit that kept 2 poses of a re-homed session of 150 left its base turned 7 degrees, and called
    the other 148 gross errors of 10 to 245 mm), its poses cannot be judged by that fit."""
    station = data.columns.get("station")
    if station is not None:
        kept = station[keep]
        for s in np.unique(station):
            if np.count_nonzero(kept == s) < 2 * REFUSE_REDUNDANCY:
                return False
    placed = dict(zip(res.model.layout.names, res.identifiable, strict=True))
    return all(
        placed.get(n, False)
        for n, ok in zip(first.model.layout.names, first.identifiable, strict=True)
        if ok and (p := parse_parameter_name(n)) is not None and p.kind == "base"
    )


def _sentence(text: str) -> str:
    """``text`` as a sentence of its own (``""`` stays empty)."""
    return f"{text[:1].upper()}{text[1:]}." if text else ""


def _refuse_contaminated(
    res: FitResult, data: MeasurementSet, far: np.ndarray, s: float, radius: float
) -> None:
    """The rule settled on more than the stated fraction of the poses: not a calibration."""
    n, k = len(data), int(far.sum())
    d = 1e3 * np.linalg.norm(res.residuals_of(data)[far], axis=1)
    rows = np.flatnonzero(far)
    where = ", ".join(
        f"line {data.lines[i]}" if data.lines is not None else f"row {i + 1}" for i in rows[:8]
    )
    more = f" and {k - 8} more" if k > 8 else ""
    raise ContaminatedError(
        f"{data.source}: {k} of {n} poses ({100 * k / n:.0f} %) are gross outliers, "
        f"{d.min():.3g} to {d.max():.3g} mm off the fit of the other {n - k} (RMS "
        f"{1e3 * res.rms:.3g} mm; beyond {radius:.2f} robust sigmas of {1e3 * s:.3g} mm): more "
        f"than the {100 * MAX_OUTLIER_FRACTION:.0f} % the lab leaves out, so the fit is not a "
        f"calibration ({where}{more}). "
        + (
            _sentence(reading_hint(res.model.described, data.q, data.xyz, data.columns))
            or "Rows of another arm or instrument, a reflector that lost lock?"
        )
        + " --outliers keep fits every pose"
    )


@dataclass
class _Round:
    """The state of the rule's iteration: the fit, the poses it was made on, what is flagged."""

    res: FitResult
    keep: np.ndarray
    far: np.ndarray
    s: float
    radius: float
    r: np.ndarray
    rounds: int

    @property
    def settled(self) -> bool:
        return bool(np.array_equal(~self.far, self.keep))

    @property
    def separated(self) -> bool:
        """Whether the poses flagged lie apart from those kept: the nearest of them at least
        :data:`GROSS_GAP` times as far as the farthest pose kept. Gross errors do (a reflector
        that lost lock is millimetres off); a missing effect's spread does not (its largest
        deviations continue its smaller ones)."""
        return self._apart_by(GROSS_GAP)

    @property
    def apart_beyond_leverage(self) -> bool:
        """:attr:`separated` with the fit's leverage taken out: the poses kept were fitted
        (their residuals shrink by about sqrt(1 - h), h = rank / rows, the mean leverage) and
        those flagged predicted (theirs grow by about sqrt(1 + h)). On a large set the two
        agree; on a small one (29 real poses, 25 parameters) a fit of the rest makes clean poses
        look apart by leverage alone, and only a gap beyond it calls them gross errors. Where
        the poses kept do not over-determine the parameters :data:`REFUSE_REDUNDANCY` times
        (h above its inverse), their fit bends to them too freely to call the rest gross."""
        h = self.res.rank / max(int(np.count_nonzero(self.r[self.keep])), 1)
        if h > 1 / REFUSE_REDUNDANCY:
            return False
        return self._apart_by(GROSS_GAP * math.sqrt((1 + h) / (1 - h)))

    def _apart_by(self, gap: float) -> bool:
        """Whether the nearest pose flagged is at least ``gap`` times as far as the farthest
        pose kept (False where none, or every one, is flagged)."""
        if not self.far.any() or self.far.all():
            return False
        d = np.linalg.norm(self.r, axis=1)
        return bool(d[self.far].min() >= gap * d[~self.far].max())


def _apart(st: _Round) -> np.ndarray | None:
    """The poses beyond the radius that lie apart from every other: the largest group above a
    gap of :data:`GROSS_GAP` in the sorted distances (gross errors among a missing effect's
    spread, which stays below it); None where there is no such gap."""
    d = np.linalg.norm(st.r, axis=1)
    ds = np.sort(d)
    limit = st.radius * st.s
    ratios = ds[1:] / np.maximum(ds[:-1], MIN_SCALE)
    split = np.flatnonzero((ds[1:] > limit) & (ratios >= GROSS_GAP))
    if not split.size:
        return None
    return d >= ds[split[0] + 1]


def _confirm_apart(
    data: MeasurementSet, model: _Model, st: _Round, flags: Flags, first: FitResult
) -> _Round | None:
    """The state with the poses :func:`_apart` names left out and the others refitted, where
    they are still apart then (settled): gross errors; else None (also where the poses left
    do not place every station: :func:`_places_stations`). ``first``: the fit of every pose."""
    top = _apart(st)
    # gross errors are the minority the trimmed fit leaves out: a "group apart" of more than
    # half the poses is the spread of an effect (a fit of the few left would fail or mean nothing)
    if top is None or top.sum() > LTS_SHARE * len(top):
        return None
    keep = ~top
    try:
        res = model.fit(data.subset(keep))
    except FitError:
        return None
    if not _places_stations(first, res, data, keep):
        return None
    _, s, radius, r = flags(res, data, keep)
    again = _Round(res, keep, top, s, radius, r, st.rounds + 1)
    d = np.linalg.norm(r, axis=1)
    if not math.isfinite(s) or not np.all(d[top] > radius * s) or not again.separated:
        return None
    return again


def _physics_explains(data: MeasurementSet, model: _Model, first: FitResult) -> bool:
    """Whether the poses a refusal would call gross errors are a catalogued effect's instead:
    for each candidate effect (:func:`lab.candidates.candidate_model`, the diagnosis's
    candidates, on all their joints) in turn, then for all of them at once (two effects: each
    alone leaves the other's spread), the model with it fitted to every pose, and the
    least-trimmed-squares start of the rule (:func:`_trimmed_fit`) applied under that model:
    where it leaves no more than the stated fraction beyond the rule, the candidate brings the
    poses within it. A load-dependent
    backlash splits the poses by the sign of a gravity torque, and within each side it is a
    constant joint offset: a trimmed fit of the model alone fits the larger side exactly and
    finds the other apart by the whole gap; with the effect among the columns both sides fit.
    A candidate speaks only where the trimmed fit's poses over-determine its model
    :data:`REFUSE_REDUNDANCY` times (fitted to half of 60 poses, 40 columns explain anything);
    where a single candidate cannot be judged so (a campaign of some 40 poses), it cannot be
    ruled out, and nothing is refused (benchmarks/lab_decisions.py found four such false
    refusals in 1,560 campaigns).
    Gross errors stay apart whatever the physics (40 % of the poses moved millimetres are as far
    off under every candidate). Where a candidate cannot be fitted (a user's effect that cannot
    be built; weighted or 6-DoF rows, which the trimmed start does not read), it explains
    nothing. ``first``: the model's fit of every pose."""
    if not model.observations(data).plain:
        return False
    try:
        full, _ = candidate_model(first.model, data)
    except (EffectError, ValueError):
        return False
    have = {e.name for e in first.model.effects}
    n = len(data)
    # the candidates' models are probes, not fits the user asked for: their warnings (a poor
    # pose set for so many columns) would only confuse
    quiet = logging.getLogger("lab.identifiability")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            new = [e for e in full.effects if e.name not in have]
            # each candidate alone, then all of them (two effects at once: each alone leaves
            # the other's spread)
            for added in [[e] for e in new] + ([new] if len(new) > 1 else []):
                probe = replace(model, effects=[*first.model.effects, *added], start=None, fixed=())
                within = _brings_within(data, probe, n)
                if within is None and len(added) == 1:
                    log.info(
                        "%s: too few poses to tell the poses apart from %s: not refused",
                        data.source,
                        added[0].label,
                    )
                    return True  # a candidate that cannot be ruled out may explain them
                if within:
                    log.info(
                        "%s: the poses apart from the rest fit %s: not gross errors",
                        data.source,
                        ", ".join(e.label for e in added),
                    )
                    return True
    finally:
        quiet.setLevel(level)
    return False


def _brings_within(data: MeasurementSet, probe: _Model, n: int) -> bool | None:
    """Whether a trimmed fit of ``probe`` (reweighted once, as :func:`_masked` does) leaves no
    more than the stated fraction of poses beyond the rule (False where ``probe`` cannot be
    fitted; None where its trimmed fit has too few poses to tell)."""
    try:
        res = probe.fit(data)
        trimmed = _trimmed_fit(res, data)
        if trimmed is None:
            return None
        r, core = trimmed
        if REFUSE_REDUNDANCY * res.rank > 3 * core.sum():
            return None  # fitted to half the poses, so many columns would explain anything
        flagged, s, _ = judge(r, core, res.rank)
        if not math.isfinite(s):
            return False
        flagged, s, _ = judge(r, ~flagged, res.rank)  # reweighted, as _masked does
    except (FitError, EffectError, ValueError):
        return False
    return bool(math.isfinite(s) and flagged.sum() <= MAX_OUTLIER_FRACTION * n)


def _columns(res: FitResult, data: MeasurementSet) -> int:
    """The columns the rule's residual is explained by: the model's and every candidate's."""
    try:
        return len(candidate_model(res.model, data)[0].layout)
    except EffectError:
        return len(res.model.layout)


def _own_flags(
    res: FitResult, data: MeasurementSet, keep: np.ndarray
) -> tuple[np.ndarray, float, float, np.ndarray]:
    """The rule on the model's own residual alone (no candidates: fitted to the few poses a
    heavy contamination leaves, they would explain the noise away and flag clean poses); plain
    3-D points only (:func:`_masked`)."""
    r = res.residuals_of(data)
    return (*judge(r, keep, res.rank), r)


Flags = Callable[
    [FitResult, MeasurementSet, np.ndarray], tuple[np.ndarray, float, float, np.ndarray]
]


def _iterate(
    data: MeasurementSet,
    model: _Model,
    st: _Round,
    flags: Flags,
    first: FitResult,
    rounds: int = MAX_ROUNDS,
) -> _Round:
    """Leave out what is flagged and refit, until the set no longer changes (or ``rounds``).
    Where the poses left would not place every station (:func:`_places_stations`; ``first``:
    the fit of every pose), the flags are a station's as a whole, not gross errors: nothing is
    flagged."""
    while st.far.any() and st.rounds < rounds and not st.settled:
        keep = ~st.far
        res = model.fit(data.subset(keep))
        if not _places_stations(first, res, data, keep):
            log.info("%s: the poses flagged leave a station unplaced: none flagged", data.source)
            return replace(st, far=np.zeros_like(st.far))
        st = _Round(res, keep, *flags(res, data, keep), st.rounds + 1)
    return st


def _from_trimmed(
    data: MeasurementSet,
    model: _Model,
    first: FitResult,
    masked: np.ndarray,
    with_candidates: Flags,
) -> _Round | None:
    """The rule started from the poses a trimmed fit keeps (``~masked``), settled; None where
    they do not place every station (:func:`_places_stations`: the trimmed fit took the half
    of the poses it fits best from one session, and cannot judge the other's)."""
    keep = ~masked
    res = model.fit(data.subset(keep))
    if not _places_stations(first, res, data, keep):
        log.info("%s: the trimmed fit leaves a station unplaced: not a start", data.source)
        return None
    # from a trimmed set the flags shrink to the gross errors: a few more rounds allowed
    # the candidates explain a missing effect's spread where the poses left are enough for
    # them; fitted to too few, they would explain the noise away and flag clean poses
    enough = 3 * keep.sum() >= 4 * _columns(first, data)
    flags: Flags = with_candidates if enough else _own_flags
    start = _Round(res, keep, *flags(res, data, keep), 1)
    robust = _iterate(data, model, start, flags, first, MAX_ROUNDS + 3)
    if not (robust.settled and robust.separated):  # gross errors among a spread?
        return _confirm_apart(data, model, robust, flags, first)
    return robust


def _fit_outliers(
    data: MeasurementSet, first: FitResult, model: _Model
) -> tuple[FitResult, _Judged]:
    """Leave gross outliers out, iterating with the fit (see the module docstring). ``first``:
    the fit of every pose of ``data``. Returns the final fit and what was judged; refuses data
    whose gross outliers settle beyond :data:`MAX_OUTLIER_FRACTION`."""
    n = len(data)
    everyone = np.ones(n, dtype=bool)
    obs = model.observations(data)

    def with_candidates(
        res: FitResult, data: MeasurementSet, keep: np.ndarray
    ) -> tuple[np.ndarray, float, float, np.ndarray]:
        return _flags(res, data, keep, obs)

    st = _Round(first, everyone, *with_candidates(first, data, everyone), 0)
    if not math.isfinite(st.s):
        note = "too few poses for the parameters to judge outliers by"
        return first, _Judged(everyone, [], st.s, st.radius, 0, note)
    # the trimmed start reads plain 3-D points (no weights, no orientations)
    masked = _masked(first, data, st.far) if obs.plain else None
    # least squares may have hidden them: start from the trimmed fit
    robust = None if masked is None else _from_trimmed(data, model, first, masked, with_candidates)
    if (
        robust is not None
        and robust.settled
        and robust.separated
        and not (
            robust.far.sum() > MAX_OUTLIER_FRACTION * n and _physics_explains(data, model, first)
        )
    ):
        st = robust  # gross errors that least squares hid, settled and apart as they are
    else:
        st = _iterate(data, model, st, with_candidates, first)
    if st.far.sum() > MAX_OUTLIER_FRACTION * n:
        if (
            st.settled
            and st.apart_beyond_leverage  # gross errors, too many for a calibration
            and not _physics_explains(data, model, first)
        ):
            _refuse_contaminated(st.res, data, st.far, st.s, st.radius)
        note = (
            f"{int(st.far.sum())} of {n} poses lie beyond the outlier radius: the model does "
            "not fit these data (a missing effect, other units, another robot); none left out"
        )
        return first, _Judged(everyone, [], st.s, st.radius, st.rounds, note)
    if not st.far.any():
        if st.rounds:  # the poses once flagged are back within the radius: every pose is fitted
            return first, _Judged(everyone, [], st.s, st.radius, st.rounds)
        return st.res, _Judged(st.keep, [], st.s, st.radius, st.rounds)
    if not st.settled:
        note = (
            f"the poses beyond the rule kept changing with the fit ({int((~st.keep).sum())}, "
            f"then {int(st.far.sum())}): the spread of an effect no candidate has, not gross "
            "errors; none left out"
        )
        return first, _Judged(everyone, [], st.s, st.radius, st.rounds, note)
    d = np.sqrt(np.sum(st.r**2, axis=1))
    outs = [
        Outlier(int(i), _line(data, int(i)), 1e3 * float(d[i]), float(d[i] / st.s))
        for i in np.flatnonzero(~st.keep)
    ]
    return st.res, _Judged(st.keep, outs, st.s, st.radius, st.rounds)


# -- the tests' rows -------------------------------------------------------------------------------
def _beyond_candidates(
    e: np.ndarray, J0: np.ndarray, Jc: np.ndarray, rule: str | None, per_pose: int = 3
) -> tuple[np.ndarray, str | None]:
    """The poses that stay gross outliers once the model *and every candidate* may explain the
    residual ``e`` (3N): least squares on their columns, the rule, iterated. Returns their
    indices and the rule as applied."""
    n = e.size // per_pose
    keep = np.ones(n, dtype=bool)
    far = np.zeros(n, dtype=bool)
    radius = s = float("nan")
    for _ in range(MAX_ROUNDS + 1):
        r, k = explained(e, J0, Jc, np.repeat(keep, per_pose).astype(float))
        far, s, radius = judge(r.reshape(n, per_pose), keep, k)
        if not np.isfinite(s) or far.sum() > MAX_OUTLIER_FRACTION * n:
            return np.empty(0, dtype=int), rule
        if np.array_equal(~far, keep):
            break
        keep = ~far
    else:  # still changing: a spread peeled away round by round, not gross errors
        return np.empty(0, dtype=int), rule
    if far.any():
        rule = (
            f"3-D residual above {radius:.2f} robust sigmas ({1e3 * radius * s:.4g} mm) beyond "
            "the model and every candidate"
        ) + (f"; the fit's: {rule}" if rule else "")
    return np.flatnonzero(far), rule


def _robust_far(
    e: np.ndarray, J0: np.ndarray, Jc: np.ndarray, iterations: int = 20, per_pose: int = 3
) -> np.ndarray:
    """The points a robust fit's tests leave out (``outliers="keep"`` with a robust loss):
    Huber IRLS of the residual ``e`` (3N) on every column the model and all candidates have, so
    that a missing effect is explained, not mistaken for outliers; then the points farther off
    than :data:`lab.solver.OUTLIER_RADIUS` robust standard deviations."""
    n = e.size // per_pose
    r, k = explained(e, J0, Jc, None)
    if k > e.size // 2:  # too few poses for the catalogue: the fit's residual as it is
        r = e
    else:
        w = np.ones_like(e)
        for _ in range(iterations):
            r, _ = explained(e, J0, Jc, w)
            f = HUBER_K * robust_sigma(r)
            w_new = np.minimum(1.0, f / np.maximum(np.abs(r), 1e-300))
            if np.max(np.abs(w_new - w)) < 1e-6:
                break
            w = w_new
    dist = np.linalg.norm(r.reshape(n, per_pose), axis=1)
    radius = OUTLIER_RADIUS if per_pose == 3 else math.sqrt(chi2.ppf(0.999, per_pose))
    return np.flatnonzero(dist > radius * robust_sigma(r))


def _untested(
    res: FitResult, kept: MeasurementSet, candidates: Sequence[str] | None, mode: str
) -> tuple[np.ndarray, str | None]:
    """The positions (in ``kept``, the rows ``res`` fitted) that the tests leave out besides,
    and the rule as applied (see the module docstring)."""
    rule = res.outlier_rule
    model = res.model
    full, groups, _ = candidate_groups(model, kept, candidates)
    inputs = full.inputs(kept.q, kept.columns, source=kept.source)
    p = full.nominal()
    p[full.layout.indices(model.layout.names)] = res.params
    J0, Jc = candidate_columns(res, full, inputs, p, candidate_indices(full, groups))
    e = res.row_residuals.reshape(-1).copy()
    k = res.row_residuals.shape[1]
    if mode == "auto":
        return _beyond_candidates(e, J0, Jc, rule, k)
    return _robust_far(e, J0, Jc, per_pose=k), rule


# -- the screen ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Screen:
    """Which rows of ``data`` count for a model, decided once by the rule of this module.

    ``fit``: the model (``robot``, ``effects``) fitted to the rows kept (its ``duplicates``,
    ``outlier_list`` and ``outlier_rule`` say what was left out of it and why);
    ``untested_rows``: positions in :attr:`kept` that a diagnosis's tests leave out besides
    (None: not judged, ``tests=False``): with ``outliers="auto"`` gross errors that show only
    beyond the model and every candidate (no further model fits them either), with a robust
    loss and ``outliers="keep"`` the robust fit's far points (of this model's tests only);
    ``untested`` the same as :class:`Outlier` s of ``data``; ``test_rule`` the rule as applied.
    ``options``, ``candidates``: what the rows were judged with."""

    data: MeasurementSet
    fit: FitResult
    robot: RobotDescription
    effects: Effects
    options: LabOptions
    candidates: tuple[str, ...] | None = None
    untested_rows: np.ndarray | None = None
    untested: tuple[Outlier, ...] = ()
    test_rule: str | None = None

    @property
    def kept(self) -> MeasurementSet:
        """The rows the model was fitted to: each distinct row once, the outliers left out."""
        return self.fit.fitted_data(self.data)

    @property
    def tested(self) -> MeasurementSet:
        """The rows a diagnosis tests: :attr:`kept` without the :attr:`untested` ones."""
        if self.untested_rows is None or not self.untested_rows.size:
            return self.kept
        rows = self._rows()
        return self.data.subset(np.delete(rows, self.untested_rows))

    @property
    def judged_tests(self) -> bool:
        return self.untested_rows is not None

    @property
    def left_out(self) -> list[Outlier]:
        """Every pose left out of the fit or of the tests, in the order of the data."""
        return sorted([*self.fit.outlier_list, *self.untested], key=lambda o: o.index)

    def _rows(self) -> np.ndarray:
        rows = self.fit.fitted_rows
        return np.arange(len(self.data)) if rows is None else rows

    @property
    def counted(self) -> MeasurementSet:
        """The rows every model of these data is fitted to: :attr:`kept`, without the gross
        errors found beyond the model and every candidate (``outliers="auto"``)."""
        return self.tested if self.options.outliers == "auto" else self.kept

    def refit(self, effects: Effects, tests: bool = True) -> Screen:
        """``effects`` fitted to the rows that count (:attr:`counted`), nothing more left out
        (``outliers="keep"``): the same rows for another model, so that models compare pose by
        pose. With ``tests``, its tests' rows judged (a robust loss's far points)."""
        model = _Model(self.robot, effects, self.options.replace(outliers="keep"))
        data = self.counted
        return _screened_fit(data, model.fit(data), model, self.candidates, tests)


#: How far past its limits a joint reading may lie and still be a pose of the arm (rad, 0.5 deg:
#: an encoder reads a little beyond a soft limit; a description's limits are rounded)
LIMIT_MARGIN = math.radians(0.5)


def _check_limits(data: MeasurementSet, robot: RobotDescription) -> None:
    """Refuse rows whose joint readings lie beyond the arm's limits (by more than
    :data:`LIMIT_MARGIN`), naming the first by line and column: no pose of this arm, they would
    drag the fit and end it far from their cause (one such row made a fit of 60 poses say that
    no parameter could be identified at a noise of 39 mm)."""
    arm = robot.to_modified()
    lo, hi = arm.lower - LIMIT_MARGIN, arm.upper + LIMIT_MARGIN
    bad = (data.q < lo) | (data.q > hi)
    rows = np.flatnonzero(bad.any(axis=1))
    if not rows.size:
        return
    i = int(rows[0])
    j = int(np.flatnonzero(bad[i])[0])
    where = f"line {data.lines[i]}" if data.lines is not None else f"row {i + 1}"
    more = f" (and {rows.size - 1} more row(s))" if rows.size > 1 else ""
    cause = (
        "a typo in the file?"
        if rows.size <= max(1, MAX_OUTLIER_FRACTION * len(data))
        else "another arm's data, or the wrong --robot?"
    )
    as_degrees = np.radians(data.q)
    turn = np.abs(data.q).max() > 2 * math.pi + LIMIT_MARGIN  # beyond a turn: not radians
    if turn and rows.size > 1 and not ((as_degrees < lo) | (as_degrees > hi)).any():
        cause = (
            "degrees read as radians? every reading is within the limits in degrees: "
            "say --angle-unit deg"
        )
    raise FitError(
        f"{data.source}, {where}, column 'q{j + 1}': {data.q[i, j]:g} rad is beyond joint "
        f"{j + 1}'s limits [{arm.lower[j]:g}, {arm.upper[j]:g}] rad of robot {arm.name!r}"
        f"{more}: not a pose of this arm ({cause})"
    )


def _screen(
    data: MeasurementSet,
    model: _Model,
    candidates: Sequence[str] | None,
    tests: bool,
) -> Screen:
    opts = model.options
    _check_limits(data, model.robot)
    distinct, dups = duplicate_rows(data)
    if dups:
        text = duplicates_text(dups)
        log.warning(
            "%s: %d row(s) repeat an earlier row exactly: %s; each is counted once",
            data.source,
            len(dups),
            text,
        )
        warn(
            f"{data.source}: {len(dups)} row(s) repeat an earlier row exactly: {text}; each is "
            "counted once",
            RowsLeftOutWarning,
        )
        unique = data.subset(distinct)
    else:
        unique = data
    try:
        # the first fit, of every distinct row, judges the stated noise before anything is
        # decided on it (lab.sanity); a fit of fewer rows (a trimmed start) would not be fair,
        # but the fit without the gross outliers the screen finds judges it again (below)
        result = model.fit(unique, judge_noise=True)
    except NoiseRefutedError:
        _implausible_first(unique, model)
        raise
    except FitError as exc:
        if dups:
            raise FitError(f"{exc} ({len(dups)} duplicate row(s) counted once)") from None
        raise
    rule, note = None, ""
    found: list[Outlier] = []
    kept = distinct
    if opts.outliers == "auto":
        result, judged = _fit_outliers(unique, result, model)
        rule, note = judged.rule(), judged.note
        kept = distinct[judged.keep]
        found = [replace(o, index=int(distinct[o.index])) for o in judged.outliers]
        found = annotate(found, result.model, data)
        if found:  # judged again without them: gross outliers inflate the residual
            check_stated_noise(result.stated_noise, opts, data, left_out=len(found))
            where = ", ".join(o.where for o in found[:5])
            log.warning(
                "%s: %d outlier(s) left out of the fit (%s)", data.source, len(found), where
            )
            warn(
                f"{data.source}: {len(found)} outlier(s) left out of the fit ({where}); rule: "
                f"{rule}",
                RowsLeftOutWarning,
            )
    return _screened_fit(
        data, result, model, candidates, tests, kept, tuple(found), tuple(dups), rule, note
    )


def _implausible_first(data: MeasurementSet, model: _Model) -> None:
    """Where a stated noise was refuted, refuse instead a fit that is no arm, made without the
    noise (data in metres read as millimetres make every residual 1000 times smaller, and the
    noise looks refuted): the slip to name is the data's unit (:func:`check_plausible`)."""
    options = model.options.replace(noise_mm=None, noise_ppm=0.0, noise_mrad=None)
    try:
        probe = replace(model, options=options).fit(data)
    except FitError:
        return
    check_plausible(probe, model.options.accept_large, data)


def _screened_fit(
    data: MeasurementSet,
    fit: FitResult,
    model: _Model,
    candidates: Sequence[str] | None,
    tests: bool,
    kept: np.ndarray | None = None,
    found: tuple[Outlier, ...] = (),
    dups: tuple[Duplicate, ...] = (),
    rule: str | None = None,
    note: str = "",
) -> Screen:
    """The screen of ``fit``, the fit of the rows ``kept`` of ``data`` (None: all): its
    plausibility checked, the result built with what was left out (:class:`RowsCounted`, joined
    to the fit's numbers here and nowhere else), and with ``tests`` the tests' rows."""
    opts = model.options
    counted = RowsCounted(
        fitted_rows=None if kept is None or len(kept) == len(data) else kept,
        n_rows=len(data),
        outlier_list=found,
        duplicates=dups,
        outliers_mode=opts.outliers,
        outlier_rule=rule,
        outlier_note=note,
        implausible=check_plausible(fit, opts.accept_large, data),
    )
    result = replace(fit, counted=counted)
    cands = None if candidates is None else tuple(candidates)
    s = Screen(data, result, model.robot, model.effects, opts, cands, None, (), rule)
    if not tests:
        return s
    if opts.outliers == "keep" and opts.loss == "linear":  # nothing to judge: every row is tested
        return replace(s, untested_rows=np.empty(0, dtype=int))
    far, test_rule = _untested(result, s.kept, cands, opts.outliers)
    rows = s._rows()
    dist = np.linalg.norm(result.row_residuals, axis=1)
    inlier = np.ones(len(dist), dtype=bool)
    inlier[far] = False
    scale = robust_sigma(result.row_residuals[inlier])
    lines = s.kept.lines
    untested = tuple(
        Outlier(
            int(rows[i]),
            None if lines is None else int(lines[i]),
            1e3 * float(dist[i]),
            float(dist[i] / scale) if scale > 0 else float("inf"),
        )
        for i in far
    )
    return replace(s, untested_rows=far, untested=untested, test_rule=test_rule)


def screen(
    data: MeasurementSet | str | Path,
    robot: RobotDescription | str | Path | None = None,
    effects: Effects | None = None,
    *,
    options: LabOptions | None = None,
    candidates: Sequence[str] | None = None,
    tests: bool = True,
    start: Mapping[str, float] | None = None,
    fixed: Iterable[str] = (),
    **keywords: Unpack[OptionFields],
) -> Screen:
    """Decide which rows of ``data`` count for ``effects`` (default geometric) of ``robot``
    (default the seed arm), once: repeated rows counted once, gross outliers left out by the rule
    of the module docstring (``outliers="auto"``), the model fitted to the rest
    (:func:`lab.estimation.fit_rows`) and checked against the plausible bound of its parameters.

    The options (``noise_mm`` ... ``register``, or ``options=``) are :class:`lab.LabOptions`.
    ``candidates``: the effects a missing one may be (default: every registered effect), for the
    tests' rows; ``tests``: also judge the rows a diagnosis's tests leave out (it costs every
    candidate's Jacobian: :func:`lab.fit` does without). ``start``: starting values by name;
    ``fixed``: names held at their starting value."""
    opts = resolve(options, **keywords)
    return screened(
        as_measurements(data),
        robot,
        effects,
        opts,
        candidates=candidates,
        tests=tests,
        start=start,
        fixed=fixed,
    )


def screened(
    data: Screen | MeasurementSet | str | Path,
    robot: RobotDescription | str | Path | None,
    effects: Effects | None,
    options: LabOptions,
    *,
    candidates: Sequence[str] | None = None,
    tests: bool = True,
    start: Mapping[str, float] | None = None,
    fixed: Iterable[str] = (),
) -> Screen:
    """The screen an entry point works on, with its options resolved (:func:`lab.options.resolve`,
    once per call): ``lab.screen(data, ...)`` made once, or ``data`` itself when it is a
    :class:`Screen` (nothing screened again): then its options hold (an option asked otherwise is
    refused), and ``effects``, when given, are fitted to its rows (:meth:`Screen.refit`).
    ``start``, ``fixed``: starting values and held parameters of a fit of data."""
    if not isinstance(data, Screen):
        fitted = "geometric" if effects is None else effects
        model = _Model(as_robot(robot), fitted, options, start, tuple(fixed))
        return _screen(as_measurements(data), model, candidates, tests)
    s = data
    clash = [
        f"{f.name}={getattr(options, f.name)!r}"
        for f in fields(LabOptions)
        if getattr(options, f.name) != getattr(DEFAULTS, f.name)
        and getattr(options, f.name) != getattr(s.options, f.name)
    ]
    if robot is not None:
        clash.append("robot")
    if candidates is not None and (s.candidates is None or tuple(candidates) != s.candidates):
        clash.append(f"candidates={list(candidates)!r}")
    if clash:
        raise FitError(
            f"the screen given was made with other options than {', '.join(clash)}; a screen "
            "carries its robot and options: screen the data again with them (lab.screen)"
        )
    if effects is not None:
        return s.refit(effects, tests)
    if tests and not s.judged_tests:
        raise FitError(
            "the screen given did not judge the rows of the tests (lab.screen(..., tests=False)); "
            "screen the data with tests=True"
        )
    return s
