"""The lab's report written as one self-contained HTML page (PNG figures inlined as base64, no
external files, scripts or fonts): :func:`render` of a :class:`lab.lab_report.LabReport`, which
:func:`lab.report.build_report` fills; nothing here fits or plots.

The page, in order: cards (nominal, calibrated, held-out RMS, noise floor, diagnosis), the models
compared, the residuals per pose (the seed paper's Fig. 8), each diagnosis with its candidates
and hints, the identified parameters (the paper's Table 3 with standard errors), their
identifiability, the error-factor sensitivity (the paper's Fig. 7) and the data. It is one
module, longer than most, because it is one page: its template reads top to bottom as the page
does.

Helpers for people reading parameters: :func:`geometric_table`
(Table 3 layout) and :func:`arm_parameters` (the parameters of the arm, not of where it stands).
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from pathlib import Path

from arm.files import atomic_write_text
from arm.params import ROW_FAMILIES, parse_parameter_name
from lab.identifiability import CONDITION_WARNING
from lab.lab_report import LabReport, ModelRun
from lab.result import FitResult
from lab.text import duplicates_text, nominal_text, readable

__all__ = ["arm_parameters", "geometric_table", "render", "write"]

# hints drawn only below this p-value: a smooth curve through the noise of a variable that
# explains nothing (30 poses of real data) would suggest a dependence that is not there
HINT_PLOT_P = 0.01


def _kind(name: str) -> str | None:
    """The kind of a catalogued parameter (``row``, ``beta``, ``base``...), None for a user's."""
    parsed = parse_parameter_name(name)
    return None if parsed is None else parsed.kind


def arm_parameters(names: Sequence[str]) -> list[int]:
    """Indices of the parameters that belong to the arm (DH rows, tool offsets, other effects),
    not to where it stands: the base transform is a registration, arbitrary for a tracker."""
    return [k for k, n in enumerate(names) if _kind(n) != "base"]


COLUMNS = tuple(zip(ROW_FAMILIES, ("alpha", "a", "theta", "d"), strict=True))


def geometric_table(result: FitResult) -> list[dict]:
    """The paper's Table 3: one row per joint i with, for alpha_{i-1}, a_{i-1}, theta_i and d_i
    (or Hayati's beta_{i-1} where z_{i-1} and z_i are parallel), a cell ``{name, nominal, error,
    std, identifiable, unit}`` in SI units (``None`` where the model has no such parameter)."""
    if "geometric" not in result.model.layout.effects:
        return []
    rows = {r["name"]: r for r in result.rows()}
    out = []
    for i in range(1, 7):
        row: dict = {"joint": i}
        for pre, key in COLUMNS:
            r = rows.get(f"{pre}{i}")
            if r is None and key == "d" and f"beta{i - 1}" in rows:
                r = rows[f"beta{i - 1}"]
            row[key] = r
        out.append(row)
    return out


# --------------------------------------------------------------------------------------------------
def _beyond_points_html(r: LabReport) -> str:
    """What the fit compared beyond one 3-D point: stations, orientations, the weights, and
    the validation stations whose bases were registered (lab.observations)."""
    fit = r.final.fit
    if fit is None:
        return ""
    bits = []
    if "station" in fit.inputs.columns:
        ids = ", ".join(map(str, fit.model.stations))
        bits.append(f"tracker stations {ids}, one base each, the arm shared")
    if fit.orientation_rms_mrad is not None:
        bits.append(
            f"orientations fitted too (RMS after the fit {fit.orientation_rms_mrad:.4f} mrad"
            + (
                f", held out {fit.validation_orientation_rms_mrad:.4f} mrad"
                if fit.validation_orientation_rms_mrad is not None
                else ""
            )
            + ")"
        )
    if fit.weighted and fit.noise_ref is not None:
        bits.append(
            "each row weighted by its stated uncertainty, every statistic on the weighted rows "
            f"(reference sigma {1e3 * fit.noise_ref:.4g} mm)"
        )
    if fit.validation_registered:
        ids = ", ".join(map(str, fit.validation_registered))
        bits.append(
            f"validation station(s) {ids} not in the fit: each one's frame registered rigidly "
            "on reference points measured there, the arm as fitted"
        )
        bits += [f"validation: {reg.text()}" for reg in fit.validation_registrations]
    return f"<p>{_e('; '.join(bits))}.</p>" if bits else ""


