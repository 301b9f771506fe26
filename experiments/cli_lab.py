"""``sixaxis lab ...``: the model lab's commands, thin layers over the Python API.

    sixaxis lab collect -o data.csv --scenario compliance     # measure the simulated arm
    sixaxis lab fit data.csv --effects geometric               # Table 3, or --json (docs/format.md)
    sixaxis lab diagnose data.csv --noise-mm 0.015             # which effect does the model miss?
    sixaxis lab report data.csv -o report.html                 # fit, diagnose, refit, plots
    sixaxis lab plan --n 30 -o poses.csv                       # poses worth measuring
    sixaxis lab export data.csv --effects geometric,compliance -o calibrated.toml
    sixaxis lab compensate targets.csv --robot calibrated.toml -o joints.csv

Bad input (a missing file, a bad CSV cell, an unknown effect or unit) prints one line
``error: ...`` naming the file, line, column or option on stderr and exits with code 2; a
traceback means a bug. Library modules are imported inside each command, so ``sixaxis --help``
stays fast and only ``collect`` loads MuJoCo.

It is one module, longer than most, because it is one typer app: its commands are thin layers over
the lab's functions that share the options, the input checks and the JSON output; what they print is
built in :mod:`experiments.cli_output`.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from experiments.cli_output import (
    candidates_table,
    command_line,
    compensation_table,
    console,
    discovery_table,
    err_console,
    fail,
    fit_table,
    hints_table,
    plan_table,
    user_errors,
)

app = typer.Typer(
    help="The model lab: compare the model with measurements, find what it misses.",
    no_args_is_help=True,
)


def _terminated(signum: int, frame: object) -> NoReturn:
    raise SystemExit(128 + signum)


@app.callback()
def _lab(ctx: typer.Context) -> None:
    # Log records (e.g. lab's "poor pose set" warning) go to stderr, so that stdout carries only
    # the command's output: with --json, one JSON object.
    import logging
    import signal
    import threading

    from rich.logging import RichHandler

    for h in logging.getLogger().handlers:
        if isinstance(h, RichHandler):
            h.console = err_console
    # SIGTERM stops a command like Ctrl-C: cleanup runs (a half-written file's temporary is
    # removed); SIGKILL runs nothing, and the next write of that file removes what it left
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _terminated)
        ctx.call_on_close(lambda: signal.signal(signal.SIGTERM, previous))
    ctx.call_on_close(lambda: setattr(console, "stderr", False))  # after an output on stdout


LENGTH_UNITS = ("m", "mm")
ANGLE_UNITS = ("rad", "deg")


# -- shared options -------------------------------------------------------------------------------
DataArg = Annotated[
    Path,
    typer.Argument(
        help="A measurement CSV (docs/format.md, the measurement CSV).", metavar="DATA.csv"
    ),
]
RobotOpt = Annotated[
    str,
    typer.Option(
        "--robot",
        "-r",
        help="The nominal arm: a robot TOML file or a shipped name.",
        metavar="FILE|NAME",
    ),
]
EffectsOpt = Annotated[
    str,
    typer.Option(
        "--effects",
        "-e",
        help="Effects to fit, comma separated, optionally on some joints: "
        "geometric,compliance[2,3]. Catalogue: geometric, compliance, transmission, joint_scale, "
        "backlash, load_backlash, thermal, cyclic with its joints and orders per turn "
        "(cyclic[2:17,29;4:2]), and any --effect-module defines.",
    ),
]
ModuleOpt = Annotated[
    list[Path] | None,
    typer.Option(
        "--effect-module",
        help="A Python file defining Effect subclasses to register (repeatable). The file is "
        "imported, so its code runs: give only files you trust.",
        metavar="FILE.py",
    ),
]
ValidateOpt = Annotated[
    Path | None,
    typer.Option(
        "--validate", help="Held-out measurements (same units) for validation RMS and median."
    ),
]
LossOpt = Annotated[
    str, typer.Option("--loss", help="linear (least squares), huber or soft_l1 (robust).")
]
LengthOpt = Annotated[
    str, typer.Option("--length-unit", help="Unit of x, y, z in the CSV files: m or mm.")
]
AngleOpt = Annotated[
    str, typer.Option("--angle-unit", help="Unit of q1..q6 in the CSV files: rad or deg.")
]
NoiseOpt = Annotated[
    float | None,
    typer.Option(
        "--noise-mm",
        help="The instrument's per-axis standard uncertainty (mm); the noise floor of a 3-D "
        "RMS is this times sqrt(3). Default: estimated from the residual.",
    ),
]
NoisePpmOpt = Annotated[
    float,
    typer.Option(
        "--noise-ppm",
        help="How the per-axis sigma grows with the distance from the tracker, um per m (a "
        "GTS3800: 6): sigma = --noise-mm + --noise-ppm x distance, the tracker at the origin of "
        "the measurement frame (of each station). Rows are weighted by it.",
    ),
]
NoiseMradOpt = Annotated[
    float | None,
    typer.Option(
        "--noise-mrad",
        help="The per-axis standard uncertainty of a measured orientation (mrad); needed to "
        "weigh orientation rows against positions (or std_rx, std_ry, std_rz columns).",
    ),
]
OrientationUnitOpt = Annotated[
    str | None,
    typer.Option(
        "--orientation-unit",
        help="Unit of the orientation columns (rvx.. or roll, pitch, yaw) and their stds: rad "
        "or deg. Default: the --angle-unit.",
    ),
]
MeasuredOpt = Annotated[
    str | None,
    typer.Option(
        "--measured",
        help="The components the instrument measures, of x,y,z,rx,ry,rz (rx..rz: the "
        "orientation about the measurement frame's axes). Default: every one the file has "
        "columns for; x,y,z fits the positions alone.",
    ),
]
OutliersOpt = Annotated[
    str,
    typer.Option(
        "--outliers",
        help="auto: leave gross outliers out of the fit and the tests, named by line (a 3-D "
        "residual beyond the radius that Gaussian noise of the robust scale exceeds in 1 % of "
        "clean data sets, once the model and every catalogued effect explain what they can); "
        "keep: fit every pose.",
    ),
]
AcceptLargeOpt = Annotated[
    bool,
    typer.Option(
        "--accept-large",
        help="Keep a model whose identified parameters exceed the plausible bound of their "
        "kind (10 mm for a DH length error, 50 mrad for a DH angle error, ten times an "
        "effect's typical size) instead of refusing it; base and tool are never bounded.",
    ),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the JSON object only.")]
JsonOutOpt = Annotated[
    Path | None,
    typer.Option("--out", help="Also write the JSON object to this file (atomically)."),
]


@contextlib.contextmanager
def _writing(path: Path) -> Iterator[None]:
    """An error while writing ``path`` (a full disk, a path that became a device) becomes one
    error line."""
    from arm.files import OutputError

    try:
        yield
    except OutputError as exc:
        fail(exc)
    except OSError as exc:
        fail(f"{path}: cannot write ({exc.strerror or exc})")


def _check_units(length_unit: str, angle_unit: str) -> None:
    if length_unit not in LENGTH_UNITS:
        fail(f"--length-unit must be one of {', '.join(LENGTH_UNITS)}, got {length_unit!r}")
    if angle_unit not in ANGLE_UNITS:
        fail(f"--angle-unit must be one of {', '.join(ANGLE_UNITS)}, got {angle_unit!r}")


def _flag(key: str) -> str:
    return "--" + key.replace("_", "-")


def _lab_options(**given: Any):
    """The lab's options (:class:`lab.LabOptions`) from the command's flags; a bad value is
    refused naming its flag, every bad one at once (the checks are the options' own)."""
    from arm.constraints import check, constraints_of
    from lab.options import LabOptions

    bad = check(given, constraints_of(LabOptions), name=_flag)
    if bad:
        fail("; ".join(bad))
    return LabOptions(**given)


def _load_modules(modules: Sequence[Path] | None) -> list[str]:
    """Register the effects of every ``--effect-module`` file; returns their names."""
    from arm.effects import load_effect_module

    names: list[str] = []
    for m in modules or ():
        with user_errors(prefix="--effect-module: "):
            names += load_effect_module(m)
    return names


def _parse_effects(effects: str) -> None:
    from arm.effects import parse_effects

    with user_errors(prefix="--effects: "):
        if not parse_effects(effects):
            fail("--effects: no effect given")


def _robot(robot: str):
    from arm.description import load_robot
    from arm.effects import check_robot_effects

    with user_errors(prefix="--robot: "):
        arm = load_robot(robot)
        check_robot_effects(arm, robot)  # after --effect-module registered its effects
        return arm


def _read(
    path: Path,
    length_unit: str,
    angle_unit: str,
    orientation_unit: str | None = None,
    measured: str | None = None,
):
    import warnings

    from arm.measurements import MeasurementWarning, read_measurements

    parts = None if measured is None else tuple(m.strip() for m in measured.split(","))
    with user_errors(), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MeasurementWarning)
        data = read_measurements(
            path,
            length_unit=length_unit,
            angle_unit=angle_unit,
            orientation_unit=orientation_unit,
            measured=parts,
        )
    for w in caught:  # unknown columns: said, not dropped
        console.print(f"[yellow]warning:[/yellow] {escape(str(w.message))}", soft_wrap=True)
    return data


