"""What the ``sixaxis lab`` commands take: their shared options and how their inputs are read.

The options' choices and ranges come from the library's vocabulary, not from this module:
:func:`declared` turns a declared constraint (:mod:`arm.constraints`: ``lab.LabOptions``'s fields,
the lab's ``ALPHA``, ``ORDER``, ``ROUNDS``, the units of :mod:`arm.measurements`) into a typer
option whose help shows the choices or the range and whose value is refused in the library's own
words, naming the flag: ``error: --noise-mm must be positive, got -1.0``. Everything else a
command is given is judged by the library it calls, inside :func:`~experiments.cli_output.
user_errors` (one line ``error: ...``, exit code 2).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from typer.core import TyperGroup

from arm.constraints import Constraint, Interval, OneOf, constraints_of
from arm.errors import SixAxisError
from arm.measurements import ANGLE_UNITS, LENGTH_UNITS
from experiments.cli_output import console, err_console, fail, user_errors
from lab.options import LabOptions

__all__ = [
    "AcceptLargeOpt",
    "AngleOpt",
    "DataArg",
    "DeclaredError",
    "EffectsOpt",
    "JsonOpt",
    "JsonOutOpt",
    "LengthOpt",
    "LossOpt",
    "MeasuredOpt",
    "ModuleOpt",
    "NoiseMradOpt",
    "NoiseOpt",
    "NoisePpmOpt",
    "OneLineErrors",
    "OrientationUnitOpt",
    "OutliersOpt",
    "RobotOpt",
    "ValidateOpt",
    "check_outputs",
    "declared",
    "lab_inputs",
    "load_modules",
    "next_step_options",
    "parse_effects",
    "read_arm",
    "read_data",
    "writing",
]


# -- declared options -------------------------------------------------------------------------------
class DeclaredError(SixAxisError, typer.BadParameter, ValueError):
    """A value a declared constraint refuses; its message names the flag already."""

    def format_message(self) -> str:
        return self.message


class OneLineErrors(TyperGroup):
    """The ``sixaxis`` group: a refused option value is one line ``error: ...`` on stderr and
    exit code 2, as every other bad input is, instead of click's usage box."""

    def invoke(self, ctx: Any) -> Any:
        try:
            return super().invoke(ctx)
        except typer.BadParameter as exc:
            fail(_declared(exc) or exc.format_message())


def _declared(exc: BaseException) -> str | None:
    """The message of the :class:`DeclaredError` behind a refused option value (typer converts
    values with pydantic, which wraps a parser's ValueError in its own error), if there is one."""
    if isinstance(exc, DeclaredError):
        return exc.message
    errors = getattr(exc.__cause__, "errors", None)
    for e in errors() if callable(errors) else ():
        found = (e.get("ctx") or {}).get("error")
        if isinstance(found, DeclaredError):
            return found.message
    return None


def declared(
    constraint: Constraint, key: str, help: str, *flags: str, lower: bool = False, **kw: Any
) -> Any:
    """A typer option checked by ``constraint`` (its choices or range shown in the help), named
    ``flags`` (default ``--key``); ``lower``: a choice given in any case."""
    flags = flags or ("--" + key.replace("_", "-"),)
    flag = flags[0]
    kind: Callable[[str], Any] = str
    if isinstance(constraint, Interval):
        kind = int if constraint.kind is int else float
        lo, hi = constraint.low, constraint.high
        metavar = "<int>" if kind is int else "<float>"
        if lo is not None or hi is not None:
            metavar += f" {constraint.predicate.removeprefix('be ').removeprefix('lie ')}"
    elif isinstance(constraint, OneOf):
        metavar = "[" + "|".join(map(str, constraint.values)) + "]"
    else:
        metavar = "<value>"

    def parse(value: Any) -> Any:
        if value is None or not isinstance(value, str):
            return value
        try:
            v = kind(value.lower() if lower else value)
        except ValueError:
            v = value
        if not constraint.holds(v):
            raise DeclaredError(f"{flag} must {constraint.predicate}, got {v!r}")
        return v

    return typer.Option(*flags, help=help, parser=parse, metavar=metavar, **kw)


def _option(key: str) -> Constraint:
    return constraints_of(LabOptions)[key][0][0]


