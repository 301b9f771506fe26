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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from arm.measurements import MeasurementSet

__all__ = ["NoiseFloor", "Repeatability", "noise_floor", "repeatability"]

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
        raise ValueError(f"tolerance must be positive, got {tolerance}")
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
