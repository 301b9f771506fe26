"""``sixaxis lab ...``: the model lab's commands, thin layers over the Python API.

    sixaxis lab collect -o data.csv --scenario compliance     # measure the simulated arm
    sixaxis lab fit data.csv --effects geometric               # Table 3, or --json (docs/format.md)
    sixaxis lab diagnose data.csv --noise-mm 0.015             # which effect does the model miss?
    sixaxis lab report data.csv -o report.html                 # fit, diagnose, refit, plots
    sixaxis lab plan --n 30 -o poses.csv                       # poses worth measuring
    sixaxis lab export data.csv --effects geometric,compliance -o calibrated.toml
    sixaxis lab compensate targets.csv --robot calibrated.toml -o joints.csv

Each command reads its inputs (:mod:`experiments.cli_inputs`: the shared options, whose choices
and ranges are the library's declared ones), calls the library, and prints with
:mod:`experiments.cli_output`; it judges no value itself. Bad input (a missing file, a bad CSV
cell, an unknown effect, an option out of range) prints one line ``error: ...`` naming the file,
line, column or option on stderr and exits with code 2; a traceback means a bug. Library modules
are imported inside each command, so ``sixaxis --help`` stays fast and only ``collect`` loads
MuJoCo.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer

from arm.constraints import Interval, OneOf
from arm.measurements import ANGLE_UNITS
from arm.noise import NOISE_MM, NOISE_MRAD, NOISE_PPM
from experiments.cli_inputs import (
    INPUTS,
    AngleOpt,
    DataArg,
    EffectsOpt,
    ExportInputs,
    JointValueOpt,
    JsonOpt,
    JsonOutOpt,
    LabArgs,
    LabInputs,
    LengthOpt,
    ModuleOpt,
    ReferencesOpt,
    RobotOpt,
    check_outputs,
    declared,
    lab_command,
    load_modules,
    module_output,
    option_of,
    parse_effects,
    read_arm,
    read_data,
    read_sessions,
    read_target,
    refuse_noise,
    sessions_json,
    writing,
)
from experiments.cli_output import (
    cautions_recorded,
    command_line,
    console,
    counted,
    emit_json,
    err_console,
    fail,
    json_text,
    print_compensation,
    print_diagnosis,
    print_discovery,
    print_fit,
    print_plan,
    print_report,
    print_sessions,
    say,
    steps,
    user_errors,
    with_cautions,
)
from lab.options import ALPHA, CRITERIA, EXPORT_FORMATS, ORDER, ROUNDS, LabOptions, UpdateOptions

if TYPE_CHECKING:
    from arm.effects import Effect
    from lab.result import FitResult

UPDATE = UpdateOptions()

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
    ctx.with_resource(cautions_recorded())  # each caution said once, and kept for the JSON


ExtrapolateOpt = Annotated[
    bool,
    typer.Option(
        "--extrapolate",
        help="Outside the fitted domain, keep every term (a line in temperature fitted over "
        "0.4 degC, a harmonic of a joint over less than its period) instead of predicting those "
        "rows without it; the warning is given either way.",
    ),
]


def _fitted(
    meas,
    arm,
    effects: list[Effect],
    opts: LabOptions,
    val,
    extrapolate: bool = False,
    accept_other_frame: bool = False,
    refs=None,
):
    """The lab's fit of a command's data (``lab fit``, ``lab export``)."""
    from lab import fit

    with user_errors():
        return fit(
            meas,
            arm,
            effects,
            options=opts,
            validate=val,
            references=refs,
            extrapolate=extrapolate,
            accept_other_frame=accept_other_frame,
        )


#: the options of held-out data, which a command without --validate takes none of
VALIDATION = (
    "validate",
    "references",
    "validate_length_unit",
    "validate_angle_unit",
    "accept_other_frame",
)


# -- fit --------------------------------------------------------------------------------------------
@lab_command(app, "fit")
def fit_cmd(
    data: DataArg,
    lab: LabArgs,
    extrapolate: ExtrapolateOpt = False,
    as_json: JsonOpt = False,
    out: JsonOutOpt = None,
) -> None:
    """Identify the model's parameters from measured tool points.

    Prints the identified parameters with standard errors, the RMS before and after, and which
    parameters the poses cannot identify; --json prints the JSON object of docs/format.md, the
    lab's JSON output (SI units)."""
    arm, meas, val, opts, effects = lab.read(data, [(out, "--out")], as_json)
    refs = lab.read_references()
    result = _fitted(meas, arm, effects, opts, val, extrapolate, lab.accept_other_frame, refs)
    expected = _expected(result, meas, lab, opts, val, extrapolate, refs)
    if not as_json:
        print_sessions(meas)
        print_fit(result)
        _print_expected(expected)
    emit_json(result.to_dict() | sessions_json(meas) | _expected_json(expected), as_json, out)


def _unseen(result: FitResult, target: Any) -> bool:
    """Whether a ``--predict`` target is a session the fit has not seen: a program's joints (it
    runs later), or measurements from a station the fit has no base of."""
    from arm.measurements import MeasurementSet

    if not isinstance(target, MeasurementSet) or "station" not in target.columns:
        return True
    import numpy as np

    return not set(np.unique(target.columns["station"]).astype(int)) <= set(result.model.stations)