_NOISE_HELP = (
    "The instrument's per-axis standard uncertainty (mm); the noise floor of a 3-D RMS is this "
    "times sqrt(3). Default: estimated from the residual."
)
NoiseOpt = Annotated[float | None, declared(_option("noise_mm"), "noise_mm", _NOISE_HELP)]
LossOpt = Annotated[
    str, declared(_option("loss"), "loss", "linear (least squares), huber or soft_l1 (robust).")
]
OutliersOpt = Annotated[
    str,
    declared(
        _option("outliers"),
        "outliers",
        "auto: leave gross outliers out of the fit and the tests, named by line (a 3-D "
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
NoisePpmOpt = Annotated[
    float,
    declared(
        _option("noise_ppm"),
        "noise_ppm",
        "How the per-axis sigma grows with the distance from the tracker, um per m (a "
        "GTS3800: 6): sigma = --noise-mm + --noise-ppm x distance, the tracker at the origin of "
        "the measurement frame (of each station). Rows are weighted by it.",
    ),
]
NoiseMradOpt = Annotated[
    float | None,
    declared(
        _option("noise_mrad"),
        "noise_mrad",
        "The per-axis standard uncertainty of a measured orientation (mrad); needed to weigh "
        "orientation rows against positions (or std_rx, std_ry, std_rz columns).",
    ),
]
OrientationUnitOpt = Annotated[
    str | None,
    declared(
        OneOf(tuple(ANGLE_UNITS)),
        "orientation_unit",
        "Unit of the orientation columns (rvx.. or roll, pitch, yaw) and their stds. Default: "
        "the --angle-unit.",
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
LengthOpt = Annotated[
    str,
    declared(OneOf(tuple(LENGTH_UNITS)), "length_unit", "Unit of x, y, z in the CSV files."),
]
AngleOpt = Annotated[
    str, declared(OneOf(tuple(ANGLE_UNITS)), "angle_unit", "Unit of q1..q6 in the CSV files.")
]


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
        help=(
            "The nominal arm: a robot TOML or URDF file, or a shipped name; a URDF's chain "
            "may follow it: 'ur5_robot.urdf#tip=tool0,base=base'. A calibrated URDF is read "
            "with the metrology file that lab export wrote beside it."
        ),
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
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the JSON object only.")]
JsonOutOpt = Annotated[
    Path | None,
    typer.Option("--out", help="Also write the JSON object to this file (atomically)."),
]


# -- inputs -----------------------------------------------------------------------------------------
@contextlib.contextmanager
def writing(path: Path) -> Iterator[None]:
    """An error while writing ``path`` (a full disk, a path that became a device) becomes one
    error line."""
    from arm.files import OutputError

    try:
        yield
    except OutputError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{path}: cannot write ({exc.strerror or exc})")


def load_modules(modules: Sequence[Path] | None) -> list[str]:
    """Register the effects of every ``--effect-module`` file; returns their names."""
    from arm.effects import load_effect_module

    names: list[str] = []
    for m in modules or ():
        with user_errors(prefix="--effect-module: "):
            names += load_effect_module(m)
    return names


def parse_effects(effects: str) -> None:
    from arm.effects import parse_effects

    with user_errors(prefix="--effects: "):
        if not parse_effects(effects):
            fail("--effects: no effect given")


def read_arm(robot: str, flag: str = "--robot") -> Any:
    from arm.description import load_robot
    from arm.effects import check_robot_effects

    with user_errors(prefix=f"{flag}: "):
        arm = _calibrated_urdf(robot, flag) or load_robot(robot)
        check_robot_effects(arm, robot)  # after --effect-module registered its effects
        return arm


def _calibrated_urdf(robot: str, flag: str) -> Any:
    """The calibrated arm of a URDF that ``lab export --format urdf`` wrote, where its metrology
    file lies beside it: the corrected chain with the tracker frame, the tool points and the
    effects' values, as ``--robot calibrated.toml`` gives them (None for any other robot)."""
    p = Path(robot)
    if "#" in robot or p.suffix.lower() != ".urdf" or not p.is_file():
        return None
    from lab.urdf_export import metrology_path, read_calibrated_urdf

    side = metrology_path(p)
    if not side.is_file():
        return None
    err_console.print(
        f"note: {flag} {escape(robot)}: read with {escape(str(side))} beside it (the tracker "
        "frame, the tool points and the effects of its calibration)"
    )
    return read_calibrated_urdf(p, side)


def read_data(
    path: Path,
    length_unit: str,
    angle_unit: str,
    orientation_unit: str | None = None,
    measured: str | None = None,
) -> Any:
    """The measurement set of ``path``; the columns the format does not know are said (a
    ``MeasurementWarning``), not dropped."""
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
    for w in caught:  # on stderr: stdout carries the command's output (with --json, only it)
        err_console.print(f"[yellow]warning:[/yellow] {escape(str(w.message))}", soft_wrap=True)
    return data


def check_outputs(
    outputs: Sequence[tuple[Path | None, str]],
    inputs: Sequence[object],
    as_json: bool = False,
) -> None:
    """Before any work: every output can be written (a regular file, or ``-`` for standard
    output), replaces no input (data, held-out data, a robot file, an effect module, a poses or
    targets file), and no two are one file. With an output on standard output, what the command
    prints goes to stderr."""
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
    if as_json or any(path is not None and is_stdout(path) for path, _ in outputs):
        # the command's tables and messages go to stderr until it ends: with --json, stdout
        # carries the JSON object alone
        console.stderr = True


def next_step_options(
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
    default = LabOptions()
    return {
        "--robot": None if robot == "seed" else robot,
        "--length-unit": None if length_unit == "m" else length_unit,
        "--angle-unit": None if angle_unit == "rad" else angle_unit,
        "--effect-module": [str(m) for m in effect_module or ()],
        "--noise-mm": noise_mm,
        "--loss": None if loss == default.loss else loss,
        "--outliers": None if outliers == default.outliers else outliers,
        "--accept-large": accept_large,
    }


def lab_inputs(
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
    as_json: bool = False,
    **options: Any,
) -> tuple[Any, Any, Any, LabOptions]:
    """The lab's options (:class:`lab.LabOptions`, the keywords ``options``), the output places
    checked, the effect modules registered, the robot and the data read: (arm, data, held-out
    data or None, options)."""
    known = {f.name for f in fields(LabOptions)}
    with user_errors():
        opts = LabOptions(**{k: v for k, v in options.items() if k in known})
    check_outputs(outputs, [data, validate, robot, *(modules or ())], as_json)
    load_modules(modules)
    parse_effects(effects)
    arm = read_arm(robot)
    meas = read_data(data, length_unit, angle_unit, orientation_unit, measured)
    val = None
    if validate is not None:
        val = read_data(validate, length_unit, angle_unit, orientation_unit, measured)
    return arm, meas, val, opts
