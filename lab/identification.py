"""Identification: fit an error model's parameters to measured tool points.

    result = fit(data, robot, "geometric,compliance", validate=other)
    print(result.table())                    # the paper's Table 3, with standard errors
    result.to_dict()                         # the JSON of docs/format.md

    s = lab.screen(data, robot, "geometric")  # which rows count, once
    result = fit(s, validate=other)           # the screen's fit: nothing screened again

:func:`fit` is the lab's front door to one identification. The work is done by the modules it
names, each one concern:

* :mod:`lab.screening`: which rows count (repeated rows once, gross outliers left out by a stated
  rule), deciding once and fitting the rows that count;
* :mod:`lab.estimation`: the fit of the rows given: registration (:mod:`lab.registration`),
  identifiability (:mod:`lab.identifiability`), Levenberg-Marquardt (:mod:`lab.solver`),
  standard errors, the plausible bound of the parameters (:mod:`lab.plausibility`);
* :mod:`lab.result`: :class:`FitResult`, the result as frozen data, said through :mod:`lab.text`;
* :mod:`lab.options`: :class:`LabOptions`, the options every lab entry point shares.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Unpack

from arm.description import RobotDescription
from arm.effects import Effect
from arm.measurements import MeasurementSet
from lab.errors import FitError
from lab.options import LabOptions, OptionFields, resolve
from lab.result import FitResult, held_out
from lab.sanity import check_validation
from lab.screening import Screen, screened

__all__ = ["fit"]

log = logging.getLogger(__name__)


def fit(
    data: Screen | MeasurementSet | str | Path,
    robot: RobotDescription | str | Path | None = None,
    effects: str | Sequence[str | Effect] | None = None,
    *,
    options: LabOptions | None = None,
    validate: MeasurementSet | str | Path | None = None,
    references: MeasurementSet | str | Path | None = None,
    start: Mapping[str, float] | None = None,
    fixed: Iterable[str] = (),
    extrapolate: bool = False,
    accept_other_frame: bool = False,
    **keywords: Unpack[OptionFields],
) -> FitResult:
    """Identify ``effects`` (default geometric) of ``robot`` (default the seed arm) from
    ``data``: a measurement set (or its file), screened once (:func:`lab.screen`), or a
    :class:`lab.Screen` made before (its fit, nothing screened again; ``effects`` given: that
    model fitted to the screen's rows).

    The options (``noise_mm`` ... ``register``, or ``options=``) are :class:`lab.LabOptions`:
    ``noise_mm`` (:data:`arm.noise.NOISE_MM`), if known (else estimated from the residual); ``loss`` ``linear`` (Levenberg-Marquardt), ``huber`` or ``soft_l1``;
    ``outliers`` ``auto`` leaves gross outliers out by the rule of :mod:`lab.screening` (the
    result names them, ``result.outlier_list``), ``keep`` fits every pose (rows repeated exactly
    are counted once either way, ``result.duplicates``); ``accept_large`` keeps a model whose
    identified parameters exceed the plausible bound of their kind (:mod:`lab.plausibility`;
    listed in ``result.implausible``) instead of refusing it; ``solver``, ``f_scale_mm``,
    ``max_evaluations``, ``register``: see :class:`lab.LabOptions`.

    ``validate``: held-out measurements for validation RMS and median; where they lie outside
    the fitted domain a warning says so, and terms whose form does not repeat over what was
    fitted are left out of those rows unless ``extrapolate`` (:mod:`lab.domain`); held-out data
    more than 100 times worse than the fit's are refused as another frame's or other units'
    (:func:`lab.sanity.check_validation`) unless ``accept_other_frame``; ``references``: poses
    measured at a station of the held-out data that the fit has not seen, which register it
    (:meth:`lab.FitResult.validate`). ``start``:
    starting values by name; ``fixed``: names to hold at their starting value.
    """
    opts = resolve(options, **keywords)
    if isinstance(data, Screen):
        if start or tuple(fixed):
            raise FitError("start and fixed apply to a fit of data, not of a screen made before")
    s = screened(data, robot, effects, opts, tests=False, start=start, fixed=fixed)
    result = s.fit
    held = held_out(validate, references)
    if held is not None:
        result = result.validate(held[0], extrapolate=extrapolate, references=held[1])
        check_validation(result, held[0].source, accept_other_frame)
    log.info("%s", result.summary())
    return result