def _check_outputs(
    outputs: Sequence[tuple[Path | None, str]],
    inputs: Sequence[object],
    as_json: bool = False,
) -> None:
    """Before any work: every output can be written (a regular file, or ``-`` for standard
    output) and replaces no input (data, held-out data, a robot file, an effect module, a poses
    or targets file). With an output on standard output, what the command prints goes to stderr."""
    from arm.files import check_output, is_stdout

    files = [Path(str(i)) for i in inputs if i is not None and Path(str(i)).is_file()]
    seen: dict[Path, str] = {}
    for path, option in outputs:
        if path is None:
            continue
        with user_errors():
            check_output(path, files, option)
        key = Path("/dev/stdout") if is_stdout(path) else path.absolute()
        if key in seen:
            fail(f"{option} {path}: also given as {seen[key]}; one file cannot hold both")
        if is_stdout(path) and as_json:
            fail(
                f"{option} -: --json prints on standard output too; give a file or leave out --json"
            )
        seen[key] = option
    if any(is_stdout(p) for p, _ in outputs):
        _print_to_stderr()


def _print_to_stderr() -> None:
    """The command's tables and messages go to stderr until it ends (stdout carries a file; the
    group's callback puts them back)."""
    console.stderr = True  # the console writes to whatever sys.stderr is when it prints


def _prepare(
    data: Path,
    robot: str,
    effects: str,
    modules: Sequence[Path] | None,
    validate: Path | None,
    length_unit: str,
    angle_unit: str,
    outputs: Sequence[tuple[Path | None, str]] = (),
    orientation_unit: str | None = None,
    measured: str | None = None,
    **options: Any,
):
    """Check the options (cheap ones first: the lab's ``options``, :class:`lab.LabOptions`) and
    the output places, register effect modules, read the robot and data."""
    opts = _lab_options(**options)
    _check_units(length_unit, angle_unit)
    if orientation_unit is not None and orientation_unit not in ANGLE_UNITS:
        fail(
            f"--orientation-unit must be one of {', '.join(ANGLE_UNITS)}, got {orientation_unit!r}"
        )
    _check_outputs(outputs, [data, validate, robot, *(modules or ())])
    _load_modules(modules)
    _parse_effects(effects)
    arm = _robot(robot)
    meas = _read(data, length_unit, angle_unit, orientation_unit, measured)
    val = None
    if validate is not None:
        val = _read(validate, length_unit, angle_unit, orientation_unit, measured)
    return arm, meas, val, opts


