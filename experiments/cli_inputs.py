"""What the ``sixaxis lab`` commands take: their shared options and how their inputs are read.

Every option is made from one declaration (:func:`arm.constraints.declare`: its name, type,
range or choices, unit and help): the fields of ``lab.LabOptions`` and of :class:`LabInputs` (what
the commands read) by :func:`option_of`, a quantity of its own (``lab.options.ALPHA``,
``arm.noise.NOISE_MM``) by :func:`declared`. The help shows the choices or the range, a bad value
is refused in the library's own words naming the flag (``error: --noise-mm must be >= 0, got
-1.0``), and :class:`LabArgs` gathers the fitting commands' options, repeats them
(:meth:`LabArgs.flags`) and carries them into a printed next step (:meth:`LabArgs.next_step`)
from the registered commands themselves. Everything else a command is given is judged by the
library it calls, inside :func:`~experiments.cli_output.user_errors` (one line ``error: ...``,
exit code 2).
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import typing
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from typer.core import TyperGroup

from arm.constraints import (
    Constraint,
    Interval,
    OneOf,
    Quantity,
    TypeOf,
    check,
    constraints_of,
    declaration,
    declare,
)
from arm.errors import SixAxisError
from arm.files import is_file
from arm.measurements import ANGLE_UNITS, LENGTH_UNITS
from arm.noise import noise_law_problems
from experiments.cli_output import console, err_console, fail, record_cautions, user_errors
from lab.options import LabOptions

if TYPE_CHECKING:
    from arm.description import RobotDescription
    from arm.effects import Effect
    from arm.measurements import MeasurementSet

__all__ = [
    "INPUTS",
    "NOT_CARRIED",
    "AngleOpt",
    "DataArg",
    "DeclaredError",
    "EffectsOpt",
    "ExportInputs",
    "JointValueOpt",
    "JsonOpt",
    "JsonOutOpt",
    "LabArgs",
    "LabInputs",
    "LengthOpt",
    "ModuleOpt",
    "OneLineErrors",
    "Read",
    "ReferencesOpt",
    "RobotOpt",
    "check_outputs",
    "cli_fields",
    "declared",
    "flag_of",
    "lab_command",
    "load_modules",
    "module_output",
    "option_of",
    "parse_effects",
    "read_arm",
    "read_data",
    "read_sessions",
    "refuse_noise",
    "sessions_json",
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
    constraint: Constraint | Quantity,
    key: str,
    help: str = "",
    *flags: str,
    lower: bool = False,
    **kw: Any,
) -> Any:
    """A typer option checked by ``constraint`` (its choices or range shown in the help), named
    ``flags`` (default ``--key``); a :class:`~arm.constraints.Quantity` gives its constraint and
    its text, which ``help`` adds to; ``lower``: a choice given in any case."""
    if isinstance(constraint, Quantity):
        checked, help = constraint.rule, constraint.text(help)
    else:
        checked = constraint
    flags = flags or (flag_of(key),)
    flag = flags[0]
    kind: Callable[[str], Any] = str
    if isinstance(checked, Interval):
        kind = int if checked.kind is int else float
        lo, hi = checked.low, checked.high
        metavar = "<int>" if kind is int else "<float>"
        if lo is not None or hi is not None:
            metavar += f" {checked.predicate.removeprefix('be ').removeprefix('lie ')}"
    elif isinstance(checked, OneOf):
        metavar = "[" + "|".join(map(str, checked.values)) + "]"
    else:
        metavar = "<value>"

    def parse(value: Any) -> Any:
        if value is None or not isinstance(value, str):
            return value
        try:
            v = kind(value.lower() if lower else value)
        except ValueError:
            v = value
        if not checked.holds(v):
            raise DeclaredError(f"{flag} must {checked.predicate}, got {v!r}")
        return v

    return typer.Option(*flags, help=help, parser=parse, **({"metavar": metavar} | kw))


def flag_of(key: str) -> str:
    """The command-line flag of a declared name: ``noise_mm`` -> ``--noise-mm``."""
    return "--" + key.replace("_", "-")


def option_of(cls: type, name: str, more: str = "", lead: str = "") -> Any:
    """The typer option of the field ``name`` of the dataclass ``cls``, made from its
    declaration (:func:`arm.constraints.declare`): its flags (``flags=``, else ``--name``; a bool
    that defaults to true also ``--no-name``), its help (``lead`` before it and ``more`` after
    it, where one command says more), its choices or range, checked in the library's words
    naming the flag. The default stays the field's: a command gives it as ``= DEFAULT.name``:

        robot: Annotated[str, option_of(LabInputs, "robot")] = INPUTS.robot
    """
    return _typed_option(cls, name, more, lead)[1]


def _typed_option(cls: type, name: str, more: str = "", lead: str = "") -> tuple[Any, Any]:
    """(the type typer reads the option as, its typer option)."""
    meta = declaration(cls, name)
    hint = typing.get_type_hints(cls)[name]
    cons, none_ok = constraints_of(cls)[name]
    default = next(f.default for f in fields(cls) if f.name == name)
    help = " ".join(t for t in (lead, meta.get("help", ""), more) if t)
    flags = tuple(meta.get("flags", ())) or (flag_of(name),)
    extra = {k: meta[k] for k in ("metavar",) if k in meta}
    if cons and isinstance(cons[0], TypeOf) and cons[0].kind is bool:
        if default is True:
            flags = (f"{flags[0]}/--no-{flags[0].removeprefix('--')}", *flags[1:])
        return bool, typer.Option(*flags, help=help, **extra)
    checked = cons[0] if cons and isinstance(cons[0], Interval | OneOf) else None
    if checked is None:
        return hint, typer.Option(*flags, help=help, **extra)
    kind: Any = str
    if isinstance(checked, Interval):
        kind = int if checked.kind is int else float
    option = declared(checked, name, help, *flags, lower=meta.get("lower", False), **extra)
    return (kind | None if none_ok else kind), option


def annotated_option(cls: type, name: str) -> Any:
    """``Annotated[type, option]`` of the field ``name`` of ``cls`` (:func:`option_of`), for a
    parameter made at run time (:func:`lab_command`)."""
    kind, option = _typed_option(cls, name)
    return Annotated[kind, option]


def cli_fields(cls: type) -> list[str]:
    """The fields of ``cls`` that are command-line options (all but those declared
    ``cli=False``), in their order."""
    return [f.name for f in fields(cls) if f.metadata.get("cli", True)]


@dataclass(frozen=True)
class LabInputs:
    """The lab's shared command-line options that are not :class:`lab.LabOptions` fields: what
    the commands read (the arm, its effects, held-out data, effect modules) and how (the units),
    each declared once here with its default, choices and help. Commands outside
    :class:`LabArgs` (``plan``, ``compensate``, ``collect``) take the same ones with
    :func:`option_of` (``robot: Annotated[str, option_of(LabInputs, "robot")] =
    INPUTS.robot``). A field declared with ``commands=(...)`` is an option of those commands
    only."""

    robot: str = declare(
        "seed",
        help="The arm: a robot TOML or URDF file, or a shipped name; a URDF's chain may follow "
        "it: 'ur5_robot.urdf#tip=tool0,base=base'. A calibrated URDF is read with the "
        "metrology file that lab export wrote beside it.",
        flags=("--robot", "-r"),
        metavar="FILE|NAME",
    )
    effects: str = declare(
        "geometric",
        help="Effects to fit, comma separated, optionally on some joints: "
        "geometric,compliance[2,3]. Catalogue: geometric, compliance, lumped_compliance (without "
        "a mass model), transmission, joint_scale, backlash, load_backlash, thermal, cyclic with "
        "its joints and orders per turn "
        "(cyclic[2:17,29;4:2]), and any --effect-module defines.",
        flags=("--effects", "-e"),
    )
    validate: Path | None = declare(
        None,
        help="Held-out measurements for validation RMS and median, in the units its '#' lines "
        "declare ('# x, y, z in mm', '# q1..q6 in deg'), else --validate-length-unit and "
        "--validate-angle-unit, else the data's.",
    )
    validate_length_unit: str | None = declare(
        None,
        OneOf(tuple(LENGTH_UNITS)),
        help="Unit of x, y, z in the --validate file. Default: the one its '#' line declares, "
        "else --length-unit.",
    )
    validate_angle_unit: str | None = declare(
        None,
        OneOf(tuple(ANGLE_UNITS)),
        help="Unit of q1..q6 in the --validate file. Default: the one its '#' line declares, "
        "else --angle-unit.",
    )
    accept_other_frame: bool = declare(
        False,
        help="Validate on held-out data that fit more than 100 times worse than the fitted "
        "data (another frame or other units: refused without it, with a warning with it).",
    )
    near: Path | None = declare(
        None,
        help="A program's joints (a CSV with q1..q6: a poses file, or measurements): the poses "
        "are chosen from its joint region (each joint's range, a little wider), where the "
        "calibration must hold for it.",
        commands=("plan",),
    )
    predict: Path | None = declare(
        None,
        help="A target file (a program's joints q1..q6, or held-out measurements): print the "
        "RMS error the calibration is expected to have there, before anything is measured "
        "(with --validate beside the measured figure); in the JSON under predicted.",
        commands=("fit", "bag", "update"),
    )
    references: Path | None = declare(
        None,
        help="Reference points measured at a station the calibration has not seen (a "
        "measurement CSV, same units: at least 3 points not on one line with their joints, or "
        "6-DoF rows): the station's frame is fitted on them alone, the arm as calibrated, and "
        "its residual printed; they stay out of any validation figure.",
        metavar="REFS.csv",
    )
    joint_value: list[str] | None = declare(
        None,
        help="Hold an extra joint of the arm (a lifting column, a track: [[extra_joints]] in a "
        "robot TOML, a prismatic joint before the arm in a URDF) at a value, NAME=VALUE in the "
        "robot file's units, where the data has no column of that name (repeatable).",
        metavar="NAME=VALUE",
    )
    orientation_unit: str | None = declare(
        None,
        OneOf(tuple(ANGLE_UNITS)),
        help="Unit of the orientation columns (rvx.. or roll, pitch, yaw) and their stds. "
        "Default: the --angle-unit.",
    )
    measured: str | None = declare(
        None,
        help="The components the instrument measures, of x,y,z,rx,ry,rz (rx..rz: the "
        "orientation about the measurement frame's axes). Default: every one the file has "
        "columns for; x,y,z fits the positions alone.",
    )
    effect_module: list[Path] | None = declare(
        None,
        help="A Python file defining Effect subclasses to register (repeatable). The file is "
        "imported, so its code runs: give only files you trust.",
        metavar="FILE.py",
    )
    length_unit: str = declare(
        "m", OneOf(tuple(LENGTH_UNITS)), help="Unit of x, y, z in the CSV files."
    )
    angle_unit: str = declare(
        "rad", OneOf(tuple(ANGLE_UNITS)), help="Unit of q1..q6 in the CSV files."
    )


INPUTS = LabInputs()


@dataclass(frozen=True)
class ExportInputs:
    """``lab export``'s own input: a saved calibration to export again, in place of DATA."""

    source: Path | None = declare(
        None,
        help="A saved calibration (a robot TOML from lab export or lab bag --export, or a "
        "calibrated URDF with its metrology file) to export again without refitting, in place of "
        "DATA; to a URDF, --robot names the nominal arm's URDF where the file records none.",
        flags=("--from",),
        metavar="CAL.toml|CAL.urdf",
    )


