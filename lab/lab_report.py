"""The lab's report as a document: what it holds (:class:`LabReport`, one :class:`ModelRun` per
model compared, the :class:`Sensitivity` of the final model). :func:`lab.report.build_report`
fills it, :mod:`lab.report_html` renders it as one self-contained HTML page
(``lab.report_html.write(report, "report.html")``); nothing here fits, plots or renders.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from arm.description import RobotDescription
from arm.measurements import MeasurementSet
from lab.diagnosis import Diagnosis
from lab.errors import ReportError
from lab.result import Duplicate, FitResult, Outlier

__all__ = ["LabReport", "ModelRun", "Sensitivity"]


@dataclass(frozen=True)
class Sensitivity:
    """How far an error of each parameter moves the tool point, RMS over the poses.

    ``per_unit``: m of tool point per SI unit of the parameter (a length: mm per mm; an angle:
    mm per mrad; the same number); ``typical_mm``: mm for an error of the parameter's typical size
    (the upper end of its effect's ``typical`` range); ``identified_mm``: mm for the error
    identified (``p`` minus nominal; zero for a parameter held at nominal)."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    per_unit: np.ndarray
    typical_mm: np.ndarray
    identified_mm: np.ndarray

    def ranked(self, by: str = "typical_mm") -> list[int]:
        v = getattr(self, by)
        return [int(k) for k in np.argsort(-v, kind="stable")]


@dataclass
class ModelRun:
    """One model of the comparison: its residuals on the fitted and held-out poses; the fit and
    its diagnosis (both None for the nominal arm)."""

    label: str
    residuals: np.ndarray
    validation_residuals: np.ndarray | None = None
    fit: FitResult | None = None
    diagnosis: Diagnosis | None = None
    n_fitted: int = 0

    @staticmethod
    def _rms(r: np.ndarray | None) -> float | None:
        if r is None or not len(r):
            return None
        return 1e3 * float(np.sqrt(np.mean(np.sum(r**2, axis=1))))

    @property
    def fitted(self) -> FitResult:
        """The fit: every run but the nominal arm's has one."""
        if self.fit is None:
            raise ReportError(f"{self.label}: the nominal arm has no fit")
        return self.fit

    @property
    def diagnosed(self) -> Diagnosis:
        """The diagnosis: every run but the nominal arm's has one."""
        if self.diagnosis is None:
            raise ReportError(f"{self.label}: the nominal arm has no diagnosis")
        return self.diagnosis

    @property
    def rms_mm(self) -> float:
        return 1e3 * float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))

    @property
    def max_mm(self) -> float:
        return 1e3 * float(np.linalg.norm(self.residuals, axis=1).max())

    @property
    def validation_rms_mm(self) -> float | None:
        return self._rms(self.validation_residuals)

    @property
    def validation_median_mm(self) -> float | None:
        r = self.validation_residuals
        return None if r is None else 1e3 * float(np.median(np.linalg.norm(r, axis=1)))


@dataclass
class LabReport:
    """Everything the report shows: :func:`lab.report_html.render` renders it as HTML,
    :func:`lab.report_html.write` writes that atomically."""

    data: MeasurementSet
    validation: MeasurementSet | None
    robot: RobotDescription
    noise_mm: float | None
    runs: list[ModelRun]
    sensitivity: Sensitivity
    title: str = "Calibration report"
    command: str | None = None
    figures: dict[str, bytes] = field(default_factory=dict, repr=False)
    # the rows of the file every model leaves out (lab.screening), and the rule applied
    outliers: list[Outlier] = field(default_factory=list)
    duplicates: list[Duplicate] = field(default_factory=list)
    outlier_rule: str | None = None
    n_rows: int | None = None

    @property
    def final(self) -> ModelRun:
        return self.runs[-1]

    @property
    def noise_floor_mm(self) -> float | None:
        return None if self.noise_mm is None else self.noise_mm * math.sqrt(3.0)
