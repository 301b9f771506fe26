"""What the user gave, judged against the data: numbers that a fit accepts but that point to a
slip (another arm's or another frame's held-out data, a noise in the wrong unit).

    check_validation(result, "validation.csv")   # held-out RMS far beyond the fit's: a warning
    check_stated_noise(stated, options, data)    # a stated noise the residual refutes: refused

* **Validation far beyond the fit.** A fit explains held-out poses of the same arm about as well
  as its own (a little worse: the parameters fitted, the region). Held-out data whose RMS is more
  than :data:`VALIDATION_FAR` times the fit's, and beyond :data:`VALIDATION_FAR_MM` (a model
  tested on poses outside its region, as a self-diagnosing agent does on purpose, misses by
  tenths of a millimetre), come from elsewhere: another arm, another frame (a tracker moved, a
  registration not applied), other units, or poses far outside the region calibrated. The
  fit stands; a :class:`lab.ValidationMismatchWarning` names the file and the likely cause.
  Beyond :data:`VALIDATION_FOREIGN` (100) times the fit's, no region explains it: the held-out
  data are another frame's or other units', and a :class:`lab.ValidationMismatchError` refuses
  them (``accept_other_frame`` validates on them as they are, with the warning).
* **A stated noise that the residual refutes** is refused (:class:`lab.NoiseRefutedError`),
  before any decision is made with it. The noise decides which parameters a fit keeps (those
  whose typical-size error moves the points by less than it are dropped), which candidates a
  diagnosis tests and how, and when discovery stops: 15 mm stated for 15 um drops 30 of the
  seed arm's 33 geometric parameters, and the candidates then pick up the missing geometry (a
  wrong verdict, ``cyclic``). The residual that judges it is the one no noise has touched yet:
  the fit of every parameter the poses identify by their structure, to every distinct row,
  before the second identifiability pass uses the noise (:mod:`lab.estimation`, step 3). A
  missing effect or gross outliers only make that residual larger, so the rule can only be
  tripped by a noise stated too large. Where the screen then leaves gross outliers out
  (:mod:`lab.screening`), the fit of the rows left judges it again, the same way: its step 3
  uses no noise either (only which rows were left out may have), and a few outliers among a
  few dozen poses would otherwise hide a 10x slip (least squares spreads them over the others).
  Where the data fitted without the noise make no arm (metres read as millimetres: every
  residual 1000 times smaller, so that a right noise looks refuted), that refusal is said
  instead, naming the data's unit (:mod:`lab.plausibility`).

  The rule (:class:`lab.repeatability.StatedNoise`): the stated per-axis noise ``sigma`` is
  refuted where even ``sigma / NOISE_MARGIN`` (3) would leave a residual this small with
  probability under ``NOISE_REFUTED_P`` (1e-6), by either of two tests: the chi-square of the
  residual sum of squares (``dof`` = rows minus parameters fitted), and a sign test of how many
  poses lie above the median residual that noise would give them (half of them would; a gross
  outlier, which inflates the sum of squares, counts once there). A stated noise up to three
  times the true one (a conservative instrument specification) is therefore refuted with
  probability under 2e-6, whatever the number of poses. A 10x slip is refuted by the chi-square
  nine times in ten at 20 degrees of freedom and but for one in 10,000 from 30 on (the seed
  arm's 25 geometric parameters need ten more poses than that); where gross outliers inflate
  the sum of squares, the sign test refutes it among a few hundred poses (among a few dozen,
  least squares spreads them over every pose: the fit without those the screen leaves out
  judges again). A 1000x one (micrometres typed as millimetres) is refuted from 3 degrees of
  freedom on. In ratios, the chi-square refutes a stated noise
  more than 6.6 times the residual's at 30 degrees of freedom, 5.0 at 60, 3.7 at 300, 3.2 at
  3,000. ``benchmarks/noise_refuted.py`` measures both rates over drawn campaigns
  (``results/noise_refuted.md``). Positions and orientations (six-DoF rows) are judged apart:
  after weighting every row has the same noise (:mod:`lab.observations`), so a slip in
  ``--noise-mrad`` shows in the orientation rows alone, one in ``--noise-mm`` in the positions.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from arm import errors
from arm.measurements import COMPONENTS, MeasurementSet
from lab.errors import NoiseRefutedError, ValidationMismatchError, ValidationMismatchWarning
from lab.repeatability import StatedNoise

if TYPE_CHECKING:
    from lab.options import LabOptions
    from lab.result import FitResult

__all__ = ["check_stated_noise", "check_validation"]

log = logging.getLogger(__name__)

VALIDATION_FAR = 10.0  # held-out RMS over the fit's RMS beyond which the data look foreign
VALIDATION_FAR_MM = 1.0  # ... and at least this (mm): a model tested off its region misses less
# held-out RMS over the fit's beyond which the data are refused as another frame's or units'
# (a region far outside the fitted one misses by tens of times the fit's, not hundreds)
VALIDATION_FOREIGN = 100.0


def _say(text: str, category: type[errors.SixAxisWarning]) -> None:
    log.warning("%s", text)
    errors.warn(text, category)


def check_validation(result: FitResult, source: str, accept_other_frame: bool = False) -> bool:
    """Warn where the held-out RMS of ``result`` (validated on ``source``) is more than
    :data:`VALIDATION_FAR` times its fit's and more than :data:`VALIDATION_FAR_MM`; True when it
    warned. Beyond :data:`VALIDATION_FOREIGN` times the fit's, the held-out data are another
    frame's or other units' (a UR5 file in mm read as m: 607,195 mm), and the validation figures
    mean nothing: :class:`lab.ValidationMismatchError`, unless ``accept_other_frame``."""
    val = result.validation_rms_mm
    fit = result.rms_mm
    if val is None or not math.isfinite(val) or not fit > 0:
        return False
    if val <= max(VALIDATION_FAR * fit, VALIDATION_FAR_MM):
        return False
    text = (
        f"{source}: validation RMS {val:.4g} mm is {val / fit:.3g} times the fit's "
        f"{fit:.4g} mm: held-out data of another arm, another frame (a tracker moved, a "
        "registration not applied) or other units"
    )
    if val > VALIDATION_FOREIGN * fit and not accept_other_frame:
        raise ValidationMismatchError(
            f"{text}; refused: give the held-out file's units (--validate-length-unit, "
            "--validate-angle-unit, or a '# x, y, z in mm' line above its header), or "
            "--accept-other-frame to validate on it as it is"
        )
    _say(f"{text}, or poses far outside those fitted?", ValidationMismatchWarning)
    return True


def _stated_text(kind: StatedNoise, options: LabOptions, stds: list[str]) -> str:
    """What the user stated for ``kind``'s rows: the options and the rows' std_* columns."""
    if kind.rows == "orientations":
        said = [f"--noise-mrad {options.noise_mrad:g}"] if options.noise_mrad is not None else []
        said += [c for c in stds if c.startswith("std_r")]
    else:
        said = [f"--noise-mm {options.noise_mm:g}"] if options.noise_mm is not None else []
        if options.noise_ppm:
            said.append(f"--noise-ppm {options.noise_ppm:g}")
        said += [c for c in stds if not c.startswith("std_r")]
    return ", ".join(said)


def _without(left_out: int) -> str:
    return f", {left_out} gross outlier(s) left out" if left_out else ""


def _p_text(p: float) -> str:
    return f"p = {p:.2g}" if p >= 1e-300 else "p < 1e-300"


#: a per-axis noise typed at least this large (mm) is no laser tracker's or CMM's: micrometres?
TYPED_AS_UM = 1.0


def _likely(kind: StatedNoise, options: LabOptions) -> str:
    """The likely slip, with what to type instead."""
    if kind.rows == "orientations":
        return (
            "a unit slip (urad, or degrees, for mrad)? state the orientations' noise in mrad, "
            "or fit the positions alone (--measured x,y,z)"
        )
    mm = options.noise_mm or 0.0
    if options.noise_ppm and 1e-3 * mm < kind.sigma / 2:  # the distance's share decides it
        return (
            "--noise-ppm is in um per metre of distance from the tracker (15 um + 6 um/m: "
            "--noise-mm 0.015 --noise-ppm 6); or leave the noise out to judge with the one the "
            "residual shows"
        )
    as_um = replace(kind, sigma=kind.sigma / 1000.0)  # the value read as micrometres
    if mm >= TYPED_AS_UM and not as_um.refuted:
        return (
            f"micrometres given as mm? --noise-mm {mm / 1000:g} for {mm:g} um; or leave the "
            "noise out to judge with the one the residual shows"
        )
    return (
        "a unit slip, or another instrument's noise? state the noise this one has, or leave it "
        "out to judge with the one the residual shows"
    )


def check_stated_noise(
    stated: Sequence[StatedNoise], options: LabOptions, data: MeasurementSet, left_out: int = 0
) -> None:
    """Refuse a noise stated for the rows of ``data`` (``options``, or its std_* columns) that
    the residual of their fit refutes (``stated``, :func:`lab.repeatability.stated_noise_of`;
    ``left_out``: the gross outliers that fit left out): one line naming the option and its
    value, the noise the residual shows and the likely slip."""
    for kind in stated:
        if not kind.refuted:
            continue
        stds = []
        if data.std is not None:
            stds = [
                f"std_{c}"
                for c, col in zip(COMPONENTS, data.std.T, strict=True)
                if np.isfinite(col).any()
            ]
        said = _stated_text(kind, options, stds)
        rms = " (RMS over the rows)" if options.noise_ppm or stds else ""
        if kind.rows == "positions":
            amount = (
                f"{1e3 * kind.sigma:.4g} mm per axis{rms} is {kind.ratio:.3g} times the "
                f"{1e3 * kind.residual_sigma:.3g} mm per axis"
            )
        else:
            amount = f"it is {kind.ratio:.3g} times the orientation noise"
        raise NoiseRefutedError(
            f"{data.source}: the stated noise of the {kind.rows} ({said}) is refuted by the "
            f"residual: {amount} that the fit leaves (even a third of it would leave more: "
            f"{_p_text(kind.p_value)} over {len(kind.pose_ss)} poses, {kind.poses_above} above "
            f"the median it would give{_without(left_out)}); no "
            f"verdict, parameter or term is decided on it: {_likely(kind, options)}"
        )
