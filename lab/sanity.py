"""Cautions about what the user gave, said in one line each: numbers that a fit accepts but that
point to a slip (another arm's or another frame's held-out data, a noise in the wrong unit).

    check_validation(result, "validation.csv")   # held-out RMS far beyond the fit's
    check_stated_noise(result, noise_mm)         # a stated noise far above the residual

Each issues a :class:`lab.LabWarning` besides its log record (the command line says the log
record, on stderr), naming the file and the likely cause; the result stands.

* **Validation far beyond the fit.** A fit explains held-out poses of the same arm about as well
  as its own (a little worse: the parameters fitted, the region). Held-out data whose RMS is more
  than :data:`VALIDATION_FAR` times the fit's, and beyond :data:`VALIDATION_FAR_MM` (a model
  tested on poses outside its region, as a self-diagnosing agent does on purpose, misses by
  tenths of a millimetre), come from elsewhere: another arm, another frame (a tracker moved, a
  registration not applied), other units, or poses far outside the region calibrated.
* **A stated noise far above the residual.** With per-axis noise sigma, a fit's 3-D RMS is
  about sigma·√3·√(1 − P/(3N)), at least 0.8·sigma·√3 with three rows per parameter; a residual
  below a :data:`NOISE_FAR`-th of the stated floor cannot come from that noise. The tests that
  judge the residual against it (the diagnosis's chi-square) then find nothing: a unit slip
  (micrometres typed as millimetres) is the usual cause.
"""

from __future__ import annotations

import logging
import math

from arm import errors
from lab.errors import NoiseMismatchWarning, ValidationMismatchWarning
from lab.result import FitResult

__all__ = ["check_stated_noise", "check_validation"]

log = logging.getLogger(__name__)

VALIDATION_FAR = 10.0  # held-out RMS over the fit's RMS beyond which the data look foreign
VALIDATION_FAR_MM = 1.0  # ... and at least this (mm): a model tested off its region misses less
NOISE_FAR = 3.0  # the stated noise floor over the fit's RMS beyond which the noise looks wrong


def _say(text: str, category: type[errors.SixAxisWarning]) -> None:
    log.warning("%s", text)
    errors.warn(text, category)


def check_validation(result: FitResult, source: str) -> bool:
    """Warn where the held-out RMS of ``result`` (validated on ``source``) is more than
    :data:`VALIDATION_FAR` times its fit's and more than :data:`VALIDATION_FAR_MM`; True when it
    warned."""
    val = result.validation_rms_mm
    fit = result.rms_mm
    if val is None or not math.isfinite(val) or not fit > 0:
        return False
    if val <= max(VALIDATION_FAR * fit, VALIDATION_FAR_MM):
        return False
    _say(
        f"{source}: validation RMS {val:.4g} mm is {val / fit:.3g} times the fit's "
        f"{fit:.4g} mm: held-out data of another arm, another frame (a tracker moved, a "
        "registration not applied) or other units, or poses far outside those fitted?",
        ValidationMismatchWarning,
    )
    return True


def check_stated_noise(result: FitResult, noise_mm: float | None) -> bool:
    """Warn where the stated per-axis noise ``noise_mm`` puts the noise floor (noise·√3) more
    than :data:`NOISE_FAR` times above the fit's RMS; True when it warned."""
    if noise_mm is None or not noise_mm > 0:
        return False
    floor = noise_mm * math.sqrt(3.0)
    fit = result.rms_mm
    if not math.isfinite(fit) or floor <= NOISE_FAR * fit:
        return False
    _say(
        f"{result.source}: the stated noise {noise_mm:g} mm per axis (a floor of {floor:.4g} mm) "
        f"is {floor / fit:.3g} times the fit's RMS {fit:.4g} mm, which noise that large cannot "
        "leave: a unit slip (micrometres given as mm: --noise-mm 0.015 for 15 um)? The tests "
        "against the noise find nothing missing with it",
        NoiseMismatchWarning,
    )
    return True
