"""The result of an identification, as frozen data: :class:`FitResult`.

    result = lab.fit(data, "seed", "geometric,compliance")
    result["c2"], result.standard_errors()["c2"]     # by name, SI units
    result.rms_mm, result.validation_rms_mm          # the ``*_mm`` properties are for people
    result.to_dict()                                 # the JSON of docs/format.md
    print(result.table())                            # text through lab.text

The numbers are computed by :mod:`lab.estimation` (the fit of the rows given) and
:mod:`lab.screening` (which rows count); this module holds them and says them.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from arm.description import RobotDescription
from arm.effect_api import EffectError, ModelInputs
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet, as_measurements
from arm.params import ROW_FAMILIES, parameter_unit, parse_parameter_name
from lab.blocks import Blocks
from lab.domain import (
    Domain,
    Excursion,
    out_of_domain,
    tool_placed_text,
    warn_out_of_domain,
    warn_tool_placed,
)
from lab.errors import FitError, RegistrationError
from lab.identifiability import Identifiability
from lab.observations import Observations
from lab.plausibility import Implausible
from lab.registration import (
    StationRegistration,
    register_station,
    tool_columns,
    tool_indices,
)
from lab.repeatability import StatedNoise
from lab.solver import OUTLIER_RADIUS, robust_sigma
from lab.text import left_out_lines, parameter_cells

__all__ = ["SCHEMA_VERSION", "Duplicate", "FitResult", "Outlier", "RowsCounted"]

SCHEMA_VERSION = 1
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Outlier:
    """One pose left out: its index in the data given, its line in the file (if read from one),
    its 3-D residual and how many robust standard deviations that is."""

    index: int
    line: int | None
    residual_mm: float
    sigmas: float
    note: str | None = None  # why the model could not say where it is, when an effect knows

    @property
    def where(self) -> str:
        return f"line {self.line}" if self.line is not None else f"row {self.index + 1}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "row": self.index + 1,
            "line": self.line,
            "residual_mm": self.residual_mm,
            "sigmas": self.sigmas,
            "note": self.note,
        }


@dataclass(frozen=True)
class Duplicate:
    """A row equal in every column to an earlier one (``first``), counted once."""

    index: int
    first: int
    line: int | None
    first_line: int | None

    @property
    def where(self) -> str:
        if self.line is not None and self.first_line is not None:
            return f"line {self.line} repeats line {self.first_line}"
        return f"row {self.index + 1} repeats row {self.first + 1}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "row": self.index + 1,
            "line": self.line,
            "first_row": self.first + 1,
            "first_line": self.first_line,
        }


@dataclass(frozen=True)
class RowsCounted:
    """What :mod:`lab.screening` decided about the rows of a fit, and the plausibility check of
    its parameters: the facts a fit of given rows cannot know, kept apart from its numbers and
    joined to them once, by the screen that decided them.

    ``fitted_rows``: the indices of the poses fitted in the data given (None: all, in order);
    ``n_rows``: how many rows those data had; ``outlier_list``, ``duplicates``: the poses left out
    and the rows counted once; ``outliers_mode``: the option they were judged by;
    ``outlier_rule``: the rule as applied (None: not screened); ``outlier_note``: why nothing was
    left out when the rule could not be applied or would leave out too much; ``implausible``:
    parameters beyond the plausible bound of their kind, accepted (``accept_large=True``)."""

    fitted_rows: np.ndarray | None = field(default=None, repr=False)
    n_rows: int | None = None
    outlier_list: tuple[Outlier, ...] = ()
    duplicates: tuple[Duplicate, ...] = ()
    outliers_mode: str = "keep"
    outlier_rule: str | None = None
    outlier_note: str = ""
    implausible: tuple[Implausible, ...] = ()


@dataclass(frozen=True)
class FitResult:
    """An identified model: parameters with names and standard errors, residuals, metrics.

    ``params`` is the full vector (fixed parameters at nominal) laid out by ``model.layout``;
    ``std`` its standard errors (NaN where fixed); ``residuals`` (N, 3) predicted minus measured
    points. Lengths in m and angles in rad throughout; the ``*_mm`` properties are for people.

    Beyond one 3-D point (:mod:`lab.observations`): ``observations``, the rows the fit compared
    with; ``weighted_rows`` (N, k), its weighted residual rows where they are not the points
    (weights, orientations), else None (:attr:`row_residuals` gives either). With a ``--validate`` set,
    ``validation_registered`` names the stations the fit had not seen, whose bases were
    registered rigidly on the validation points.
    """

    model: ErrorModel
    params: np.ndarray
    std: np.ndarray
    identifiable: np.ndarray
    residuals: np.ndarray
    identifiability: Identifiability
    loss: str
    iterations: int
    evaluations: int
    sigma: float
    initial_rms: float
    inputs: ModelInputs = field(repr=False)
    weights: np.ndarray | None = field(default=None, repr=False)
    validation_residuals: np.ndarray | None = field(default=None, repr=False)
    source: str = "<memory>"
    # what the fit left out of the data given and its plausibility (lab.screening)
    counted: RowsCounted = RowsCounted()
    weighted_rows: np.ndarray | None = field(default=None, repr=False)
    observations: Observations | None = field(default=None, repr=False)
    validation_rotation: np.ndarray | None = field(default=None, repr=False)
    validation_registered: tuple[int, ...] = ()
    # each of those stations' registration on its reference points, with its residual
    validation_registrations: tuple[StationRegistration, ...] = ()
    # tool-point parameters the fit had not identified, placed with those stations' bases on the
    # validation points: {name: its change from the fit's value (m)}
    validation_tool_placed: dict[str, float] = field(default_factory=dict)
    # the validation data outside the model's domain (lab.domain), and the parameters whose
    # terms were left out of the rows they do not hold on (none with extrapolate=True)
    validation_excursions: tuple[Excursion, ...] = ()
    validation_dropped: tuple[str, ...] = ()
    # what the residual says of the stated noise, before the noise was used (lab.sanity): one
    # per kind of row whose noise was stated (positions, orientations); () where none was
    stated_noise: tuple[StatedNoise, ...] = ()
    # the fit again with some parameters held at zero, on the same rows: the model without
    # those terms (lab.estimation sets it; None: the terms' parameters are zeroed instead)
    refit: Callable[[Sequence[str]], np.ndarray] | None = field(
        default=None, repr=False, compare=False
    )
    # the parameters' covariance and the spread between sessions where the fit states them
    # itself (an update's posterior: lab.update), as a calibration file's [uncertainty] table
    # (lab.uncertainty); None: an export measures them
    uncertainty: Mapping[str, Any] | None = field(default=None, repr=False, compare=False)
    # where the model was identified, where it is not the fitted rows' alone (an update: the
    # calibration's domain and the new poses'); None: the fitted rows' (Domain.of(inputs))
    fitted_domain: Domain | None = field(default=None, repr=False, compare=False)

    # -- the rows counted (lab.screening) ---------------------------------------------------------
    @property
    def fitted_rows(self) -> np.ndarray | None:
        return self.counted.fitted_rows

    @property
    def n_rows(self) -> int | None:
        return self.counted.n_rows

    @property
    def outlier_list(self) -> tuple[Outlier, ...]:
        return self.counted.outlier_list

    @property
    def duplicates(self) -> tuple[Duplicate, ...]:
        return self.counted.duplicates

    @property
    def outliers_mode(self) -> str:
        return self.counted.outliers_mode

    @property
    def outlier_rule(self) -> str | None:
        return self.counted.outlier_rule

    @property
    def outlier_note(self) -> str:
        return self.counted.outlier_note

    @property
    def implausible(self) -> tuple[Implausible, ...]:
        return self.counted.implausible

    # -- metrics ---------------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return self.model.layout.names

    @property
    def effects(self) -> list[str]:
        return self.model.effect_names

    @property
    def n_points(self) -> int:
        return int(self.residuals.shape[0])

    @property
    def rank(self) -> int:
        return int(self.identifiable.sum())

    @property
    def n_parameters(self) -> int:
        return len(self.params)

    @property
    def rms(self) -> float:
        """3-D RMS of the fit residuals (m)."""
        return rms(self.residuals)

    @property
    def rms_mm(self) -> float:
        return 1e3 * self.rms

    @property
    def max_mm(self) -> float:
        return 1e3 * float(np.linalg.norm(self.residuals, axis=1).max())

    @property
    def validation_rms_mm(self) -> float | None:
        r = self.validation_residuals
        return None if r is None else 1e3 * rms(r)

    @property
    def validation_median_mm(self) -> float | None:
        r = self.validation_residuals
        return None if r is None else 1e3 * float(np.median(np.linalg.norm(r, axis=1)))

    @property
    def sigma_mm(self) -> float:
        """The per-axis noise the residual implies, sqrt(sum r^2 / (3N - rank)), in mm."""
        return 1e3 * self.sigma

    @property
    def condition_number(self) -> float:
        return self.identifiability.condition_number

    @property
    def unidentifiable(self) -> list[str]:
        return self.identifiability.unidentifiable

    @property
    def jacobian(self) -> np.ndarray:
        """The identification Jacobian (N, 3, P) at the solution, computed on demand (it is not
        kept: 200,000 poses of geometric + compliance make 190 MB); of the weighted rows (N, k,
        P) where they are not the points (:attr:`row_residuals`)."""
        if self.weighted_rows is not None and self.observations is not None:
            J = self.observations.rows(self.model, self.inputs, self.params)[1]
            assert J is not None
            return J
        _, J = self.model.predict(self.inputs, self.params, jacobian=True)
        return J

    @property
    def row_residuals(self) -> np.ndarray:
        """The fit's residual rows (N, k), weighted: what every statistic of the lab tests
        (:mod:`lab.observations`); the points' residuals (N, 3) in the plain case."""
        return self.residuals if self.weighted_rows is None else self.weighted_rows

    @property
    def n_equations(self) -> int:
        """The rows measured (3 per point in the plain case)."""
        if self.observations is None or self.weighted_rows is None:
            return int(self.residuals.size)
        return self.observations.n_equations

    @property
    def weighted(self) -> bool:
        """Whether the rows were weighted by differing uncertainties (or orientations fitted)."""
        return self.weighted_rows is not None

    @property
    def noise_ref(self) -> float | None:
        """The per-row noise (m) after weighting, where the instrument states it."""
        return None if self.observations is None else self.observations.sigma_ref

    @property
    def orientation_rms_mrad(self) -> float | None:
        """RMS of the orientation residuals' rotation angle (mrad), over the rows that measured
        an orientation; None where none was fitted."""
        obs = self.observations
        if obs is None or obs.rotation is None:
            return None
        e = obs.orientation_errors(self.model, self.inputs, self.params)
        e = e[np.isfinite(e[:, 0])]
        return 1e3 * float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) if len(e) else None

    @property
    def validation_orientation_rms_mrad(self) -> float | None:
        e = self.validation_rotation
        if e is None:
            return None
        e = e[np.isfinite(e[:, 0])]
        return 1e3 * float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) if len(e) else None

    @property
    def outliers(self) -> np.ndarray:
        """Indices (into the data given to :func:`fit`) of the poses left out as gross outliers
        (``outliers="auto"``; :mod:`lab.screening` states the rule)."""
        return np.array([o.index for o in self.outlier_list], dtype=int)

    @property
    def far_points(self) -> np.ndarray:
        """Indices of fitted points farther off the fit than :data:`OUTLIER_RADIUS` robust
        standard deviations: a point of Gaussian noise lies that far out once in 1,000."""
        r = np.linalg.norm(self.residuals, axis=1)
        return np.flatnonzero(r > OUTLIER_RADIUS * robust_sigma(self.residuals))

    def fitted_data(self, data: MeasurementSet) -> MeasurementSet:
        """The poses of ``data`` (the data given to :func:`fit`) that this fit used."""
        if self.n_rows is not None and len(data) != self.n_rows:
            raise FitError(
                f"{data.source}: {len(data)} rows, but the fit was made on data of {self.n_rows}"
            )
        return data if self.fitted_rows is None else data.subset(self.fitted_rows)

    def parameters(self) -> dict[str, float]:
        return self.model.layout.as_dict(self.params)

    def standard_errors(self) -> dict[str, float | None]:
        return {
            n: (None if np.isnan(s) else float(s))
            for n, s in zip(self.names, self.std, strict=True)
        }

    def __getitem__(self, name: str) -> float:
        return float(self.params[self.model.layout.index(name)])

    # -- use -------------------------------------------------------------------------------------
    def predict(self, data: MeasurementSet | ModelInputs) -> np.ndarray:
        """Predicted tool points (M, 3) of other poses with the identified parameters, every
        term extrapolated (:meth:`validate` and :meth:`predict_in_domain` are not)."""
        inputs = data if isinstance(data, ModelInputs) else inputs_of(self.model, data)
        return Blocks(self.model, inputs).predict(self.params)

    @property
    def domain(self) -> Domain:
        """Where the model was identified: the ranges of the fitted poses (lab.domain), or
        those it states (:attr:`fitted_domain`)."""
        return self.fitted_domain if self.fitted_domain is not None else Domain.of(self.inputs)

    def out_of_domain(
        self, data: MeasurementSet | ModelInputs
    ) -> tuple[list[Excursion], dict[str, np.ndarray]]:
        """The variables of ``data`` outside :attr:`domain`, and the parameters whose terms do
        not hold there with the rows they do not hold on (:func:`lab.domain.out_of_domain`)."""
        inputs = data if isinstance(data, ModelInputs) else self._first_station_inputs(data)
        return out_of_domain(
            self.model, self.params, self.identifiable, self.domain, self.inputs, inputs
        )

    def _first_station_inputs(self, data: MeasurementSet) -> ModelInputs:
        """The inputs of ``data`` as measured from the fit's first station (what a station
        the fit has not seen is predicted from, before its base is registered)."""
        cols = {k: v for k, v in data.columns.items() if k != "station"}
        if "station" in self.inputs.columns:
            cols["station"] = np.full(len(data), float(self.model.stations[0]))
        return inputs_of(self.model, MeasurementSet(data.q, data.xyz, cols, data.source))

    def predict_in_domain(
        self, data: MeasurementSet | ModelInputs, extrapolate: bool = False, source: str = ""
    ) -> np.ndarray:
        """:meth:`predict`, each row outside the range a term holds over predicted without
        that term (unless ``extrapolate``), with a warning where data lie outside the domain."""
        inputs = data if isinstance(data, ModelInputs) else inputs_of(self.model, data)
        exc, drop = self.out_of_domain(inputs)
        name = source or getattr(data, "source", "") or "<memory>"
        warn_out_of_domain(name, exc, drop, extrapolate)
        return self._predict_rows(inputs, {} if extrapolate else drop)

    def _predict_rows(self, inputs: ModelInputs, drop: dict[str, np.ndarray]) -> np.ndarray:
        """Predictions with, in each row, the parameters ``drop`` marks there at zero."""
        pred = Blocks(self.model, inputs).predict(self.params)
        if not drop:
            return pred
        names = list(drop)
        marks = np.column_stack([drop[n] for n in names])
        patterns, which = np.unique(marks, axis=0, return_inverse=True)
        which = np.asarray(which).reshape(-1)
        for i, pattern in enumerate(patterns):
            if not pattern.any():
                continue
            rows = np.flatnonzero(which == i)
            p = self.without([n for n, off in zip(names, pattern, strict=True) if off])
            pred[rows] = Blocks(self.model, inputs.subset(rows)).predict(p)
        return pred

    def without(self, names: Sequence[str]) -> np.ndarray:
        """The parameters of the model without the terms ``names``: refitted with them held at
        zero on the rows of this fit (:attr:`refit`), or, where it cannot be refitted (a
        result built elsewhere, a refit that fails), these parameters with them zeroed."""
        if self.refit is not None:
            try:
                return self.refit(tuple(names))
            except FitError as exc:
                log.info("%s: the model without %s cannot be refitted: %s", self.source, names, exc)
        p = self.params.copy()
        p[self.model.layout.indices(list(names))] = 0.0
        return p

    def residuals_of(self, data: MeasurementSet) -> np.ndarray:
        """Predicted minus measured points (M, 3) of another measurement set, m."""
        return self.predict(data) - data.xyz

    def validate(
        self,
        data: MeasurementSet,
        extrapolate: bool = False,
        references: MeasurementSet | None = None,
        register_on_rows: bool = False,
    ) -> FitResult:
        """This result with validation metrics on ``data`` (held-out poses).

        Rows outside the model's domain (:mod:`lab.domain`) are named in a warning, and
        predicted without the terms that do not hold there unless ``extrapolate``
        (``validation_excursions``, ``validation_dropped``).

        Rows of a station the fit had not seen (a ``station`` id not among the model's) have no
        fitted base: the arm's fitted model is placed there by a rigid registration on
        ``references``, other poses measured at that station
        (:func:`lab.registration.register_station`; named in ``validation_registered``, with
        each registration's residual in ``validation_registrations``); the validation then
        measures the arm on rows nothing was fitted on. A row of ``data`` that is also a
        reference is left out of the figure. Without references such a station is refused
        (:class:`lab.errors.RegistrationError`): a base fitted on the rows it validates
        flatters them. ``register_on_rows`` registers such a station on the validated rows
        themselves instead (blocked cross-validation compares models alike this way; its figure
        is not an accuracy)."""
        model = self.model
        which = data.columns.get("station")
        known = set(model.stations)
        if which is None and len(model.stations) > 1:
            raise FitError(
                f"{data.source}: no station column, but the fit has stations "
                f"{', '.join(map(str, model.stations))}: say which station measured it"
            )
        ids = [] if which is None else sorted({int(v) for v in which})
        new = tuple(i for i in ids if i not in known) if len(known) > 1 else ()
        if len(known) == 1 and which is not None and ids != [model.stations[0]]:
            new = tuple(ids)  # one base fitted: every other station is placed anew
        if new and references is None and register_on_rows:
            references = data.subset(np.flatnonzero(np.isin(data.columns["station"], new)))
        elif new and references is None:
            raise RegistrationError(
                f"{data.source}: station(s) {', '.join(map(str, new))} not among the fit's "
                f"({', '.join(map(str, model.stations))}): their frame is unknown, and a base "
                "fitted on the rows it validates flatters them; give reference points measured "
                "there (--references REFS.csv: at least 3 points not on one line, or 6-DoF "
                "rows), which register the station and stay out of the figure"
            )
        if new and references is not None and not register_on_rows:
            data = _without_references(data, references)
            which = data.columns["station"]
        exc, drop = self.out_of_domain(data)
        warn_out_of_domain(data.source, exc, drop, extrapolate)
        if extrapolate:
            drop = {}
        outside = (tuple(exc), tuple(drop))

        def predict(d: MeasurementSet, rows: np.ndarray | None = None) -> np.ndarray:
            sub = drop if rows is None else {n: m[rows] for n, m in drop.items()}
            return self._predict_rows(
                inputs_of(model, d), {n: m for n, m in sub.items() if m.any()}
            )

        if not new:
            return self._validated(data, predict(data), None, (), outside)
        assert which is not None and references is not None
        # the arm as fitted, in the frame of the fit's first station (its zero offsets the
        # sessions' mean: a new station's session was re-homed); each new station's frame is
        # registered on its reference points
        cols = {k: v for k, v in data.columns.items() if k != "station"}
        if "station" in self.inputs.columns:  # as measured from the fit's first station
            cols["station"] = np.full(len(data), float(model.stations[0]))
        first = MeasurementSet(data.q, data.xyz, cols, data.source, data.lines)
        unseen = self.at_session_mean()
        pred = unseen._predict_rows(
            inputs_of(model, first), {n: m for n, m in drop.items() if m.any()}
        )
        pts = np.array(pred, dtype=float)
        turns = np.repeat(np.eye(3)[None], len(data), axis=0)
        # a tool offset the fit could not identify is placed with the new frames (lab.domain)
        loose = self.unidentified_tool()
        columns = (
            tool_columns(model, inputs_of(model, first), self.params, loose) if loose else None
        )
        placed = [unseen.register(_references_of(references, sid, new), loose) for sid in new]
        shift: dict[str, float] = {}
        for sid in ids:
            if sid not in new:
                on = which == sid
                pts[on] = predict(data.subset(np.flatnonzero(on)), on)
        for sid, reg in zip(new, placed, strict=True):
            on = which == sid
            moved = pred[on]
            if columns is not None and reg.tool:
                delta = np.array([reg.tool[n] for n in loose])
                moved = moved + columns[on] @ delta
                shift |= reg.tool
            pts[on] = moved @ reg.R.T + reg.t
            turns[on] = reg.R
        warn_tool_placed(data.source, new, shift)
        return replace(
            self._validated(data, pts, (first, turns), new, outside, shift),
            validation_registrations=tuple(placed),
        )

    def at_session_mean(self) -> FitResult:
        """This result as it stands for a session it has not seen: each station's session's own
        zero offsets (``dtheta{i}_s{s}``, several stations) at zero, the sessions' mean; itself
        where it has none."""
        names = self.model.layout.names
        own = [
            k for k, n in enumerate(names) if (p := parse_parameter_name(n)) and p.kind == "rehome"
        ]
        if not own:
            return self

        def mean(params: np.ndarray) -> np.ndarray:
            out = params.copy()
            out[own] = 0.0
            return out

        inner = self.refit
        refit = None if inner is None else (lambda left_out: mean(inner(left_out)))
        return replace(self, params=mean(self.params), refit=refit)

    def register(
        self, references: MeasurementSet, tool: list[str] | None = None
    ) -> StationRegistration:
        """The frame of a station this fit has not seen, registered on ``references`` measured
        there with the arm as fitted (:func:`lab.registration.register_station`); ``tool``: the
        unidentified tool parameters placed with it."""
        try:
            return register_station(self.model, self.params, references, tool)
        except EffectError as exc:
            raise FitError(str(exc)) from None

    def unidentified_tool(self) -> list[str]:
        """The tool-point parameters (``tx ty tz``, per target) this fit could not identify and
        was not told (``fixed``): the poses never turned the flange enough to separate them
        from the base (a series of ISO cubes at one flange orientation leaves ``tz``)."""
        if "geometric" not in self.model.layout.effects:
            return []
        names = self.model.layout.names
        held = set(self.identifiability.held)
        return [
            str(names[i])
            for i in tool_indices(self.model)
            if not self.identifiable[i] and names[i] not in held
        ]

    def _validated(self, data, pts, moved, new, outside=((), ()), placed=None) -> FitResult:
        rot = None
        if self.observations is not None and self.observations.rotation is not None:
            if data.has_orientation:
                rot = self._orientation_errors(data, moved)
        return replace(
            self,
            validation_residuals=pts - data.xyz,
            validation_rotation=rot,
            validation_registered=tuple(new),
            validation_tool_placed=dict(placed or {}),
            validation_excursions=outside[0],
            validation_dropped=outside[1],
        )

    def _orientation_errors(self, data: MeasurementSet, moved) -> np.ndarray:
        """The held-out orientation errors (M, 3), rad; NaN where not measured."""
        from arm.so3 import rotation_matrix, rotation_vector

        model = self.model
        if moved is None:
            _, R = model.predict_pose(inputs_of(model, data), self.params)
        else:
            first, turns = moved
            _, R = model.predict_pose(inputs_of(model, first), self.params)
            R = turns @ R
            for sid in {int(v) for v in data.columns["station"]} & set(model.stations):
                on = data.columns["station"] == sid
                if len(model.stations) > 1:
                    _, R[on] = model.predict_pose(
                        inputs_of(model, data.subset(np.flatnonzero(on))), self.params
                    )
        assert data.orientation is not None
        e = rotation_vector(R @ rotation_matrix(data.orientation).transpose(0, 2, 1))
        e[~data.measured[:, 3:].any(axis=1)] = np.nan
        return e

    def description(self, name: str | None = None) -> RobotDescription:
        """The calibrated arm: a description whose nominal model reproduces this fit."""
        desc = self.model.description(self.params, name=name)
        dom = self.domain
        desc = replace(desc, domain={"n_poses": dom.n_poses, **dom.ranges})
        return (
            desc if self.uncertainty is None else replace(desc, uncertainty=dict(self.uncertainty))
        )

    # -- tables ----------------------------------------------------------------------------------
    def rows(self) -> list[dict]:
        """One dict per parameter: name, effect, unit, nominal (the described value it
        corrects), error (identified minus nominal), value (nominal + error), std, identifiable;
        SI units."""
        ref = reference_values(self.model)
        err = self.params - self.model.nominal()
        out = []
        for k, n in enumerate(self.names):
            out.append(
                {
                    "name": n,
                    "effect": self.model.layout.effect_of(n),
                    "unit": parameter_unit(n),
                    "nominal": float(ref[k]),
                    "error": float(err[k]),
                    "value": float(ref[k] + err[k]),
                    "std": None if np.isnan(self.std[k]) else float(self.std[k]),
                    "identifiable": bool(self.identifiable[k]),
                }
            )
        return out

    def table(self) -> str:
        """The paper's Table 3 and more: per parameter its nominal value, the identified error and
        its standard error (lengths in mm; angles: nominal in deg, errors in mrad;
        :mod:`lab.text`)."""
        lines = [f"{'parameter':<10} {'nominal':>14} {'error':>12} {'std':>10}  unit"]
        for row in self.rows():
            c = parameter_cells(row)
            lines.append(
                f"{c['name']:<10} {c['nominal']:>14} {c['error']:>12} {c['std']:>10}  {c['unit']}"
            )
        return "\n".join(lines)

    def summary(self) -> str:
        out = [
            f"fit of {', '.join(self.effects)} to {self.n_points} points ({self.loss} loss): "
            f"RMS {self.initial_rms * 1e3:.4f} mm -> {self.rms_mm:.4f} mm, max {self.max_mm:.4f} mm, "
            f"{self.iterations} iterations"
        ]
        if self.orientation_rms_mrad is not None:
            out.append(f"orientation RMS {self.orientation_rms_mrad:.4f} mrad")
        if self.validation_residuals is not None:
            out.append(
                f"validation on {len(self.validation_residuals)} points: RMS "
                f"{self.validation_rms_mm:.4f} mm, median {self.validation_median_mm:.4f} mm"
            )
            for reg in self.validation_registrations:
                out.append(f"validation: {reg.text()}")
            if self.validation_tool_placed:
                out.append(
                    tool_placed_text(self.validation_registered, self.validation_tool_placed)
                )
        out.append(self.identifiability.summary())
        out += self.screening_lines()
        return "\n".join(out)

    def screening_lines(self, limit: int = 10) -> list[str]:
        """What was left out of the fit and why, for people: duplicates, outliers."""
        out = left_out_lines(
            self.duplicates,
            self.outlier_list,
            self.outlier_rule,
            of="the fit",
            note=self.outlier_note,
            limit=limit,
        )
        if self.implausible:
            out.append(
                "accepted beyond the plausible bound of their kind: "
                + "; ".join(b.text() for b in self.implausible)
            )
        return out

    def to_dict(self) -> dict:
        """The JSON object of ``sixaxis lab fit --json`` (docs/format.md, fit)."""
        ident = self.identifiability
        return {
            "schema_version": SCHEMA_VERSION,
            "effects": self.effects,
            "n_points": self.n_points,
            "rms_mm": self.rms_mm,
            "max_mm": self.max_mm,
            "validation_rms_mm": self.validation_rms_mm,
            "validation_median_mm": self.validation_median_mm,
            "parameters": self.parameters(),
            "std": self.standard_errors(),
            "rank": self.rank,
            "n_parameters": self.n_parameters,
            "unidentifiable": self.unidentifiable,
            "condition_number": _finite(self.condition_number),
            "o1": ident.o1,
            "o4": ident.o4,
            "identifiable": [n for n, ok in zip(self.names, self.identifiable, strict=True) if ok],
            "sigma_mm": self.sigma_mm,
            "initial_rms_mm": 1e3 * self.initial_rms,
            "loss": self.loss,
            "iterations": self.iterations,
            "robot": self.model.robot.name,
            "targets": list(self.model.targets),
            "source": self.source,
            "n_rows": self.n_points if self.n_rows is None else self.n_rows,
            "outliers_mode": self.outliers_mode,
            "outliers": [o.to_dict() for o in self.outlier_list],
            "outlier_rule": self.outlier_rule,
            "duplicates": [d.to_dict() for d in self.duplicates],
            "implausible": [b.to_dict() for b in self.implausible],
            "stations": list(self.model.stations) if "station" in self.inputs.columns else None,
            "weighted": self.weighted,
            "noise_ref_mm": None if self.noise_ref is None else 1e3 * self.noise_ref,
            "orientation_rms_mrad": self.orientation_rms_mrad,
            "validation_orientation_rms_mrad": self.validation_orientation_rms_mrad,
            "validation_registered": list(self.validation_registered),
            "validation_registrations": [r.to_dict() for r in self.validation_registrations],
            "validation_tool_placed_mm": {
                k: 1e3 * v for k, v in self.validation_tool_placed.items()
            },
            "domain": self.domain.to_dict(),
            "validation_outside_domain": [e.to_dict() for e in self.validation_excursions],
            "validation_terms_left_out": list(self.validation_dropped),
        }


