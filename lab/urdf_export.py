"""The calibrated arm as a URDF: the arm's URDF with corrected joint origins, and beside it the
metrology frames and the effects a URDF cannot express.

    result = fit("data.csv", "ur5_robot.urdf")            # a robot read from a URDF
    out = export_urdf(result, "calibrated.urdf")          # + calibrated.metrology.toml
    robot = read_calibrated_urdf("calibrated.urdf")       # the whole calibrated arm, read back

**The URDF.** The text of the arm's URDF with only the ``<origin xyz rpy>`` of its six arm joints
rewritten (:func:`arm.urdf.calibrated_urdf`): every link keeps its pose in its DH frame, so its
inertial, visuals, collisions, meshes (``package://`` paths as they were), limits and every other
joint (fixed tool frames included) stay as they were. It carries the calibrated kinematics
itself (no ``<calibration rising>`` tags, which most consumers ignore): any URDF reader computes
the calibrated forward kinematics from it, in the URDF's base link.

**The metrology file** (:data:`METROLOGY_SUFFIX`, TOML, docs/format.md, "The calibrated URDF"):
what the calibration measured besides the arm and what a URDF has no place for: the measurement
frame <- base link (the tracker's registration, one per station), the tool points (targets) and
a measured tool frame's rotation in the tip link's frame, and the values of every effect other
than the geometry (compliance, backlash, cyclic errors... by parameter name, SI units), which a
controller applies on top of the URDF's kinematics.

Before writing, both files are read back (the URDF by :func:`arm.urdf.read_urdf`) into a
calibrated description whose predictions of the fitted poses must equal the fitted model's to
:data:`lab.export.EXPORT_TOL` (1 nm), as for a robot TOML; else nothing is written.
"""

from __future__ import annotations

import logging
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from arm.description import DescriptionError, RobotDescription, from_urdf, vec3
from arm.files import OutputError, atomic_write_text, read_input_text
from arm.params import TOOL_ROTATION_NAMES
from arm.so3 import rotation_matrix, rotation_vector
from arm.urdf import (
    UrdfArm,
    UrdfError,
    UrdfSource,
    calibrated_urdf,
    joint_origins,
    read_urdf,
    rpy_of,
)
from lab.export import (
    EXPORT_TOL,
    CompensationError,
    ExportError,
    calibrated_description,
    description_difference,
    effect_modules,
    exported_difference,
    register_own_effects,
    station_frames,
    write_modules,
)
from lab.result import SCHEMA_VERSION, FitResult
from lab.uncertainty import Uncertainty

__all__ = ["UrdfExport", "export_urdf", "metrology_path", "read_calibrated_urdf", "require_urdf"]

log = logging.getLogger(__name__)

METROLOGY_SUFFIX = ".metrology.toml"


@dataclass(frozen=True)
class UrdfExport:
    """What :func:`export_urdf` wrote: the URDF, its metrology file, the arm joints whose origin
    changed, the calibrated arm as read back from both, and how far that arm's predictions of the
    fitted poses lie from the fitted model's (m)."""

    urdf: Path
    metrology: Path
    joints: tuple[str, ...]
    robot: RobotDescription
    difference_m: float
    modules: tuple[Path, ...] = ()


def metrology_path(urdf: str | Path) -> Path:
    """The metrology file beside a calibrated URDF: ``calibrated.urdf`` -> ``calibrated.metrology.toml``."""
    p = Path(urdf)
    return p.with_name(p.stem + METROLOGY_SUFFIX)


def _pose(R: np.ndarray, t: np.ndarray) -> dict:
    return {
        "translation": [float(v) for v in t],
        "rotation_vector": [float(v) for v in rotation_vector(R)],
        "rpy": [float(v) for v in rpy_of(R)],
    }


def _not_urdf(robot: RobotDescription) -> str:
    return (
        f"the arm {robot.name!r} was not read from a URDF, so there is no URDF to correct; "
        "fit with --robot ARM.urdf, or export a robot TOML"
    )


def require_urdf(robot: RobotDescription) -> None:
    """Refuse an arm that was not read from a URDF: there is no URDF to correct."""
    if robot.urdf is None:
        raise ExportError(_not_urdf(robot))


