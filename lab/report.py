"""Building the lab's report: the fits, diagnoses, sensitivity and figures that
:class:`lab.lab_report.LabReport` shows, written as one self-contained HTML file that a
calibration engineer can send to a colleague.

    report = build_report("data.csv", "seed", "geometric", validate="other.csv", noise_mm=0.015)
    lab.report_html.write(report, "report.html")

The loop it documents: the nominal arm (base and tool registered), the model asked for, then as
long as the diagnosis names a missing catalogued effect (up to ``rounds`` times) the model with
it. For every model: residuals per pose (the seed paper's Fig. 8), RMS on fitted and held-out
poses; for every diagnosis: the verdict, the candidates and the hints, with the residual plotted
against the hinted variables; for the final model: the identified parameters (the paper's
Table 3 with standard errors), identifiability, and the error-factor sensitivity of the paper's
section 3.3 (Fig. 7: how far a unit error of each parameter moves the tool point).

Helpers used elsewhere as well: :func:`error_sensitivity`; the "before" of every comparison is
:func:`lab.registration.nominal_parameters` (the nominal arm with its base and tool registered).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Unpack

import numpy as np

from arm.description import RobotDescription
from arm.effect_api import ModelInputs
from arm.effects import Effect
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from arm.params import parameter_unit
from lab import plots
from lab.diagnosis import diagnose, hint_variables
from lab.errors import FitError
from lab.identifiability import CONDITION_WARNING, typical_magnitudes
from lab.lab_report import LabReport, ModelRun, Sensitivity
from lab.options import LabOptions, OptionFields, resolve
from lab.registration import nominal_parameters
from lab.report_html import HINT_PLOT_P, arm_parameters
from lab.result import FitResult, held_out, inputs_of
from lab.screening import Screen, screened

__all__ = ["build_report", "error_sensitivity"]

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------------
def error_sensitivity(
    model: ErrorModel, inputs: ModelInputs, p: np.ndarray | None = None
) -> Sensitivity:
    """The error-factor analysis of the seed paper's section 3.3 (its Fig. 7), from the
    identification Jacobian at ``p`` (default nominal) over the poses of ``inputs``: the RMS over
    the poses of the tool point's displacement by a small error of each parameter."""
    p = model.nominal() if p is None else np.asarray(p, dtype=float)
    _, J = model.predict(inputs, p, jacobian=True)
    per_unit = np.sqrt(np.mean(np.sum(J**2, axis=1), axis=0))
    names = model.layout.names
    return Sensitivity(
        names=names,
        units=tuple(parameter_unit(n) for n in names),
        per_unit=per_unit,
        typical_mm=1e3 * per_unit * typical_magnitudes(model),
        identified_mm=1e3 * per_unit * np.abs(p - model.nominal()),
    )


# --------------------------------------------------------------------------------------------------
def build_report(
    data: Screen | MeasurementSet | str | Path,
    robot: RobotDescription | str | Path | None = None,
    effects: str | Sequence[str | Effect] | None = None,
    *,
    options: LabOptions | None = None,
    validate: MeasurementSet | str | Path | None = None,
    references: MeasurementSet | str | Path | None = None,
    rounds: int = 3,
    title: str | None = None,
    command: str | None = None,
    progress: Callable[[str], None] | None = None,
    **keywords: Unpack[OptionFields],
) -> LabReport:
    """Fit ``effects`` (default geometric), diagnose, and while the verdict names a missing
    catalogued effect (at most ``rounds`` times) fit the suggested model and diagnose again; see
    the module docstring.

    ``data``: a measurement set (or its file), screened once (:func:`lab.screen`), or a
    :class:`lab.Screen` made before; every model is then fitted to the rows that count
    (:attr:`lab.Screen.counted`), so that the models compare pose by pose, and nothing more is
    left out; the report names what was. The options (``noise_mm`` ... ``register``, or
    ``options=``) are :class:`lab.LabOptions`. ``validate``: held-out measurements; ``references``: poses that register a station of
    them the fit has not seen (:meth:`lab.FitResult.validate`)."""
    opts = resolve(options, **keywords)
    step = progress or (lambda msg: None)
    held = held_out(validate, references)
    val, refs = (None, None) if held is None else held
    shown = "geometric" if effects is None else effects
    step(
        "screening the rows and fitting "
        + (shown if isinstance(shown, str) else ",".join(map(str, shown)))
    )
    s = screened(data, robot, effects, opts, tests=True)

    def validated(cur: Screen) -> Screen:
        return cur if val is None else replace(cur, fit=cur.fit.validate(val, references=refs))

    # the rows every model is fitted to: without the gross errors the tests found as well
    cur = validated(s if not s.untested else s.refit(s.effects))
    data = cur.kept
    first = cur.fit
    p0 = nominal_parameters(first.model, first.inputs, data.xyz)
    runs = [
        ModelRun(
            "nominal",
            first.model.predict(first.inputs, p0) - data.xyz,
            None if val is None else _nominal_validation(first, p0, val, refs),
        )
    ]
    seen = {",".join(first.effects)}
    for k in range(max(rounds, 0) + 1):
        res = cur.fit
        step(f"diagnosing {', '.join(res.effects)}")
        d = diagnose(cur)
        runs.append(
            ModelRun(
                ", ".join(res.effects),
                res.residuals,
                res.validation_residuals,
                fit=res,
                diagnosis=d,
                n_fitted=res.rank,
            )
        )
        nxt = d.suggestion
        if k == rounds or not nxt or nxt in seen or d.verdict in ("none", "unexplained"):
            break
        seen.add(nxt)
        step(f"fitting {nxt}")
        cur = validated(cur.refit(nxt))

    final = runs[-1].fitted
    step("error-factor sensitivity")
    sens = error_sensitivity(final.model, final.inputs, final.params)
    report = LabReport(
        data=data,
        validation=val,
        robot=s.robot,
        noise_mm=s.options.noise_mm,
        runs=runs,
        sensitivity=sens,
        title=title or f"Calibration report: {Path(data.source).name}",
        command=command,
        outliers=s.left_out,
        duplicates=list(s.fit.duplicates),
        outlier_rule=s.test_rule,
        n_rows=len(s.data),
    )
    step("plotting")
    report.figures = _figures(report)
    return report


