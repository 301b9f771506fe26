"""Repeatability: the scatter of repeated measurements of one pose.

Where the data measure a pose more than once (the same joint angles within ``tolerance``, the
same target and station), the differences between those measurements are the instrument's noise
plus the arm's own scatter (its repeatability): no model of the arm's geometry can explain them,
so they are the floor that a perfect model reaches. Pooled over every repeated pose, per axis:

    sigma^2 = sum over groups g, points i in g of |x_i - mean_g|^2 / (3 * sum_g (n_g - 1))

(``3 (n - groups)`` degrees of freedom). The lab uses it as the noise when none is stated
(``noise_mm``), and shows it beside a stated one.

    rep = repeatability(data)
    rep.sigma_mm, rep.groups, rep.dof   # None when no pose is repeated

A stated noise is judged against a fit's residual too (:class:`StatedNoise`): refuted where
even a :data:`NOISE_MARGIN`-th of it would leave a residual as small with probability under
:data:`NOISE_REFUTED_P`, by the sum of squares or by the count of poses above their median
(:mod:`lab.sanity` refuses it; its docstring says why).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from arm.measurements import MeasurementSet
from lab.errors import FitError

__all__ = [
    "NoiseFloor",
    "Repeatability",
    "StatedNoise",
    "noise_floor",
    "repeatability",
    "stated_noise_of",
]

#: a stated noise up to this many times the true one is a conservative statement, not a slip
NOISE_MARGIN = 3.0
#: ... and it is refuted where even a NOISE_MARGIN-th of it leaves a residual this improbable
NOISE_REFUTED_P = 1e-6
TOLERANCE = 1e-4  # rad: joint angles this close are one pose (0.006 deg)
MIN_DOF = 6  # fewer degrees of freedom than this measure no repeatability


@dataclass(frozen=True)
class Repeatability:
    """The pooled scatter of repeated poses: ``sigma_mm`` per axis (mm), from ``groups`` poses
    measured ``repeats`` times in all (``dof`` degrees of freedom), ``tolerance`` (rad)."""

    sigma_mm: float
    groups: int
    repeats: int
    dof: int
    tolerance: float

    def interval_mm(self, level: float = 0.95) -> tuple[float, float]:
        """The ``level`` confidence interval of ``sigma_mm`` (chi-square, Gaussian scatter)."""
        a = (1.0 - level) / 2.0
        lo = self.sigma_mm * math.sqrt(self.dof / stats.chi2.ppf(1.0 - a, self.dof))
        hi = self.sigma_mm * math.sqrt(self.dof / stats.chi2.ppf(a, self.dof))
        return lo, hi

    def text(self) -> str:
        lo, hi = self.interval_mm()
        return (
            f"repeatability {self.sigma_mm:.4f} mm per axis (95 % interval {lo:.4f}-{hi:.4f}) "
            f"from {self.groups} poses measured {self.repeats} times in all"
        )

    def to_dict(self) -> dict:
        lo, hi = self.interval_mm()
        return {
            "sigma_mm": self.sigma_mm,
            "interval_mm": [lo, hi],
            "groups": self.groups,
            "repeats": self.repeats,
            "dof": self.dof,
            "tolerance_rad": self.tolerance,
        }


def repeatability(data: MeasurementSet, tolerance: float = TOLERANCE) -> Repeatability | None:
    """The scatter of the poses that ``data`` measures more than once (the same q1..q6 within
    ``tolerance`` rad, and the same ``target`` and ``station`` where the data have them), or
    None when too few repeat (fewer than :data:`MIN_DOF` degrees of freedom)."""
    if not tolerance > 0:
        raise FitError(f"tolerance must be positive, got {tolerance}")
    n = len(data)
    if n < 2:
        return None
    keys = [np.floor(np.asarray(data.q, dtype=float) / tolerance + 0.5).astype(np.int64)]
    for name in ("target", "station"):
        if name in data.columns:
            keys.append(np.asarray(data.columns[name], dtype=float).astype(np.int64)[:, None])
    _, group, counts = np.unique(np.hstack(keys), axis=0, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    repeated = counts[group] > 1
    if not repeated.any():
        return None
    g = group[repeated]
    x = np.asarray(data.xyz, dtype=float)[repeated]
    size = np.maximum(np.bincount(g, minlength=len(counts)), 1).astype(float)
    sums = np.stack([np.bincount(g, x[:, a], minlength=len(counts)) for a in range(3)], axis=1)
    mean = sums / size[:, None]
    ss = float(np.sum((x - mean[g]) ** 2))
    groups = int(np.count_nonzero(counts > 1))
    repeats = int(repeated.sum())
    dof = 3 * (repeats - groups)
    if dof < MIN_DOF:
        return None
    return Repeatability(1e3 * math.sqrt(ss / dof), groups, repeats, dof, tolerance)


@dataclass(frozen=True)
class NoiseFloor:
    """The per-axis noise the lab's tests use (``noise_mm``, mm): the one stated
    (``source`` ``"stated"``), else the repeatability of repeated poses (``"repeated poses"``),
    else none; and the repeatability wherever it was measured."""

    noise_mm: float | None
    source: str | None
    repeatability: Repeatability | None

    def text(self) -> str | None:
        """A sentence on the noise floor, or None without one."""
        rep = self.repeatability
        if self.source == "repeated poses" and rep is not None:
            return f"noise from repeated poses: {rep.text()}; used as the noise floor"
        if rep is not None and self.noise_mm is not None:
            return f"stated noise {self.noise_mm:g} mm per axis; {rep.text()}"
        return None


def noise_like(e: np.ndarray, alpha: float = 0.01) -> bool:
    """Whether no pose of the residual ``e`` (3N) lies beyond the 3-D radius that Gaussian noise
    of the residual's own per-axis scale exceeds at one of N poses with probability ``alpha``
    (Bonferroni): a gross miss is not noise."""
    r = np.asarray(e, dtype=float).reshape(-1, 3)
    if not len(r):
        return True
    s2 = float(np.sum(r**2)) / r.size
    radius2 = float(stats.chi2.isf(alpha / len(r), 3))
    return bool(np.max(np.sum(r**2, axis=1)) <= radius2 * s2)


def noise_p_value(rss: float, dof: int, floor: NoiseFloor) -> float | None:
    """The p-value of a residual sum of squares ``rss`` (m^2) with ``dof`` degrees of freedom
    being noise of the floor: chi-square against a stated noise (known), F against the
    repeatability (itself estimated, with its own degrees of freedom); None without a floor."""
    if floor.noise_mm is None:
        return None
    s2 = (1e-3 * floor.noise_mm) ** 2
    dof = max(dof, 1)
    if floor.source == "repeated poses" and floor.repeatability is not None:
        return float(stats.f.sf(rss / dof / s2, dof, floor.repeatability.dof))
    return float(stats.chi2.sf(rss / s2, dof))


def noise_floor(stated_mm: float | None, data: MeasurementSet) -> NoiseFloor:
    """The noise the tests use: ``stated_mm`` if given, else the repeatability of ``data``."""
    rep = repeatability(data)
    if stated_mm is not None:
        return NoiseFloor(stated_mm, "stated", rep)
    if rep is not None:
        return NoiseFloor(rep.sigma_mm, "repeated poses", rep)
    return NoiseFloor(None, None, None)


def implied_noise_text(implied_mm: float, stated_mm: float, source: str | None) -> str:
    """``the residual left is noise of 0.0159 mm per axis, 6 % above the stated 0.015 mm``."""
    what = "the noise from repeated poses" if source == "repeated poses" else "the stated"
    pct = 100.0 * (implied_mm / stated_mm - 1.0)
    return (
        f"no structure is left: the residual is noise of {implied_mm:.4g} mm per axis, "
        f"{pct:.0f} % above {what} {stated_mm:.4g} mm"
    )


@dataclass(frozen=True)
class StatedNoise:
    """What a fit's residual says of a stated noise, for one kind of row (``rows``:
    ``positions`` or ``orientations``): ``sigma``, the stated per-row noise after weighting (m:
    the rows' common noise, :mod:`lab.observations`); ``rss`` (m^2) and ``dof``, the residual
    sum of squares of those rows and its degrees of freedom in the fit of every parameter the
    poses identify by their structure, before the noise decided which to keep (the parameters'
    share of the rows: ``rows - parameters x rows / all rows``); ``pose_ss`` and ``pose_rows``,
    each pose's sum of squares and rows of that kind.

    Two tests of "the noise is at least a :data:`NOISE_MARGIN`-th of the stated one", each at
    :data:`NOISE_REFUTED_P`: the **chi-square** of the sum of squares, and a **sign test** of
    how many poses lie above the median that noise would give them (chi-square of their rows,
    shrunk by the parameters' share); it would give half of them, and gross outliers, which
    inflate the sum of squares, count only once each there."""

    rows: str
    sigma: float
    rss: float
    dof: float
    pose_ss: np.ndarray = field(repr=False, compare=False)
    pose_rows: np.ndarray = field(repr=False, compare=False)

    @property
    def residual_sigma(self) -> float:
        """The per-row noise the residual shows (m): at most the true noise's, up to chance,
        where the model misses nothing; more where it does."""
        return math.sqrt(self.rss / self.dof) if self.dof > 0 else math.nan

    @property
    def ratio(self) -> float:
        """The stated noise over the residual's."""
        r = self.residual_sigma
        return self.sigma / r if r > 0 else math.inf

    @property
    def chi2_p_value(self) -> float:
        """The probability that a noise of a :data:`NOISE_MARGIN`-th of the stated one leaves
        a residual sum of squares as small as this one (chi-square, ``dof``)."""
        if not self.dof > 0 or not self.sigma > 0:
            return 1.0
        return float(stats.chi2.cdf(self.rss / (self.sigma / NOISE_MARGIN) ** 2, self.dof))

    @property
    def poses_above(self) -> int:
        """The poses above the median residual that a :data:`NOISE_MARGIN`-th of the stated
        noise gives them."""
        n = len(self.pose_ss)
        if not n:
            return 0
        share = max(self.dof, 0.0) / max(float(np.sum(self.pose_rows)), 1.0)
        median = (self.sigma / NOISE_MARGIN) ** 2 * share * stats.chi2.median(self.pose_rows)
        return int(np.count_nonzero(self.pose_ss > median))

    @property
    def sign_p_value(self) -> float:
        """The probability of so few poses above that median (binomial, one half)."""
        n = len(self.pose_ss)
        if not n or not self.dof > 0 or not self.sigma > 0:
            return 1.0
        return float(stats.binom.cdf(self.poses_above, n, 0.5))

    @property
    def p_value(self) -> float:
        """The smaller of the two tests' p-values."""
        return min(self.chi2_p_value, self.sign_p_value)

    @property
    def refuted(self) -> bool:
        """Whether the residual refutes the stated noise: either test below
        :data:`NOISE_REFUTED_P` (so a noise stated up to :data:`NOISE_MARGIN` times the true one
        is refuted with probability under twice that)."""
        return self.p_value < NOISE_REFUTED_P

    def to_dict(self) -> dict:
        return {
            "rows": self.rows,
            "stated_sigma": self.sigma,
            "residual_sigma": self.residual_sigma,
            "dof": self.dof,
            "poses": len(self.pose_ss),
            "poses_above": self.poses_above,
            "p_value": self.p_value,
            "refuted": self.refuted,
        }


def stated_noise_of(
    residuals: np.ndarray, measured: np.ndarray, sigma: float | None, n_free: int
) -> tuple[StatedNoise, ...]:
    """The evidence on a stated noise ``sigma`` (m, every row's after weighting; None: none
    stated) from a fit's weighted residual rows ``residuals`` (N, k; ``measured`` (N, k) marks
    the rows measured) with ``n_free`` parameters fitted: one :class:`StatedNoise` per kind of
    row measured (positions; orientations too in six-DoF rows); none where no noise is stated."""
    if sigma is None:
        return ()
    measured = np.asarray(measured, dtype=bool).reshape(len(measured), -1)
    r = np.asarray(residuals, dtype=float).reshape(measured.shape)
    total = int(measured.sum())
    if total == 0:
        return ()
    out = []
    kinds = [("positions", slice(0, 3))]
    if measured.shape[1] == 6:
        kinds.append(("orientations", slice(3, 6)))
    for name, cols in kinds:
        m = measured[:, cols]
        rows = int(m.sum())
        if not rows:
            continue
        per_pose = m.sum(axis=1)
        seen = per_pose > 0
        ss = np.sum(np.where(m, r[:, cols], 0.0) ** 2, axis=1)
        dof = rows - n_free * rows / total
        out.append(StatedNoise(name, float(sigma), float(ss.sum()), dof, ss[seen], per_pose[seen]))
    return tuple(out)
