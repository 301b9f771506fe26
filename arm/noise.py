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

from dataclasses import dataclass
from typing import Any

import numpy as np

from arm.constraints import NON_NEGATIVE, Quantity, check, refuse
from arm.errors import NoiseError
from arm.measurements import MeasurementSet

__all__ = [
    "NOISE_MM",
    "NOISE_MRAD",
    "NOISE_PPM",
    "InstrumentNoise",
    "NoiseError",
    "noise_law_problems",
]


def _flag(key: str) -> str:
    return "--" + key.replace("_", "-")


#: the instrument's noise, declared once for every place that takes it (the lab's options and
#: command line, the simulated tracker of the env and of ``collect``): >= 0 each; where it is a
#: stated uncertainty that weighs rows (the lab), :func:`noise_law_problems` adds that a law of
#: zero states none. A simulator draws no noise from 0 (a perfect instrument).
NOISE_MM = Quantity(NON_NEGATIVE, "mm", "The instrument's per-axis standard uncertainty")
NOISE_PPM = Quantity(
    NON_NEGATIVE,
    "um per m",
    "How the per-axis standard uncertainty grows with the distance from the tracker (a GTS3800: "
    "6): sigma = --noise-mm + --noise-ppm x distance, the tracker at the origin of the "
    "measurement frame (of each station)",
)
NOISE_MRAD = Quantity(
    NON_NEGATIVE, "mrad", "The per-axis standard uncertainty of a measured orientation"
)


def noise_law_problems(
    mm: float | None, ppm: float = 0.0, mrad: float | None = None, name: Any = str
) -> list[str]:
    """What is wrong with a stated instrument model (every problem, each naming its option by
    ``name(key)``, e.g. as a flag): each value out of its declared range, then a law that weighs
    a row infinitely (``noise_mm`` 0 without a ``noise_ppm`` term, ``noise_mrad`` 0)."""
    quantities = {"noise_mm": NOISE_MM, "noise_ppm": NOISE_PPM, "noise_mrad": NOISE_MRAD}
    values = {"noise_mm": mm, "noise_ppm": ppm, "noise_mrad": mrad}
    rules = {k: ([q.rule], k != "noise_ppm") for k, q in quantities.items()}
    found = check(values, rules, name=name)
    if found:
        return found
    if mm == 0 and not ppm:
        found.append(
            f"{name('noise_mm')} 0 without {name('noise_ppm')} states no noise at all (rows would "
            "weigh infinitely): give a distance term, or a noise > 0"
        )
    if mrad == 0:
        found.append(f"{name('noise_mrad')} must be positive where it weighs rows, got 0")
    return found


@dataclass(frozen=True)
class InstrumentNoise:
    """Per axis ``sigma = mm + ppm * distance`` (mm, and um per m of distance from the tracker)
    for positions; ``mrad`` per axis for orientations. ``mm`` None: not stated (then ``ppm``
    alone, if given, is the whole law). The values' rules: :data:`NOISE_MM`, :data:`NOISE_PPM`,
    :data:`NOISE_MRAD` and :func:`noise_law_problems`."""

    mm: float | None = None
    ppm: float = 0.0
    mrad: float | None = None

    def __post_init__(self) -> None:
        refuse(noise_law_problems(self.mm, self.ppm, self.mrad, _flag), NoiseError)

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