def _nominal_validation(
    first: FitResult, p0: np.ndarray, val: MeasurementSet, refs: MeasurementSet | None
) -> np.ndarray:
    """The nominal arm's residuals on the held-out poses: as a fit's validation does it (a
    station the fit has not seen gets its base registered), with the nominal parameters."""
    if "station" not in val.columns:
        return first.model.predict(inputs_of(first.model, val), p0) - val.xyz
    nominal = replace(first, params=p0)
    r = nominal.validate(val, references=refs).validation_residuals
    assert r is not None
    return r


# -- the residual against the hinted variables -------------------------------------------------------
_JOINT_VAR = re.compile(r"(q|tau|dir)([1-6])")


def _hint_projection(
    res: FitResult, data: MeasurementSet, variable: str, direction: str | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str, str]:
    """Per pose, the residual of ``res`` along the direction that depends on ``variable`` most:
    for q_j, tau_j, dir_j the equivalent angle error of joint j (mrad: the residual projected on
    the tool point's motion by joint j), and for every variable the x, y, z and radial components
    (mm); the one that the variable's smooth functions explain best (highest R^2), or
    ``direction`` when given (to draw another model along the same one). Returns (mask of the
    poses used, x, y, y label, direction)."""
    e = res.residuals
    n = len(e)
    m = _JOINT_VAR.fullmatch(variable)
    if variable in data.columns:
        x = data.columns[variable]
    elif m and m.group(1) == "q":
        x = data.q[:, int(m.group(2)) - 1]
    elif m and m.group(1) == "tau":
        x = res.inputs.tau[:, int(m.group(2)) - 1]
    else:
        x = np.zeros(n)
    every = np.ones(n, dtype=bool)
    options: dict[str, tuple[np.ndarray, np.ndarray, str]] = {}
    if m and direction in (None, "joint"):
        j = int(m.group(2)) - 1
        _, Jq = res.model.joint_jacobian(res.inputs, res.params)
        g = Jq[:, :, j]
        norm = np.linalg.norm(g, axis=1)
        use = norm > 0.25 * np.median(norm)  # poses where joint j moves the point
        y = np.zeros(n)
        y[use] = 1e3 * np.sum(g[use] * e[use], axis=1) / norm[use] ** 2
        options["joint"] = (use, y, f"equivalent joint-{j + 1} angle error (mrad)")
    if direction != "joint":
        pts = res.predict(res.inputs)
        base = res.model.state(res.inputs, res.params).base_t
        radial = pts - base
        radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-9)
        comps = {"x": e[:, 0], "y": e[:, 1], "z": e[:, 2], "radial": np.sum(e * radial, axis=1)}
        for name, v in comps.items():
            if direction in (None, name):
                options[name] = (every, 1e3 * v, f"{name} error (mm)")
    if direction is None:
        phi = hint_variables(res, data).get(variable)
        best = -np.inf
        for name, (use, y, _) in options.items():  # the joint first: it wins ties
            r2 = _r2(y[use], None if phi is None else phi[use])
            if r2 > best + 1e-9:
                best, direction = r2, name
    if direction is None:
        raise FitError(f"no direction to project the residual on for {variable!r}")
    use, y, label = options[direction]
    return use, x, y, label, direction