def _urdf_nominal(
    calibration: FitResult | RobotDescription, nominal: RobotDescription | None, path: Path
) -> RobotDescription:
    """The nominal arm read from a URDF that the calibration corrects: a fit's own, else
    ``nominal`` (checked to be the arm the calibration records, ``[nominal]``), else the arm's
    own URDF (a calibrated URDF read back, exported again)."""
    if isinstance(calibration, FitResult):
        fitted = calibration.model.robot
        if fitted.urdf is None:
            raise ExportError(f"{path}: {_not_urdf(fitted)}")
        return fitted
    cal = calibration
    # the nominal arm given, else the recorded one where it keeps its URDF, else the arm's own
    arm: RobotDescription = nominal or cal
    if nominal is None and cal.nominal is not None and cal.nominal.urdf is not None:
        arm = cal.nominal
    if arm.urdf is None:
        raise ExportError(
            f"{path}: the calibrated arm {cal.name!r} records no URDF to correct: give the "
            "nominal arm's URDF it was fitted to (--robot ARM.urdf; nominal= in Python)"
        )
    if nominal is not None and cal.nominal is not None:
        recorded, given = cal.nominal.to_modified(), nominal.to_modified()
        far = max(
            float(np.max(np.abs(recorded.column(k) - given.column(k))))
            for k in ("alpha", "a", "d", "theta_offset")
        )
        if far > 1e-9:
            raise ExportError(
                f"{path}: {nominal.name!r} is not the arm {cal.name!r} was fitted to (its "
                f"[nominal], {cal.nominal.name!r}: a DH value differs by {far:.3g}); give the "
                "URDF of the arm it was fitted to"
            )
    return arm


def _station_table(T: np.ndarray, sid: int | None = None) -> dict:
    return ({} if sid is None else {"station": int(sid)}) | _pose(T[:3, :3], T[:3, 3])


def export_urdf(
    calibration: FitResult | RobotDescription,
    path: str | Path,
    name: str | None = None,
    nominal: RobotDescription | None = None,
    uncertainty: Uncertainty | None = None,
) -> UrdfExport:
    """Write the calibrated arm of ``calibration`` as a URDF at ``path`` and its metrology file
    beside it (:func:`metrology_path`), both atomically, after checking them (module
    docstring). ``calibration``: a fit of a robot read from a URDF, or a calibrated arm read
    from a file (a robot TOML, a calibrated URDF: exported again without refitting), with
    ``nominal`` the URDF arm it was fitted to where it does not record one. An effect the
    catalogue does not define goes with its module: the one it was loaded from is named in the
    metrology file, one made in memory (a bag's discovered terms) is written beside as
    ``path`` with ``.py``. The parameters' covariance and the spread between sessions
    (``[uncertainty]``, :mod:`lab.uncertainty`) as :func:`lab.export.export_robot` writes them.
    Raises :class:`lab.export.ExportError` naming what is wrong; nothing
    is written then."""
    path = Path(path)
    if path.suffix.lower() != ".urdf":
        raise ExportError(f"{path}: a calibrated URDF's name ends in .urdf")
    arm_nominal = _urdf_nominal(calibration, nominal, path)
    src = arm_nominal.urdf
    assert src is not None
    side = metrology_path(path)
    if isinstance(calibration, FitResult):
        register_own_effects(calibration)
        cal = calibrated_description(
            calibration, name or f"{arm_nominal.name}-calibrated", uncertainty
        )
        targets = tuple(calibration.model.targets)
        fit_doc = {
            "source": str(calibration.source),
            "effects": list(calibration.model.effect_names),
            "rms_mm": float(calibration.rms_mm),
        }
    else:
        cal = calibration if name is None else replace(calibration, name=name)
        if uncertainty is not None:
            cal = replace(cal, uncertainty=uncertainty.to_dict())
        cal = replace(cal, nominal=replace(arm_nominal, nominal=None))
        targets = tuple(range(len(cal.tools)))
        fit_doc = {"source": cal.name, "effects": ["geometric", *cal.effects]}
    cal = cal.to_modified()
    try:
        arm = read_urdf(src.path, tip=src.tip_link, base=src.base_link, text=src.text)
        origins = joint_origins(
            arm,
            cal.column("alpha"),
            cal.column("a"),
            cal.column("beta"),
            cal.column("d"),
            cal.column("theta_offset"),
        )
        text = calibrated_urdf(arm, origins)
    except UrdfError as exc:
        raise ExportError(f"{path}: cannot write the calibrated URDF: {exc}; not written") from None
    modules, writes = effect_modules(cal, path)
    doc = _metrology(cal, arm, arm_nominal, path, src, targets, fit_doc, modules)
    import tomli_w

    side_text = (
        f"# sixaxis-track: what {path.name} cannot express (docs/format.md, 'The calibrated "
        "URDF')\n" + tomli_w.dumps(doc)
    )
    back = _calibrated(text, side_text, str(path), targets)
    try:
        if isinstance(calibration, FitResult):
            diff = exported_difference(calibration, back)
        else:
            diff = description_difference(cal, back)
    except CompensationError as exc:
        raise ExportError(f"{path}: cannot export the calibrated arm: {exc}; not written") from None
    if not diff <= EXPORT_TOL:
        raise ExportError(
            f"{path}: the calibrated URDF and {side.name}, read back, predict the fitted poses "
            f"{diff * 1e3:.3g} mm away from the fitted model (tolerance {EXPORT_TOL * 1e3:g} mm): an "
            "effect whose values depend on the DH table's form cannot go beside a URDF; export a "
            "robot TOML instead; not written"
        )
    try:
        atomic_write_text(path, text)
        atomic_write_text(side, side_text)
    except (OSError, OutputError) as exc:
        raise ExportError(f"{path}: cannot be written ({exc})") from None
    write_modules(writes, path)
    log.info("wrote the calibrated URDF %s and %s (max difference %.2g m)", path, side, diff)
    return UrdfExport(path, side, tuple(arm.joint_names), back, diff, tuple(writes))


