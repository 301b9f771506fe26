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

**Compensation.** A controller with the nominal kinematics sends the joint angles of the nominal
inverse kinematics; the real arm then misses the desired point by its calibration error. Here the
nominal solution (:func:`arm.ik.solve_point`, damped least squares on the tool point, from the
joint angles given with each target or from a ready pose aimed at it) starts a damped
least-squares solve on the *calibrated* model (:func:`arm.ik.solve_position`), every effect
included. Both are reported through the calibrated model: the error that compensation removes.
Targets are in the measurement frame of the calibration (the calibrated arm's base transform
applies); the nominal arm stands at its own base transform, or, when the calibration placed the
arm far from it (a laser tracker's frame, metres away), at the calibrated one.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from arm.description import RobotDescription, load_robot
from arm.effect_api import EffectError
from arm.effects import EFFECTS
from arm.errormodel import ErrorModel
from arm.errors import SixAxisError
from arm.files import OutputError, atomic_write_text
from arm.ik import solve_point, solve_position
from arm.measurements import (
    ANGLE_UNITS,
    JOINTS,
    LENGTH_UNITS,
    POSITION,
    check_ranges,
    parse_numeric_csv,
    read_text,
)
from arm.so3 import rotation_matrix
from lab.domain import Domain, out_of_domain, warn_out_of_domain
from lab.result import SCHEMA_VERSION, FitResult

__all__ = [
    "EXPORT_TOL",
    "Compensation",
    "CompensationError",
    "ExportError",
    "TargetSet",
    "calibrated_model",
    "compensate",
    "export_robot",
    "exported_difference",
    "read_targets",
    "target_id_list",
    "torque_difference",
    "write_joints",
]

log = logging.getLogger(__name__)

# m: with the fit's gravity torques, the exported arm predicts the fitted poses this well (TOML
# carries every float to its last bit in m/rad; mm/deg conversions cost a few ulp: ~1e-15 m).
EXPORT_TOL = 1e-9
# the nominal arm is placed at the calibrated base when the two differ by more than this (m, rad)
BASE_FAR_M = 0.05
BASE_FAR_RAD = 0.05


class ExportError(SixAxisError, ValueError):
    """The calibrated arm cannot be exported faithfully; nothing was written."""


class CompensationError(SixAxisError, ValueError):
    """Bad compensation input: the message names the file, line, column or effect."""


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
        return ErrorModel(robot, ["geometric", *effects], targets=targets)
    except EffectError as exc:
        raise CompensationError(f"robot {robot.name!r}: {exc}") from None


def export_robot(
    result: FitResult,
    path: str | Path,
    name: str | None = None,
    length_unit: str = "m",
    angle_unit: str = "deg",
) -> RobotDescription:
    """Write the calibrated arm of ``result`` as a robot TOML (atomically) and return it as read
    back (what ``load_robot(path)`` gives).

    Before writing, the text is parsed and its predictions of the fitted poses compared with the
    fitted model's (with the fit's gravity torques, see the module docstring); a difference over
    :data:`EXPORT_TOL`, an effect whose values the file cannot bring back, bad units or a path that
    cannot be written raise :class:`ExportError`, and nothing is written (an existing file is left
    as it was).
    """
    path = Path(path)
    if length_unit not in LENGTH_UNITS:
        raise ExportError(f"{path}: length unit must be one of m, mm, got {length_unit!r}")
    if angle_unit not in ANGLE_UNITS:
        raise ExportError(f"{path}: angle unit must be one of rad, deg, got {angle_unit!r}")
    desc = result.description(name or f"{result.model.robot.name}-calibrated")
    text = desc.to_toml(length_unit, angle_unit)
    back = RobotDescription.from_toml(text, source=str(path))
    try:
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
    log.info(
        "wrote the calibrated arm %r to %s (max difference %.2g m; %.2g m with the gravity "
        "torques of its own table)",
        desc.name,
        path,
        diff,
        own,
    )
    if own > 0.25 * result.sigma:
        log.warning(
            "%s: the calibrated arm, with the gravity torques of its own (calibrated) table, "
            "predicts the fitted poses up to %.3g mm away from the fit, which used the nominal "
            "table's: more than a quarter of the noise (%.3g mm per axis)",
            path,
            own * 1e3,
            result.sigma_mm,
        )
    return back


def _compare(result: FitResult, robot: RobotDescription, fit_torques: bool) -> float:
    model = calibrated_model(robot, result.model.targets)
    # a fit of several tracker stations exports the first station's base: its rows compare
    rows = np.ones(result.inputs.n, dtype=bool)
    if len(result.model.stations) > 1:
        rows = result.inputs.stations == 0
    columns = {k: v[rows] for k, v in result.inputs.columns.items() if k != "station"}
    try:
        inputs = model.inputs(result.inputs.q[rows], columns, source=result.source)
    except EffectError as exc:
        raise CompensationError(str(exc)) from None
    if fit_torques:
        inputs = replace(inputs, tau=result.inputs.tau[rows], _cache={})
    pred = model.predict(inputs, model.nominal())
    fitted = result.model.predict(result.inputs, result.params)[rows]
    return float(np.max(np.linalg.norm(pred - fitted, axis=1)))


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
    """Desired tool points ``xyz`` (N, 3) in m, with optional start joint angles ``q`` (N, 6)
    (e.g. those of the program being corrected) and the other columns (target, payload,
    temperature, dir1..6...) that the calibrated arm's effects may need."""

    xyz: np.ndarray
    q: np.ndarray | None = None
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = "<memory>"
    lines: np.ndarray | None = None  # each target's line in its file

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
    """A CSV of desired tool points: columns x, y, z (required), target, q1..q6 (optional start
    joint angles), any other numeric column. Errors name the file, line and column."""
    path = Path(path)
    if length_unit not in LENGTH_UNITS:
        raise CompensationError(f"length unit must be one of m, mm, got {length_unit!r}")
    if angle_unit not in ANGLE_UNITS:
        raise CompensationError(f"angle unit must be one of rad, deg, got {angle_unit!r}")
    text = read_text(path, CompensationError)
    table = parse_numeric_csv(text, str(path), POSITION, comments=True, error=CompensationError)
    header = table.header
    qcols = [c for c in JOINTS if c in header]
    if qcols and len(qcols) != 6:
        raise CompensationError(
            f"{path}, line {table.header_line}: start joint angles need all of q1..q6, found "
            f"only {', '.join(qcols)}"
        )
    if not len(table.values):
        raise CompensationError(f"{path}: no target rows")
    col = {h: table.values[:, k] for k, h in enumerate(header)}
    if "target" in col:
        bad = np.flatnonzero(col["target"] != np.round(col["target"]))
        if bad.size:
            raise CompensationError(
                f"{path}, line {table.lines[bad[0]]}, column 'target': {col['target'][bad[0]]:g} must be an integer"
            )
    L, A = LENGTH_UNITS[length_unit], ANGLE_UNITS[angle_unit]
    check_ranges(
        table,
        str(path),
        {length_unit: (L, POSITION), angle_unit: (A, JOINTS)},
        error=CompensationError,
    )
    xyz = np.column_stack([col[c] for c in POSITION]) * L
    q = np.column_stack([col[c] for c in JOINTS]) * A if qcols else None
    other = {h: col[h] for h in header if h not in (*POSITION, *JOINTS)}
    return TargetSet(xyz, q, other, str(path), table.lines)


# --------------------------------------------------------------------------------------------------
@dataclass
class Compensation:
    """Compensated joint angles for desired tool points, and what they correct.

    ``q_nominal`` (N, 6): the nominal inverse kinematics; ``q`` (N, 6): the joint angles to command
    (the calibrated model puts its tool point on the target); ``error_nominal`` and ``error``
    (N, 3): the calibrated model's point minus the target at each, m. ``converged``: the solve on
    the calibrated model met its tolerance (``nominal_converged`` likewise for the nominal IK).
    """

    targets: TargetSet
    q_nominal: np.ndarray
    q: np.ndarray
    error_nominal: np.ndarray
    error: np.ndarray
    converged: np.ndarray
    nominal_converged: np.ndarray
    robot: str
    nominal_robot: str
    nominal_base: str

    @property
    def n(self) -> int:
        return len(self.q)

    @staticmethod
    def _stats(e: np.ndarray) -> tuple[float, float]:
        d = np.linalg.norm(e, axis=1)
        return 1e3 * float(np.sqrt(np.mean(d**2))), 1e3 * float(d.max())

    @property
    def error_nominal_mm(self) -> np.ndarray:
        return 1e3 * np.linalg.norm(self.error_nominal, axis=1)

    @property
    def error_mm(self) -> np.ndarray:
        return 1e3 * np.linalg.norm(self.error, axis=1)

    def to_dict(self) -> dict:
        rms0, max0 = self._stats(self.error_nominal)
        rms1, max1 = self._stats(self.error)
        return {
            "schema_version": SCHEMA_VERSION,
            "n_targets": self.n,
            "robot": self.robot,
            "nominal_robot": self.nominal_robot,
            "nominal_base": self.nominal_base,
            "nominal_rms_mm": rms0,
            "nominal_max_mm": max0,
            "rms_mm": rms1,
            "max_mm": max1,
            "converged": int(self.converged.sum()),
            "not_converged": [int(i) for i in np.flatnonzero(~self.converged)],
            "max_joint_change_mrad": 1e3 * float(np.max(np.abs(self.q - self.q_nominal))),
            "source": self.targets.source,
        }

    def unreached(self) -> CompensationError | None:
        """The error that names the targets the compensated joint angles do not reach (out of
        reach, or only beyond the joint limits), or None when every solve met its tolerance."""
        bad = np.flatnonzero(~self.converged)
        if not bad.size:
            return None
        t = self.targets
        miss = self.error_mm
        shown = "; ".join(
            f"{t.row_name(int(i))}: ({', '.join(f'{v:.4g}' for v in t.xyz[i])}) m missed by "
            f"{miss[i]:.4g} mm"
            for i in bad[:5]
        )
        more = f"; and {bad.size - 5} more" if bad.size > 5 else ""
        return CompensationError(
            f"{t.source}: {bad.size} of {self.n} targets not reached ({shown}{more}): out of the "
            "arm's reach, or only beyond its joint limits"
        )

    def to_csv(self) -> str:
        """q1..q6 to command, then the target x, y, z (and target id), the calibrated model's
        error of the nominal and of the compensated joint angles (mm), and whether the solve
        reached the target (``converged``, 1 or 0)."""
        t = self.targets
        names = [*JOINTS, "x", "y", "z"]
        cols = [self.q, t.xyz]
        if "target" in t.columns:
            names.append("target")
            cols.append(t.columns["target"][:, None])
        names += ["nominal_error_mm", "error_mm", "converged"]
        cols += [
            self.error_nominal_mm[:, None],
            self.error_mm[:, None],
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


def _within_domain(cal, model, p, cols, targets, res, e, extrapolate: bool, tol: float):
    """The compensation's solution where the arm records a domain: a warning for poses and
    columns outside it, and the rows outside the range a term holds over solved again without
    that term (lab.domain), unless ``extrapolate``."""
    dom = Domain.of_description(cal.domain)
    if dom is None:
        return res, e
    inp = model.inputs(res.q, cols, source=targets.source)
    exc, drop = out_of_domain(model, p, np.ones(len(p), dtype=bool), dom, inp, inp)
    warn_out_of_domain(targets.source, exc, drop, extrapolate)
    if extrapolate or not drop:
        return res, e
    names = list(drop)
    marks = np.column_stack([drop[k] for k in names])
    patterns, which = np.unique(marks, axis=0, return_inverse=True)
    which = np.asarray(which).reshape(-1)
    q, converged, e = res.q.copy(), res.converged.copy(), e.copy()
    for i, pattern in enumerate(patterns):
        if not pattern.any():
            continue
        rows = np.flatnonzero(which == i)
        p2 = p.copy()
        for k, off in zip(names, pattern, strict=True):
            if off:
                p2[model.layout.index(k)] = 0.0
        sub = {k: v[rows] for k, v in cols.items()}
        again = solve_position(
            model, sub, p2, targets.xyz[rows], res.q[rows], tol=tol, max_iter=100
        )
        q[rows], converged[rows] = again.q, again.converged
        inp2 = model.inputs(again.q, sub, source=targets.source)
        e[rows] = model.predict(inp2, p2) - targets.xyz[rows]
    return res._replace(q=q, converged=converged), e


def compensate(
    robot: RobotDescription | str | Path,
    targets: TargetSet | np.ndarray,
    nominal: RobotDescription | str | Path | None = "seed",
    *,
    nominal_base: str = "auto",
    target_ids: Sequence[int] | None = None,
    columns: Mapping[str, np.ndarray] | None = None,
    tol: float = 1e-10,
    seed: int = 0,
    extrapolate: bool = False,
) -> Compensation:
    """Joint angles that put the calibrated arm ``robot``'s tool point on ``targets``.

    ``nominal``: the arm the controller believes in (default the seed arm); ``nominal_base``:
    where it stands, ``"nominal"`` (its own base transform), ``"calibrated"`` or ``"auto"`` (the
    calibrated base when the two differ by more than 5 cm or 50 mrad). ``target_ids``: the
    calibration's target ids, in the order of the arm's tool points. ``columns``: extra per-target
    columns (payload, temperature, dir1..6) for the effects that need them. ``seed``: the random
    restarts of the nominal inverse kinematics where the first start fails.

    An arm that records its domain (``[domain]``, lab.domain) warns where the compensated poses
    or the columns lie outside it, and solves the rows outside the range a term holds over
    without that term, unless ``extrapolate``.
    """
    cal = robot if isinstance(robot, RobotDescription) else load_robot(robot)
    cal = cal.to_modified()
    nom = nominal if isinstance(nominal, RobotDescription) else load_robot(nominal)
    nom = nom.to_modified()
    if not isinstance(targets, TargetSet):
        targets = TargetSet(np.asarray(targets, dtype=float).reshape(-1, 3))
    cols = dict(targets.columns) | {
        k: np.asarray(v, dtype=float) for k, v in (columns or {}).items()
    }
    n = len(targets)
    if n == 0:
        raise CompensationError(f"{targets.source}: no targets")
    ids = cols.get("target")
    model_targets = _model_targets(len(cal.tools), ids, target_ids)
    model = calibrated_model(cal, model_targets)
    try:
        model.inputs(np.zeros((1, 6)), {k: v[:1] for k, v in cols.items()}, source=targets.source)
    except EffectError as exc:
        raise CompensationError(str(exc)) from None
    p = model.nominal()

    # where the nominal arm stands
    if nominal_base not in ("auto", "nominal", "calibrated"):
        raise CompensationError(
            f"nominal_base must be auto, nominal or calibrated, got {nominal_base!r}"
        )
    far = (
        np.linalg.norm(np.subtract(nom.base_translation, cal.base_translation)) > BASE_FAR_M
        or np.linalg.norm(np.subtract(nom.base_rotation, cal.base_rotation)) > BASE_FAR_RAD
    )
    where = nominal_base if nominal_base != "auto" else ("calibrated" if far else "nominal")
    if where == "calibrated":
        nom = replace(nom, base_translation=cal.base_translation, base_rotation=cal.base_rotation)
    R = rotation_matrix(np.array(nom.base_rotation))
    xyz_base = (targets.xyz - np.array(nom.base_translation)) @ R  # R^T (x - t), row-wise

    # nominal inverse kinematics, target by target's tool point
    index = (
        np.searchsorted(np.array(sorted(model_targets)), ids).astype(int)
        if ids is not None
        else np.zeros(n, dtype=int)
    )
    order = np.argsort(model_targets)  # sorted position -> tool index
    tool_of = order[index]
    nom_tools = nom.tool_points
    q0 = targets.q if targets.q is not None else _ready_starts(nom, xyz_base)
    q_nom = np.empty((n, 6))
    ok_nom = np.zeros(n, dtype=bool)
    rng = np.random.default_rng(seed)
    for k in np.unique(tool_of):
        rows = np.flatnonzero(tool_of == k)
        point = nom_tools[k] if k < len(nom_tools) else nom_tools[0]
        res = solve_point(nom, xyz_base[rows], q0[rows], point=point, tol=1e-12, max_iter=200)
        q_nom[rows], ok_nom[rows] = res.q, res.converged
        fail = rows[~res.converged]
        for _ in range(7):  # random restarts where the start led nowhere
            if fail.size == 0:
                break
            starts = rng.uniform(nom.lower, nom.upper, (fail.size, 6))
            res = solve_point(nom, xyz_base[fail], starts, point=point, tol=1e-12, max_iter=200)
            good = res.converged
            q_nom[fail[good]], ok_nom[fail[good]] = res.q[good], True
            fail = fail[~good]
    if not ok_nom.all():
        log.info(  # Compensation.unreached() names them; the caller decides
            "the nominal inverse kinematics did not reach %d of %d targets (out of reach?)",
            int((~ok_nom).sum()),
            n,
        )

    # the calibrated model, from the nominal solution
    res = solve_position(model, cols, p, targets.xyz, q_nom, tol=tol, max_iter=100)
    inp_nom = model.inputs(q_nom, cols, source=targets.source)
    inp = model.inputs(res.q, cols, source=targets.source)
    e_nom = model.predict(inp_nom, p) - targets.xyz
    e = model.predict(inp, p) - targets.xyz
    if not res.converged.all():
        log.info(
            "compensation did not converge for %d of %d targets", int((~res.converged).sum()), n
        )
    res, e = _within_domain(cal, model, p, cols, targets, res, e, extrapolate, tol)
    return Compensation(
        targets=targets,
        q_nominal=q_nom,
        q=res.q,
        error_nominal=e_nom,
        error=e,
        converged=res.converged,
        nominal_converged=ok_nom,
        robot=cal.name,
        nominal_robot=nom.name,
        nominal_base=where,
    )