def _design(phi: np.ndarray | None, n: int) -> np.ndarray:
    return np.ones((n, 1)) if phi is None else np.column_stack([np.ones(n), phi])


def _r2(v: np.ndarray, phi: np.ndarray | None) -> float:
    A = _design(phi, len(v))
    coef, *_ = np.linalg.lstsq(A, v, rcond=None)
    ss = float(np.sum((v - v.mean()) ** 2))
    return 1.0 - float(np.sum((v - A @ coef) ** 2)) / ss if ss > 0 else 0.0


def _smooth(res: FitResult, data: MeasurementSet, variable: str, y: np.ndarray, use: np.ndarray):
    phi = hint_variables(res, data).get(variable)
    A = _design(None if phi is None else phi[use], int(use.sum()))
    coef, *_ = np.linalg.lstsq(A, y[use], rcond=None)
    return A @ coef


def hint_panels(report: LabReport, top: int = 3) -> list[plots.HintPanel]:
    """Panels of the first fitted model's top significant hints (p < :data:`HINT_PLOT_P`), with
    the final model's residual overlaid."""
    first, last = report.runs[1], report.runs[-1]
    d = first.diagnosis
    hints = [h for h in (d.hints if d is not None else []) if h.p_value < HINT_PLOT_P]
    models = [(1, first)] + ([(len(report.runs) - 1, last)] if last is not first else [])
    panels = []
    for h in hints[:top]:
        series = []
        direction = None
        y_label = x_label = h.variable
        for _, run in models:
            use, x, y, y_label, direction = _hint_projection(
                run.fitted, report.data, h.variable, direction
            )
            yfit = _smooth(run.fitted, report.data, h.variable, y, use)
            series.append((run.label, x[use], y[use], yfit))
        x_label = _variable_label(h.variable)
        discrete = h.variable.startswith("dir") or h.variable == "target"
        panels.append(plots.HintPanel(h.variable, x_label, y_label, h.score, series, discrete))
    return panels


def _variable_label(v: str) -> str:
    m = _JOINT_VAR.fullmatch(v)
    if m and m.group(1) == "q":
        return f"joint {m.group(2)} angle q{m.group(2)} (rad)"
    if m and m.group(1) == "tau":
        return f"gravity torque about axis {m.group(2)} (N·m)"
    if m and m.group(1) == "dir":
        return f"last direction of joint {m.group(2)} (±1)"
    return {"t": "time (s)", "temperature": "temperature (°C)", "payload": "payload (kg)"}.get(v, v)


# -- figures -----------------------------------------------------------------------------------------
def _figures(r: LabReport) -> dict[str, bytes]:
    colors = [plots.color(k) for k in range(len(r.runs))]
    figs: dict[str, bytes] = {}
    figs["rms"] = plots.png(
        plots.rms_figure(
            [run.label for run in r.runs],
            [run.rms_mm for run in r.runs],
            [run.validation_rms_mm for run in r.runs] if r.validation is not None else None,
            r.noise_floor_mm,
        )
    )
    if r.validation is not None:
        figs["residuals_validation"] = plots.png(
            plots.residuals_figure(
                [
                    (run.label, run.validation_residuals)
                    for run in r.runs
                    if run.validation_residuals is not None
                ],
                f"held-out poses ({len(r.validation)}, {Path(r.validation.source).name})",
                colors,
                r.noise_floor_mm,
            )
        )
    figs["residuals"] = plots.png(
        plots.residuals_figure(
            [(run.label, run.residuals) for run in r.runs],
            f"fitted poses ({len(r.data)}, {Path(r.data.source).name})",
            colors,
            r.noise_floor_mm,
        )
    )
    panels = hint_panels(r)
    if panels:
        sel = [colors[1]] + ([colors[len(r.runs) - 1]] if len(r.runs) > 2 else [])
        figs["hints"] = plots.png(plots.hints_figure(panels, sel))
    for k, run in enumerate(r.runs[1:], start=1):
        d = run.diagnosis
        if d is not None and d.candidates:
            top = d.candidates[:15]
            figs[f"candidates{k}"] = plots.png(
                plots.candidates_figure(
                    [c.label for c in top],
                    [c.cv_rms_mm for c in top],
                    [c.significant and c.confirmed for c in top],
                    d.cv_rms_mm,
                    d.noise_floor_mm,
                )
            )
    s = r.sensitivity
    final = r.final.fitted
    keep = arm_parameters(s.names)
    figs["sensitivity"] = plots.png(
        plots.sensitivity_figure(
            [s.names[k] for k in keep],
            s.typical_mm[keep],
            [s.units[k] for k in keep],
            s.identified_mm[keep],
            final.identifiable[keep],
        )
    )
    figs["singular_values"] = plots.png(
        plots.singular_values_figure(final.identifiability.singular_values, CONDITION_WARNING)
    )
    return figs