def _expected(
    result: FitResult,
    meas: Any,
    lab: LabArgs,
    opts: LabOptions,
    val: Any,
    extrapolate: bool,
    refs: Any = None,
) -> tuple[Any, float | None] | None:
    """With ``--predict``: the :class:`lab.prediction.Expectation` on its target, and the chosen
    model's RMS measured on the ``--validate`` rows (None without them)."""
    if lab.predict is None:
        return None
    from lab.prediction import expect

    target = read_target(lab.predict, lab.length_unit, lab.angle_unit)
    with user_errors(), console.status("the blocked checks for the prediction..."):
        e = expect(result, meas, target, unseen=_unseen(result, target), options=opts)
        measured = None
        if val is not None:
            done = e.result.validate(val, extrapolate=extrapolate, references=refs)
            measured = done.validation_rms_mm
    return e, measured


def _print_expected(expected: tuple[Any, float | None] | None) -> None:
    if expected is None:
        return
    e, measured = expected
    say(f"--predict: {e.text()}")
    if measured is not None:
        say(
            f"--predict: predicted {e.prediction.rms_mm:.4f} mm, measured {measured:.4f} mm on "
            "the --validate rows"
        )


def _expected_json(
    expected: tuple[Any, float | None] | None, say_it: bool = False
) -> dict[str, Any]:
    """The JSON of a --predict (none without it); ``say_it``: print it too (its text)."""
    if say_it:
        _print_expected(expected)
    if expected is None:
        return {}
    e, measured = expected
    return {"predicted": e.to_dict() | {"measured_rms_mm": measured}}


AlphaOpt = Annotated[float, declared(ALPHA, "alpha")]


# -- diagnose ---------------------------------------------------------------------------------------
@lab_command(app, "diagnose", omit=VALIDATION)
def diagnose_cmd(
    data: DataArg,
    lab: LabArgs,
    alpha: AlphaOpt = 0.02,
    as_json: JsonOpt = False,
    out: JsonOutOpt = None,
) -> None:
    """Fit the model and test which catalogued effect it misses.

    The verdict names the missing effect, or says none (the residual is noise; needs --noise-mm)
    or unexplained; candidates are ranked with their p-values, hints say which measured variables
    the residual still depends on."""
    from lab import diagnose

    arm, meas, _, opts, effects = lab.read(data, [(out, "--out")], as_json)
    with user_errors(), console.status("fitting and testing the candidate effects..."):
        d = diagnose(meas, arm, effects, options=opts, alpha=alpha)
    if not as_json:
        print_sessions(meas)
        print_diagnosis(d, data, {c: lab.next_step(c) for c in ("fit", "discover")})
    emit_json(d.to_dict() | sessions_json(meas), as_json, out)


# -- discover ---------------------------------------------------------------------------------------
DiscoverEffectsOpt = Annotated[
    str,
    typer.Option(
        "--effects",
        "-e",
        help="The model E to start from (default geometric; or the diagnosis's best "
        "catalogued model, e.g. geometric,compliance[2,3]).",
    ),
]