def _json_safe(obj: Any) -> Any:
    """Plain JSON: numpy scalars and arrays as numbers and lists, NaN and inf as null."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_safe(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    return obj


def _dump(obj: dict) -> str:
    return json.dumps(_json_safe(obj), indent=2, allow_nan=False)


def _emit_json(obj: dict, as_json: bool, out: Path | None) -> None:
    from arm.files import atomic_write_text, is_stdout

    text = _dump(obj)
    if out is not None:
        with _writing(out):
            atomic_write_text(out, text + "\n")
    if as_json and not is_stdout(out):
        print(text)
    elif out is not None:
        console.print(f"wrote {out}", highlight=False, soft_wrap=True)


def _size_kb(path: Path) -> str:
    """`` (12 KB)``: the size of the file written; nothing for standard output."""
    return "" if str(path) == "-" else f" ({path.stat().st_size / 1024:.0f} KB)"


# -- fit --------------------------------------------------------------------------------------------
def _fitted(meas, arm, effects: str, opts, val):
    """The lab's fit of the command's data (``lab fit``, ``lab export``)."""
    from lab import fit

    with user_errors():
        return fit(meas, arm, effects, options=opts, validate=val)


def _print_fit(result) -> None:
    console.print(fit_table(result))
    console.print(escape(result.summary()), highlight=False, soft_wrap=True)


@app.command("fit")
def fit_cmd(
    data: DataArg,
    robot: RobotOpt = "seed",
    effects: EffectsOpt = "geometric",
    validate: ValidateOpt = None,
    loss: LossOpt = "linear",
    effect_module: ModuleOpt = None,
    length_unit: LengthOpt = "m",
    angle_unit: AngleOpt = "rad",
    noise_mm: NoiseOpt = None,
    noise_ppm: NoisePpmOpt = 0.0,
    noise_mrad: NoiseMradOpt = None,
    orientation_unit: OrientationUnitOpt = None,
    measured: MeasuredOpt = None,
    outliers: OutliersOpt = "auto",
    accept_large: AcceptLargeOpt = False,
    as_json: JsonOpt = False,
    out: JsonOutOpt = None,
) -> None:
    """Identify the model's parameters from measured tool points.

    Prints the identified parameters with standard errors, the RMS before and after, and which
    parameters the poses cannot identify; --json prints the JSON object of docs/format.md, the
    lab's JSON output (SI units)."""
    arm, meas, val, opts = _prepare(
        data,
        robot,
        effects,
        effect_module,
        validate,
        length_unit,
        angle_unit,
        outputs=[(out, "--out")],
        noise_mm=noise_mm,
        noise_ppm=noise_ppm,
        noise_mrad=noise_mrad,
        orientation_unit=orientation_unit,
        measured=measured,
        loss=loss,
        outliers=outliers,
        accept_large=accept_large,
    )
    result = _fitted(meas, arm, effects, opts, val)
    if not as_json:
        _print_fit(result)
    _emit_json(result.to_dict(), as_json, out)


# -- what the user gave, for the commands printed as next steps ---------------------------------------
def _context(
    robot: str = "seed",
    length_unit: str = "m",
    angle_unit: str = "rad",
    effect_module: Sequence[Path] | None = None,
    noise_mm: float | None = None,
    loss: str = "linear",
    outliers: str = "auto",
    accept_large: bool = False,
) -> dict[str, Any]:
    """The options of a command that a printed next step must repeat to work on the same data
    (the arm, the units, the effect modules, the noise and the screening), as command-line flags;
    the defaults left out."""
    return {
        "--robot": None if robot == "seed" else robot,
        "--length-unit": None if length_unit == "m" else length_unit,
        "--angle-unit": None if angle_unit == "rad" else angle_unit,
        "--effect-module": [str(m) for m in effect_module or ()],
        "--noise-mm": noise_mm,
        "--loss": None if loss == "linear" else loss,
        "--outliers": None if outliers == "auto" else outliers,
        "--accept-large": accept_large,
    }


def _print_noise(obj) -> None:
    """The noise floor's source (repeated poses) and, when only noise is left, what it implies."""
    from lab.repeatability import NoiseFloor

    text = NoiseFloor(obj.noise_mm, obj.noise_source, obj.repeatability).text()
    if text:
        console.print(escape(text), highlight=False, soft_wrap=True)
    if obj.noise_note:
        console.print(f"[yellow]{escape(obj.noise_note)}[/yellow]", highlight=False, soft_wrap=True)


def _print_notes(notes: Sequence[str], title: str) -> None:
    for n in notes:
        console.print(f"{title}: {escape(n)}", highlight=False, soft_wrap=True)


