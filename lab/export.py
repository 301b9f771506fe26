"""What a calibration engineer delivers: the calibrated arm as a robot TOML, and compensation.

    result = fit("data.csv", "seed", "geometric,compliance")
    export_robot(result, "calibrated.toml")          # read back by load_robot / --robot

    comp = compensate(load_robot("calibrated.toml"), targets)   # targets (N, 3), m
    comp.q                   # joint angles to command so that the calibrated arm reaches them
    comp.error_nominal_mm    # what commanding the nominal inverse kinematics would miss by

**Export.** :meth:`FitResult.description` folds the identified geometric errors into the DH
table (Hayati's beta included), the base and the tool points, and keeps the other effects' values
under ``[effects]``; the file is checked before it is written: read back, its predictions on the
fitted poses must equal the fitted model's to :data:`EXPORT_TOL` (1 nm), else nothing is written.

The gravity torques of the compliance and load-backlash effects are the one thing the file cannot
carry as fitted: the fit evaluates them once, on the *nominal* arm (``ModelInputs.tau``), while the
calibrated arm read back computes them on its own, calibrated table. The difference is of second
order (the compliance angle ``c*tau``, about 1 mrad, times the relative change of ``tau`` that the
geometric errors make, ~1e-3): about 1 um on the seed arm with typical compliance. The check
therefore compares the predictions with the fit's own gravity torques (what the file carries,
parameter by parameter, to round-off); :func:`torque_difference` measures the second-order term,
which :func:`export_robot` logs (a warning when it exceeds a quarter of the fit's noise).

**Compensation.** A program taught on the nominal arm misses on the real one by the calibration
error. Each target is a pose: the point ``x, y, z`` in the calibration's measurement frame (the
tracker's: the calibrated arm's base transform, its registration, maps it) and the orientation of
the tool frame, given by orientation columns or held from the program (its joint angles through
the calibrated model). The compensated joint angles solve the six equations of that pose on the
calibrated model, every effect included (:func:`arm.ik.solve_model_pose`), starting at the
program and staying on its branch: damped steps from it, each taken only where it lowers the error,
follow the branch the program is on (targets whose joints move more than :data:`FAR_RAD` are
named). At a singular start (:func:`arm.ik.singularity`: axes 4 and 6 aligned, the elbow
stretched) the six equations have solutions only far from it, joints 4 and 6 turned a long way in
opposite senses or the elbow bent by the square root of the correction: there, where the start is
a solution within the calibration's correction and the six equations' solution moves a joint more
than :data:`SPLIT_RAD` (or is not found), the point is solved alone, the joints kept near
the start (its split of joints 4 and 6) and the orientation as near the target's as that allows
(:func:`arm.ik.solve_model_point_near`); such targets are named singular, and those not reached
either unreachable or singular. Without a program the start is the nominal arm's inverse kinematics,
the nominal arm placed by the calibration's base and tool (:func:`nominal_arm`): the nominal arm
defaults to the one the calibrated file records (``[nominal]``, written by :func:`export_robot`).
A targets file with neither joint angles nor an orientation is refused: the point alone leaves
three degrees of freedom, in which the wrist would turn anyhow, unless the caller asks for a free
orientation. The errors reported are the calibrated model's: at the start (the program's own
error, or the nominal solution's) and at the compensated joint angles (zero to the solver's
tolerance: what remains on the real arm is the calibration's own error), with the joint change.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from arm.description import RobotDescription, load_robot, vec3
from arm.effect_api import EffectError, ModelInputs
from arm.effects import EFFECTS
from arm.errormodel import ErrorModel
from arm.files import OutputError, atomic_write_text
from arm.ik import (
    IKResult,
    InverseKinematics,
    singular_directions,
    singularity,
    solve_model_point_near,
    solve_model_pose,
    solve_position,
)
from arm.measurements import (
    ANGLE_UNITS,
    JOINTS,
    LENGTH_UNITS,
    ORIENTATION_FORMS,
    POSITION,
    MeasurementSet,
    check_ranges,
    orientation_form,
    orientation_rotvec,
    parse_numeric_csv,
    read_measurements,
    read_text,
)
from arm.params import TOOL_ROTATION_NAMES
from arm.so3 import rotation_matrix, rotation_vector
from lab.domain import Domain, out_of_domain, warn_out_of_domain
from lab.errors import CompensationError, ExportError
from lab.registration import StationRegistration, register_station
from lab.result import SCHEMA_VERSION, FitResult
from lab.uncertainty import Uncertainty, uncertainty_of

__all__ = [
    "Compensation",
    "CompensationError",
    "ExportError",
    "TargetSet",
    "calibrated_description",
    "compensate",
    "export_robot",
    "read_targets",
    "register_references",
    "target_id_list",
    "write_joints",
]

log = logging.getLogger(__name__)

# m: with the fit's gravity torques, the exported arm predicts the fitted poses this well (TOML
# carries every float to its last bit in m/rad; mm/deg conversions cost a few ulp: ~1e-15 m).
EXPORT_TOL = 1e-9
# rad: a compensated joint angle this far from its start is named (a calibration moves the joints
# by milliradians)
FAR_RAD = 0.2
# rad: at a singular start, a solution of the pose's six equations that moves no joint more than
# this is kept; beyond it the point is solved alone, the start's split of the joints kept (the
# joints a calibration moves by milliradians would turn by tens or hundreds there)
SPLIT_RAD = 0.01


# --------------------------------------------------------------------------------------------------
def calibrated_model(robot: RobotDescription, targets: Sequence[int] = (0,)) -> ErrorModel:
    """The error model of a calibrated arm: geometric plus every effect whose values the
    description carries; its nominal vector is the calibration (``model.nominal()``)."""
    unknown = [e for e in robot.effects if e not in EFFECTS]
    if unknown:
        raise CompensationError(
            f"robot {robot.name!r} carries values of effect(s) {', '.join(unknown)} that are not "
            "registered: load the module that defines them (--effect-module FILE.py)"
        )
    try:
        # [effects.geometric] holds what the DH table cannot (a 6-DoF fit's tool frame): the
        # geometric effect reads it itself
        effects = [
            EFFECTS[n].from_parameters(list(v))
            for n, v in robot.effects.items()
            if n != "geometric"
        ]
        # a 6-DoF fit's tool frame rotation (trx try trz) turns the tool frame it reports
        six_dof = any(k in TOOL_ROTATION_NAMES for k in robot.effects.get("geometric", {}))
        return ErrorModel(robot, ["geometric", *effects], targets=targets, orientation=six_dof)
    except EffectError as exc:
        raise CompensationError(f"robot {robot.name!r}: {exc}") from None


def calibrated_description(
    result: FitResult, name: str | None = None, uncertainty: Uncertainty | None = None
) -> RobotDescription:
    """The calibrated arm of ``result`` as a file records it: the fit's description
    (:meth:`FitResult.description`), the nominal arm it was fitted to (what a controller believes
    in, where compensation without a program starts), the parameters' covariance and the spread
    between the sessions of the fit (``uncertainty`` where given, else measured from the fit,
    :mod:`lab.uncertainty`) and, where the data named their tracker station, each station's
    frame (so that targets given in a station's frame are mapped, and a station the calibration
    never saw is refused)."""
    desc = result.description(name or f"{result.model.robot.name}-calibrated")
    desc = replace(desc, nominal=replace(result.model.robot, nominal=None))
    if uncertainty is None:
        uncertainty = uncertainty_of(result)
    desc = replace(desc, uncertainty=uncertainty.to_dict())
    if "station" in result.inputs.columns or len(result.model.stations) > 1:
        desc = replace(
            desc,
            stations=tuple(
                (sid, vec3(T[:3, 3]), vec3(rotation_vector(T[:3, :3])))
                for sid, T in station_bases(result)
            ),
        )
    return desc


def export_robot(
    calibration: FitResult | RobotDescription,
    path: str | Path,
    name: str | None = None,
    length_unit: str = "m",
    angle_unit: str = "deg",
    uncertainty: Uncertainty | None = None,
) -> RobotDescription:
    """Write the calibrated arm of ``calibration`` (a fit, or a calibrated arm read from a
    file: a TOML or a calibrated URDF, exported again without refitting) as a robot TOML
    (atomically) and return it as read back (what ``load_robot(path)`` gives). It carries the
    parameters' covariance and the spread between the sessions of the fit (``[uncertainty]``,
    :mod:`lab.uncertainty`): ``uncertainty`` where given, else the result's own (an update's),
    else measured from the fit (its sessions each fitted alone); a saved calibration keeps its
    own.

    Before writing, the text is parsed and its predictions compared with the fitted model's on
    the fitted poses (with the fit's gravity torques, see the module docstring), or with the
    given arm's on poses drawn within its limits; a difference over :data:`EXPORT_TOL`, an
    effect whose values the file cannot bring back, bad units or a path that cannot be written
    raise :class:`ExportError`, and nothing is written (an existing file is left as it was).
    """
    path = Path(path)
    if length_unit not in LENGTH_UNITS:
        raise ExportError(f"{path}: length unit must be one of m, mm, got {length_unit!r}")
    if angle_unit not in ANGLE_UNITS:
        raise ExportError(f"{path}: angle unit must be one of rad, deg, got {angle_unit!r}")
    if isinstance(calibration, RobotDescription):
        desc = calibration if name is None else replace(calibration, name=name)
        if uncertainty is not None:
            desc = replace(desc, uncertainty=uncertainty.to_dict())
        result = None
    else:
        result = calibration
        register_own_effects(result)
        desc = calibrated_description(result, name, uncertainty)
    text = desc.to_toml(length_unit, angle_unit)
    back = RobotDescription.from_toml(text, source=str(path))
    try:
        if result is None:
            diff = own = description_difference(desc, back)
        else:
            diff = exported_difference(result, back)
            own = torque_difference(result, back)
    except CompensationError as exc:
        raise ExportError(f"{path}: cannot export the calibrated arm: {exc}; not written") from None
    if not diff <= EXPORT_TOL:
        raise ExportError(
            f"{path}: the exported arm predicts the fitted poses {diff * 1e3:.3g} mm away from the "
            f"fitted model (tolerance {EXPORT_TOL * 1e3:g} mm); not written"
        )
    try:
        atomic_write_text(path, text)
    except (OSError, OutputError) as exc:
        raise ExportError(f"{path}: cannot be written ({exc})") from None
    write_modules(effect_modules(desc, path)[1], path)
    log.info(
        "wrote the calibrated arm %r to %s (max difference %.2g m; %.2g m with the gravity "
        "torques of its own table)",
        desc.name,
        path,
        diff,
        own,
    )
    if result is not None and own > 0.25 * result.sigma:
        log.warning(
            "%s: the calibrated arm, with the gravity torques of its own (calibrated) table, "
            "predicts the fitted poses up to %.3g mm away from the fit, which used the nominal "
            "table's: more than a quarter of the noise (%.3g mm per axis)",
            path,
            own * 1e3,
            result.sigma_mm,
        )
    return back


def register_own_effects(result: FitResult) -> None:
    """Register the effects of ``result``'s model that were made in memory with their module's
    text (a bag's discovered terms, :func:`lab.terms.term_effect`) and are not the registered
    class of their name, so that its calibrated arm can be read back in this process; the
    export writes that module beside the file, for another process (``--effect-module``). An
    effect class without its module stays unregistered: the export refuses it."""
    from arm.effects import effect_module_file, register_effect

    for e in result.model.effects:
        cls, known = type(e), EFFECTS.get(e.name)
        if known is cls or not getattr(cls, "module_text", ""):
            continue
        if known is None or effect_module_file(known) is None:
            register_effect(cls)


def effect_modules(robot: RobotDescription, path: Path) -> tuple[dict[str, str], dict[Path, str]]:
    """The module of each effect the calibrated arm uses that the catalogue does not define:
    ``{effect: module file}`` (the ``--effect-module`` it was loaded from, else the one to write
    beside ``path``), and the modules to write, ``{file: text}``: an effect made in memory (a
    bag's discovered terms) carries its module's text, written as ``path`` with ``.py``."""
    from arm.effects import effect_module_file, is_catalogued

    names: dict[str, str] = {}
    writes: dict[Path, str] = {}
    for name in robot.effects:
        cls = EFFECTS.get(name)
        if cls is None or is_catalogued(cls):
            continue
        where = effect_module_file(cls)
        text = getattr(cls, "module_text", "")
        if where is None and text:
            target = path.with_suffix(".py")
            if target in writes:
                target = path.with_name(f"{path.stem}_{name}.py")
            writes[target] = text
            where = str(target)
        if where is not None:
            names[name] = where
    return names, writes


def write_modules(writes: Mapping[Path, str], path: Path) -> None:
    """Write the effect modules of :func:`effect_modules` beside the exported ``path``."""
    for target, text in writes.items():
        try:
            atomic_write_text(target, text)
        except (OSError, OutputError) as exc:
            raise ExportError(f"{target}: cannot be written ({exc})") from None
        log.info("wrote %s, the module of an effect %s uses (--effect-module)", target, path)


def station_frames(robot: RobotDescription) -> list[tuple[int | None, RobotDescription]]:
    """Each station of a calibrated arm as the arm placed in that station's frame (its base the
    station's), the first station first; one ``(None, robot)`` for an arm without stations."""
    if not robot.stations:
        return [(None, robot)]
    return [
        (sid, replace(robot, base_translation=t, base_rotation=r, stations=()))
        for sid, t, r in robot.stations
    ]


def description_difference(
    robot: RobotDescription, other: RobotDescription, n: int = 200, seed: int = 0
) -> float:
    """Largest distance (m) between the tool points that two calibrated arms predict, every tool
    point and every station's frame, on ``n`` poses drawn within ``robot``'s limits (each effect's
    columns at a typical value: 20 degC, no payload, each joint approached from +): what an arm
    exported again from a file keeps of it."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.lower, robot.upper, (n, 6))
    ours, theirs = station_frames(robot), station_frames(other)
    if [s for s, _ in ours] != [s for s, _ in theirs] or len(robot.tools) != len(other.tools):
        return float("inf")
    worst = 0.0
    for (_, a), (_, b) in zip(ours, theirs, strict=True):
        for k in range(len(robot.tools)):
            targets = tuple(range(len(robot.tools)))
            cols = {
                "target": np.full(n, float(k)),
                "temperature": np.full(n, 20.0),
                "payload": np.zeros(n),
                **{f"dir{j}": np.ones(n) for j in range(1, 7)},
            }
            pa = _predicted(calibrated_model(a, targets), q, cols)
            pb = _predicted(calibrated_model(b, targets), q, cols)
            worst = max(worst, float(np.max(np.linalg.norm(pa - pb, axis=1))))
    return worst


def _predicted(model: ErrorModel, q: np.ndarray, cols: dict[str, np.ndarray]) -> np.ndarray:
    try:
        return model.predict(model.inputs(q, cols), model.nominal())
    except EffectError as exc:
        raise CompensationError(str(exc)) from None


def station_bases(result: FitResult) -> list[tuple[int, np.ndarray]]:
    """(station id, 4x4 measurement frame <- robot base) of each station of the fit."""
    model, params = result.model, result.parameters()
    stations = model.stations
    out = []
    for s in stations:
        suffix = "" if len(stations) == 1 else str(s)
        t = np.array([params[f"b{c}{suffix}"] for c in "xyz"])
        r = np.array([params[f"br{c}{suffix}"] for c in "xyz"])
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = rotation_matrix(r), t
        out.append((int(s), T))
    return out


def _compare(result: FitResult, robot: RobotDescription, fit_torques: bool) -> float:
    """The largest distance of the calibrated arm's predictions from the fit's, every station's
    rows through that station's frame. A fit of several stations is compared at its sessions'
    mean zero offsets (:meth:`FitResult.at_session_mean`): a file keeps each station's frame,
    not the zero offsets of the session measured there (the arm is re-homed before its next
    use)."""
    fitted = result.model.predict(result.inputs, result.at_session_mean().params)
    frames = station_frames(robot)
    several = len(result.model.stations) > 1
    worst = 0.0
    for s, (_, arm) in enumerate(frames if several else frames[:1]):
        model = calibrated_model(arm, result.model.targets)
        rows = result.inputs.stations == s if several else np.ones(result.inputs.n, dtype=bool)
        if not rows.any():
            continue
        columns = {k: v[rows] for k, v in result.inputs.columns.items() if k != "station"}
        try:
            inputs = model.inputs(result.inputs.q[rows], columns, source=result.source)
        except EffectError as exc:
            raise CompensationError(str(exc)) from None
        if fit_torques:
            inputs = replace(inputs, tau=result.inputs.tau[rows], _cache={})
        pred = model.predict(inputs, model.nominal())
        worst = max(worst, float(np.max(np.linalg.norm(pred - fitted[rows], axis=1))))
    return worst


def exported_difference(result: FitResult, robot: RobotDescription) -> float:
    """Largest distance (m) between the predictions of ``robot`` (a calibrated description, at
    its nominal values, with the gravity torques the fit used) and of the fitted model on the
    fitted poses: what the description carries of the fit, parameter by parameter."""
    return _compare(result, robot, fit_torques=True)


def torque_difference(result: FitResult, robot: RobotDescription) -> float:
    """Largest distance (m) between the predictions of ``robot`` as it stands, gravity torques
    computed on its own table, and of the fitted model on the fitted poses (zero without a
    torque-driven effect; see the module docstring)."""
    return _compare(result, robot, fit_torques=False)


# --------------------------------------------------------------------------------------------------
@dataclass
class TargetSet:
    """Desired tool poses: points ``xyz`` (N, 3) in m in the calibration's measurement frame, with
    optional joint angles ``q`` (N, 6) (the program being corrected: its orientation is held and
    its branch kept), an optional orientation ``R`` (N, 3, 3) (measurement frame <- tool frame,
    from ``rvx, rvy, rvz`` or ``roll, pitch, yaw``), and the other columns (target, station,
    payload, temperature, dir1..6...) that the calibrated arm's effects may need."""

    xyz: np.ndarray
    q: np.ndarray | None = None
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = "<memory>"
    lines: np.ndarray | None = None  # each target's line in its file
    R: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.xyz)

    def row_name(self, i: int) -> str:
        """Target ``i`` (0-based) as the user finds it: ``line 7`` of the file, else ``row 6``."""
        return f"line {int(self.lines[i])}" if self.lines is not None else f"row {i + 1}"


def target_id_list(text: str | None) -> list[int] | None:
    """``"0,1"`` -> ``[0, 1]``: the calibration's target ids in the order of the arm's tool
    points (None: not given)."""
    if text is None:
        return None
    try:
        return [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise CompensationError(
            f"target ids must be integers separated by commas, got {text!r}"
        ) from None


def read_targets(path: str | Path, length_unit: str = "m", angle_unit: str = "rad") -> TargetSet:
    """A CSV of desired tool poses: columns x, y, z (required), q1..q6 (the program's joint
    angles), rvx, rvy, rvz or roll, pitch, yaw (the tool frame's orientation, in ``angle_unit``),
    target, station, any other numeric column. Errors name the file, line and column."""
    path = Path(path)
    if length_unit not in LENGTH_UNITS:
        raise CompensationError(f"length unit must be one of m, mm, got {length_unit!r}")
    if angle_unit not in ANGLE_UNITS:
        raise CompensationError(f"angle unit must be one of rad, deg, got {angle_unit!r}")
    text = read_text(path, CompensationError)
    table = parse_numeric_csv(text, str(path), POSITION, blank_lines=True, error=CompensationError)
    header = table.header
    qcols = [c for c in JOINTS if c in header]
    if qcols and len(qcols) != 6:
        raise CompensationError(
            f"{path}, line {table.header_line}: start joint angles need all of q1..q6, found "
            f"only {', '.join(qcols)}"
        )
    form = orientation_form(header, str(path), table.header_line, CompensationError)
    if not len(table.values):
        raise CompensationError(f"{path}: no target rows")
    col = {h: table.values[:, k] for k, h in enumerate(header)}
    for name in ("target", "station"):
        if name in col:
            bad = np.flatnonzero(col[name] != np.round(col[name]))
            if bad.size:
                raise CompensationError(
                    f"{path}, line {table.lines[bad[0]]}, column '{name}': "
                    f"{col[name][bad[0]]:g} must be an integer"
                )
    L, A = LENGTH_UNITS[length_unit], ANGLE_UNITS[angle_unit]
    ocols = ORIENTATION_FORMS[form] if form else ()
    check_ranges(
        table,
        str(path),
        {length_unit: (L, POSITION), angle_unit: (A, (*JOINTS, *ocols))},
        error=CompensationError,
    )
    xyz = np.column_stack([col[c] for c in POSITION]) * L
    q = np.column_stack([col[c] for c in JOINTS]) * A if qcols else None
    R = None
    if form:
        angles = np.column_stack([col[c] for c in ocols]) * A
        R = rotation_matrix(orientation_rotvec(angles, form))
    other = {h: col[h] for h in header if h not in (*POSITION, *JOINTS, *ocols)}
    return TargetSet(xyz, q, other, str(path), table.lines, R)


# --------------------------------------------------------------------------------------------------
@dataclass
class Compensation:
    """Compensated joint angles for desired tool poses, and what they correct.

    ``q_start`` (N, 6): the joint angles compensation starts from, the program's (``start ==
    "program"``) or the nominal arm's inverse kinematics (``"nominal_ik"``, the nominal table
    with the calibration's base and tool); ``q`` (N, 6): the joint angles to command, on the
    start's branch, that put the calibrated model's tool frame on the target pose (its point
    alone with ``orientation == "free"``). ``error_start`` and ``error`` (N, 3): the calibrated
    model's point minus the target at each, m; ``turn`` (N,): the compensated tool frame's
    rotation from the target orientation, rad (zero with a free orientation). ``converged``: the
    solve met its tolerance (``start_converged`` likewise for the nominal inverse kinematics; all
    True for a program)."""

    targets: TargetSet
    q_start: np.ndarray
    q: np.ndarray
    error_start: np.ndarray
    error: np.ndarray
    turn: np.ndarray
    converged: np.ndarray
    start_converged: np.ndarray
    robot: str
    nominal_robot: str
    start: str
    orientation: str
    # the station the targets were given in, registered from reference points measured there
    registration: StationRegistration | None = None
    singular: np.ndarray | None = None  # (N,) of str: each start's singularity, "" for none

    @property
    def n(self) -> int:
        return len(self.q)

    @staticmethod
    def _stats(e: np.ndarray) -> tuple[float, float]:
        d = np.linalg.norm(e, axis=1)
        return 1e3 * float(np.sqrt(np.mean(d**2))), 1e3 * float(d.max())

    @property
    def error_start_mm(self) -> np.ndarray:
        return 1e3 * np.linalg.norm(self.error_start, axis=1)

    @property
    def error_mm(self) -> np.ndarray:
        return 1e3 * np.linalg.norm(self.error, axis=1)

    @property
    def joint_change_mrad(self) -> np.ndarray:
        """Each target's largest joint change from the start (N,), mrad."""
        return 1e3 * np.max(np.abs(self.q - self.q_start), axis=1)

    def to_dict(self) -> dict:
        rms0, max0 = self._stats(self.error_start)
        rms1, max1 = self._stats(self.error)
        change = self.joint_change_mrad
        return {
            "schema_version": SCHEMA_VERSION,
            "n_targets": self.n,
            "robot": self.robot,
            "nominal_robot": self.nominal_robot,
            "start": self.start,
            "orientation": self.orientation,
            "start_rms_mm": rms0,
            "start_max_mm": max0,
            "rms_mm": rms1,
            "max_mm": max1,
            "max_turn_mrad": None if self.orientation == "free" else 1e3 * float(self.turn.max()),
            "converged": int(self.converged.sum()),
            "not_converged": [int(i) for i in np.flatnonzero(~self.converged)],
            "max_joint_change_mrad": float(change.max()),
            "far_from_start": [int(i) for i in np.flatnonzero(change > 1e3 * FAR_RAD)],
            "median_joint_change_mrad": 1e3 * float(np.median(np.abs(self.q - self.q_start))),
            "singular": self.singular_rows(),
            "unreachable": [int(i) for i in np.flatnonzero(~self.converged & ~self._singular)],
            "source": self.targets.source,
            "registration": None if self.registration is None else self.registration.to_dict(),
        }

    @property
    def _singular(self) -> np.ndarray:
        kinds = self.singular if self.singular is not None else np.full(self.n, "", dtype=object)
        return np.asarray(kinds != "", dtype=bool)

    def singular_rows(self) -> dict[str, list[int]]:
        """The targets (0-based rows) whose start is at a singular pose, by its kind (wrist,
        elbow, elbow+wrist...): their point is reached with the start's split of the joints
        kept, the orientation held as near as that allows (``turn``)."""
        out: dict[str, list[int]] = {}
        for i in np.flatnonzero(self._singular):
            out.setdefault(str(self.singular[i]), []).append(int(i))  # type: ignore[index]
        return out

    def _named(self, rows: np.ndarray) -> str:
        t, miss = self.targets, self.error_mm
        shown = "; ".join(
            f"{t.row_name(int(i))}: ({', '.join(f'{v:.4g}' for v in t.xyz[i])}) m missed by "
            f"{miss[i]:.4g} mm" + (f", {self.singular[i]} singularity" if self._singular[i] else "")  # type: ignore[index]
            for i in rows[:5]
        )
        return shown + (f"; and {rows.size - 5} more" if rows.size > 5 else "")

    def unreached(self) -> CompensationError | None:
        """The error that names the targets the compensated joint angles do not reach, or None
        when every solve met its tolerance: those out of the arm's reach (or only beyond its
        joint limits on the start's branch), and apart from them those at a singular pose
        (where the arm cannot move the point towards the target at all), each with its row."""
        bad = ~self.converged
        if not bad.any():
            return None
        far, sing = np.flatnonzero(bad & ~self._singular), np.flatnonzero(bad & self._singular)
        branch = "the program" if self.start == "program" else "the nominal solution"
        parts = []
        if far.size:
            parts.append(
                f"{far.size} unreachable ({self._named(far)}): out of the arm's reach, or only "
                f"beyond its joint limits on the branch of {branch}"
            )
        if sing.size:
            parts.append(
                f"{sing.size} at a singular pose ({self._named(sing)}): the arm, stretched or "
                "with axes 4 and 6 aligned, cannot move the point towards the target there"
            )
        return CompensationError(
            f"{self.targets.source}: {int(bad.sum())} of {self.n} targets not reached: "
            + "; ".join(parts)
        )

    def to_csv(self) -> str:
        """q1..q6 to command, then the target x, y, z (and target id), the calibrated model's
        error of the start and of the compensated joint angles (mm), the largest joint change
        (mrad), and whether the solve reached the target (``converged``, 1 or 0)."""
        t = self.targets
        names = [*JOINTS, "x", "y", "z"]
        cols = [self.q, t.xyz]
        if "target" in t.columns:
            names.append("target")
            cols.append(t.columns["target"][:, None])
        names += ["start_error_mm", "error_mm", "joint_change_mrad", "converged"]
        cols += [
            self.error_start_mm[:, None],
            self.error_mm[:, None],
            self.joint_change_mrad[:, None],
            self.converged.astype(float)[:, None],
        ]
        table = np.hstack(cols)
        ints = {names.index(c) for c in ("target", "converged") if c in names}
        buf = io.StringIO()
        buf.write(f"# sixaxis-track compensated joints, schema_version {SCHEMA_VERSION}\n")
        buf.write(",".join(names) + "\n")
        for row in table:
            buf.write(
                ",".join(str(int(v)) if i in ints else repr(float(v)) for i, v in enumerate(row))
                + "\n"
            )
        return buf.getvalue()


def write_joints(comp: Compensation, path: str | Path) -> None:
    atomic_write_text(Path(path), comp.to_csv())


def _model_targets(n_tools: int, ids: np.ndarray | None, target_ids: Sequence[int] | None):
    """The calibrated model's target ids: those of the calibration (``target_ids``), else those in
    the file when it names one per tool, else 0..n_tools-1."""
    if target_ids is not None:
        out = tuple(int(t) for t in target_ids)
        if len(out) != n_tools:
            raise CompensationError(
                f"{len(out)} target ids given for a calibrated arm with {n_tools} tool point(s)"
            )
    elif ids is not None and len(np.unique(ids)) == n_tools:
        out = tuple(int(t) for t in np.unique(ids))
    else:
        out = tuple(range(n_tools))
    if ids is not None:
        unknown = sorted({int(v) for v in ids} - set(out))
        if unknown:
            raise CompensationError(
                f"target id(s) {unknown} are not among the calibrated arm's {out}; give the "
                "calibration's ids (--target-ids) when the file names only some of them"
            )
    return out


def _ready_starts(robot: RobotDescription, xyz_base: np.ndarray) -> np.ndarray:
    """A start per target: joint 1 aimed at it, the others at the middle of their limits, the
    wrist bent away from its singularity."""
    lo, hi = robot.lower, robot.upper
    q = np.broadcast_to(0.5 * (lo + hi), (len(xyz_base), 6)).copy()
    q[:, 0] = np.clip(np.arctan2(xyz_base[:, 1], xyz_base[:, 0]), lo[0], hi[0])
    q[:, 4] = np.clip(q[:, 4] + 0.6, lo[4], hi[4])
    return q


def nominal_arm(calibrated: RobotDescription, nominal: RobotDescription) -> RobotDescription:
    """The nominal arm as a controller that knows the calibration's registration sees it: the
    nominal joint table, the calibrated arm's base (the tracker's frame) and tool points (and the
    tool frame's rotation of a 6-DoF fit), so that its error compares like with like."""
    cal = calibrated.to_modified()
    nom = nominal.to_modified()
    geometric = {"geometric": dict(cal.effects["geometric"])} if "geometric" in cal.effects else {}
    return replace(
        nom,
        base_translation=cal.base_translation,
        base_rotation=cal.base_rotation,
        tools=cal.tools,
        effects=geometric,
        nominal=None,
    )


def _solve(
    model: ErrorModel,
    cols: Mapping[str, np.ndarray],
    p: np.ndarray,
    xyz: np.ndarray,
    R: np.ndarray | None,
    q0: np.ndarray,
    tol: float,
) -> IKResult:
    if R is None:
        return solve_position(model, cols, p, xyz, q0, tol=tol, max_iter=100)
    return solve_model_pose(model, cols, p, xyz, R, q0, tol=tol, max_iter=100)


def _pose_starts(
    model: ErrorModel, xyz: np.ndarray, R: np.ndarray, q0: np.ndarray, tool_of: np.ndarray
) -> np.ndarray:
    """Per target pose, the closed-form (or multi-start) inverse kinematics solution of the
    nominal arm ``model.robot`` nearest ``q0``, or ``q0`` where it has none: the start that damped
    least squares on the model then finishes."""
    robot = model.robot
    T = np.zeros((len(xyz), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, xyz, 1.0
    T = np.linalg.inv(robot.base_matrix) @ T  # robot base <- tool frame
    turn = robot.effects.get("geometric", {})
    tool = np.eye(4)
    tool[:3, :3] = rotation_matrix(np.array([turn.get(k, 0.0) for k in TOOL_ROTATION_NAMES]))
    out = q0.copy()
    for k in np.unique(tool_of):
        rows = np.flatnonzero(tool_of == k)
        tool[:3, 3] = robot.tool_points[min(k, len(robot.tool_points) - 1)]
        ik = InverseKinematics(robot, tool=np.linalg.inv(robot.flange_matrix) @ tool)
        res = ik.nearest(T[rows], q0[rows])
        out[rows[res.converged]] = res.q[res.converged]
    return out


def _to_first_station(
    cal: RobotDescription, targets: TargetSet, registered: StationRegistration | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """The targets' points and orientations in the calibrated arm's measurement frame (its
    first station's): a ``station`` column maps each row from its station's frame through the
    stations the calibration recorded, or through the station ``registered`` from reference
    points measured there (every row, without a station column)."""
    station = targets.columns.get("station")
    if station is None and registered is None:
        return targets.xyz, targets.R
    t0 = np.array(cal.base_translation)
    R0 = cal.base_matrix[:3, :3]
    # each station's map to the first station's frame: x_first = M (x - t) + t0
    maps = {sid: (R0 @ rotation_matrix(np.array(r)).T, np.array(t)) for sid, t, r in cal.stations}
    if registered is not None:
        new = registered_id(cal, targets, registered)
        T = registered.base(cal.base_matrix)
        maps[new] = (R0 @ T[:3, :3].T, T[:3, 3])
        if station is None:
            station = np.full(len(targets), float(new))
        others = {int(v) for v in station} - {new}
        if not cal.stations and len(others) == 1:  # the calibration's one station, unrecorded
            maps[others.pop()] = (np.eye(3), t0)
    elif not maps and station is not None:  # one station, its id not recorded: the arm's base
        maps = {int(station[0]): (np.eye(3), t0)}
    assert station is not None
    unknown = sorted({int(v) for v in station} - set(maps))
    if unknown:
        raise CompensationError(
            f"{targets.source}: station(s) {unknown} not among the calibration's "
            f"{sorted(maps)}: targets given in the frame of a station the calibration has not "
            "seen need reference points measured there to register it (--references REFS.csv: "
            "at least 3 points not on one line, with their joints, or 6-DoF rows)"
        )
    xyz = np.empty_like(targets.xyz)
    R = None if targets.R is None else np.empty_like(targets.R)
    for sid, (M, t) in maps.items():
        on = station == sid
        xyz[on] = (targets.xyz[on] - t) @ M.T + t0
        if R is not None and targets.R is not None:
            R[on] = M @ targets.R[on]
    return xyz, R


def registered_id(
    cal: RobotDescription, targets: TargetSet, registered: StationRegistration
) -> int:
    """The station id the registration places: the references' own, else the one station of
    the targets that the calibration has not seen (-1: the targets name no station); one the
    calibration has is refused (its frame is fitted)."""
    own = {sid for sid, _, _ in cal.stations}
    station = targets.columns.get("station")
    ids = set() if station is None else {int(v) for v in station}
    new = registered.station
    if new is None:
        unseen = sorted(ids - own) if own else sorted(ids)
        if len(unseen) > 1:
            raise CompensationError(
                f"{targets.source}: stations {unseen} are not the calibration's, and the "
                f"references ({registered.source}) name none: give them a station column"
            )
        new = unseen[0] if unseen else -1
    if new in own:
        raise CompensationError(
            f"{registered.source}: station {new} is the calibration's own (its frame is "
            "fitted): reference points register a station it has not seen"
        )
    if ids and new not in ids:
        raise CompensationError(
            f"{registered.source}: the references were measured at station {new}, but "
            f"{targets.source} names station(s) {sorted(ids)}"
        )
    return new


def register_references(
    robot: RobotDescription | str | Path,
    references: MeasurementSet | str | Path,
    columns: Mapping[str, np.ndarray] | None = None,
    length_unit: str = "m",
    angle_unit: str = "rad",
) -> StationRegistration:
    """The station where ``references`` (a measurement CSV or set: joints and measured points)
    were measured, registered on them with the calibrated arm ``robot`` as it stands
    (:func:`lab.registration.register_station`); ``columns``: values for the effects' columns
    the references lack (e.g. the temperature)."""
    cal = robot if isinstance(robot, RobotDescription) else load_robot(robot)
    if not isinstance(references, MeasurementSet):
        references = read_measurements(references, length_unit=length_unit, angle_unit=angle_unit)
    if columns:
        extra = {
            k: np.broadcast_to(np.asarray(v, dtype=float), len(references))
            for k, v in columns.items()
        }
        references = replace(references, columns=extra | references.columns)
    cal = cal.to_modified()
    ids = references.columns.get("target")
    model = calibrated_model(cal, _model_targets(len(cal.tools), ids, None))
    try:
        return register_station(model, model.nominal(), references)
    except EffectError as exc:
        raise CompensationError(str(exc)) from None


def _take(cols: Mapping[str, np.ndarray], rows: np.ndarray) -> dict[str, np.ndarray]:
    return {k: v[rows] for k, v in cols.items()}


def _turn(R: np.ndarray | None, Rq: np.ndarray) -> np.ndarray:
    """The angle (rad) between each target orientation and the tool frame reached."""
    if R is None:
        return np.zeros(len(Rq))
    return np.linalg.norm(rotation_vector(R @ np.swapaxes(Rq, 1, 2)), axis=1)


def _within_domain(
    cal: RobotDescription,
    model: ErrorModel,
    p: np.ndarray,
    cols: Mapping[str, np.ndarray],
    xyz: np.ndarray,
    R: np.ndarray | None,
    source: str,
    res: IKResult,
    e: np.ndarray,
    turn: np.ndarray,
    extrapolate: bool,
    tol: float,
) -> tuple[IKResult, np.ndarray, np.ndarray]:
    """The compensation's solution where the arm records a domain: a warning for poses and
    columns outside it, and the rows outside the range a term holds over solved again without
    that term (lab.domain), unless ``extrapolate``."""
    dom = Domain.of_description(cal.domain)
    if dom is None:
        return res, e, turn
    inp = model.inputs(res.q, cols, source=source)
    exc, drop = out_of_domain(model, p, np.ones(len(p), dtype=bool), dom, inp, inp)
    warn_out_of_domain(source, exc, drop, extrapolate)
    if extrapolate or not drop:
        return res, e, turn
    names = list(drop)
    marks = np.column_stack([drop[k] for k in names])
    patterns, which = np.unique(marks, axis=0, return_inverse=True)
    which = np.asarray(which).reshape(-1)
    q, converged, e, turn = res.q.copy(), res.converged.copy(), e.copy(), turn.copy()
    for i, pattern in enumerate(patterns):
        if not pattern.any():
            continue
        rows = np.flatnonzero(which == i)
        p2 = p.copy()
        for k, off in zip(names, pattern, strict=True):
            if off:
                p2[model.layout.index(k)] = 0.0
        sub = _take(cols, rows)
        r_rows = None if R is None else R[rows]
        again = _solve(model, sub, p2, xyz[rows], r_rows, res.q[rows], tol)
        q[rows], converged[rows] = again.q, again.converged
        point, Rq = model.predict_pose(model.inputs(again.q, sub, source=source), p2)
        e[rows] = point - xyz[rows]
        turn[rows] = _turn(r_rows, Rq)
    return res._replace(q=q, converged=converged), e, turn


def _singular_starts(
    model: ErrorModel,
    nom_model: ErrorModel,
    cols: Mapping[str, np.ndarray],
    p: np.ndarray,
    inp_start: ModelInputs,
    e_start: np.ndarray,
) -> np.ndarray:
    """Each start's singularity (N,) of str: ``""``, ``"wrist"``, ``"elbow"``,
    ``"elbow+wrist"``... (:func:`arm.ik.singularity`, on the calibrated model), where the start
    is a solution within the calibration's correction (the calibrated model's error there at
    most twice the distance between the calibrated and the nominal arm's points): a target
    farther from its start is no singular pose of the program but a target elsewhere."""
    _, _, Jp, Jw = model.joint_pose_jacobian(inp_start, p)
    kinds = singularity(Jp, Jw)[1]
    nominal = nom_model.predict(nom_model.inputs(inp_start.q, cols), nom_model.nominal())
    correction = np.linalg.norm(model.predict(inp_start, p) - nominal, axis=1)
    kinds[np.linalg.norm(e_start, axis=1) > 2.0 * correction + 1e-6] = ""
    return kinds


def _keep_split(
    model: ErrorModel,
    cols: Mapping[str, np.ndarray],
    p: np.ndarray,
    xyz: np.ndarray,
    R: np.ndarray,
    q_start: np.ndarray,
    singular: np.ndarray,
    res: IKResult,
    e_start: np.ndarray,
    tol: float,
) -> IKResult:
    """The solution with the singular poses solved again for their point exactly, their joints
    near the start and their orientation as near the target's as that allows
    (:func:`arm.ik.solve_model_point_near`): the six equations there have solutions only far
    from the start (joints 4 and 6 turned a long way in opposite senses), or none. A singular
    pose whose six equations were solved with no joint moved more than :data:`SPLIT_RAD` keeps
    that solution, and is no longer named in ``singular`` (changed in place)."""
    singular[res.converged & (np.abs(res.q - q_start).max(axis=1) <= SPLIT_RAD)] = ""
    rows = np.flatnonzero(singular != "")
    if not rows.size:
        return res
    sub = _take(cols, rows)
    args = (model, sub, p, xyz[rows], R[rows], q_start[rows])
    near = solve_model_point_near(*args, tol=tol)
    # at the singularity itself the point may not move first-order: starts off it on either
    # side of the split, the one that reaches the point with the least change kept
    _, _, Jp, Jw = model.joint_pose_jacobian(model.inputs(q_start[rows], sub), p)
    for v in np.swapaxes(singular_directions(Jp, Jw), 0, 1):
        for side in (1.0, -1.0):
            other = solve_model_point_near(*args, tol=tol, start=q_start[rows] + side * 0.05 * v)
            change = np.abs(other.q - q_start[rows]).max(axis=1)
            take = other.converged & (
                ~near.converged | (change < np.abs(near.q - q_start[rows]).max(axis=1))
            ) | (~near.converged & (other.error < near.error))
            near = IKResult(
                *(
                    np.where(take.reshape(-1, *[1] * (x.ndim - 1)), y, x)
                    for x, y in zip(near, other, strict=True)
                )
            )
    q, converged, err = res.q.copy(), res.converged.copy(), res.error.copy()
    # the point reached near the start, else the six equations' solution where they have one,
    # else the nearer of the point's best and the start
    use = near.converged | ~res.converged[rows]
    stay = use & ~near.converged & (np.linalg.norm(e_start[rows], axis=1) < near.error)
    q[rows[use]], converged[rows[use]], err[rows[use]] = (
        near.q[use],
        near.converged[use],
        near.error[use],
    )
    q[rows[stay]] = q_start[rows[stay]]
    log.info(
        "%d target(s) at a singular pose: the point reached, the program's split of the joints "
        "kept, the orientation held as near as that allows",
        rows.size,
    )
    return res._replace(q=q, converged=converged, error=err)


def _nominal_start(
    cal: RobotDescription,
    nom_model: ErrorModel,
    cols: dict[str, np.ndarray],
    xyz: np.ndarray,
    R: np.ndarray | None,
    tol: float,
    seed: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The compensation's start where the targets have no program: the nominal arm's inverse
    kinematics (``nom_model``) of the targets, from ready poses (and, with orientations, pose
    starts), with random restarts (``seed``) where a start leads nowhere. Returns the joint
    angles and which of them reached their target."""
    n = len(xyz)
    p_nom = nom_model.nominal()
    Rb = rotation_matrix(np.array(cal.base_rotation))
    q0 = _ready_starts(nom_model.robot, (xyz - np.array(cal.base_translation)) @ Rb)
    if R is not None:
        q0 = _pose_starts(nom_model, xyz, R, q0, nom_model.inputs(q0, cols).target)
    res = _solve(nom_model, cols, p_nom, xyz, R, q0, tol)
    q_start, ok_start = res.q, res.converged
    rng = np.random.default_rng(seed)
    for _ in range(7):  # random restarts where the start led nowhere
        fail = np.flatnonzero(~ok_start)
        if fail.size == 0:
            break
        starts = rng.uniform(nom_model.robot.lower, nom_model.robot.upper, (fail.size, 6))
        r_f = None if R is None else R[fail]
        res = _solve(nom_model, _take(cols, fail), p_nom, xyz[fail], r_f, starts, tol)
        q_start[fail[res.converged]] = res.q[res.converged]
        ok_start[fail[res.converged]] = True
    if not ok_start.all():
        log.info(  # Compensation.unreached() names them; the caller decides
            "the nominal inverse kinematics did not reach %d of %d targets (out of reach?)",
            int((~ok_start).sum()),
            n,
        )
    return q_start, ok_start


def _nominal_of(
    cal: RobotDescription, nominal: RobotDescription | str | Path | None
) -> tuple[RobotDescription, bool]:
    """The arm the controller believes in: ``nominal`` where given, else the one the calibrated
    file records, else the arm itself; and whether that was taken without a record."""
    if nominal is not None:
        return (nominal if isinstance(nominal, RobotDescription) else load_robot(nominal)), False
    # a shipped arm is its own nominal; one that carries a calibration's marks (effect values,
    # Hayati's beta) and no record of its nominal arm was exported before the record existed
    calibrated = bool(cal.effects) or any(j.beta for j in cal.joints)
    return (cal.nominal if cal.nominal is not None else cal), cal.nominal is None and calibrated


def _target_set(targets: TargetSet | np.ndarray, free_orientation: bool) -> TargetSet:
    """The targets as a set (points (N, 3) alone as given), refused where there are none or
    where they fix no orientation and none is asked to be free."""
    if not isinstance(targets, TargetSet):
        targets = TargetSet(np.asarray(targets, dtype=float).reshape(-1, 3))
    if len(targets) == 0:
        raise CompensationError(f"{targets.source}: no targets")
    if targets.q is None and targets.R is None and not free_orientation:
        raise CompensationError(
            f"{targets.source}: the targets have neither the program's joint angles (q1..q6) nor "
            "an orientation (rvx, rvy, rvz or roll, pitch, yaw), so the tool's orientation is "
            "free and the arm may turn its wrist anyhow; give one of them, or ask for a free "
            "orientation (--free-orientation)"
        )
    return targets


def _say_unrecorded(cal: RobotDescription, unrecorded: bool) -> None:
    if unrecorded:
        log.warning(
            "%s records no nominal arm (not written by lab export): its own table is taken "
            "as the nominal one; give the arm the controller believes in (--nominal)",
            cal.name,
        )


def compensate(
    robot: RobotDescription | str | Path,
    targets: TargetSet | np.ndarray,
    nominal: RobotDescription | str | Path | None = None,
    *,
    free_orientation: bool = False,
    target_ids: Sequence[int] | None = None,
    columns: Mapping[str, np.ndarray] | None = None,
    tol: float = 1e-10,
    seed: int = 0,
    extrapolate: bool = False,
    references: StationRegistration | MeasurementSet | str | Path | None = None,
) -> Compensation:
    """Joint angles that put the calibrated arm ``robot``'s tool frame on the target poses.

    The orientation of each target is the targets' own (``R``) or the program's (its joint angles
    ``q`` through the calibrated model); with neither, a :class:`CompensationError`, unless
    ``free_orientation`` asks for the point alone. The solve starts at the program, else at the
    nominal arm's inverse kinematics (``nominal``, default the arm the calibrated file records,
    :func:`nominal_arm` places it), and keeps its branch. ``target_ids``: the calibration's target
    ids, in the order of the arm's tool points. ``columns``: extra per-target columns (payload,
    temperature, dir1..6) for the effects that need them. ``seed``: the random restarts of the
    nominal inverse kinematics where the first start fails.

    An arm that records its domain (``[domain]``, lab.domain) warns where the compensated poses
    or the columns lie outside it, and solves the rows outside the range a term holds over
    without that term, unless ``extrapolate``.

    Targets given in the frame of a station the calibration has not seen (a ``station`` id it
    does not record, or no station column) are mapped through that station, registered from
    ``references`` measured there (:func:`register_references`, or its result); without them
    such a station id is refused.
    """
    cal = robot if isinstance(robot, RobotDescription) else load_robot(robot)
    registered = (
        references
        if references is None or isinstance(references, StationRegistration)
        else register_references(cal, references)
    )
    targets = _target_set(targets, free_orientation)
    n = len(targets)
    nom, unrecorded = _nominal_of(cal, nominal)
    cal = cal.to_modified()
    cols = dict(targets.columns) | {
        k: np.asarray(v, dtype=float) for k, v in (columns or {}).items()
    }
    cols.pop("station", None)  # the rows are mapped to the first station's frame below
    ids = cols.get("target")
    model_targets = _model_targets(len(cal.tools), ids, target_ids)
    model = calibrated_model(cal, model_targets)
    try:
        model.inputs(np.zeros((1, 6)), _take(cols, np.arange(1)), source=targets.source)
    except EffectError as exc:
        raise CompensationError(str(exc)) from None
    p = model.nominal()
    xyz, R_given = _to_first_station(cal, targets, registered)

    # the target orientations
    R = None if free_orientation else R_given
    orientation = "free" if free_orientation else "targets" if R is not None else "program"
    if orientation == "program" and targets.q is not None:
        R = model.predict_pose(model.inputs(targets.q, cols, source=targets.source), p)[1]

    # the start: the program, else the nominal arm's inverse kinematics
    nom_model = calibrated_model(nominal_arm(cal, nom), model_targets)
    if targets.q is not None:
        q_start, ok_start, start = np.array(targets.q, dtype=float), np.ones(n, bool), "program"
    else:
        _say_unrecorded(cal, unrecorded)
        q_start, ok_start = _nominal_start(cal, nom_model, cols, xyz, R, tol, seed)
        start = "nominal_ik"

    # the calibrated model, from the start, on its branch; at a singular pose, the start's split
    # of the joints kept
    res = _solve(model, cols, p, xyz, R, q_start, tol)
    inp_start = model.inputs(q_start, cols, source=targets.source)
    e_start = model.predict(inp_start, p) - xyz
    singular = _singular_starts(model, nom_model, cols, p, inp_start, e_start)
    if R is not None:
        res = _keep_split(model, cols, p, xyz, R, q_start, singular, res, e_start, tol)
    inp = model.inputs(res.q, cols, source=targets.source)
    point, Rq = model.predict_pose(inp, p)
    e = point - xyz
    turn = _turn(R, Rq)
    res, e, turn = _within_domain(
        cal, model, p, cols, xyz, R, targets.source, res, e, turn, extrapolate, tol
    )
    converged = res.converged & ok_start
    if not converged.all():
        log.info("compensation did not converge for %d of %d targets", int((~converged).sum()), n)
    return Compensation(
        targets=targets,
        q_start=q_start,
        q=res.q,
        error_start=e_start,
        error=e,
        turn=turn,
        converged=converged,
        start_converged=ok_start,
        robot=cal.name,
        nominal_robot=nom.name,
        start=start,
        orientation=orientation,
        registration=registered,
        singular=singular,
    )