# -- HTML ----------------------------------------------------------------------------------------------
_CSS = """
:root { --ink:#1b1f24; --muted:#5f6b76; --line:#d9dee3; --bg:#f6f8fa; --accent:#1f77b4;
        --good:#2e7d32; --bad:#c62828; --warn:#b26a00; }
* { box-sizing: border-box; }
body { margin:0; font:14px/1.5 -apple-system, "Segoe UI", Roboto, Helvetica, Arial, sans-serif;
       color:var(--ink); background:#fff; }
main { max-width: 1020px; margin: 0 auto; padding: 28px 24px 60px; }
header h1 { font-size: 24px; margin: 0 0 4px; }
header p { color: var(--muted); margin: 0; }
h2 { font-size: 18px; margin: 36px 0 8px; padding-bottom: 4px; border-bottom: 2px solid var(--line); }
h3 { font-size: 15px; margin: 22px 0 6px; }
p.note, figcaption { color: var(--muted); font-size: 12.5px; }
.cards { display: flex; flex-wrap: wrap; gap: 12px; margin: 20px 0 8px; }
.card { flex: 1 1 150px; background: var(--bg); border: 1px solid var(--line); border-radius: 8px;
        padding: 10px 14px; }
.card .k { color: var(--muted); font-size: 12px; text-transform: uppercase; letter-spacing: .04em; }
.card .v { font-size: 21px; font-weight: 600; font-variant-numeric: tabular-nums; }
.card .s { color: var(--muted); font-size: 12px; }
.verdict { display:inline-block; padding: 2px 10px; border-radius: 12px; font-weight: 600; }
.verdict.effect { background:#fdecea; color: var(--bad); }
.verdict.none { background:#e8f5e9; color: var(--good); }
.verdict.unexplained { background:#fff4e5; color: var(--warn); }
table { border-collapse: collapse; width: 100%; margin: 8px 0 4px; font-size: 12.5px;
        font-variant-numeric: tabular-nums; }
th, td { padding: 4px 8px; border-bottom: 1px solid var(--line); text-align: right; white-space: nowrap; }
th { background: var(--bg); font-weight: 600; }
td.l, th.l { text-align: left; }
tbody tr:nth-child(even) { background: #fbfcfd; }
td.fixed { color: #9aa4ad; font-style: italic; }
.std { color: var(--muted); }
.yes { color: var(--good); font-weight: 600; }
.no { color: #9aa4ad; }
figure { margin: 12px 0 18px; }
figure img { max-width: 100%; border: 1px solid var(--line); border-radius: 6px; }
details summary { cursor: pointer; color: var(--accent); margin: 10px 0 4px; }
code { background: var(--bg); padding: 1px 5px; border-radius: 4px; font-size: 12.5px; }
ul.combos { columns: 2; font-size: 12.5px; }
.warn { border-left: 4px solid var(--warn); background: #fff8ec; padding: 6px 12px; margin: 8px 0; }
footer { margin-top: 40px; color: var(--muted); font-size: 12px; border-top: 1px solid var(--line);
         padding-top: 8px; }
"""


def _e(x: object) -> str:
    return html.escape(str(x), quote=True)


def _img(r: LabReport, key: str, caption: str) -> str:
    data = r.figures.get(key)
    if data is None:
        return ""
    b64 = base64.b64encode(data).decode("ascii")
    return (
        f'<figure><img alt="{_e(caption)}" src="data:image/png;base64,{b64}">'
        f"<figcaption>{caption}</figcaption></figure>"
    )


def _mm(v: float | None, digits: int = 4) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


Cell = str | tuple[str, str]  # html, or (html, css class)