@lab_command(
    app,
    "discover",
    omit=("loss", "outliers", "accept_large", "f_scale_mm", "accept_other_frame"),
    effects=DiscoverEffectsOpt,
)
def discover_cmd(
    data: DataArg,
    output: Annotated[
        Path | None, module_output("when terms are found (nothing when nothing is found)")
    ] = None,
    *,
    lab: LabArgs,
    alpha: AlphaOpt = 0.02,
    order: Annotated[int, declared(ORDER, "order")] = 64,
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
    from lab.discovery import check_module_path, discover

    if output is not None:
        with user_errors():
            check_module_path(output)
    arm, meas, val, opts, effects = lab.read(data, [(output, "--output"), (out, "--out")], as_json)
    with user_errors(), console.status("fitting the model and searching the library..."):
        d = discover(
            meas,
            arm,
            effects,
            options=opts,
            validate=val,
            references=lab.read_references(),
            alpha=alpha,
            order=order,
            name=name,
        )
    written = None
    if output is not None and d.terms:
        with user_errors(), writing(output):
            written = d.write_module(output)
    if not as_json:
        print_sessions(meas)
        print_discovery(d, written, data, lab.next_step("fit"))
    emit_json(d.to_dict() | sessions_json(meas), as_json, out)


# -- bag --------------------------------------------------------------------------------------------
@lab_command(app, "bag", omit=("effects",))
def bag_cmd(
    data: DataArg,
    output: Annotated[
        Path | None,
        module_output(
            "of every draw's discovered terms, when there are any (the averaged values are in "
            "--json)"
        ),
    ] = None,
    *,
    lab: LabArgs,
    bags: Annotated[int, typer.Option(min=1, help="Draws of the poses.")] = 10,
    poses: Annotated[
        int,
        typer.Option(
            min=12,
            help="Poses each draw takes of a session (the session column, else station) at most.",
        ),
    ] = 1000,
    seed: Annotated[int, typer.Option(help="Draws the poses.")] = 0,
    name: Annotated[
        str, typer.Option(help="The discovered effect's name (lower case, digits, _).")
    ] = "bagged",
    export: Annotated[
        Path | None,
        typer.Option(
            help="Also write the averaged calibration as `lab export` does: a robot TOML "
            "(FILE.toml) or, for an arm read from a URDF, the calibrated URDF and its metrology "
            "file (FILE.urdf); with discovered terms, use it with their module (-o, default "
            "FILE.py beside it): --robot FILE --effect-module FILE.py.",
            metavar="FILE.toml|FILE.urdf",
        ),
    ] = None,
    extrapolate: ExtrapolateOpt = False,
    as_json: JsonOpt = False,
    out: JsonOutOpt = None,
) -> None:
    """Run the lab's path (screen, diagnose, discover, fit) on draws of the poses and average
    the models into one calibration.

    Each draw takes at most --poses poses of each session (or station), so that no session
    outweighs another by its number of poses; the models are averaged by parameter name over the
    union of the effects the draws chose, and only the stations' bases are fitted again. Which
    terms a path keeps depends on the poses measured; their average holds across sessions
    (docs/lab.md, the UR10)."""
    from lab.bagging import bag
    from lab.discovery import check_module_path
    from lab.sanity import check_validation
    from lab.urdf_export import metrology_path, require_urdf

    as_urdf = export is not None and export_format_of(export, None) == "urdf"
    if output is None and export is not None:  # the discovered terms go beside the arm
        output = export.with_suffix(".py")
    if output is not None:
        with user_errors():
            check_module_path(output)
    places = [(output, "--output"), (out, "--out"), (export, "--export")]
    if as_urdf and export is not None:
        places.append((metrology_path(export), "--export's metrology file"))
    arm, meas, val, opts, _ = lab.read(data, places, as_json)
    refs = lab.read_references()
    if as_urdf:
        with user_errors():  # before the draws: a TOML arm has no URDF to correct
            require_urdf(arm)
    with user_errors(), console.status(f"the lab's path on {bags} draws of the poses..."):
        b = bag(meas, arm, bags=bags, poses=poses, seed=seed, name=name, options=opts)
        result = (
            b.result
            if val is None
            else b.result.validate(val, extrapolate=extrapolate, references=refs)
        )
        if val is not None:  # foreign held-out data: warned about as `lab fit` does
            check_validation(result, val.source, lab.accept_other_frame)
    expected = _expected(b.result, meas, lab, opts, val, extrapolate, refs)
    written = None
    if output is not None and b.discovered is not None:
        with user_errors(), writing(output):
            written = b.write_module(output)
    if export is not None:
        from arm.effects import load_effect_module
        from lab.export import export_robot
        from lab.urdf_export import export_urdf

        with user_errors(), writing(export):
            if written is not None:
                load_effect_module(written)  # the arm names the effect: it must be registered
            if as_urdf:
                export_urdf(b.result, export)
            else:
                export_robot(b.result, export)
    if not as_json:
        print_sessions(meas)
        print_fit(result)
        draws = "1 draw" if b.bags == 1 else f"{b.bags} draws"
        say(f"bag: {draws} of at most {poses} poses per session; effects: {b.suggestion}")
        for why in b.refused:
            say(f"left out of the average: {why}")
        if written is not None:
            say(f"wrote {written} (the discovered terms of every draw: --effect-module)")
        if export is not None:
            beside = f" and {metrology_path(export)}" if as_urdf else ""
            say(
                f"wrote the averaged calibration to {export}{beside}; use it with --robot "
                f"{export}" + (f" --effect-module {written}" if written is not None else "")
            )
    emit_json(
        result.to_dict()
        | sessions_json(meas)
        | _expected_json(expected, not as_json)
        | {"bag": {"bags": b.bags, "poses": poses, "seed": seed} | _bag_choice(b)},
        as_json,
        out,
    )


def _bag_choice(b: Any) -> dict[str, Any]:
    return {"effects": b.suggestion, "refused": b.refused}


# -- report -----------------------------------------------------------------------------------------
@lab_command(app, "report", omit=("accept_other_frame",))
def report_cmd(
    data: DataArg,
    output: Annotated[Path, typer.Option("--output", "-o", help="The HTML file to write.")] = Path(
        "report.html"
    ),
    *,
    lab: LabArgs,
    rounds: Annotated[int, declared(ROUNDS, "rounds")] = 3,
) -> None:
    """Fit, diagnose, refit what the diagnosis suggests; write an HTML report.

    Repeats diagnose-and-refit while the verdict names a missing catalogued effect (at most
    --rounds times); the report has the tables and plots of every model."""
    from lab.report import build_report
    from lab.report_html import write as write_html

    arm, meas, val, opts, effects = lab.read(data, [(output, "--output")])
    command = command_line("lab", "report", data, **lab.flags())
    t0 = time.perf_counter()
    with steps() as step:
        with user_errors():
            rep = build_report(
                meas,
                arm,
                effects,
                options=opts,
                validate=val,
                references=lab.read_references(),
                rounds=rounds,
                command=command,
                progress=step,
            )
        step("writing the HTML")
        with writing(output):
            write_html(rep, output)
        step(None)
    print_report(rep, output, time.perf_counter() - t0)


# -- update -----------------------------------------------------------------------------------------
@app.command("update")
def update_cmd(
    calibration: Annotated[
        str,
        typer.Argument(
            help="The calibration to update: a robot TOML that sixaxis lab export (or lab bag "
            "--export, lab update -o) wrote, or its calibrated URDF with the metrology file "
            "beside it; it carries the parameters' covariance and spread (its uncertainty "
            "table).",
            metavar="CAL.toml",
        ),
    ],
    data: DataArg,
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            help="Write the updated calibration as a robot TOML (with its posterior "
            "covariance): --robot FILE.toml anywhere, or updated again.",
            metavar="FILE.toml",
        ),
    ] = None,
    remount: Annotated[bool, option_of(UpdateOptions, "remount")] = UPDATE.remount,
    noise_mm: Annotated[float | None, option_of(UpdateOptions, "noise_mm")] = UPDATE.noise_mm,
    rehome_mrad: Annotated[float, option_of(UpdateOptions, "rehome_mrad")] = UPDATE.rehome_mrad,
    remount_mm: Annotated[float, option_of(UpdateOptions, "remount_mm")] = UPDATE.remount_mm,
    robot: Annotated[
        str | None,
        option_of(
            LabInputs,
            "robot",
            lead="The arm the new poses were measured on, refused unless it is the one the "
            "calibration calibrated (by name); default: not checked.",
        ),
    ] = None,
    validate: Annotated[Path | None, option_of(LabInputs, "validate")] = None,
    predict: Annotated[Path | None, option_of(LabInputs, "predict")] = INPUTS.predict,
    references: ReferencesOpt = None,
    effect_module: ModuleOpt = None,
    length_unit: LengthOpt = INPUTS.length_unit,
    angle_unit: AngleOpt = INPUTS.angle_unit,
    extrapolate: ExtrapolateOpt = False,
    as_json: JsonOpt = False,
    out: JsonOutOpt = None,
) -> None:
    """Update a calibration with a few poses of a new session or region (a MAP fit).

    The calibration's parameters, with their covariance widened by the spread between the
    sessions it was fitted on, are the prior; the new session's base (and with --remount the
    tool) is fitted on the new poses alone; each effect is kept, refitted or dropped as the new
    poses predict best. The result is a calibration like any other (-o: export, compensate)."""
    from dataclasses import replace

    from lab.export import export_robot
    from lab.uncertainty import predicted_rms
    from lab.update import prior_of, update

    if output is not None and export_format_of(output, None) == "urdf":
        fail(
            f"--output {output}: an updated calibration is written as a robot TOML; give FILE.toml"
        )
    inputs = [calibration, *data, validate, references, predict, robot, *(effect_module or ())]
    check_outputs([(output, "--output"), (out, "--out")], inputs, as_json)
    load_modules(effect_module)
    cal = read_arm(calibration, "CAL")
    arm = read_arm(robot) if robot is not None else None
    meas = read_sessions(data, length_unit, angle_unit)
    val = (
        None
        if validate is None
        else read_data(validate, length_unit, angle_unit, option="--validate")
    )
    refs = None
    if references is not None:
        if val is None:
            fail(f"--references {references}: they register --validate's station; give --validate")
        refs = read_data(references, length_unit, angle_unit, option="--references")
    options: dict[str, Any] = {
        "remount": remount,
        "noise_mm": noise_mm,
        "rehome_mrad": rehome_mrad,
        "remount_mm": remount_mm,
    }
    with user_errors(), console.status(f"updating {calibration} with {len(meas)} poses..."):
        prior = replace(prior_of(cal), source=calibration)
        u = update(prior, meas, robot=arm, **options)
        result = (
            u.result
            if val is None
            else u.result.validate(val, extrapolate=extrapolate, references=refs)
        )
        alone = predicted = None
        if val is not None and u.prior_result is not None:
            alone = u.prior_result.validate(val, extrapolate=extrapolate, references=refs)
            predicted = (
                predicted_rms(u.result, val, unseen=False),
                predicted_rms(u.prior_result, val, unseen=True, u=u.prior.uncertainty),
            )
    target_pred, measured = _update_prediction(
        u, meas, predict, (length_unit, angle_unit), options, (val, extrapolate, refs)
    )
    if output is not None:
        with user_errors(), writing(output):
            export_robot(result, output)
    if not as_json:
        print_sessions(meas)
        _say_update(u, result, val, alone, predicted, (predict, target_pred), output)
    summary = result.to_dict() | sessions_json(meas) | {"update": u.to_dict()}
    if alone is not None:
        summary["update"]["prior_validation_rms_mm"] = alone.validation_rms_mm
    if predicted is not None:
        summary["update"]["predicted"] = predicted[0].to_dict()
        summary["update"]["prior_predicted"] = predicted[1].to_dict()
    if target_pred is not None:
        summary["predicted"] = target_pred.to_dict() | {"measured_rms_mm": measured}
    emit_json(summary, as_json, out)