# -- diagnose ---------------------------------------------------------------------------------------
def _print_diagnosis(d, data: Path, context: dict[str, Any] | None = None) -> None:
    floor = f", noise floor {d.noise_floor_mm:.4f} mm" if d.noise_floor_mm else ""
    console.print(
        f"model [bold]{escape(', '.join(d.effects))}[/bold] on {d.fit.n_points} points: RMS "
        f"{d.rms_mm:.4f} mm, held-out {d.cv_rms_mm:.4f} mm{floor}",
        highlight=False,
        soft_wrap=True,
    )
    ctx = dict(context or {})
    _print_noise(d)
    colour = {"none": "green", "unexplained": "yellow", "noise": "yellow"}.get(d.verdict, "red")
    line = f"verdict: [bold {colour}]{escape(d.verdict)}[/bold {colour}]"
    if d.verdict == "none" and d.noise_mm is None:
        line += (
            " (no catalogued effect is significant; give --noise-mm to test the residual "
            "against the instrument's noise)"
        )
    elif d.verdict == "none":
        line += " (the residual is consistent with the noise: nothing missing)"
    elif d.verdict == "noise":
        line += " (nothing is missing, but the noise is above the one the tests used)"
    elif d.verdict == "unexplained":
        line += " (the residual is above the noise and no catalogued effect explains it)"
    if d.suggestion:
        then = escape(command_line("lab", "fit", data, **{"--effects": d.suggestion}, **ctx))
        if d.verdict == "unexplained":
            line += f"; the catalogue's best, which explains part: {then}"
        else:
            line += f"; next: {then}"
    console.print(line, highlight=False, soft_wrap=True)
    if d.cyclic_orders:
        console.print(
            "cyclic errors, orders per turn: "
            + "; ".join(
                f"joint {j}: {', '.join(map(str, ks))}" for j, ks in d.cyclic_orders.items()
            ),
            highlight=False,
            soft_wrap=True,
        )
        for reading in d.readings:
            console.print(f"  {escape(reading)}", highlight=False, soft_wrap=True)
    _print_notes(d.notes, "cannot resolve")
    _print_notes(d.implausible, "passed over as implausible")
    if d.verdict == "unexplained":
        console.print(
            "next: let the lab search for the missing term's form: "
            + escape(discover_command(data, d, ctx)),
            highlight=False,
            soft_wrap=True,
        )
    from lab.text import left_out_lines

    for text in left_out_lines(
        d.fit.duplicates, d.outlier_list, d.outlier_rule, of="the fit and the tests"
    ):
        console.print(escape(text), highlight=False, soft_wrap=True)
    lack: dict[str, list[str]] = {}  # what is missing -> the candidates that need it
    for label, why in d.skipped.items():
        if why.startswith("needs "):
            lack.setdefault(why[len("needs ") :], []).append(label)
    if lack:
        console.print(
            "[yellow]not tested[/yellow], for lack of data: "
            + escape("; ".join(f"{', '.join(k)} (needs {v})" for v, k in lack.items())),
            highlight=False,
            soft_wrap=True,
        )
    shown = d.candidates[:10]
    if shown:
        console.print(candidates_table(shown))
    if len(d.candidates) > len(shown):
        console.print(f"... and {len(d.candidates) - len(shown)} more (--json lists all)")
    if d.hints:
        console.print(hints_table(d.hints[:6]))


def discover_command(data: Path, d, context: dict[str, Any] | None = None) -> str:
    """The ``sixaxis lab discover`` command that continues an ``unexplained`` diagnosis: from
    the diagnosed model (not the catalogue's partial explanation, whose approximating terms would
    hide the form), with its noise (the one stated, not one measured from repeated poses, which
    discover measures again) and the options the diagnosis was given."""
    effects = ",".join(d.effects)
    ctx = dict(context or {})
    ctx.pop("--accept-large", None)  # discover's own fits keep the bounds
    if d.noise_source == "stated":
        ctx["--noise-mm"] = d.noise_mm
    return command_line(
        "lab",
        "discover",
        data,
        **{"--effects": None if effects == "geometric" else effects, "-o": "discovered.py"},
        **ctx,
    )


@app.command("diagnose")
def diagnose_cmd(
    data: DataArg,
    robot: RobotOpt = "seed",
    effects: EffectsOpt = "geometric",
    noise_mm: NoiseOpt = None,
    noise_ppm: NoisePpmOpt = 0.0,
    noise_mrad: NoiseMradOpt = None,
    orientation_unit: OrientationUnitOpt = None,
    measured: MeasuredOpt = None,
    loss: LossOpt = "linear",
    effect_module: ModuleOpt = None,
    length_unit: LengthOpt = "m",
    angle_unit: AngleOpt = "rad",
    alpha: Annotated[float, typer.Option(help="Family-wise false-alarm rate of the tests.")] = 0.02,
    outliers: OutliersOpt = "auto",
    accept_large: AcceptLargeOpt = False,
    as_json: JsonOpt = False,
    out: JsonOutOpt = None,
) -> None:
    """Fit the model and test which catalogued effect it misses.

    The verdict names the missing effect, or says none (the residual is noise; needs --noise-mm)
    or unexplained; candidates are ranked with their p-values, hints say which measured variables
    the residual still depends on."""
    from lab import diagnose

    arm, meas, _, opts = _prepare(
        data,
        robot,
        effects,
        effect_module,
        None,
        length_unit,
        angle_unit,
        outputs=[(out, "--out")],
        noise_mm=noise_mm,
        noise_ppm=noise_ppm,
        noise_mrad=noise_mrad,
        orientation_unit=orientation_unit,
        measured=measured,
        loss=loss,
        outliers=outliers,
        accept_large=accept_large,
    )
    if not 0 < alpha < 1:
        fail(f"--alpha must lie in (0, 1), got {alpha}")
    with user_errors():
        with console.status("fitting and testing the candidate effects..."):
            d = diagnose(meas, arm, effects, options=opts, alpha=alpha)
    if not as_json:
        ctx = _context(
            robot, length_unit, angle_unit, effect_module, noise_mm, loss, outliers, accept_large
        )
        _print_diagnosis(d, data, ctx)
    _emit_json(d.to_dict(), as_json, out)