def held_out(
    validate: MeasurementSet | str | Path | None, references: MeasurementSet | str | Path | None
) -> tuple[MeasurementSet, MeasurementSet | None] | None:
    """The held-out data and the reference points of a station of them the fit has not seen, as
    measurement sets (None: no held-out data; references without them are refused)."""
    if validate is None:
        if references is not None:
            raise FitError(
                "reference points register a station of held-out data: give the data too "
                "(validate=, --validate)"
            )
        return None
    return as_measurements(validate), None if references is None else as_measurements(references)


def _references_of(references: MeasurementSet, station: int, new: Sequence[int]) -> MeasurementSet:
    """The reference rows of ``station``: its rows by the references' station column, or all of
    them where they have none and ``station`` is the one new station."""
    which = references.columns.get("station")
    if which is None:
        if len(new) > 1:
            raise RegistrationError(
                f"{references.source}: no station column, but the validation has several "
                f"stations the fit has not seen ({', '.join(map(str, new))}): say which "
                "station measured each reference"
            )
        return references
    rows = np.flatnonzero(which == station)
    if not rows.size:
        raise RegistrationError(
            f"{references.source}: no reference points of station {station}, which the fit has "
            "not seen: measure at least 3 there (not on one line), or 6-DoF rows"
        )
    return references.subset(rows)


