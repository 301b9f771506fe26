"""One fold of a blocked check: a model fitted on every row but a block, and its residuals on
that block. :func:`lab.transfer.blocked_folds` (sessions, stations or joint regions left out in
turn) and :mod:`lab.lumped_choice` (a lumped compliance's groups judged on blocks of poses) are
two uses of it; :mod:`lab.prediction` reads the folds' own fits as well as their errors."""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from arm.measurements import MeasurementSet
from lab.errors import FitError
from lab.result import FitResult

log = logging.getLogger(__name__)


class Fold(NamedTuple):
    """The fit of every row but a block (``result``) and its 3-D residuals (m, (n, 3)) on the
    block."""

    result: FitResult
    residuals: np.ndarray

    @property
    def rms(self) -> float:
        """The 3-D RMS (m) of the block's residuals."""
        return math.sqrt(float(np.mean(np.sum(self.residuals**2, axis=1))))


def fold(
    data: MeasurementSet,
    held: np.ndarray,
    fit: Callable[[MeasurementSet], FitResult],
    *,
    register: bool,
    ignore: type[Warning] = Warning,
) -> Fold | None:
    """``fit`` of the rows of ``data`` but ``held`` (a boolean mask or indices), and its
    residuals on the rows ``held``; None where the fit or the prediction is refused
    (:class:`lab.errors.FitError`). ``register``: a held-out station's frame is placed on the
    held rows themselves (every model alike), as a blocked check of stations needs; else the
    fitted stations are used as they are. Warnings of the kind ``ignore`` are silenced: a fold is
    a means, its warnings are not the user's."""
    mask = np.zeros(len(data), dtype=bool)
    mask[held] = True
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ignore)
            res = fit(data.subset(np.flatnonzero(~mask)))
            v = res.validate(data.subset(np.flatnonzero(mask)), register_on_rows=register)
    except FitError as exc:
        log.info("blocked fold of %d rows: %s", int(mask.sum()), exc)
        return None
    if v.validation_residuals is None:  # validate always sets them; without, no prediction
        return None
    return Fold(res, v.validation_residuals)