# -- discover ---------------------------------------------------------------------------------------
def _print_discovery(
    d, output: Path | None, data: Path | None = None, context: dict[str, Any] | None = None
) -> None:
    floor = f", noise floor {d.noise_floor_mm:.4f} mm" if d.noise_floor_mm else ""
    console.print(
        f"model [bold]{escape(', '.join(d.effects))}[/bold] on {d.base.n_points} points: RMS "
        f"{d.rms_mm:.4f} mm{floor}; {d.n_candidates} candidate terms (harmonics to order "
        f"{d.order} per turn, fewer where the sampling resolves fewer), family-wise "
        f"false-discovery rate {d.alpha:g}",
        highlight=False,
        soft_wrap=True,
    )
    _print_noise(d)
    colour = {"none": "green", "unexplained": "yellow", "noise": "yellow"}.get(d.verdict, "red")
    line = f"verdict: [bold {colour}]{escape(d.verdict)}[/bold {colour}]"
    if d.verdict == "none" and d.noise_mm is None:
        line += " (no term is significant; give --noise-mm to test the residual against the noise)"
    elif d.verdict == "none":
        line += " (the residual is consistent with the noise: nothing missing)"
    elif d.verdict == "noise":
        line += " (no term is significant, but the noise is above the one the tests used)"
    elif d.verdict == "unexplained" and d.terms:
        line += " (the terms found explain part; the residual stays above the noise)"
    elif d.verdict == "unexplained":
        line += " (the residual is above the noise and no term of the library explains it)"
    console.print(line, highlight=False, soft_wrap=True)
    _print_notes(d.notes, "cannot resolve")
    if not d.terms:
        return
    for f in d.formulas.values():
        console.print(f"  [bold]{escape(f)}[/bold]", highlight=False, soft_wrap=True)
    console.print(discovery_table(d.terms))
    for reading in dict.fromkeys(t.reading for t in d.terms):
        terms = ", ".join(t.expression for t in d.terms if t.reading == reading)
        console.print(f"  {escape(terms)}: {escape(reading)}", highlight=False, soft_wrap=True)
    held = f", held-out {d.validation_rms_mm:.4f} mm" if d.validation_rms_mm is not None else ""
    console.print(
        f"with the terms: RMS {d.rms_after_mm:.4f} mm{held}", highlight=False, soft_wrap=True
    )
    if output is not None:
        ctx = dict(context or {})
        modules = [*ctx.pop("--effect-module", []), str(output)]
        console.print(
            f"wrote the effect to {escape(str(output))}; fit it with: "
            + escape(
                command_line(
                    "lab",
                    "fit",
                    data if data is not None else "DATA.csv",
                    **{"--effect-module": modules, "--effects": d.suggestion},
                    **ctx,
                )
            ),
            highlight=False,
            soft_wrap=True,
        )


@app.command("discover")
def discover_cmd(
    data: DataArg,
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            help="The effect module (Python) to write when terms are found; load it with "
            "--effect-module. Nothing is written when nothing is found.",
            metavar="MODULE.py",
        ),
    ] = None,
    robot: RobotOpt = "seed",
    effects: Annotated[
        str,
        typer.Option(
            "--effects",
            "-e",
            help="The model E to start from (default geometric; or the diagnosis's best "
            "catalogued model, e.g. geometric,compliance[2,3]).",
        ),
    ] = "geometric",
    noise_mm: NoiseOpt = None,
    noise_ppm: NoisePpmOpt = 0.0,
    noise_mrad: NoiseMradOpt = None,
    orientation_unit: OrientationUnitOpt = None,
    measured: MeasuredOpt = None,
    validate: ValidateOpt = None,
    effect_module: ModuleOpt = None,
    length_unit: LengthOpt = "m",
    angle_unit: AngleOpt = "rad",
    alpha: Annotated[
        float, typer.Option(help="Family-wise false-discovery rate (as diagnose's --alpha).")
    ] = 0.02,
    order: Annotated[
        int,
        typer.Option(
            help="The highest harmonic sin/cos(m*q) per turn scanned on every joint (fewer on a "
            "joint whose sampling resolves fewer: a grid aliases high orders)."
        ),
    ] = 64,
    name: Annotated[
        str, typer.Option(help="The discovered effect's name (lower case, digits, _).")
    ] = "discovered",
    as_json: JsonOpt = False,
    out: JsonOutOpt = None,
) -> None:
    """Search a library of candidate terms for the form of what the model misses.

    Sparse regression over joint-angle terms theta_j = q_j + k*f(variables) (harmonics of q_j,
    powers and the sign of tau_j, temperature and its products, t, payload, dir_j), each
    projected through the identification Jacobian and out of the model's span; the terms found
    are refitted with the model and written as an effect class (-o MODULE.py)."""
    from lab.discovery import discover

    if output is not None and output.suffix != ".py" and not output.is_dir():
        fail(f"{output}: the effect module must be a .py file")
    arm, meas, val, opts = _prepare(
        data,
        robot,
        effects,
        effect_module,
        validate,
        length_unit,
        angle_unit,
        outputs=[(output, "--output"), (out, "--out")],
        noise_mm=noise_mm,
        noise_ppm=noise_ppm,
        noise_mrad=noise_mrad,
        orientation_unit=orientation_unit,
        measured=measured,
    )
    if not 0 < alpha < 1:
        fail(f"--alpha must lie in (0, 1), got {alpha}")
    with user_errors():
        with console.status("fitting the model and searching the library..."):
            d = discover(
                meas, arm, effects, options=opts, validate=val, alpha=alpha, order=order, name=name
            )
    written = None
    if output is not None and d.terms:
        with _writing(output):
            written = d.write_module(output)
    if not as_json:
        ctx = _context(robot, length_unit, angle_unit, effect_module, noise_mm)
        _print_discovery(d, written, data, ctx)
    _emit_json(d.to_dict(), as_json, out)