def _without_references(data: MeasurementSet, references: MeasurementSet) -> MeasurementSet:
    """``data`` without the rows that are also references (the same joints and point): what
    registered a station is not evidence of the arm's accuracy there."""
    ref = {(tuple(q), tuple(x)) for q, x in zip(references.q, references.xyz, strict=True)}
    same = np.array(
        [(tuple(q), tuple(x)) in ref for q, x in zip(data.q, data.xyz, strict=True)], dtype=bool
    )
    if not same.any():
        return data
    if same.all():
        raise RegistrationError(
            f"{data.source}: every validation row is a reference point ({references.source}): "
            "nothing is left to validate on"
        )
    log.info("%s: %d rows are reference points, left out of the figure", data.source, same.sum())
    return data.subset(np.flatnonzero(~same))


def rms(r: np.ndarray) -> float:
    """The 3-D RMS of residuals (one row per pose); NaN for none."""
    return float(np.sqrt(np.mean(np.sum(np.asarray(r) ** 2, axis=1)))) if len(r) else float("nan")


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def inputs_of(model: ErrorModel, data: MeasurementSet) -> ModelInputs:
    """What every effect of ``model`` reads of ``data`` (:meth:`arm.errormodel.ErrorModel.inputs`),
    a missing column refused as a :class:`FitError`."""
    try:
        return model.inputs(data.q, data.columns, source=data.source)
    except EffectError as exc:
        raise FitError(str(exc)) from None