def _metrology(
    cal: RobotDescription,
    arm: UrdfArm,
    nominal: RobotDescription,
    path: Path,
    src: UrdfSource,
    targets: tuple[int, ...],
    fit_doc: dict,
    modules: dict[str, str],
) -> dict:
    """The metrology file's table: the frames in the base link and the tip link (URDF frames,
    not DH frames), the tools, the effects and their modules, the nominal arm, the domain."""
    to_base = np.linalg.inv(arm.base)  # frame 0 -> base link, nominal (joint 1's parent rigid)
    to_tip = np.linalg.inv(nominal.flange_matrix)  # frame 6 -> tip link
    doc: dict = {
        "schema_version": SCHEMA_VERSION,
        "urdf": path.name,
        "robot": cal.name,
        "base_link": src.base_link,
        "tip_link": src.tip_link,
        "joints": list(arm.joint_names),
        "units": "m, rad; effect values in SI by parameter name",
        "fit": fit_doc,
    }
    doc["tracker"] = _station_table(cal.base_matrix @ to_base)
    if cal.stations:  # every station's frame, the first the tracker's above
        doc["stations"] = [
            _station_table(station.base_matrix @ to_base, sid)
            for sid, station in station_frames(cal)
        ]
    tools = []
    for tid, point in zip(targets, cal.tools, strict=False):
        p = to_tip[:3, :3] @ np.array(point) + to_tip[:3, 3]
        tools.append({"target": int(tid), "point": [float(v) for v in p]})
    doc["tools"] = tools
    effects = {n: dict(v) for n, v in cal.effects.items()}
    tool_r = effects.get("geometric", {})
    if any(n in tool_r for n in TOOL_ROTATION_NAMES):  # a measured tool frame: in the tip link
        r6 = np.array([tool_r.pop(n, 0.0) for n in TOOL_ROTATION_NAMES])
        R = to_tip[:3, :3] @ rotation_matrix(r6)
        doc["tool_frame"] = {
            "rotation_vector": [float(v) for v in rotation_vector(R)],
            "rpy": [float(v) for v in rpy_of(R)],
        }
        if not tool_r:
            effects.pop("geometric")
    if effects:
        doc["effects"] = effects
    if modules:  # beside the URDF where they are: the name alone
        doc["effect_modules"] = {
            n: Path(m).name if Path(m).parent.resolve() == path.parent.resolve() else m
            for n, m in modules.items()
        }
    # the parameters' covariance and the spread between sessions (lab.uncertainty), as a robot
    # TOML carries them: by parameter name, relative to the nominal arm below
    doc["uncertainty"] = dict(cal.uncertainty)
    # the arm the controller believes in, as a robot description (compensation starts from it)
    doc["nominal"] = tomllib.loads(replace(nominal, nominal=None).to_toml("m", "rad"))
    if cal.domain:
        doc["domain"] = tomllib.loads(replace(nominal, nominal=None, domain=cal.domain).to_toml())[
            "domain"
        ]
    return doc