# -- report -----------------------------------------------------------------------------------------
@app.command("report")
def report_cmd(
    data: DataArg,
    output: Annotated[Path, typer.Option("--output", "-o", help="The HTML file to write.")] = Path(
        "report.html"
    ),
    robot: RobotOpt = "seed",
    effects: EffectsOpt = "geometric",
    validate: ValidateOpt = None,
    noise_mm: NoiseOpt = None,
    noise_ppm: NoisePpmOpt = 0.0,
    noise_mrad: NoiseMradOpt = None,
    orientation_unit: OrientationUnitOpt = None,
    measured: MeasuredOpt = None,
    loss: LossOpt = "linear",
    effect_module: ModuleOpt = None,
    length_unit: LengthOpt = "m",
    angle_unit: AngleOpt = "rad",
    rounds: Annotated[
        int, typer.Option(help="At most this many rounds of diagnose-and-refit.")
    ] = 3,
    outliers: OutliersOpt = "auto",
    accept_large: AcceptLargeOpt = False,
) -> None:
    """Fit, diagnose, refit what the diagnosis suggests; write an HTML report.

    Repeats diagnose-and-refit while the verdict names a missing catalogued effect (at most
    --rounds times); the report has the tables and plots of every model."""
    from lab.report import build_report

    arm, meas, val, opts = _prepare(
        data,
        robot,
        effects,
        effect_module,
        validate,
        length_unit,
        angle_unit,
        outputs=[(output, "--output")],
        noise_mm=noise_mm,
        noise_ppm=noise_ppm,
        noise_mrad=noise_mrad,
        orientation_unit=orientation_unit,
        measured=measured,
        loss=loss,
        outliers=outliers,
        accept_large=accept_large,
    )
    if rounds < 0:
        fail(f"--rounds must be >= 0, got {rounds}")
    command = command_line(
        "lab",
        "report",
        data,
        **{
            "-o": output,
            "--robot": None if robot == "seed" else robot,
            "--effects": None if effects == "geometric" else effects,
            "--validate": validate,
            "--noise-mm": noise_mm,
            "--noise-ppm": noise_ppm or None,
            "--noise-mrad": noise_mrad,
            "--orientation-unit": orientation_unit,
            "--measured": measured,
            "--loss": None if loss == "linear" else loss,
            "--effect-module": [str(m) for m in effect_module or []],
            "--length-unit": None if length_unit == "m" else length_unit,
            "--angle-unit": None if angle_unit == "rad" else angle_unit,
            "--rounds": None if rounds == 3 else rounds,
            "--outliers": None if outliers == "auto" else outliers,
            "--accept-large": accept_large,
        },
    )
    t0 = time.perf_counter()
    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        TimeElapsedColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task("starting", total=None)
        last = [None, t0]

        def step(message: str | None) -> None:
            now = time.perf_counter()
            if last[0] is not None:
                bar.console.print(
                    f"[green]done[/green] {escape(last[0])} ({now - last[1]:.2f} s)",
                    highlight=False,
                    soft_wrap=True,
                )
            last[:] = [message, now]
            if message is not None:
                bar.update(task, description=escape(message))

        with user_errors():
            rep = build_report(
                meas,
                arm,
                effects,
                options=opts,
                validate=val,
                rounds=rounds,
                command=command,
                progress=step,
            )
        step("writing the HTML")
        with _writing(output):
            rep.write(output)
        step(None)
    from lab.text import left_out_lines

    for text in left_out_lines(
        rep.duplicates, rep.outliers, rep.outlier_rule, of="every model and every test"
    ):
        console.print(escape(text), highlight=False, soft_wrap=True)
    for run in rep.runs:
        verdict = f", verdict {run.diagnosis.verdict}" if run.diagnosis is not None else ""
        held = (
            f", held-out {run.validation_rms_mm:.4f} mm"
            if run.validation_rms_mm is not None
            else ""
        )
        console.print(
            f"  {escape(run.label):<28} RMS {run.rms_mm:.4f} mm{held}{verdict}",
            highlight=False,
            soft_wrap=True,
        )
    console.print(
        f"wrote {output}{_size_kb(output)} in {time.perf_counter() - t0:.1f} s",
        highlight=False,
        soft_wrap=True,
    )