ReferencesOpt = Annotated[Path | None, option_of(LabInputs, "references")]
JointValueOpt = Annotated[list[str] | None, option_of(LabInputs, "joint_value")]
RobotOpt = Annotated[str, option_of(LabInputs, "robot")]
ModuleOpt = Annotated[list[Path] | None, option_of(LabInputs, "effect_module")]
LengthOpt = Annotated[str, option_of(LabInputs, "length_unit")]
AngleOpt = Annotated[str, option_of(LabInputs, "angle_unit")]
EffectsOpt = Annotated[str, option_of(LabInputs, "effects")]


DataArg = Annotated[
    list[Path],
    typer.Argument(
        help="Measurement CSV files (docs/format.md, the measurement CSV), each a session: a "
        "station column decides a row's station, a file without one is a station of its own, "
        "the same id in two files is the same station.",
        metavar="DATA.csv...",
    ),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the JSON object only.")]
JsonOutOpt = Annotated[
    Path | None,
    typer.Option("--out", help="Also write the JSON object to this file (atomically)."),
]


def module_output(help: str) -> Any:
    """``-o MODULE.py``: where a command writes the effect module of discovered terms (``lab
    discover``, ``lab bag``); ``help`` says when it is written."""
    return typer.Option(
        "--output",
        "-o",
        help=f"The effect module (Python) to write {help}; load it with --effect-module.",
        metavar="MODULE.py",
    )


# -- the lab's shared options -----------------------------------------------------------------------
#: options that a printed next step never repeats: where a command writes (its own outputs)
NOT_CARRIED = frozenset({"output", "out", "as_json"})


@dataclass(frozen=True)
class Read:
    """What :meth:`LabArgs.read` read: the arm, the data, the held-out data (or None), the
    options checked and the effects parsed."""

    arm: RobotDescription
    data: MeasurementSet
    validation: MeasurementSet | None
    options: LabOptions
    effects: list[Effect]

    def __iter__(self) -> Iterator[Any]:  # arm, data, validation, options, effects = lab.read()
        return iter((self.arm, self.data, self.validation, self.options, self.effects))


@dataclass(frozen=True)
class LabArgs(LabInputs):
    """What the lab's commands that fit take alike (fit, diagnose, discover, bag, report,
    export): the options of :class:`LabInputs` and every command-line field of
    :class:`lab.LabOptions`, both made from their declarations. :func:`lab_command` puts them into
    a command where it declares ``lab: LabArgs`` and gathers them here, with the command's own
    context (``run``: its click context, every option's value by name), from which
    :meth:`flags` and :meth:`next_step` are derived: no option is listed twice.

    Adding an option to the lab's fitting commands is one declaration (a ``LabOptions`` field,
    or a ``LabInputs`` field for what the command reads) and the code that uses it:

        # lab/options.py, in LabOptions
        gate_mm: float | None = declare(None, POSITIVE, help="Leave out rows beyond it (mm).")
        # experiments/cli_inputs.py, in LabInputs (a file the command reads)
        references: Path | None = declare(None, help="The reference points (CSV).")

    ``--gate-mm`` then appears in every fitting command, its value goes to ``LabOptions`` and
    the printed next steps repeat it where the next command takes it."""

    given: Mapping[str, Any] = field(default_factory=dict)
    run: Any = field(default=None, repr=False, compare=False)

    def options(self) -> LabOptions:
        """The :class:`lab.LabOptions` these state (``measured`` is the data's: it is read with
        them); a value the options refuse is one error line naming its flag."""
        values = dict(self.given)
        found = check(values, constraints_of(LabOptions), name=flag_of)
        if not found and {"noise_mm", "noise_ppm", "noise_mrad"} <= values.keys():
            found = noise_law_problems(
                values["noise_mm"], values["noise_ppm"], values["noise_mrad"], flag_of
            )
        if found:
            fail("; ".join(found))
        with user_errors():
            return LabOptions(**values)

    def read(
        self,
        data: Sequence[Path],
        outputs: Sequence[tuple[Path | None, str]] = (),
        as_json: bool = False,
    ) -> Read:
        """The options checked, the output places checked, the effect modules registered, the
        effects parsed (a bad ``--effects`` refused before the data are read), the robot and the
        data read, several files joined as sessions (:func:`read_sessions`): (arm, data,
        held-out data or None, options, effects). The command hands the parsed effects to the
        lab, which takes them as they are (parsed once)."""
        opts = self.options()
        check_outputs(
            outputs,
            [
                *data,
                self.validate,
                self.references,
                self.predict,
                self.robot,
                *(self.effect_module or ()),
            ],
            as_json,
        )
        load_modules(self.effect_module)
        effects = parse_effects(self.effects)
        arm = read_arm(self.robot, joint_values=self.joint_value)
        units = (self.length_unit, self.angle_unit, self.orientation_unit, self.measured)
        meas = read_sessions(data, *units)
        val = None
        if self.validate is not None:  # its own units: given, else declared, else the data's
            val = read_data(
                self.validate,
                self.validate_length_unit,
                self.validate_angle_unit,
                *units[2:],
                option="--validate",
                fallback=(self.length_unit, self.angle_unit),
            )
        return Read(arm, meas, val, opts, effects)

    def read_references(self) -> MeasurementSet | None:
        """The ``--references`` measurement set (None when not given), in the data's units;
        refused without ``--validate``, whose new station they register."""
        if self.references is None:
            return None
        if self.validate is None:
            fail(
                f"--references {self.references}: reference points register the station of "
                "--validate's data; give --validate too"
            )
        units = (self.length_unit, self.angle_unit, self.orientation_unit, self.measured)
        return read_data(self.references, *units, option="--references")

    def next_step(self, command: str, replaced: Sequence[str] = ("effects",)) -> dict[str, Any]:
        """The flags that a printed ``sixaxis lab COMMAND`` step repeats so as to work on the same
        data alike: every option given to this command (not at the next one's default) that
        ``command`` takes (read from its registered parameters), but those ``replaced`` (the
        step states its own) and the outputs (:data:`NOT_CARRIED`); none that ``command``
        refuses."""
        ctx = self.run
        if ctx is None:
            return {}
        target = ctx.parent.command.get_command(ctx.parent, command)
        skip = NOT_CARRIED | set(replaced)
        return _flags(ctx.params, [p for p in target.params if p.name not in skip])

    def flags(self) -> dict[str, Any]:
        """Every option given to this command, as the command-line flags that repeat it (the
        defaults left out), in the command's order."""
        ctx = self.run
        return {} if ctx is None else _flags(ctx.params, ctx.command.params)


def _flags(values: Mapping[str, Any], params: Sequence[Any]) -> dict[str, Any]:
    """``values`` (by parameter name) as the flags of the options ``params`` (click parameters),
    those at the option's default left out: a bool as a bare flag (``--no-x`` for false where
    the default is true), a list repeated."""
    out: dict[str, Any] = {}
    for p in params:
        if getattr(p, "param_type_name", "") != "option" or p.name not in values:
            continue
        value = values[p.name]
        if isinstance(value, tuple):
            value = list(value)
        if _same(value, p.default) or value is None or value == []:
            continue
        if isinstance(value, bool):
            out[p.opts[0] if value else p.secondary_opts[0]] = True
        elif isinstance(value, list):
            out[p.opts[0]] = [str(v) for v in value]
        else:
            out[p.opts[0]] = value
    return out


def _same(a: Any, b: Any) -> bool:
    if isinstance(b, tuple | list):
        b = list(b)
    return (type(a) is type(b) and a == b) or (
        isinstance(a, float) and isinstance(b, int) and a == b
    )


_RUN = "lab_run_context"


def lab_command(
    app: typer.Typer, name: str, omit: Sequence[str] = (), **replace: Any
) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Register a function as the command ``name`` of ``app`` with :class:`LabArgs`' options in
    place of its ``lab: LabArgs`` parameter (but those of ``omit``; those of ``replace`` with
    the typer annotation given there), and call it with them gathered in one ``LabArgs``.

        @lab_command(app, "diagnose", omit=("validate",))
        def diagnose_cmd(data: DataArg, lab: LabArgs, alpha: AlphaOpt = 0.02) -> None: ...
    """
    own = [
        n
        for n in cli_fields(LabInputs)
        if name in declaration(LabInputs, n).get("commands", (name,))
    ]
    shared = [(LabInputs, n) for n in own if n not in omit] + [
        (LabOptions, n) for n in cli_fields(LabOptions) if n not in omit
    ]
    defaults = {n: getattr(cls(), n) for cls, n in shared}
    inputs = set(cli_fields(LabInputs))

    def register(func: Callable[..., None]) -> Callable[..., None]:
        sig = inspect.signature(func, eval_str=True)
        params = list(sig.parameters.values())
        at = [p.name for p in params].index("lab")
        made = [
            inspect.Parameter(
                n,
                params[at].kind,
                default=defaults[n],
                annotation=replace.get(n) or annotated_option(cls, n),
            )
            for cls, n in shared
        ]
        # the command's own context (typer passes it to a parameter of its type): its values
        run = inspect.Parameter(_RUN, inspect.Parameter.KEYWORD_ONLY, annotation=typer.Context)
        rest = [*params[at + 1 :], run]
        signature = sig.replace(parameters=[*params[:at], *made, *rest])
        names = [p.name for p in made]

        @functools.wraps(func)
        def command(*args: Any, **kwargs: Any) -> None:
            got = {k: kwargs.pop(k) for k in names}
            lab = LabArgs(
                **{k: v for k, v in got.items() if k in inputs},
                given={k: v for k, v in got.items() if k not in inputs},
                run=kwargs.pop(_RUN),
            )
            func(*args, lab=lab, **kwargs)

        command.__signature__ = signature  # type: ignore[attr-defined]
        command.__annotations__ = {p.name: p.annotation for p in signature.parameters.values()} | {
            "return": None
        }
        return app.command(name)(command)

    return register


def refuse_noise(mm: float | None, ppm: float = 0.0, mrad: float | None = None) -> None:
    """One error line if the instrument model these flags state is refused
    (:func:`arm.noise.noise_law_problems`, naming the flags), for a command outside
    :class:`LabArgs` (``lab plan``)."""
    found = noise_law_problems(mm, ppm, mrad, flag_of)
    if found:
        fail("; ".join(found))


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


def read_arm(
    robot: str, flag: str = "--robot", joint_values: Sequence[str] | None = None
) -> RobotDescription:
    """The arm of ``--robot`` (a calibrated URDF with its metrology file), its extra joints held
    at ``--joint-value``'s values."""
    from arm.description import load_robot
    from arm.effects import check_robot_effects
    from arm.extra_joints import parse_joint_values

    with user_errors(prefix=f"{flag}: "):
        arm = _calibrated_urdf(robot, flag) or load_robot(robot)
        check_robot_effects(arm, robot)  # after --effect-module registered its effects
    with user_errors():
        return arm.holding(parse_joint_values(joint_values or ()))


def _calibrated_urdf(robot: str, flag: str) -> RobotDescription | None:
    """The calibrated arm of a URDF that ``lab export --format urdf`` wrote, where its metrology
    file lies beside it: the corrected chain with the tracker frame, the tool points and the
    effects' values, as ``--robot calibrated.toml`` gives them (None for any other robot)."""
    p = Path(robot)
    if "#" in robot or p.suffix.lower() != ".urdf" or not is_file(p):
        return None
    from lab.urdf_export import metrology_path, read_calibrated_urdf

    side = metrology_path(p)
    if not is_file(side):
        return None
    err_console.print(
        f"note: {flag} {escape(robot)}: read with {escape(str(side))} beside it (the tracker "
        "frame, the tool points and the effects of its calibration)"
    )
    return read_calibrated_urdf(p, side)


def read_data(
    path: Path,
    length_unit: str | None,
    angle_unit: str | None,
    orientation_unit: str | None = None,
    measured: str | None = None,
    option: str = "",
    fallback: tuple[str, str] = ("m", "rad"),
) -> MeasurementSet:
    """The measurement set of ``path``; the columns the format does not know are said (a
    ``MeasurementWarning``), not dropped. ``option`` (e.g. ``--validate``) is named in an error
    about a file given by an option. A unit None is the one the file declares, else
    ``fallback``'s (:func:`arm.measurements.file_units`)."""
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
            fallback=fallback,
        )
    for w in caught:  # on stderr: stdout carries the command's output (with --json, only it)
        err_console.print(f"[yellow]warning:[/yellow] {escape(str(w.message))}", soft_wrap=True)
    record_cautions(caught)
    return data