def _frame(table: dict) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rotation_matrix(np.array(table["rotation_vector"], dtype=float))
    T[:3, 3] = table["translation"]
    return T


def _calibrated(
    urdf_text: str, metrology_text: str, source: str, targets: tuple[int, ...] | None = None
) -> RobotDescription:
    """The calibrated arm of a URDF text and its metrology text (see :func:`read_calibrated_urdf`)."""
    try:
        doc = tomllib.loads(metrology_text)
    except tomllib.TOMLDecodeError as exc:
        raise ExportError(f"{metrology_path(source)}: not valid TOML: {exc}") from None
    side = metrology_path(source)
    try:
        arm = read_urdf(source, tip=doc["tip_link"], base=doc["base_link"], text=urdf_text)
        robot = from_urdf(arm)
        frame = doc["tracker"] if "tracker" in doc else doc["stations"][0]
        B = _frame(frame) @ robot.base_matrix  # measurement frame <- frame 0 of the URDF read back
        stations = tuple(
            (int(st["station"]), vec3(S[:3, 3]), vec3(rotation_vector(S[:3, :3])))
            for st in doc.get("stations", [])
            for S in [_frame(st) @ robot.base_matrix]
        )
        F = robot.flange_matrix  # its frame 6 <- tip link
        tools = doc["tools"]
        if targets is not None:
            order = {int(t["target"]): t for t in tools}
            tools = [order[t] for t in targets if t in order] or tools
        points = tuple(
            vec3(F[:3, :3] @ np.array(t["point"], dtype=float) + F[:3, 3]) for t in tools
        )
        effects = {n: dict(v) for n, v in doc.get("effects", {}).items()}
        if "tool_frame" in doc:
            R6 = F[:3, :3] @ rotation_matrix(np.array(doc["tool_frame"]["rotation_vector"]))
            effects["geometric"] = effects.get("geometric", {}) | dict(
                zip(TOOL_ROTATION_NAMES, map(float, rotation_vector(R6)), strict=True)
            )
        recorded = None
        domain: dict = {}
        if "nominal" in doc:
            import tomli_w

            recorded = RobotDescription.from_toml(
                tomli_w.dumps(doc["nominal"]), source=f"{side} [nominal]"
            )
            if "domain" in doc:  # read by the robot TOML's own rules
                domain = RobotDescription.from_toml(
                    tomli_w.dumps(doc["nominal"] | {"domain": doc["domain"]}),
                    source=f"{side} [domain]",
                ).domain
        return replace(
            robot,
            nominal=recorded,
            name=str(doc.get("robot", robot.name)),
            tools=points,
            base_translation=vec3(B[:3, 3]),
            base_rotation=vec3(rotation_vector(B[:3, :3])),
            effects=effects,
            stations=stations,
            domain=domain,
            uncertainty=dict(doc.get("uncertainty", {})),
        )
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, UrdfError | DescriptionError):
            raise ExportError(str(exc)) from None
        raise ExportError(f"{side}: not a metrology file of sixaxis-track ({exc!r})") from None


def read_calibrated_urdf(path: str | Path, metrology: str | Path | None = None) -> RobotDescription:
    """The calibrated arm that :func:`export_urdf` wrote: the URDF's chain (its base link and
    tip link as the metrology file names them) with the tracker frame as its base, the tool points
    and the effects' values; usable wherever a robot description is (``lab.export.compensate``,
    ``lab.fit`` as a new nominal arm)."""
    path = Path(path)
    side = Path(metrology) if metrology is not None else metrology_path(path)
    urdf = read_input_text(path, "URDF file", "urdf", ExportError)
    return _calibrated(
        urdf, read_input_text(side, "metrology file", "toml", ExportError), str(path)
    )