def _say_update(
    u: Any, result: Any, val: Any, alone: Any, predicted: Any, target: Any, output: Path | None
) -> None:
    """The text of ``lab update``: what it did, the --predict target's prediction, the
    validation beside the calibration alone, where it wrote."""
    say(u.summary())
    if target[1] is not None:
        say(f"--predict {target[0]}: {target[1].text()}")
    if alone is not None and val is not None:
        say(
            f"validation on {len(val)} points: RMS "
            f"{result.validation_rms_mm:.4f} mm updated, {alone.validation_rms_mm:.4f} mm "
            "the calibration alone (its base placed on the new poses)"
        )
    if predicted is not None:
        say(f"updated: {predicted[0].text()}")
        say(f"the calibration alone: {predicted[1].text()}")
    if output is not None:
        say(f"wrote the updated calibration to {output}; use it with --robot {output}")


def _update_prediction(
    u: Any,
    meas: Any,
    predict: Path | None,
    units: tuple[str, str],
    options: dict[str, Any],
    validation: tuple[Any, bool, Any],
) -> tuple[Any, float | None]:
    """``--predict`` of an update: the model its poses expect best on the target (the fallback:
    each pose left out in turn, :func:`lab.prediction.expect_update`) with its posterior
    covariance through the target's poses, and that model's RMS on the ``--validate`` rows
    (``validation``: the rows, --extrapolate, the references), validated as the update is."""
    if predict is None:
        return None, None
    from lab.prediction import expect_update

    target = read_target(predict, *units)
    val, extrapolate, refs = validation
    with user_errors():
        e = expect_update(u, meas, target, **options)
        if val is None:
            return e, None
        done = e.result.validate(val, extrapolate=extrapolate, references=refs)
    return e, done.validation_rms_mm