def read_target(path: Path, length_unit: str, angle_unit: str) -> Any:
    """A ``--predict`` target: held-out measurements (a file with ``x, y, z``, read as
    :func:`read_data` reads) or a program's joints (``q1..q6`` alone, (N, 6) rad)."""
    import csv

    from arm.measurements import read_poses

    with user_errors(OSError, prefix=f"--predict {path}: "):
        with open(path, newline="") as fh:
            rows = (r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#"))
            header = {c.strip() for c in next(rows, [])}
        if {"x", "y", "z"} <= header:
            return read_data(path, length_unit, angle_unit, option="--predict")
        return read_poses(path, angle_unit)


def read_sessions(
    paths: Sequence[Path],
    length_unit: str,
    angle_unit: str,
    orientation_unit: str | None = None,
    measured: str | None = None,
) -> Any:
    """The measurement files, each read as :func:`read_data` does, joined as the sessions they
    are (:func:`arm.sessions.join_sessions`; what the join says, on stderr)."""
    import warnings

    from arm.measurements import MeasurementWarning
    from arm.sessions import join_sessions

    sets = [read_data(p, length_unit, angle_unit, orientation_unit, measured) for p in paths]
    with user_errors(), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MeasurementWarning)
        joined = join_sessions(sets)
    for w in caught:
        err_console.print(f"[yellow]warning:[/yellow] {escape(str(w.message))}", soft_wrap=True)
    record_cautions(caught)
    return joined


def sessions_json(data: Any) -> dict[str, Any]:
    """The sessions a command's data were joined from, for its JSON (docs/format.md)."""
    return {"sessions": [s.to_dict() for s in data.sessions]}


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

    files = [Path(str(i)) for i in inputs if i is not None and is_file(str(i))]
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
