"""The instrument's standard uncertainty, per measured component of each row (docs/format.md,
the measurement CSV): what weights a row in the fit and what every statistical test of the lab
compares the residual with.

A laser tracker's noise grows with the distance from it: per axis, sigma = a + b * distance
(``--noise-mm a --noise-ppm b``; the GTS3800 of the public UR5 set states 15 um + 6 um/m). The
tracker stands at the origin of the measurement frame (of its station, with several): the distance
is that of the measured point from the origin, where the registered base puts the arm. An
orientation (a 6-DoF probe) has its own per-axis uncertainty (``--noise-mrad``).

A row's own stated uncertainties (``std_x``... columns) are what an instrument reports with each
point: the spread of its own averaging over that measurement, which can be a few micrometres
while the tracker's uncertainty (its MPE, its registration) is tens. So they raise a row's sigma
above the instrument model but never lower it: per component, sigma = max(std, model) where the
model is stated; no row then weighs more than the stated noise allows. Where no model is stated
the std is the row's sigma as given.

    noise = InstrumentNoise(mm=0.015, ppm=6.0, mrad=0.1)
    sigma = noise.sigmas(data)        # (N, 6) in m and rad; NaN where nothing is stated
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from arm.errors import NoiseError
from arm.measurements import MeasurementSet

__all__ = ["InstrumentNoise", "NoiseError"]


@dataclass(frozen=True)
class InstrumentNoise:
    """Per axis ``sigma = mm + ppm * distance`` (mm, and um per m of distance from the tracker)
    for positions; ``mrad`` per axis for orientations. ``mm`` None: not stated (then ``ppm``
    alone, if given, is the whole law)."""

    mm: float | None = None
    ppm: float = 0.0
    mrad: float | None = None

    def __post_init__(self) -> None:
        for name, v in (("--noise-mm", self.mm), ("--noise-ppm", self.ppm)):
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise NoiseError(f"{name} must be a finite number >= 0, got {v}")
        if self.mrad is not None and not (math.isfinite(self.mrad) and self.mrad > 0):
            raise NoiseError(f"--noise-mrad must be a finite number > 0, got {self.mrad}")
        if self.mm == 0 and self.ppm == 0:
            raise NoiseError("--noise-mm 0 without --noise-ppm states no noise at all")

    @property
    def positions_stated(self) -> bool:
        return self.mm is not None or self.ppm > 0

    @property
    def distance_dependent(self) -> bool:
        return self.ppm > 0

    def point_sigma(self, distance: np.ndarray | float) -> np.ndarray:
        """Per-axis sigma (m) of a point ``distance`` (m) from the tracker."""
        a = 0.0 if self.mm is None else self.mm * 1e-3
        return a + self.ppm * 1e-6 * np.asarray(distance, dtype=float)

    def text(self) -> str:
        """``15 um + 6 um/m per axis, 0.1 mrad`` for people."""
        parts = []
        if self.positions_stated:
            law = f"{1e3 * (self.mm or 0.0):g} um"
            if self.ppm:
                law += f" + {self.ppm:g} um/m of distance"
            parts.append(law + " per axis")
        if self.mrad is not None:
            parts.append(f"{self.mrad:g} mrad per axis of orientation")
        return ", ".join(parts) or "not stated"

    def sigmas(self, data: MeasurementSet) -> np.ndarray:
        """(N, 6) standard uncertainties of ``x y z rx ry rz`` (m, rad): this model's, raised to
        the row's own where it states a larger one (or the row's own where the model states none);
        NaN where neither states one or the row did not measure the component."""
        n = len(data)
        out = np.full((n, 6), np.nan)
        if self.positions_stated:
            out[:, :3] = self.point_sigma(np.linalg.norm(data.xyz, axis=1))[:, None]
        if self.mrad is not None:
            out[:, 3:] = self.mrad * 1e-3
        if data.std is not None:
            # fmax: the row's own where the model states none
            out = np.where(np.isfinite(data.std), np.fmax(data.std, out), out)
        out[~data.measured] = np.nan
        return out
