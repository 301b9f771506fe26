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
import functools
import inspect
import typing
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from typer.core import TyperGroup

from arm.constraints import Constraint, Interval, OneOf, constraints_of
from arm.errors import SixAxisError
from arm.measurements import ANGLE_UNITS, LENGTH_UNITS
from experiments.cli_output import console, err_console, fail, user_errors

if TYPE_CHECKING:
    from arm.effects import Effect
from lab.options import LabOptions

__all__ = [
    "AcceptLargeOpt",
    "AngleOpt",
    "DataArg",
    "DeclaredError",
    "EffectsOpt",
    "JsonOpt",
    "JsonOutOpt",
    "LabArgs",
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
    "ReferencesOpt",
    "RobotOpt",
    "ValidateOpt",
    "check_outputs",
    "declared",
    "lab_command",
    "load_modules",
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
    "times sqrt(3). Refused where the fit's residual refutes it (more than 3x the noise it "
    "shows, beyond chance: a unit slip). Default: estimated from the residual."
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
ReferencesOpt = Annotated[
    Path | None,
    typer.Option(
        "--references",
        help="Reference points measured at a station the calibration has not seen (a "
        "measurement CSV, same units: at least 3 points not on one line with their joints, or "
        "6-DoF rows): the station's frame is fitted on them alone, the arm as calibrated, and "
        "its residual printed; they stay out of any validation figure.",
        metavar="REFS.csv",
    ),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the JSON object only.")]
JsonOutOpt = Annotated[
    Path | None,
    typer.Option("--out", help="Also write the JSON object to this file (atomically)."),
]


# -- the lab's shared options -----------------------------------------------------------------------
_LAB_DEFAULT = LabOptions()


@dataclass(frozen=True)
class LabArgs:
    """What the lab's commands that fit take alike (fit, diagnose, discover, report, export): the
    arm, the model, the held-out data, the instrument, the fit's options and the data's units,
    each declared once with its help (the ``...Opt`` types above) and its default (a
    :class:`lab.LabOptions` field's own). :func:`lab_command` puts them into a command where it
    declares ``lab: LabArgs``, in this order, and calls the command with them gathered here."""

    robot: RobotOpt = "seed"
    effects: EffectsOpt = "geometric"
    validate: ValidateOpt = None
    references: ReferencesOpt = None
    noise_mm: NoiseOpt = _LAB_DEFAULT.noise_mm
    noise_ppm: NoisePpmOpt = _LAB_DEFAULT.noise_ppm
    noise_mrad: NoiseMradOpt = _LAB_DEFAULT.noise_mrad
    orientation_unit: OrientationUnitOpt = None
    measured: MeasuredOpt = None
    loss: LossOpt = _LAB_DEFAULT.loss
    effect_module: ModuleOpt = None
    length_unit: LengthOpt = "m"
    angle_unit: AngleOpt = "rad"
    outliers: OutliersOpt = _LAB_DEFAULT.outliers
    accept_large: AcceptLargeOpt = _LAB_DEFAULT.accept_large

    def options(self) -> LabOptions:
        """The :class:`lab.LabOptions` these state (``measured`` is the data's: it is read with
        them); a value the options refuse is one error line."""
        known = {f.name for f in fields(LabOptions)} - {"measured"}
        with user_errors():
            return LabOptions(
                **{f.name: getattr(self, f.name) for f in fields(self) if f.name in known}
            )

    def read(
        self,
        data: Path,
        outputs: Sequence[tuple[Path | None, str]] = (),
        as_json: bool = False,
    ) -> tuple[Any, Any, Any, LabOptions, list[Effect]]:
        """The options checked, the output places checked, the effect modules registered, the
        effects parsed (a bad ``--effects`` refused before the data are read), the robot and the
        data read: (arm, data, held-out data or None, options, effects). The command hands the
        parsed effects to the lab, which takes them as they are (parsed once)."""
        opts = self.options()
        check_outputs(
            outputs,
            [data, self.validate, self.references, self.robot, *(self.effect_module or ())],
            as_json,
        )
        load_modules(self.effect_module)
        effects = parse_effects(self.effects)
        arm = read_arm(self.robot)
        units = (self.length_unit, self.angle_unit, self.orientation_unit, self.measured)
        meas = read_data(data, *units)
        val = (
            None if self.validate is None else read_data(self.validate, *units, option="--validate")
        )
        return arm, meas, val, opts, effects

    def read_references(self) -> Any:
        """The ``--references`` measurement set (None when not given), in the data's units."""
        if self.references is None:
            return None
        if self.validate is None:
            fail(
                f"--references {self.references}: reference points register the station of "
                "--validate's data; give --validate too"
            )
        units = (self.length_unit, self.angle_unit, self.orientation_unit, self.measured)
        return read_data(self.references, *units, option="--references")

    def next_step(self) -> dict[str, Any]:
        """The options that a printed next step must repeat to work on the same data (the arm,
        the units, the effect modules, the noise and the screening), as command-line flags; the
        defaults left out."""
        default = LabArgs()
        return {
            "--robot": _given(self.robot, default.robot),
            "--length-unit": _given(self.length_unit, default.length_unit),
            "--angle-unit": _given(self.angle_unit, default.angle_unit),
            "--effect-module": [str(m) for m in self.effect_module or ()],
            "--noise-mm": self.noise_mm,
            "--loss": _given(self.loss, default.loss),
            "--outliers": _given(self.outliers, default.outliers),
            "--accept-large": self.accept_large,
        }

    def flags(self) -> dict[str, Any]:
        """Every option given, as the command-line flags that repeat it (defaults left out)."""
        default = LabArgs()
        return {
            "--robot": _given(self.robot, default.robot),
            "--effects": _given(self.effects, default.effects),
            "--validate": self.validate,
            "--references": self.references,
            "--noise-mm": self.noise_mm,
            "--noise-ppm": self.noise_ppm or None,
            "--noise-mrad": self.noise_mrad,
            "--orientation-unit": self.orientation_unit,
            "--measured": self.measured,
            "--loss": _given(self.loss, default.loss),
            "--effect-module": [str(m) for m in self.effect_module or []],
            "--length-unit": _given(self.length_unit, default.length_unit),
            "--angle-unit": _given(self.angle_unit, default.angle_unit),
            "--outliers": _given(self.outliers, default.outliers),
            "--accept-large": self.accept_large,
        }


def _given(value: Any, default: Any) -> Any:
    return None if value == default else value


def lab_command(
    app: typer.Typer, name: str, omit: Sequence[str] = (), **replace: Any
) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Register a function as the command ``name`` of ``app`` with :class:`LabArgs`' options in
    place of its ``lab: LabArgs`` parameter (but those of ``omit``; those of ``replace`` with
    the typer annotation given there), and call it with them gathered in one ``LabArgs``.

        @lab_command(app, "diagnose", omit=("validate",))
        def diagnose_cmd(data: DataArg, lab: LabArgs, alpha: AlphaOpt = 0.02) -> None: ...
    """
    hints = typing.get_type_hints(LabArgs, include_extras=True)

    def register(func: Callable[..., None]) -> Callable[..., None]:
        sig = inspect.signature(func, eval_str=True)
        params = list(sig.parameters.values())
        at = [p.name for p in params].index("lab")
        shared = [
            inspect.Parameter(
                f.name,
                params[at].kind,
                default=f.default,
                annotation=replace.get(f.name, hints[f.name]),
            )
            for f in fields(LabArgs)
            if f.name not in omit
        ]
        signature = sig.replace(parameters=[*params[:at], *shared, *params[at + 1 :]])
        names = [p.name for p in shared]

        @functools.wraps(func)
        def command(*args: Any, **kwargs: Any) -> None:
            lab = LabArgs(**{k: kwargs.pop(k) for k in names})
            func(*args, lab=lab, **kwargs)

        command.__signature__ = signature  # type: ignore[attr-defined]
        command.__annotations__ = {p.name: p.annotation for p in signature.parameters.values()} | {
            "return": None
        }
        return app.command(name)(command)

    return register


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


def parse_effects(effects: str) -> list[Effect]:
    """``--effects`` as effect instances, to hand on to the lab (which takes them as they are);
    a bad specification, or none, is one error line."""
    from arm.effects import parse_effects

    with user_errors(prefix="--effects: "):
        parsed = parse_effects(effects)
    if not parsed:
        fail("--effects: no effect given")
    return parsed


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
    option: str = "",
) -> Any:
    """The measurement set of ``path``; the columns the format does not know are said (a
    ``MeasurementWarning``), not dropped. ``option`` (e.g. ``--validate``) is named in an error
    about a file given by an option."""
    import warnings

    from arm.measurements import MeasurementWarning, read_measurements

    parts = None if measured is None else tuple(m.strip() for m in measured.split(","))
    prefix = f"{option} " if option else ""
    with user_errors(prefix=prefix), warnings.catch_warnings(record=True) as caught:
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
