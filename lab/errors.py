"""The lab's errors and its cautions.

Every error of the lab derives from :class:`LabError` (a :class:`arm.errors.SixAxisError`), each
keeping its built-in parent: :class:`FitError` is what every lab function raises for input it
cannot use (too few poses, an option out of range, an effect the data cannot support); the message
says why and where. :class:`ExportError` and :class:`CompensationError` are the export's and the
compensation's (re-exported by :mod:`lab.export`).
The cautions are warnings (:func:`arm.errors.warn`), issued besides the log record, so that a
user can filter them, make them errors or assert them:

    import warnings, lab
    with warnings.catch_warnings():
        warnings.simplefilter("error", lab.PoorPoseSetWarning)   # refuse a poor pose set
        lab.fit(data, "seed", "geometric")
"""

from __future__ import annotations

from arm.errors import SixAxisError, SixAxisWarning

__all__ = [
    "CompensationError",
    "ContaminatedError",
    "ExportError",
    "FitError",
    "ImplausibleAcceptedWarning",
    "LabError",
    "LabWarning",
    "NoiseRefutedError",
    "OrientationNotFittedWarning",
    "OutOfDomainWarning",
    "PoorPoseSetWarning",
    "RegistrationError",
    "ReportError",
    "RowsLeftOutWarning",
    "ToolPlacedWarning",
    "UncertaintyError",
    "UnknownOptionError",
    "UpdateWarning",
    "ValidationMismatchError",
    "ValidationMismatchWarning",
]


class LabError(SixAxisError):
    """Base of the lab's errors: ``except lab.LabError`` catches every one of them."""


class FitError(LabError, ValueError):
    """A fit that cannot be done as asked: too few poses, bad options; the message says why."""


class ContaminatedError(FitError):
    """More of the poses are gross outliers than a calibration allows (the screen's stated
    fraction, :data:`lab.screening.MAX_OUTLIER_FRACTION`): the fit is refused rather than called
    a calibration. ``outliers="keep"`` fits every pose (with a robust loss, they weigh less)."""


class NoiseRefutedError(FitError):
    """The stated noise is far above what the fit's residual allows
    (:func:`lab.sanity.check_stated_noise`): a unit slip, most likely. Nothing is decided on
    it: the noise decides which parameters are fitted, the verdict and when discovery stops."""


class RegistrationError(FitError):
    """A station the calibration has not seen cannot be placed: no reference points measured
    there, too few, or on one line (:func:`lab.registration.register_station`)."""


class UnknownOptionError(LabError, TypeError):
    """A lab entry point called with a keyword that is not one of the lab's options."""


class ExportError(LabError, ValueError):
    """The calibrated arm cannot be exported faithfully; nothing was written."""


class CompensationError(LabError, ValueError):
    """Bad compensation input: the message names the file, line, column or effect."""


class ReportError(LabError, ValueError):
    """A part of a report asked of a run that has none (the nominal arm's fit or diagnosis)."""


class ValidationMismatchError(FitError):
    """Held-out data fit more than :data:`lab.sanity.VALIDATION_FOREIGN` times worse than the
    fitted data (:func:`lab.sanity.check_validation`): another frame or other units, so that the
    validation figures would mean nothing; refused unless ``accept_other_frame``."""


class LabWarning(SixAxisWarning):
    """A caution from the lab: its result stands, but read it with this in mind."""


class PoorPoseSetWarning(LabWarning):
    """The poses determine the identifiable parameters poorly (a large condition number)."""


class RowsLeftOutWarning(LabWarning):
    """Rows of the data were not fitted: exact duplicates (counted once) or gross outliers."""


class ImplausibleAcceptedWarning(LabWarning):
    """Identified values beyond the plausible bound of their kind were kept (``accept_large``)."""


class OrientationNotFittedWarning(LabWarning):
    """The data measured orientations, but their uncertainty is stated nowhere: without it they
    cannot be weighed against the positions, and the positions alone were fitted."""


class ValidationMismatchWarning(LabWarning):
    """Held-out data fit far worse than the fitted data (:func:`lab.sanity.check_validation`):
    another arm, another frame or other units, most likely."""


class OutOfDomainWarning(LabWarning):
    """Data outside the domain a model was identified on (lab.domain)."""


class ToolPlacedWarning(OutOfDomainWarning):
    """A tool offset the fit could not identify, placed on validation data with a new station's
    base (lab.domain, :meth:`lab.result.FitResult.validate`)."""


class UncertaintyError(FitError):
    """A calibration's ``[uncertainty]`` that cannot be used: the message names the file and the
    key."""


class UpdateWarning(LabWarning):
    """An update that could not free every parameter it frees: too few poses (named)."""