def _table(head: Sequence[str], rows: Sequence[Sequence[Cell]], left: int = 1) -> str:
    th = "".join(
        f'<th class="l">{h}</th>' if k < left else f"<th>{h}</th>" for k, h in enumerate(head)
    )
    body = []
    for row in rows:
        cells = []
        for k, c in enumerate(row):
            cls = ' class="l"' if k < left else ""
            if isinstance(c, tuple):
                c, extra = c
                cls = f' class="{extra}{" l" if k < left else ""}"'
            cells.append(f"<td{cls}>{c}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><thead><tr>{th}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _verdict(v: str) -> str:
    cls = {"none": "none", "unexplained": "unexplained", "noise": "unexplained"}.get(v, "effect")
    return f'<span class="verdict {cls}">{_e(v)}</span>'


def _card(k: str, v: str, s: str = "") -> str:
    return f'<div class="card"><div class="k">{k}</div><div class="v">{v}</div><div class="s">{s}</div></div>'


def _cell(c: dict | None) -> tuple[str, str]:
    """(nominal, error ± std) of a Table-3 cell."""
    if c is None:
        return "", ""
    unit = c["unit"]
    nom = nominal_text(c["nominal"], unit, symbols=True)
    name = _e(c["name"])
    if not c["identifiable"]:
        return nom, f'<span class="no" title="{name}">fixed</span>'
    err, _ = readable(c["error"], unit, signed=True)
    std, _ = readable(c["std"], unit)
    return nom, f'<span title="{name}">{err} <span class="std">± {std}</span></span>'


def _parameter_tables(fit: FitResult) -> str:
    out = []
    table = geometric_table(fit)
    if table:
        head = [
            "joint i",
            "α<sub>i-1</sub>",
            "Δα (mrad)",
            "a<sub>i-1</sub> (mm)",
            "Δa (mm)",
            "θ offset",
            "Δθ (mrad)",
            "d<sub>i</sub> (mm) / β",
            "Δd (mm) / Δβ (mrad)",
        ]
        rows: list[list[Cell]] = []
        for row in table:
            cells: list[Cell] = [str(row["joint"])]
            for _, key in COLUMNS:
                c = row[key]
                nom, err = _cell(c)
                parsed = None if c is None else parse_parameter_name(c["name"])
                if parsed is not None and parsed.kind == "beta":
                    nom = f"β{parsed.number} {nom}"
                cells += [nom, err]
            rows.append(cells)
        out.append(
            "<h3>DH table (the paper's Table 3): nominal value and identified error ± standard error</h3>"
        )
        out.append(_table(head, rows))
        out.append(
            '<p class="note">Errors are identified minus nominal; <i>fixed</i>: not identifiable '
            "from these poses (see Identifiability), held at nominal.</p>"
        )
    other = [r for r in fit.rows() if _kind(r["name"]) not in ("row", "beta")]
    if other:
        rows = []
        for r in other:
            val, unit = readable(r["value"], r["unit"])
            err, _ = readable(r["error"], r["unit"], signed=True)
            std, _ = readable(r["std"], r["unit"])
            ident = r["identifiable"]
            rows.append(
                [
                    f"<code>{_e(r['name'])}</code>",
                    _e(r["effect"]),
                    val if ident else (val, "fixed"),
                    err if ident else ("fixed", "fixed"),
                    std if ident else "",
                    _e(unit),
                ]
            )
        out.append("<h3>Base, tool and other effects</h3>")
        out.append(_table(["parameter", "effect", "value", "error", "std", "unit"], rows, left=2))
    rows = [
        [
            f"<code>{_e(r['name'])}</code>",
            _e(r["effect"]),
            f"{r['value']:.10g}",
            f"{r['error']:+.6g}" if r["identifiable"] else ("fixed", "fixed"),
            f"{r['std']:.3g}" if r["std"] is not None else "",
            _e(r["unit"]),
        ]
        for r in fit.rows()
    ]
    out.append(
        "<details><summary>Every parameter by the name of the JSON output "
        "(<code>sixaxis lab fit --json</code>), SI units</summary>"
        + _table(["parameter", "effect", "value", "error", "std", "unit"], rows, left=2)
        + "</details>"
    )
    return "\n".join(out)


def _diagnosis_html(run: ModelRun, r: LabReport, k: int) -> str:
    d = run.diagnosed
    out = [f"<h3>Model {_e(run.label)}: verdict {_verdict(d.verdict)}</h3>"]
    facts = [
        f"RMS {d.rms_mm:.4f} mm on the fitted poses, {d.cv_rms_mm:.4f} mm leave-one-out",
    ]
    if d.noise_floor_mm is not None:
        facts.append(f"noise floor {d.noise_floor_mm:.4f} mm")
    if d.chi2_p_value is not None:
        facts.append(f"χ² test of the residual against the noise: p = {d.chi2_p_value:.3g}")
    out.append(f"<p>{'; '.join(facts)}.</p>")
    if d.noise_note:
        out.append(f"<p>{_e(d.noise_note)}.</p>")
    if d.suggestion:
        out.append(f"<p>Next model: <code>--effects {_e(d.suggestion)}</code></p>")
    if d.readings:
        orders = "; ".join(
            f"joint {j}: {', '.join(map(str, ks))}" for j, ks in d.cyclic_orders.items()
        )
        out.append(
            f"<p>Cyclic errors found (orders per turn: {_e(orders)}), and what such an order "
            "usually is:</p><ul>" + "".join(f"<li>{_e(r)}</li>" for r in d.readings) + "</ul>"
        )
    if d.notes:
        out.append(
            "<p>What the data cannot resolve:</p><ul>"
            + "".join(f"<li>{_e(n)}</li>" for n in d.notes)
            + "</ul>"
        )
    elif d.verdict == "unexplained":
        out.append(
            '<p class="warn">The residual is above the noise floor and no catalogued effect '
            "explains it: look at the hints, and consider a user effect (--effect-module).</p>"
        )
    rows: list[list[Cell]] = []
    for c in d.candidates[:10]:
        ok = c.significant and c.confirmed
        rows.append(
            [
                _e(c.label),
                f"{c.rms_mm:.4f}",
                f"{c.cv_rms_mm:.4f}",
                f"{c.p_value:.3g}",
                ("yes", "yes") if ok else ("no", "no"),
            ]
        )
    if rows:
        out.append(
            _table(
                ["candidate", "RMS after (mm)", "held-out RMS (mm)", "p-value", "significant"], rows
            )
        )
    out.append(
        _img(
            r,
            f"candidates{k}",
            "Held-out (leave-one-pose-out) RMS after adding each candidate; red: significant at the family-wise level and confirmed on held-out poses.",
        )
    )
    hrows = [
        [f"<code>{_e(h.variable)}</code>", f"{h.score:.3f}", f"{h.p_value:.3g}"]
        for h in d.hints[:8]
    ]
    if hrows:
        out.append(
            "<p>Hints: the measured variables the remaining residual depends on (adjusted R², p-value):</p>"
        )
        out.append(_table(["variable", "score", "p-value"], hrows))
    return "\n".join(out)


def _left_out_html(r: LabReport) -> str:
    """What every model left out of the file, by line, and why."""
    out = []
    if r.duplicates:
        out.append(
            f'<p class="warn">{len(r.duplicates)} row(s) repeat an earlier row exactly and are '
            f"counted once: {_e(duplicates_text(r.duplicates, 20))}.</p>"
        )
    if r.outliers:
        items = "".join(
            f"<li>{_e(o.where)}: {o.residual_mm:.4g} mm ({o.sigmas:.3g} σ)"
            + (f"; {_e(o.note)}" if o.note else "")
            + "</li>"
            for o in r.outliers[:50]
        )
        more = f"<li>… {len(r.outliers) - 50} more</li>" if len(r.outliers) > 50 else ""
        out.append(
            f'<p class="warn">{len(r.outliers)} gross outlier(s) left out of every model and '
            f"every test (rule: {_e(r.outlier_rule or '')}; <code>--outliers keep</code> fits "
            f"them):</p><ul>{items}{more}</ul>"
        )
    return "".join(out)


def write(report: LabReport, path: str | Path) -> None:
    """Write the report's page (:func:`render`) to ``path``, atomically."""
    atomic_write_text(Path(path), render(report))


def render(r: LabReport) -> str:
    """The report's page: one self-contained HTML document, its sections in the order of the
    module docstring."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        ver = version("sixaxis-track")
    except PackageNotFoundError:  # pragma: no cover
        ver = "dev"
    cards = _cards(r)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{_e(r.title)}</title><style>{_CSS}</style></head><body><main>",
        f"<header><h1>{_e(r.title)}</h1><p>{len(r.data)} poses from <code>{_e(r.data.source)}</code>"
        + (
            f", validated on {len(r.validation)} held-out poses from <code>{_e(r.validation.source)}</code>"
            if r.validation is not None
            else ""
        )
        + f"; nominal arm <code>{_e(r.robot.name)}</code>.</p>{_beyond_points_html(r)}"
        + f"{_left_out_html(r)}</header>",
        f'<div class="cards">{"".join(cards)}</div>',
        *_errors_section(r),
        *_diagnosis_section(r),
        *_parameters_section(r),
        *_identifiability_section(r),
        *_sensitivity_section(r),
        *_data_section(r),
        f"<footer>sixaxis-track {ver}"
        + (f" · <code>{_e(r.command)}</code>" if r.command else "")
        + "</footer>",
        "</main></body></html>",
    ]
    return "\n".join(p for p in parts if p)


def _cards(r: LabReport) -> list[str]:
    """The cards: nominal, calibrated, held-out RMS, noise floor, diagnosis."""
    nominal, final = r.runs[0], r.final
    first_d = r.runs[1].diagnosed
    cards = [
        _card("nominal RMS", f"{nominal.rms_mm:.3f} mm", f"max {nominal.max_mm:.3f} mm"),
        _card("calibrated RMS", f"{final.rms_mm:.4f} mm", f"max {final.max_mm:.4f} mm"),
    ]
    if r.validation is not None and final.validation_rms_mm is not None:
        cards.append(
            _card(
                "held-out RMS",
                f"{final.validation_rms_mm:.4f} mm",
                f"median {final.validation_median_mm:.4f} mm, {len(r.validation)} poses",
            )
        )
    if r.noise_floor_mm is not None:
        cards.append(
            _card("noise floor", f"{r.noise_floor_mm:.4f} mm", f"σ = {r.noise_mm:g} mm per axis")
        )
    cards.append(
        _card(
            "diagnosis",
            _verdict(first_d.verdict),
            "of "
            + _e(r.runs[1].label)
            + (f" → final {_verdict(final.diagnosed.verdict)}" if len(r.runs) > 2 else ""),
        )
    )

    return cards


def _errors_section(r: LabReport) -> list[str]:
    """1. The error before and after each model: the table and its figures."""
    model_rows = []
    for run in r.runs:
        model_rows.append(
            [
                _e(run.label),
                str(run.n_fitted) if run.fit is not None else "base, tool",
                f"{run.rms_mm:.4f}",
                f"{run.max_mm:.4f}",
                _mm(run.validation_rms_mm),
                _mm(run.validation_median_mm),
                _mm(run.diagnosis.cv_rms_mm) if run.diagnosis else "-",
                _verdict(run.diagnosis.verdict) if run.diagnosis else "",
            ]
        )

    floor_txt = (
        f" The dashed line is the noise floor σ·√3 = {r.noise_floor_mm:.4f} mm of a perfect model on held-out poses."
        if r.noise_floor_mm
        else ""
    )
    return [
        "<h2>1. Error before and after each model</h2>",
        "<p>The nominal arm (its base transform and tool offsets registered to the measurements), "
        "then each fitted model; every model after the first is the one the diagnosis of the model "
        "before it suggested.</p>",
        _table(
            [
                "model",
                "parameters fitted",
                "RMS (mm)",
                "max (mm)",
                "held-out RMS (mm)",
                "held-out median (mm)",
                "leave-one-out RMS (mm)",
                "verdict",
            ],
            model_rows,
        ),
        _img(
            r,
            "rms",
            "3-D RMS error of each model on the fitted poses and, hatched, on held-out poses."
            + floor_txt,
        ),
        _img(
            r,
            "residuals_validation",
            "Residual (predicted minus measured) per held-out pose, x, y, z and 3-D, for each model (the seed paper's Fig. 8).",
        ),
        _img(r, "residuals", "Residual per fitted pose, x, y, z and 3-D, for each model."),
    ]


def _diagnosis_section(r: LabReport) -> list[str]:
    """2. Each diagnosis, with the figure of the hints."""
    first_d = r.runs[1].diagnosed
    return [
        "<h2>2. Diagnosis: what does the model miss?</h2>",
        "<p>Each catalogued effect not in the model is tested per joint by a nested-model F-test, "
        f"with one family-wise significance level α = {first_d.alpha:g} over all candidates (Holm), "
        "and confirmed by its leave-one-pose-out RMS. Hints score every measured variable by how much "
        "of the remaining residual its smooth functions explain.</p>",
        *(_diagnosis_html(run, r, k) for k, run in enumerate(r.runs[1:], start=1)),
        _img(
            r,
            "hints",
            "The residual against the top hints of the first model, with the final model's overlaid, "
            "along the direction the variable explains best: the x, y, z or radial component, or for "
            "a joint variable the equivalent angle error of that joint (the residual projected on the "
            "tool point's motion by the joint). Lines: least-squares smooth fits.",
        )
        if "hints" in r.figures
        else f'<p class="note">No measured variable explains the residual of model {_e(r.runs[1].label)} '
        f"significantly (p &lt; {HINT_PLOT_P:g}): no hint is plotted.</p>",
    ]


def _parameters_section(r: LabReport) -> list[str]:
    """3. The identified parameters of the final model."""
    final = r.final
    fit = final.fitted
    return [
        f"<h2>3. Identified parameters: {_e(final.label)}</h2>",
        f"<p>Fit: {fit.loss} loss, {fit.iterations} iterations; residual σ = {fit.sigma_mm:.4f} mm per axis.</p>",
        _parameter_tables(fit),
    ]


def _identifiability_section(r: LabReport) -> list[str]:
    """4. Identifiability: rank, condition number, observability, the parameters fixed."""
    ident = r.final.fitted.identifiability
    combos = "".join(f"<li><code>{_e(c)}</code></li>" for c in ident.unidentifiable)
    warn = ""
    if ident.condition_number > CONDITION_WARNING:
        warn = (
            f'<p class="warn">Poor pose set: condition number {ident.condition_number:.3g} &gt; '
            f"{CONDITION_WARNING:g}. Plan poses with <code>sixaxis lab plan</code> or fit fewer effects.</p>"
        )
    return [
        "<h2>4. Identifiability</h2>",
        f"<p>{ident.rank} of {ident.n_parameters} parameters identifiable from {ident.n_poses} poses; "
        f"condition number of the column-scaled identification Jacobian {ident.condition_number:.3g}; "
        f"observability indices O1 = {ident.o1:.4g} (Borm &amp; Menq), O4 = {ident.o4:.4g} (Nahvi &amp; Hollerbach).</p>",
        warn,
        (
            f'<p>Fixed at nominal (each with the combination it cannot be separated from):</p><ul class="combos">{combos}</ul>'
            if combos
            else ""
        ),
        _img(
            r,
            "singular_values",
            "Singular values of the column-scaled identification Jacobian (identifiable parameters).",
        ),
    ]


def _sensitivity_section(r: LabReport) -> list[str]:
    """5. The error-factor sensitivity: the figure and the table of the arm's parameters."""
    fit = r.final.fitted
    s = r.sensitivity
    srows = []
    arm = set(arm_parameters(s.names))
    for k in [k for k in s.ranked("typical_mm") if k in arm][:12]:
        per, unit = s.per_unit[k], s.units[k]
        per_s = (
            f"{per:.3f} mm/mm"
            if unit == "m"
            else (
                f"{per:.3f} mm/mrad"
                if unit == "rad"
                else f"{per * 1e3:.4g} mm per {unit or 'unit'}"
            )
        )
        srows.append(
            [
                f"<code>{_e(s.names[k])}</code>",
                per_s,
                f"{s.typical_mm[k]:.4f}",
                f"{s.identified_mm[k]:.4f}" if fit.identifiable[k] else ("fixed", "fixed"),
                ("yes", "yes") if fit.identifiable[k] else ("no", "no"),
            ]
        )

    return [
        "<h2>5. Error-factor sensitivity</h2>",
        "<p>How far an error of each parameter of the arm moves the tool point, RMS over these poses "
        "(the seed paper's section 3.3 and Fig. 7): per unit error, for an error of the parameter's "
        "typical size (the tolerance that matters most when the arm is built), and for the error "
        "identified on this arm. The base transform is left out: it is where the arm stands.</p>",
        _img(
            r,
            "sensitivity",
            "Bars: RMS tool-point displacement for a typical-size error of each parameter (angles red, lengths blue); dots: for the error identified; hatched: not identifiable from these poses.",
        ),
        _table(
            [
                "parameter",
                "per unit error",
                "typical error moves (mm)",
                "identified error moves (mm)",
                "identifiable",
            ],
            srows,
        ),
    ]


def _data_section(r: LabReport) -> list[str]:
    """The data: the file, its columns and targets, the robot, the instrument's noise."""
    cols = (
        ", ".join(["q1..q6", "x, y, z", *r.data.columns]) if r.data.columns else "q1..q6, x, y, z"
    )
    return [
        "<h2>Data</h2>",
        _table(
            ["", ""],
            [
                ["measurements", f"<code>{_e(r.data.source)}</code>, {len(r.data)} poses"],
                *(
                    [["sessions", _e("; ".join(x.text() for x in r.data.sessions))]]
                    if len(r.data.sessions) > 1
                    else []
                ),
                ["columns", _e(cols)],
                ["targets", _e(", ".join(map(str, r.data.targets)))],
                ["robot", f"<code>{_e(r.robot.name)}</code>, {_e(r.robot.convention)} DH"],
                ["instrument noise", "-" if r.noise_mm is None else f"{r.noise_mm:g} mm per axis"],
            ],
            left=2,
        ),
    ]