# -- plan -------------------------------------------------------------------------------------------
@app.command("plan")
def plan_cmd(
    n: Annotated[int, typer.Option("--n", "-n", help="How many poses to choose.")] = 30,
    output: Annotated[
        Path, typer.Option("--output", "-o", help="The poses CSV to write (q1..q6).")
    ] = Path("poses.csv"),
    robot: RobotOpt = "seed",
    effects: EffectsOpt = "geometric",
    effect_module: ModuleOpt = None,
    candidates: Annotated[
        int, typer.Option(help="Random candidate poses (within the limits) to choose from.")
    ] = 2000,
    criterion: Annotated[
        str, typer.Option(help="O1 (D-optimal, all parameters) or O4 (the weakest one).")
    ] = "O1",
    noise_mm: Annotated[
        float,
        typer.Option(
            "--noise-mm",
            help="The instrument's per-axis noise (mm): parameters that N poses cannot "
            "determine above it are not planned for.",
        ),
    ] = 0.015,
    seed: Annotated[int, typer.Option(help="Seed of the random candidates.")] = 0,
    angle_unit: Annotated[
        str, typer.Option("--angle-unit", help="Unit of q1..q6 in the file: rad or deg.")
    ] = "rad",
    noise_mrad: Annotated[
        float | None,
        typer.Option(
            "--noise-mrad",
            help="Plan for an instrument that measures the tool frame's orientation too, with "
            "this per-axis noise (mrad): six rows a pose, weighted against the position's.",
        ),
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """Choose N calibration poses that identify the most; write their joint angles.

    O1 (Borm & Menq) is D-optimality over all identifiable parameters, O4 (Nahvi & Hollerbach)
    the noise amplification of the weakest one; both are printed beside random pose sets."""
    from arm.measurements import write_poses
    from lab import plan

    _check_units("m", angle_unit)
    _lab_options(noise_mm=noise_mm, noise_mrad=noise_mrad)
    crit = criterion.lower()
    if crit not in ("o1", "o4"):
        fail(f"--criterion must be O1 or O4, got {criterion!r}")
    if n < 1:
        fail(f"--n must be at least 1, got {n}")
    if candidates < n:
        fail(f"--candidates ({candidates}) must be at least --n ({n})")
    _check_outputs([(output, "--output")], [robot, *(effect_module or ())], as_json)
    _load_modules(effect_module)
    _parse_effects(effects)
    arm = _robot(robot)
    with user_errors():
        with console.status(f"choosing {n} of {candidates} poses by {crit.upper()}..."):
            p = plan(
                n,
                arm,
                effects,
                criterion=crit,
                candidates=candidates,
                noise_mm=noise_mm,
                seed=seed,
                noise_mrad=noise_mrad,
            )
    with _writing(output):
        write_poses(p.q, output, angle_unit)
    if as_json:
        print(_dump(p.to_dict() | {"output": str(output), "angle_unit": angle_unit}))
        return
    console.print(plan_table(p, crit))
    ident = p.identifiability
    console.print(
        f"{ident.rank} of {ident.n_parameters} parameters identifiable, condition number "
        f"{p.condition_number:.3g}",
        highlight=False,
        soft_wrap=True,
    )
    if ident.unidentifiable:
        console.print(
            (
                "not identifiable from poses (fixed): "
                if noise_mrad
                else "not identifiable from positions (fixed): "
            )
            + escape("; ".join(ident.unidentifiable)),
            highlight=False,
            soft_wrap=True,
        )
    console.print(f"wrote {output} (q1..q6 in {angle_unit})", highlight=False, soft_wrap=True)


# -- collect ----------------------------------------------------------------------------------------
@app.command("collect")
def collect_cmd(
    output: Annotated[Path, typer.Option("--output", "-o", help="The measurement CSV to write.")],
    scenario: Annotated[
        str,
        typer.Option(
            help="The simulated arm's hidden effects: nominal, geometric, compliance, "
            "transmission, backlash, thermal, payload, all, cyclic."
        ),
    ] = "compliance",
    n: Annotated[int, typer.Option("--n", "-n", help="Random poses to measure.")] = 200,
    noise_mm: Annotated[
        float, typer.Option("--noise-mm", help="The tracker's per-axis noise (mm).")
    ] = 0.015,
    seed: Annotated[int, typer.Option(help="Seed of the poses, the motions and the noise.")] = 0,
    arm_seed: Annotated[
        int | None,
        typer.Option(
            help="Seed of the hidden arm (default: --seed). Measure one arm twice, e.g. for "
            "held-out data: --seed 1 and --seed 2 --arm-seed 1."
        ),
    ] = None,
    poses: Annotated[
        Path | None,
        typer.Option(help="A poses CSV (q1..q6, e.g. from sixaxis lab plan) instead of --n."),
    ] = None,
    angle_unit: Annotated[
        str | None,
        typer.Option(
            "--angle-unit",
            help="Unit of q1..q6 in --poses: rad or deg (default: the unit the file's # line "
            "declares, as sixaxis lab plan writes it; else rad).",
        ),
    ] = None,
    robot: RobotOpt = "seed",
    noise_ppm: Annotated[
        float,
        typer.Option(
            "--noise-ppm",
            help="The noise grows with the distance from the tracker: sigma = --noise-mm + "
            "--noise-ppm um per m of distance, per axis.",
        ),
    ] = 0.0,
    stations: Annotated[
        int,
        typer.Option(
            "--stations",
            help="Tracker stations around the arm (2-6 m away, each its own frame): the poses "
            "are measured in blocks, one per station, with a station column. 0: the world "
            "frame, no station column.",
        ),
    ] = 0,
    first_station: Annotated[
        int,
        typer.Option(
            "--first-station",
            help="The first station's id (the others follow): a held-out campaign from other "
            "stations of the same arm takes other ids.",
        ),
    ] = 1,
    orientation: Annotated[
        bool,
        typer.Option(
            "--orientation",
            help="A 6-DoF probe on the flange measures the tool frame's orientation too "
            "(roll, pitch, yaw columns).",
        ),
    ] = False,
    noise_mrad: Annotated[
        float, typer.Option("--noise-mrad", help="The orientation's per-axis noise (mrad).")
    ] = 0.1,
    orientation_fraction: Annotated[
        float,
        typer.Option(
            "--orientation-fraction",
            help="The fraction of rows in which the probe's orientation is seen (the others "
            "leave it blank: the measurement mask).",
        ),
    ] = 1.0,
    stds: Annotated[
        bool,
        typer.Option(
            "--stds", help="Write each row's stated uncertainty (std_x ... std_rz columns)."
        ),
    ] = False,
) -> None:
    """Measure the simulated arm (MuJoCo) like a laser-tracker campaign.

    Each pose is approached from a random side, settled, and its tool point measured with
    noise; the CSV (docs/format.md, the measurement CSV) has every optional column. A campaign
    can be measured from several tracker stations, with distance-dependent noise, a 6-DoF probe
    and each row's stated uncertainty."""
    import numpy as np

    from arm.measurements import read_poses
    from arm.sampling import rng_from
    from envs.scenarios import SCENARIOS, draw_truth

    _check_units("m", angle_unit or "rad")
    _check_outputs([(output, "--output")], [poses, robot])
    if scenario not in SCENARIOS:
        fail(f"--scenario: unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")
    for flag, v in (
        ("--noise-mm", noise_mm),
        ("--noise-ppm", noise_ppm),
        ("--noise-mrad", noise_mrad),
    ):
        if not (math.isfinite(v) and v >= 0):
            fail(f"{flag} must be >= 0, got {v}")
    if stations < 0:
        fail(f"--stations must be >= 0, got {stations}")
    if not 0.0 <= orientation_fraction <= 1.0:
        fail(f"--orientation-fraction must lie in [0, 1], got {orientation_fraction}")
    if poses is None and n < 1:
        fail(f"--n must be at least 1, got {n}")
    arm = _robot(robot)
    q = None
    if poses is not None:
        with user_errors():
            q = read_poses(poses, angle_unit)
        outside = ~arm.within_limits(q)
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            fail(f"{poses}: pose {i + 1} is outside the joint limits of {arm.name}: {q[i]}")
    from envs.collect import collect_measurements  # MuJoCo is loaded only here

    with user_errors():
        rng = rng_from(
            seed if arm_seed is None else arm_seed, "--arm-seed" if arm_seed else "--seed"
        )
        truth = draw_truth(scenario, arm, rng)
    total = len(q) if q is not None else n
    t0 = time.perf_counter()
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=console,
    ) as bar:
        task = bar.add_task(f"measuring ({scenario})", total=total)
        with user_errors(), _writing(output):
            meas = collect_measurements(
                truth=truth,
                poses=q,
                n=total,
                scenario=scenario,
                noise_mm=noise_mm,
                seed=seed,
                robot=arm,
                path=output,
                progress=lambda i, _n: bar.update(task, completed=i),
                noise_ppm=noise_ppm,
                stations=stations,
                first_station=first_station,
                orientation=orientation,
                noise_mrad=noise_mrad,
                orientation_fraction=orientation_fraction,
                stds=stds,
            )
    console.print(
        f"wrote {len(meas)} measurements of the simulated arm ({scenario}, noise "
        f"{noise_mm:g} mm"
        + (f" + {noise_ppm:g} um/m" if noise_ppm else "")
        + " per axis"
        + (f", {stations} station(s)" if stations else "")
        + (f", orientations ({noise_mrad:g} mrad)" if orientation else "")
        + f") to {output} in {time.perf_counter() - t0:.1f} s",
        highlight=False,
        soft_wrap=True,
    )


# -- export / compensate ----------------------------------------------------------------------------
@app.command("export")
def export_cmd(
    data: DataArg,
    output: Annotated[
        Path, typer.Option("--output", "-o", help="The calibrated robot TOML to write.")
    ] = Path("calibrated.toml"),
    robot: RobotOpt = "seed",
    effects: EffectsOpt = "geometric",
    validate: ValidateOpt = None,
    loss: LossOpt = "linear",
    effect_module: ModuleOpt = None,
    length_unit: LengthOpt = "m",
    angle_unit: AngleOpt = "rad",
    noise_mm: NoiseOpt = None,
    noise_ppm: NoisePpmOpt = 0.0,
    noise_mrad: NoiseMradOpt = None,
    orientation_unit: OrientationUnitOpt = None,
    measured: MeasuredOpt = None,
    name: Annotated[
        str | None, typer.Option(help="The calibrated arm's name (default: <robot>-calibrated).")
    ] = None,
    outliers: OutliersOpt = "auto",
    accept_large: AcceptLargeOpt = False,
) -> None:
    """Fit, then write the calibrated arm as a robot TOML.

    The geometric errors are folded into the DH table, base and tool, other effects' values
    kept; the file works as --robot anywhere."""
    from lab.export import export_robot

    arm, meas, val, opts = _prepare(
        data,
        robot,
        effects,
        effect_module,
        validate,
        length_unit,
        angle_unit,
        outputs=[(output, "--output")],
        noise_mm=noise_mm,
        noise_ppm=noise_ppm,
        noise_mrad=noise_mrad,
        orientation_unit=orientation_unit,
        measured=measured,
        loss=loss,
        outliers=outliers,
        accept_large=accept_large,
    )
    result = _fitted(meas, arm, effects, opts, val)
    console.print(escape(result.summary()), highlight=False, soft_wrap=True)
    with user_errors(), _writing(output):
        cal = export_robot(result, output, name=name)
    console.print(
        f"wrote the calibrated arm {cal.name!r} to {output}; use it with --robot {output}",
        highlight=False,
        soft_wrap=True,
    )


@app.command("compensate")
def compensate_cmd(
    targets: Annotated[
        Path,
        typer.Argument(
            help="Desired tool points: CSV with x, y, z (and optionally q1..q6 start angles, "
            "target, and the columns the arm's effects need)."
        ),
    ],
    robot: Annotated[
        str,
        typer.Option("--robot", "-r", help="The calibrated arm (a TOML from sixaxis lab export)."),
    ],
    output: Annotated[
        Path, typer.Option("--output", "-o", help="The joint-angle CSV to write.")
    ] = Path("joints.csv"),
    nominal: Annotated[
        str, typer.Option(help="The arm the controller believes in (TOML or shipped name).")
    ] = "seed",
    nominal_base: Annotated[
        str,
        typer.Option(help="Where the nominal arm stands: auto, nominal or calibrated."),
    ] = "auto",
    target_ids: Annotated[
        str | None,
        typer.Option(
            help="The calibration's target ids in the order of the arm's tool points, e.g. 0,1 "
            "(needed when the targets file names only some of them)."
        ),
    ] = None,
    effect_module: ModuleOpt = None,
    length_unit: LengthOpt = "m",
    angle_unit: AngleOpt = "rad",
    as_json: JsonOpt = False,
) -> None:
    """Joint angles that put the calibrated arm's tool point on each target.

    Also prints the error that commanding the nominal inverse kinematics would leave."""
    from lab.export import compensate, read_targets, write_joints

    _check_units(length_unit, angle_unit)
    if nominal_base not in ("auto", "nominal", "calibrated"):
        fail(f"--nominal-base must be auto, nominal or calibrated, got {nominal_base!r}")
    ids = None
    if target_ids is not None:
        try:
            ids = [int(t) for t in target_ids.split(",") if t.strip()]
        except ValueError:
            fail(f"--target-ids must be integers separated by commas, got {target_ids!r}")
    _check_outputs(
        [(output, "--output")], [targets, robot, nominal, *(effect_module or ())], as_json
    )
    _load_modules(effect_module)
    cal = _robot(robot)
    nom = _robot(nominal)
    with user_errors():
        tset = read_targets(targets, length_unit=length_unit, angle_unit=angle_unit)
    with user_errors():
        with console.status(f"solving {len(tset)} targets..."):
            comp = compensate(cal, tset, nom, nominal_base=nominal_base, target_ids=ids)
    with _writing(output):
        write_joints(comp, output)
    summary = comp.to_dict() | {"output": str(output)}
    if as_json:
        print(_dump(summary))
        return
    console.print(compensation_table(cal.name, nom.name, comp.n, summary))
    console.print(
        f"compensation removes {summary['nominal_rms_mm'] - summary['rms_mm']:.4f} mm RMS "
        f"(largest joint change {summary['max_joint_change_mrad']:.3f} mrad); "
        f"{summary['converged']} of {comp.n} converged",
        highlight=False,
        soft_wrap=True,
    )
    if summary["not_converged"]:
        console.print(
            f"[yellow]not converged (out of reach?):[/yellow] rows "
            f"{', '.join(str(i + 1) for i in summary['not_converged'][:20])}",
            highlight=False,
            soft_wrap=True,
        )
    console.print(f"wrote {output}", highlight=False, soft_wrap=True)