# -- plan -------------------------------------------------------------------------------------------
@app.command("plan")
def plan_cmd(
    n: Annotated[
        int, declared(Interval(int, 1, None), "n", "How many poses to choose.", "--n", "-n")
    ] = 30,
    output: Annotated[
        Path, typer.Option("--output", "-o", help="The poses CSV to write (q1..q6).")
    ] = Path("poses.csv"),
    robot: RobotOpt = INPUTS.robot,
    effects: EffectsOpt = INPUTS.effects,
    effect_module: ModuleOpt = None,
    candidates: Annotated[
        int, typer.Option(help="Random candidate poses (within the limits) to choose from.")
    ] = 2000,
    criterion: Annotated[
        str,
        declared(
            OneOf(CRITERIA),
            "criterion",
            "O1 (D-optimal, all parameters) or O4 (the weakest one).",
            lower=True,
        ),
    ] = "o1",
    noise_mm: Annotated[
        float,
        declared(
            NOISE_MM,
            "noise_mm",
            "Parameters that N poses cannot determine above it are not planned for.",
        ),
    ] = 0.015,
    seed: Annotated[int, typer.Option(help="Seed of the random candidates.")] = 0,
    near: Annotated[Path | None, option_of(LabInputs, "near")] = INPUTS.near,
    angle_unit: AngleOpt = INPUTS.angle_unit,
    noise_mrad: Annotated[
        float | None,
        declared(
            NOISE_MRAD,
            "noise_mrad",
            "Plan for an instrument that measures the tool frame's orientation too: six rows a "
            "pose, weighted against the position's.",
        ),
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """Choose N calibration poses that identify the most; write their joint angles.

    O1 (Borm & Menq) is D-optimality over all identifiable parameters, O4 (Nahvi & Hollerbach)
    the noise amplification of the weakest one; both are printed beside random pose sets."""
    from arm.measurements import read_poses, write_poses
    from arm.sampling import region_of
    from lab import plan

    refuse_noise(noise_mm, 0.0, noise_mrad)
    given = [robot, *(effect_module or ()), *([near] if near is not None else [])]
    check_outputs([(output, "--output")], given, as_json)
    load_modules(effect_module)
    parsed = parse_effects(effects)
    arm = read_arm(robot)
    program = None
    if near is not None:
        with user_errors(prefix=f"--near {near}: "):
            program = read_poses(near, angle_unit)
            region_of(arm, program)  # within the limits, else refused here, by joint
    if program is not None and arm.uncertainty and arm.nominal is not None:
        _plan_update(n, arm, program, candidates, seed, noise_mm, output, angle_unit, as_json)
        return
    with user_errors(), console.status(f"choosing {n} of {candidates} poses by {criterion}..."):
        p = plan(
            n,
            arm,
            parsed,
            criterion=criterion,
            candidates=candidates,
            noise_mm=noise_mm,
            seed=seed,
            noise_mrad=noise_mrad,
            near=program,
        )
    with writing(output):
        write_poses(p.q, output, angle_unit)
    if as_json:
        print(
            json_text(
                with_cautions(p.to_dict() | {"output": str(output), "angle_unit": angle_unit})
            )
        )
    else:
        print_plan(p, criterion, output, angle_unit, poses=bool(noise_mrad))


def _plan_update(
    n: int,
    cal: Any,
    program: Any,
    candidates: int,
    seed: int,
    noise_mm: float,
    output: Path,
    angle_unit: str,
    as_json: bool,
) -> None:
    """``plan --near`` of a calibration (a file with its ``[uncertainty]``): the poses its update
    needs where the program runs (:func:`lab.planning.plan_update`)."""
    from arm.measurements import write_poses
    from lab.planning import plan_update

    with user_errors(), console.status(f"choosing {n} of {candidates} poses for the update..."):
        p = plan_update(n, cal, program, candidates=candidates, seed=seed, noise_mm=noise_mm)
    with writing(output):
        write_poses(p.q, output, angle_unit)
    if as_json:
        extra = {"output": str(output), "angle_unit": angle_unit}
        print(json_text(with_cautions(p.to_dict() | extra)))
    else:
        say(f"{p.summary()}; wrote {output}")


# -- collect ----------------------------------------------------------------------------------------
# the options of collect
CollectScenarioOpt = Annotated[
    str,
    typer.Option(
        help="The simulated arm's hidden effects: nominal, geometric, compliance, "
        "transmission, backlash, thermal, payload, all, cyclic."
    ),
]
CollectNOpt = Annotated[
    int, declared(Interval(int, 1, None), "n", "Random poses to measure.", "--n", "-n")
]
CollectNoiseMmOpt = Annotated[
    float, declared(NOISE_MM, "noise_mm", "The simulated tracker's; 0: none drawn.")
]
CollectSeedOpt = Annotated[int, typer.Option(help="Seed of the poses, the motions and the noise.")]
CollectArmSeedOpt = Annotated[
    int | None,
    typer.Option(
        help="Seed of the hidden arm (default: --seed). Measure one arm twice, e.g. for "
        "held-out data: --seed 1 and --seed 2 --arm-seed 1."
    ),
]
CollectPosesOpt = Annotated[
    Path | None,
    typer.Option(help="A poses CSV (q1..q6, e.g. from sixaxis lab plan) instead of --n."),
]
CollectAngleUnitOpt = Annotated[
    str | None,
    declared(
        OneOf(tuple(ANGLE_UNITS)),
        "angle_unit",
        "Unit of q1..q6 in --poses (default: the unit the file's # line declares, as "
        "sixaxis lab plan writes it; else rad).",
    ),
]
CollectNoisePpmOpt = Annotated[float, declared(NOISE_PPM, "noise_ppm")]
CollectStationsOpt = Annotated[
    int,
    declared(
        Interval(int, 0, None),
        "stations",
        "Tracker stations around the arm (2-6 m away, each its own frame): the poses are "
        "measured in blocks, one per station, with a station column. 0: the world frame, no "
        "station column.",
    ),
]
CollectFirstStationOpt = Annotated[
    int,
    typer.Option(
        "--first-station",
        help="The first station's id (the others follow): a held-out campaign from other "
        "stations of the same arm takes other ids.",
    ),
]
CollectOrientationOpt = Annotated[
    bool,
    typer.Option(
        "--orientation",
        help="A 6-DoF probe on the flange measures the tool frame's orientation too "
        "(roll, pitch, yaw columns).",
    ),
]
CollectNoiseMradOpt = Annotated[
    float, declared(NOISE_MRAD, "noise_mrad", "The simulated probe's, with --orientation.")
]
CollectOrientationFractionOpt = Annotated[
    float,
    declared(
        Interval(float, 0.0, 1.0),
        "orientation_fraction",
        "The fraction of rows in which the probe's orientation is seen (the others leave it "
        "blank: the measurement mask).",
    ),
]
CollectStdsOpt = Annotated[
    bool,
    typer.Option("--stds", help="Write each row's stated uncertainty (std_x ... std_rz columns)."),
]


@app.command("collect")
def collect_cmd(
    output: Annotated[Path, typer.Option("--output", "-o", help="The measurement CSV to write.")],
    scenario: CollectScenarioOpt = "compliance",
    n: CollectNOpt = 200,
    noise_mm: CollectNoiseMmOpt = 0.015,
    seed: CollectSeedOpt = 0,
    arm_seed: CollectArmSeedOpt = None,
    poses: CollectPosesOpt = None,
    angle_unit: CollectAngleUnitOpt = None,
    robot: RobotOpt = INPUTS.robot,
    noise_ppm: CollectNoisePpmOpt = 0.0,
    stations: CollectStationsOpt = 0,
    first_station: CollectFirstStationOpt = 1,
    orientation: CollectOrientationOpt = False,
    noise_mrad: CollectNoiseMradOpt = 0.1,
    orientation_fraction: CollectOrientationFractionOpt = 1.0,
    stds: CollectStdsOpt = False,
) -> None:
    """Measure the simulated arm (MuJoCo) like a laser-tracker campaign.

    Each pose is approached from a random side, settled, and its tool point measured with
    noise; the CSV (docs/format.md, the measurement CSV) has every optional column. A campaign
    can be measured from several tracker stations, with distance-dependent noise, a 6-DoF probe
    and each row's stated uncertainty."""
    from arm.measurements import read_poses
    from arm.sampling import rng_from
    from envs.collect import check_poses, collect_measurements  # MuJoCo loads only to measure
    from envs.scenarios import draw_truth

    check_outputs([(output, "--output")], [poses, robot])
    arm = read_arm(robot)
    q = None
    if poses is not None:
        with user_errors():
            q = check_poses(read_poses(poses, angle_unit), arm, source=str(poses))

    with user_errors():
        rng = rng_from(
            seed if arm_seed is None else arm_seed, "--arm-seed" if arm_seed else "--seed"
        )
        truth = draw_truth(scenario, arm, rng)
    total = len(q) if q is not None else n
    t0 = time.perf_counter()
    with counted(f"measuring ({scenario})", total) as progress:
        with user_errors(), writing(output):
            meas = collect_measurements(
                truth=truth,
                poses=q,
                n=total,
                scenario=scenario,
                noise_mm=noise_mm,
                seed=seed,
                robot=arm,
                path=output,
                progress=progress,
                noise_ppm=noise_ppm,
                stations=stations,
                first_station=first_station,
                orientation=orientation,
                noise_mrad=noise_mrad,
                orientation_fraction=orientation_fraction,
                stds=stds,
            )
    say(
        f"wrote {len(meas)} measurements of the simulated arm ({scenario}, noise "
        f"{noise_mm:g} mm"
        + (f" + {noise_ppm:g} um/m" if noise_ppm else "")
        + " per axis"
        + (f", {stations} station(s)" if stations else "")
        + (f", orientations ({noise_mrad:g} mrad)" if orientation else "")
        + f") to {output} in {time.perf_counter() - t0:.1f} s"
    )


# -- export / compensate ----------------------------------------------------------------------------
@lab_command(app, "export")
def export_cmd(
    data: Annotated[
        list[Path] | None,
        typer.Argument(
            help="Measurement CSV files to fit, then export (docs/format.md, the measurement "
            "CSV; each a session, as lab fit takes them); or leave them out and give --from.",
            metavar="[DATA.csv...]",
        ),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            help="The file to write: its suffix, .toml or .urdf, says the format (default "
            "calibrated.toml, or calibrated.urdf with --format urdf).",
        ),
    ] = None,
    *,
    lab: LabArgs,
    source: Annotated[Path | None, option_of(ExportInputs, "source")] = None,
    name: Annotated[
        str | None, typer.Option(help="The calibrated arm's name (default: <robot>-calibrated).")
    ] = None,
    export_format: Annotated[
        str | None,
        declared(
            OneOf(EXPORT_FORMATS),
            "format",
            "toml: a robot TOML (any arm); urdf: the arm's URDF (--robot ARM.urdf) with its joint "
            "origins corrected, and NAME.metrology.toml beside it with the tracker frame, the "
            "tool points and the effects a URDF cannot express (docs/format.md, the calibrated "
            "URDF). Default: the --output's suffix, else toml; one that disagrees with the "
            "suffix is refused.",
            lower=True,
        ),
    ] = None,
) -> None:
    """Fit, then write the calibrated arm as a robot TOML or as its URDF; or write a saved
    calibration (--from) in either format.

    The geometric errors are folded into the DH table, base and tool, other effects' values
    kept; the TOML works as --robot anywhere. With --format urdf the arm's own URDF is written
    with corrected joint origins, everything else as it was."""
    from lab.export import export_robot
    from lab.urdf_export import export_urdf, metrology_path, require_urdf

    if bool(data) == (source is not None):
        fail(
            "give DATA.csv (fit it, then export) or --from CAL (export a saved calibration), "
            + ("not both" if data else "one of them")
        )
    export_format = export_format_of(output, export_format)
    if output is None:
        output = Path(f"calibrated.{export_format}")
    outputs: list[tuple[Path | None, str]] = [(output, "--output")]
    if export_format == "urdf":
        outputs.append((metrology_path(output), "--output's metrology file"))
    if source is not None:
        _export_saved(source, output, export_format, lab, name, outputs)
        return
    assert data
    arm, meas, val, opts, effects = lab.read(data, outputs)
    if export_format == "urdf":
        with user_errors():  # before the fit: a TOML arm has no URDF to correct
            require_urdf(arm)
    result = _fitted(
        meas,
        arm,
        effects,
        opts,
        val,
        accept_other_frame=lab.accept_other_frame,
        refs=lab.read_references(),
    )
    say(result.summary())
    if export_format == "urdf":
        with user_errors(), writing(output):
            out = export_urdf(result, output, name=name)
        _said_urdf(output, out)
        return
    with user_errors(), writing(output):
        cal = export_robot(result, output, name=name)
    say(f"wrote the calibrated arm {cal.name!r} to {output}; use it with --robot {output}")


def _said_urdf(output: Path, out) -> None:
    say(
        f"wrote the calibrated URDF {output} (the origins of {', '.join(out.joints)}) and "
        f"{out.metrology} (the tracker frame"
        + ("s of its stations" if out.robot.stations else "")
        + ", the tool points"
        + (", the effects" if out.robot.effects else "")
        + "); a controller loads the URDF and applies the rest: docs/format.md, the "
        "calibrated URDF"
    )
    for m in out.modules:
        say(f"wrote {m}, the module of its discovered effect: --effect-module {m}")


# what `lab export --from` takes of the shared options: the nominal arm, the effect modules
_SAVED_FLAGS = ("--robot", "--effect-module", "--from", "--output", "--name", "--format")


def _export_saved(
    source: Path,
    output: Path,
    export_format: str,
    lab: LabArgs,
    name: str | None,
    outputs: Sequence[tuple[Path | None, str]],
) -> None:
    """``lab export --from CAL``: a saved calibration written again, nothing refitted."""
    from lab.export import export_robot
    from lab.urdf_export import export_urdf

    given = [f for f, v in lab.flags().items() if v and f not in _SAVED_FLAGS]
    if given:
        fail(
            f"{given[0]}: --from exports a saved calibration as it is, nothing is fitted; leave "
            "out the fit's options"
        )
    check_outputs(outputs, [source, *(lab.effect_module or ())])
    load_modules(lab.effect_module)
    cal = read_arm(str(source), "--from")
    if export_format == "urdf":
        nominal = None if lab.robot == INPUTS.robot else read_arm(lab.robot)
        with user_errors(), writing(output):
            out = export_urdf(cal, output, name=name, nominal=nominal)
        _said_urdf(output, out)
        return
    with user_errors(), writing(output):
        back = export_robot(cal, output, name=name)
    say(f"wrote the calibrated arm {back.name!r} to {output}; use it with --robot {output}")


def export_format_of(output: Path | None, given: str | None) -> str:
    """The format an export writes: ``--format`` where given, else the output's suffix (.toml,
    .urdf), else toml; a ``--format`` that the suffix contradicts is refused (a TOML in a file
    named .urdf fails where it is read)."""
    suffix = output.suffix.lower().lstrip(".") if output is not None else ""
    named = suffix if suffix in EXPORT_FORMATS else None
    if given is not None and named is not None and given != named:
        fail(
            f"--format {given}: --output {output} names a .{named} file; give --output "
            f"NAME.{given}, or leave out --format"
        )
    return given or named or "toml"


@app.command("compensate")
def compensate_cmd(
    targets: Annotated[
        Path,
        typer.Argument(
            help="Desired tool poses: CSV with x, y, z in the calibration's measurement frame, "
            "and q1..q6 (the program: its orientation is held, its branch kept) or rvx, rvy, rvz "
            "/ roll, pitch, yaw (the tool's orientation); optionally target and the columns the "
            "arm's effects need."
        ),
    ],
    robot: Annotated[
        str, option_of(LabInputs, "robot", lead="The calibrated arm (from sixaxis lab export).")
    ],
    output: Annotated[
        Path, typer.Option("--output", "-o", help="The joint-angle CSV to write.")
    ] = Path("joints.csv"),
    nominal: Annotated[
        str | None,
        typer.Option(
            help="The arm the controller believes in (TOML or shipped name); default: the one "
            "the calibrated file records (lab export writes it)."
        ),
    ] = None,
    free_orientation: Annotated[
        bool,
        typer.Option(
            "--free-orientation",
            help="Targets are points alone: solve for the tool point and let the orientation "
            "change (without it a file with neither q1..q6 nor an orientation is refused).",
        ),
    ] = False,
    target_ids: Annotated[
        str | None,
        typer.Option(
            help="The calibration's target ids in the order of the arm's tool points, e.g. 0,1 "
            "(needed when the targets file names only some of them)."
        ),
    ] = None,
    effect_module: ModuleOpt = None,
    length_unit: LengthOpt = INPUTS.length_unit,
    angle_unit: AngleOpt = INPUTS.angle_unit,
    references: ReferencesOpt = None,
    joint_value: JointValueOpt = None,
    keep_unreached: Annotated[
        bool,
        typer.Option(
            "--keep-unreached",
            help="Write the joints even where a target is not reached (its row has converged "
            "= 0) instead of refusing the file.",
        ),
    ] = False,
    extrapolate: ExtrapolateOpt = False,
    as_json: JsonOpt = False,
) -> None:
    """Joint angles that put the calibrated arm's tool frame on each target pose.

    Starts at the program (q1..q6) and keeps its branch, else at the nominal arm's inverse
    kinematics; prints the start's error and the joint change, through the calibrated model."""
    from lab.export import (
        compensate,
        read_targets,
        register_references,
        target_id_list,
        write_joints,
    )

    with user_errors(prefix="--target-ids: "):
        ids = target_id_list(target_ids)
    inputs = [targets, robot, *([nominal] if nominal else []), *(effect_module or ())]
    check_outputs([(output, "--output")], [*inputs, references], as_json)
    load_modules(effect_module)
    cal = read_arm(robot, joint_values=joint_value)
    nom = read_arm(nominal, "--nominal", joint_value) if nominal is not None else None
    refs = None
    if references is not None:
        refs = read_data(references, length_unit, angle_unit, option="--references")
    with user_errors():
        tset = read_targets(targets, length_unit=length_unit, angle_unit=angle_unit)
        registered = None if refs is None else register_references(cal, refs)
        if registered is not None and not as_json:
            say(registered.text())
        with console.status(f"solving {len(tset)} targets..."):
            comp = compensate(
                cal,
                tset,
                nom,
                free_orientation=free_orientation,
                target_ids=ids,
                extrapolate=extrapolate,
                references=registered,
            )
    unreached = comp.unreached()
    if unreached is not None and not keep_unreached:
        fail(f"{unreached}; nothing written (--keep-unreached writes them with converged = 0)")
    with writing(output):
        write_joints(comp, output)
    summary = comp.to_dict() | {"output": str(output)}
    if as_json:
        print(json_text(with_cautions(summary)))
    else:
        print_compensation(comp, summary, output)