# --------------------------------------------------------------------------------------------------
def reference_values(model: ErrorModel) -> np.ndarray:
    """The described quantity each parameter corrects (alpha_{i-1} for ``dalpha{i}``, the tool
    point coordinate for ``tx``, the base value for ``bx``...), so value = reference + error."""
    rob = model.robot
    tp = rob.tool_points  # target k takes tool k of the description, else the first
    tools = np.array([tp[k] if k < len(tp) else tp[0] for k in range(len(model.targets))])
    nominal = model.nominal()
    out = np.zeros(len(model.layout))
    fields = dict(zip(ROW_FAMILIES, ("alpha", "a", "theta_offset", "d"), strict=True))
    geo = (
        set(model.layout.names[model.layout.slice("geometric")])
        if ("geometric" in model.layout.effects)
        else set()
    )
    for k, n in enumerate(model.layout.names):
        p = parse_parameter_name(n) if n in geo else None
        if p is not None and p.kind == "row" and p.number is not None:
            out[k] = getattr(rob.joints[p.number - 1], fields[p.family])
        elif p is not None and p.kind == "beta" and p.number is not None:
            out[k] = rob.joints[p.number].beta
        elif p is not None and p.kind == "tool":
            idx = p.number if p.number is not None else model.targets[0]
            out[k] = tools[model.targets.index(idx), "xyz".index(p.family[1])]
        else:  # the base, and every other effect: the parameter is the value itself
            out[k] = nominal[k]
    return out
