"""Robot descriptions: a small typed structure for a serial 6R arm, read from and written to TOML.

A description holds the nominal DH table (modified/Craig or standard), joint offsets and limits, an
optional mass model, one or more tool points (targets) in the last frame, an optional base transform
(measurement frame <- robot base) and, for a calibrated arm, the values of any error-model effects.

Internally every numeric routine works on the modified-DH form. A standard-DH arm is converted once
by :meth:`RobotDescription.to_modified`: row i of the modified table takes alpha/a of standard row
i-1, and the last standard row's ``TransX(a6) RotX(alpha6)`` becomes a fixed flange transform folded
into the tool points and the last link's mass model.

SI units inside (m, rad, kg). The TOML file states its own units::

    name = "seed"
    convention = "modified"      # or "standard"
    length_unit = "m"            # or "mm"
    angle_unit = "deg"           # or "rad"
    payload = 0.0                # kg, a point mass at the first tool point

    [[joints]]
    alpha = 0.0                  # alpha_{i-1} (modified) or alpha_i (standard)
    a = 0.0
    d = 0.080
    theta_offset = 0.0
    limits = [-170.2, 170.2]
    mass = 15.0
    com = [0.0, 0.0, -0.04]      # centre of mass in frame i

    [[tools]]
    point = [0.0, 0.0, 0.050]

    [base]                       # optional: measurement frame <- robot base
    translation = [0.0, 0.0, 0.0]
    rotation_vector = [0.0, 0.0, 0.0]   # in angle_unit

    [flange]                     # optional: frame 6 <- flange (a URDF's tip link, a standard
    a = 0.0                      # DH arm's last row): TransX(a) RotX(alpha) Trans(translation)
    alpha = 0.0                  # Rot(rotation_vector); informs IK and the URDF writer, tool
    translation = [0.0, 0.0, 0.0]          # points stay in frame 6
    rotation_vector = [0.0, 0.0, 0.0]

    [effects.compliance]         # optional: calibrated effect values, SI (docs/format.md)
    c2 = 6e-6

    [[stations]]                 # optional, a calibration from several tracker stations: each
    station = 1                  # station's frame <- robot base (the base above: the first's)
    translation = [2.0, -1.2, -0.6]
    rotation_vector = [0.0, 0.0, 126.0]

    [[extra_joints]]             # optional: a joint before the arm's base (a lifting column,
    name = "column"              # a track, a rotary table), held at a value per row: the
    type = "prismatic"           # data's column named after it (in this file's units), else
    axis = [0.0, 0.0, 1.0]       # --joint-value column=V, else default (arm.extra_joints)
    translation = [0.0, 0.0, 0.0]          # its origin in the previous frame (the first's:
    rotation_vector = [0.0, 0.0, 0.0]      # the base above)
    default = 0.0

    [mount]                      # optional, with extra joints: the arm's frame 0 in the last
    translation = [0.0, 0.0, 0.3]          # extra joint's frame
    rotation_vector = [0.0, 0.0, 0.0]

    [[couplings]]                # optional: a joint's DH angle moves with another's; the
    joint = 3                    # data's rows are the controller's angles: theta_3 = q_3 +
    on = 2                       # factor * q_2 (FANUC's J3, measured from the horizon)
    factor = -1.0

    [nominal]                    # optional, written by `lab export`: the nominal arm that was
    name = "seed"                # calibrated, a whole description in the same form (its own
    ...                          # units; no [nominal] of its own)

    [uncertainty]                # optional, written by `lab export`: the calibration's parameters
    parameters = ["da2", ...]    # relative to [nominal], their covariance and the spread between
    ...                          # the sessions it was fitted on, SI (docs/format.md)
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np

from arm.errors import DescriptionError
from arm.extra_joints import ExtraJoint, place
from arm.files import atomic_write_text, is_file, read_input_text, shown
from arm.ranges import payload_problem
from arm.so3 import rotation_matrix, rotation_vector
from arm.urdf import UrdfArm, UrdfError, UrdfSource, read_urdf

__all__ = [
    "MAX_JOINT_TRAVEL",
    "DescriptionError",
    "Joint",
    "RobotDescription",
    "as_robot",
    "from_urdf",
    "load_robot",
    "seed_robot",
    "vec3",
]

Convention = Literal["modified", "standard"]
Vec3 = tuple[float, float, float]

_LENGTH = {"m": 1.0, "mm": 1e-3}
_ANGLE = {"rad": 1.0, "deg": math.pi / 180.0}


#: The farthest a joint limit may lie from zero: two turns either way, rad. Industrial wrists
#: turn up to +-400 deg (a UR's +-360 deg); beyond two turns a limit is a unit slip (degrees
#: declared as radians) or a typo, and ``plan`` would write poses no arm can reach.
MAX_JOINT_TRAVEL = 4.0 * math.pi


@dataclass(frozen=True)
class Joint:
    """One row of the DH table, with the joint's limits and the mass model of the link it moves.

    For the modified convention ``alpha`` and ``a`` are alpha_{i-1} and a_{i-1}; ``beta`` is Hayati's
    rotation about y between RotX(alpha) and TransX(a) (zero for a nominal arm, set by a calibration of
    parallel consecutive axes).
    """

    alpha: float
    a: float
    d: float
    theta_offset: float = 0.0
    lower: float = -math.pi
    upper: float = math.pi
    mass: float = 0.0
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    beta: float = 0.0


@dataclass(frozen=True)
class RobotDescription:
    """A serial 6R arm. Immutable; derive variants with :func:`dataclasses.replace`."""

    name: str
    joints: tuple[Joint, ...]
    tools: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0),)
    convention: Convention = "modified"
    payload: float = 0.0
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    base_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    flange: tuple[float, float] = (0.0, 0.0)  # (a, alpha) of a standard-DH last row, once folded
    flange_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)  # then this (a URDF's tip)
    flange_rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)  # rotation vector
    # the URDF this arm was read from (what `lab export --format urdf` edits); not part of equality
    urdf: UrdfSource | None = field(default=None, compare=False, repr=False)
    # a calibration from several tracker stations: (id, translation, rotation vector) of each
    # station's frame <- robot base; the base above is the first station's
    stations: tuple[tuple[int, Vec3, Vec3], ...] = ()
    # linear couplings of the joints: (joint, on, factor), theta_joint = q_joint + factor *
    # q_on in the DH table, q the controller's angles (FANUC's J3, measured from the horizon:
    # (3, 2, -1.0)); the rows of a data file are the controller's angles
    couplings: tuple[tuple[int, int, float], ...] = ()
    # joints before the arm's base, held at a value per row (arm.extra_joints): measurement
    # frame <- base <- extra joints <- mount <- frame 0
    extra_joints: tuple[ExtraJoint, ...] = ()
    mount_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # the file it was read from (a shipped one as robots/NAME.toml), for messages; not part of
    # equality
    source: str = field(default="", compare=False, repr=False)
    # a calibrated arm's nominal arm, as `lab export` records it (what a controller believes in)
    nominal: RobotDescription | None = field(default=None, compare=False, repr=False)
    # a calibrated arm's domain: where it was identified, {variable: (lo, hi)} in SI units
    # (q1..q6 rad, tau1..tau6 N·m, temperature degC, payload kg, t s) and "n_poses"
    # (lab.domain); empty for a drawn arm. Not part of equality.
    domain: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)
    # a calibrated arm's parameters with their covariance and the spread between the sessions
    # it was fitted on (docs/format.md, [uncertainty]; lab.uncertainty reads it), SI units;
    # empty for an arm no calibration wrote. Not part of equality.
    uncertainty: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        if len(self.joints) != 6:
            raise DescriptionError(
                f"robot {self.name!r}: 6 joints expected, got {len(self.joints)}"
            )
        if not self.tools:
            raise DescriptionError(f"robot {self.name!r}: at least one tool point is needed")
        for i, j in enumerate(self.joints, start=1):
            if not j.lower < j.upper:
                raise DescriptionError(
                    f"robot {self.name!r}: joint {i} limits [{j.lower}, {j.upper}] are empty"
                )
            if max(abs(j.lower), abs(j.upper)) > MAX_JOINT_TRAVEL:
                raise DescriptionError(
                    f"robot {self.name!r}: joint {i} limits [{j.lower:g}, {j.upper:g}] rad reach "
                    f"beyond two turns either way ({MAX_JOINT_TRAVEL:.4g} rad, 720 deg); no arm "
                    "turns that far (degrees given as radians?)"
                )
            if j.mass < 0:
                raise DescriptionError(f"robot {self.name!r}: joint {i} mass {j.mass} < 0")
        self._check_couplings()
        self._check_extra_joints()
        why = payload_problem(self.payload)  # the rule of the measurement reader too
        if why:
            raise DescriptionError(f"robot {self.name!r}: {why}")

    def _check_couplings(self) -> None:
        seen = set()
        for c in self.couplings:
            joint, on, factor = c
            where = f"robot {self.name!r}: coupling of joint {joint} on joint {on}"
            if not (1 <= joint <= 6 and 1 <= on <= 6) or joint == on:
                raise DescriptionError(
                    f"{where}: joints are 1..6 and a joint is not coupled on itself"
                )
            if not math.isfinite(factor) or factor == 0:
                raise DescriptionError(
                    f"{where}: factor {factor!r} must be a finite non-zero number"
                )
            if (joint, on) in seen:
                raise DescriptionError(f"{where}: stated twice")
            seen.add((joint, on))
        if self.couplings and abs(np.linalg.det(self.coupling_matrix)) < 1e-9:
            raise DescriptionError(
                f"robot {self.name!r}: the couplings {self.couplings} leave the joints dependent "
                "(the controller's angles could not be recovered from the arm's)"
            )

    def _check_extra_joints(self) -> None:
        names = [j.name for j in self.extra_joints]
        taken = {f"q{i}" for i in range(1, 7)} | {"x", "y", "z", "t", "temperature", "payload"}
        for n in names:
            if names.count(n) > 1 or n in taken or not n:
                raise DescriptionError(
                    f"robot {self.name!r}: extra joint name {n!r} is empty, stated twice or a "
                    "measurement column's name (the data's column named after it holds its value)"
                )
        if not self.extra_joints and (any(self.mount_translation) or any(self.mount_rotation)):
            raise DescriptionError(
                f"robot {self.name!r}: a [mount] without extra joints (put the arm's place in "
                "[base])"
            )

    def holding(self, values: Mapping[str, float]) -> RobotDescription:
        """The arm with extra joints held at fixed values (``{"column": 0.35}``, in the robot
        file's units, as a data column's): each one's default, what a row without its column
        holds. A name that is none of the arm's extra joints is refused, naming them."""
        if not values:
            return self
        known = {j.name: j for j in self.extra_joints}
        for name in values:
            if name not in known:
                raise DescriptionError(
                    f"robot {self.name!r} has no extra joint {name!r} "
                    f"({', '.join(known) or 'it has none'})"
                )
        joints = tuple(
            replace(j, default=values[j.name] * j.unit) if j.name in values else j
            for j in self.extra_joints
        )
        nominal = self.nominal
        if nominal is not None:  # what compensation starts from holds them too
            nominal = nominal.holding({k: v for k, v in values.items() if k in nominal.extra_names})
        return replace(self, extra_joints=joints, nominal=nominal)

    @property
    def extra_names(self) -> tuple[str, ...]:
        """The names of the extra joints (the data's columns that hold their values)."""
        return tuple(j.name for j in self.extra_joints)

    @property
    def mount_matrix(self) -> np.ndarray:
        """4x4: the last extra joint's frame <- the arm's frame 0 (the identity without)."""
        T = np.eye(4)
        T[:3, :3] = rotation_matrix(np.array(self.mount_rotation))
        T[:3, 3] = self.mount_translation
        return T

    @property
    def coupling_matrix(self) -> np.ndarray:
        """(6, 6) ``C``: the DH table's angles are ``C q + theta_offset``, q the controller's
        (the identity for an arm without couplings)."""
        C = np.eye(6)
        for joint, on, factor in self.couplings:
            C[joint - 1, on - 1] += factor
        return C

    # -- arrays -------------------------------------------------------------------------------
    def column(self, key: str) -> np.ndarray:
        """One field of every joint as a (6,) array, e.g. ``column("alpha")``."""
        return np.array([getattr(j, key) for j in self.joints], dtype=float)

    @property
    def lower(self) -> np.ndarray:
        return self.column("lower")

    @property
    def upper(self) -> np.ndarray:
        return self.column("upper")

    @property
    def masses(self) -> np.ndarray:
        return self.column("mass")

    @property
    def coms(self) -> np.ndarray:
        return np.array([j.com for j in self.joints], dtype=float)

    @property
    def tool_points(self) -> np.ndarray:
        """(n_targets, 3) tool points in the last frame."""
        return np.array(self.tools, dtype=float)

    @property
    def has_mass_model(self) -> bool:
        return bool(np.any(self.masses > 0))

    @property
    def base_matrix(self) -> np.ndarray:
        """4x4 transform measurement frame <- robot base."""
        T = np.eye(4)
        T[:3, :3] = rotation_matrix(np.array(self.base_rotation))
        T[:3, 3] = self.base_translation
        return T

    @property
    def flange_matrix(self) -> np.ndarray:
        """4x4 transform frame 6 <- flange: ``TransX(a) RotX(alpha)`` of ``flange`` (a standard-DH
        arm's last row, in the modified form) then ``flange_translation``/``flange_rotation`` (a
        URDF's tip link); the identity for the seed arm."""
        a, alpha = self.flange
        c, s = math.cos(alpha), math.sin(alpha)
        T = np.array([[1.0, 0, 0, a], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])
        G = np.eye(4)
        G[:3, :3] = rotation_matrix(np.array(self.flange_rotation))
        G[:3, 3] = self.flange_translation
        return T @ G

    def within_limits(self, q: np.ndarray, tol: float = 0.0) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        return np.all((q >= self.lower - tol) & (q <= self.upper + tol), axis=-1)

    @property
    def reach(self) -> float:
        """The arm's size, m: the lengths of its links from the shoulder to the flange, every
        ``|a|`` and ``|d|`` of the modified DH table but the first row's ``d`` (the shoulder's
        height above the base moves nothing), and the flange's offset. An upper bound of the
        reach a data sheet states (1.46 m for a UR10 of 1.3 m, 3.11 m for a FANUC R-2000iC of
        2.66 m), computed the same way for every arm; what the plausible bounds of its lengths
        scale with (:class:`arm.effect_api.ArmSize`)."""
        m = self.to_modified()
        flange = np.linalg.norm(m.flange_matrix[:3, 3])
        return float(np.abs(m.column("a")).sum() + np.abs(m.column("d")[1:]).sum() + flange)

    def frame0_gravity(self, values: np.ndarray | None = None) -> np.ndarray:
        """Gravity in the arm's frame 0 (m/s²): ``gravity`` itself without extra joints (3,); with
        them, ``gravity`` is in the frame they start from, and frame 0 turns with them and the
        mount: at each row's values (N, k), SI, (N, 3), or at their defaults (zero where none),
        (3,). A tilted mount or a tilting rotary table so tilts the gravity the arm feels."""
        g = np.asarray(self.gravity, dtype=float)
        if not self.extra_joints:
            return g
        held = values is None
        if held:
            values = np.array([[j.default or 0.0 for j in self.extra_joints]])
        R = place(self.extra_joints, self.mount_matrix, np.asarray(values, dtype=float)).R
        out = np.einsum("nji,j->ni", R, g)  # R^T g: frame 0 <- the extra joints' first frame
        return out[0] if held else out

    def parallel_rows(self, tol: float = 1e-6) -> tuple[int, ...]:
        """Rows i (1-based, i >= 2) whose axis z_i is parallel to z_{i-1} (alpha_{i-1} = 0 or pi).

        These rows take Hayati's ``beta`` instead of ``d`` as an error parameter.
        """
        m = self.to_modified()
        return tuple(
            i for i, j in enumerate(m.joints, start=1) if i >= 2 and abs(math.sin(j.alpha)) < tol
        )

    # -- conventions --------------------------------------------------------------------------
    def to_modified(self) -> RobotDescription:
        """The same arm in the modified (Craig) convention; identity for a modified description."""
        if self.convention == "modified":
            return self
        std = self.joints
        rows = []
        for i, j in enumerate(std):
            prev = std[i - 1] if i > 0 else None
            # standard frame i = modified frame i . TransX(a_i) RotX(alpha_i)
            com = _std_to_mod_point(j.a, j.alpha, np.array(j.com))
            rows.append(
                replace(
                    j,
                    alpha=prev.alpha if prev else 0.0,
                    a=prev.a if prev else 0.0,
                    com=vec3(com),
                )
            )
        last = std[-1]
        tools = tuple(vec3(_std_to_mod_point(last.a, last.alpha, np.array(t))) for t in self.tools)
        return replace(
            self,
            joints=tuple(rows),
            tools=tools,
            convention="modified",
            flange=(last.a, last.alpha),
        )

    # -- URDF ---------------------------------------------------------------------------------
    def to_urdf(self) -> str:
        """The arm as a URDF (:func:`arm.urdf.urdf_of_chain`): frame 0 as ``base_link``, the DH
        frames as ``link1`` .. ``link6``, the flange as ``flange``; its masses as point masses.
        The base transform and the tool points are metrology, not the arm's: they stay out; the
        joints' couplings stay in (``<coupling joint on factor/>``, which :func:`from_urdf` reads),
        and so do its extra joints, before ``base_link``, each declared with its default
        (``<extra_joint joint default/>``)."""
        from arm.urdf import urdf_of_chain

        m = self.to_modified()
        return urdf_of_chain(
            m.name,
            m.column("alpha"),
            m.column("a"),
            m.column("beta"),
            m.column("d"),
            m.column("theta_offset"),
            m.lower,
            m.upper,
            m.masses,
            m.coms,
            m.flange_matrix,
            m.couplings,
            [(j.name, j.kind, np.array(j.axis), j.origin) for j in m.extra_joints],
            m.mount_matrix,
            {j.name: j.default for j in m.extra_joints if j.default is not None},
        )

    # -- TOML ---------------------------------------------------------------------------------
    def to_toml(self, length_unit: str = "m", angle_unit: str = "deg") -> str:
        import tomli_w

        return tomli_w.dumps(self._to_dict(length_unit, angle_unit))

    def _to_dict(self, length_unit: str, angle_unit: str) -> dict:
        L, A = _LENGTH[length_unit], _ANGLE[angle_unit]
        doc: dict = {
            "name": self.name,
            "convention": self.convention,
            "length_unit": length_unit,
            "angle_unit": angle_unit,
            "payload": self.payload,
            "gravity": list(self.gravity),
        }
        flange: dict = {}
        if self.flange != (0.0, 0.0):
            flange |= {"a": self.flange[0] / L, "alpha": self.flange[1] / A}
        if any(self.flange_translation) or any(self.flange_rotation):
            flange["translation"] = [c / L for c in self.flange_translation]
            flange["rotation_vector"] = [c / A for c in self.flange_rotation]
        if flange:
            doc["flange"] = flange
        joints = []
        for j in self.joints:
            row = {
                "alpha": j.alpha / A,
                "a": j.a / L,
                "d": j.d / L,
                "theta_offset": j.theta_offset / A,
                "limits": [j.lower / A, j.upper / A],
                "mass": j.mass,
                "com": [c / L for c in j.com],
            }
            if j.beta:
                row["beta"] = j.beta / A
            joints.append(row)
        doc["joints"] = joints
        doc["tools"] = [{"point": [c / L for c in t]} for t in self.tools]
        if any(self.base_translation) or any(self.base_rotation):
            doc["base"] = {
                "translation": [c / L for c in self.base_translation],
                "rotation_vector": [c / A for c in self.base_rotation],
            }
        if self.effects:
            doc["effects"] = {k: dict(v) for k, v in self.effects.items()}
        if self.couplings:
            doc["couplings"] = [{"joint": j, "on": o, "factor": f} for j, o, f in self.couplings]
        if self.extra_joints:
            doc["extra_joints"] = [_extra_doc(j, L, A) for j in self.extra_joints]
            doc["mount"] = {
                "translation": [c / L for c in self.mount_translation],
                "rotation_vector": [c / A for c in self.mount_rotation],
            }
        if self.stations:
            doc["stations"] = [
                {
                    "station": sid,
                    "translation": [c / L for c in t],
                    "rotation_vector": [c / A for c in r],
                }
                for sid, t, r in self.stations
            ]
        if self.nominal is not None:
            doc["nominal"] = replace(self.nominal, nominal=None)._to_dict(length_unit, angle_unit)
        if self.domain:
            doc["domain"] = {
                k: (int(v) if k == "n_poses" else [float(v[0]), float(v[1])])
                for k, v in self.domain.items()
            }
        if self.uncertainty:
            doc["uncertainty"] = dict(self.uncertainty)
        return doc

    def save(self, path: str | Path, length_unit: str = "m", angle_unit: str = "deg") -> None:
        atomic_write_text(Path(path), self.to_toml(length_unit, angle_unit))

    @classmethod
    def from_toml(cls, text: str, source: str = "<string>") -> RobotDescription:
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise DescriptionError(f"{source}: not valid TOML: {exc}") from exc
        except RecursionError:  # arrays or tables nested thousands deep
            raise DescriptionError(
                f"{source}: not a robot description: arrays or tables nested too deeply to read"
            ) from None
        return _from_dict(doc, source)


def vec3(values: Iterable[float]) -> Vec3:
    """Three numbers as the plain float triple a description stores."""
    x, y, z = (float(c) for c in values)
    return (x, y, z)


def _std_to_mod_point(a: float, alpha: float, p: np.ndarray) -> np.ndarray:
    """A point given in standard frame i, expressed in modified frame i."""
    c, s = math.cos(alpha), math.sin(alpha)
    x, y, z = p
    return np.array([x + a, c * y - s * z, s * y + c * z])


def _get(doc: dict, key: str, source: str, kind, where: str, default=None):
    if key not in doc:
        if default is not None:
            return default
        raise DescriptionError(f"{source}: {where}missing key '{key}'")
    val = doc[key]
    if kind is float:
        if isinstance(val, bool) or not isinstance(val, int | float):
            raise DescriptionError(f"{source}: {where}'{key}' must be a number, got {val!r}")
        if not math.isfinite(val):
            raise DescriptionError(f"{source}: {where}'{key}' is not finite")
        return float(val)
    if kind == "vec3":
        if not isinstance(val, list) or len(val) != 3:
            raise DescriptionError(f"{source}: {where}'{key}' must be a list of 3 numbers")
        return tuple(_get({"v": v}, "v", source, float, f"{where}{key}: ") for v in val)
    if kind is str:
        if not isinstance(val, str):
            raise DescriptionError(f"{source}: {where}'{key}' must be a string, got {val!r}")
        return val
    return val


_KEYS = {
    "": {
        "name",
        "convention",
        "length_unit",
        "angle_unit",
        "payload",
        "gravity",
        "joints",
        "tools",
        "base",
        "flange",
        "effects",
        "stations",
        "nominal",
        "domain",
        "couplings",
        "uncertainty",
        "extra_joints",
        "mount",
    },
    "extra_joint": {"name", "type", "axis", "translation", "rotation_vector", "default"},
    "mount": {"translation", "rotation_vector"},
    "station": {"station", "translation", "rotation_vector"},
    "coupling": {"joint", "on", "factor"},
    "joint": {"alpha", "a", "d", "theta_offset", "limits", "mass", "com", "beta"},
    "tool": {"point"},
    "base": {"translation", "rotation_vector"},
    "flange": {"a", "alpha", "translation", "rotation_vector"},
}


def _domain(doc, source: str) -> dict[str, Any]:
    """``[domain]``: ``n_poses`` and each variable's fitted range ``[lo, hi]`` (SI units)."""
    if not isinstance(doc, dict):
        raise DescriptionError(f"{source}: [domain] must be a table of ranges")
    out: dict[str, Any] = {}
    for k, v in doc.items():
        if k == "n_poses":
            if not isinstance(v, int) or v < 0:
                raise DescriptionError(f"{source}: domain: n_poses must be a whole number >= 0")
            out[k] = v
            continue
        ok = (
            isinstance(v, list)
            and len(v) == 2
            and all(isinstance(x, int | float) and math.isfinite(x) for x in v)
            and v[0] <= v[1]
        )
        if not ok:
            raise DescriptionError(
                f"{source}: domain: {k} must be a range [lo, hi] of two finite numbers, got {v!r}"
            )
        out[k] = (float(v[0]), float(v[1]))
    return out


def _table(val, source: str, where: str, kind: str) -> dict:
    """A TOML table with only the keys of ``kind``: a typo must not silently drop a value."""
    if not isinstance(val, dict):
        raise DescriptionError(f"{source}: {where}must be a table, got {val!r}")
    unknown = sorted(set(val) - _KEYS[kind])
    if unknown:
        raise DescriptionError(
            f"{source}: {where}unknown key(s) {', '.join(map(repr, unknown))}; "
            f"known: {', '.join(sorted(_KEYS[kind]))}"
        )
    return val


def _stations(doc: dict, source: str, L: float, A: float) -> tuple[tuple[int, Vec3, Vec3], ...]:
    """The ``[[stations]]`` of a description: (id, translation, rotation vector), SI."""
    rows = doc.get("stations", [])
    if not isinstance(rows, list):
        raise DescriptionError(f"{source}: [[stations]] must be a list of tables")
    out = []
    for k, st in enumerate(rows):
        w = f"station {k + 1}: "
        _table(st, source, w, "station")
        sid = _get(st, "station", source, float, w)
        if sid != int(sid):
            raise DescriptionError(f"{source}: {w}'station' must be an integer, got {sid:g}")
        t = vec3(c * L for c in _get(st, "translation", source, "vec3", w))
        r = vec3(c * A for c in _get(st, "rotation_vector", source, "vec3", w))
        out.append((int(sid), t, r))
    return tuple(out)


def _couplings(doc: dict, source: str) -> tuple[tuple[int, int, float], ...]:
    """The ``[[couplings]]`` of a description: (joint, on, factor), ``theta_joint = q_joint +
    factor * q_on`` in the DH table."""
    rows = doc.get("couplings", [])
    if not isinstance(rows, list):
        raise DescriptionError(f"{source}: [[couplings]] must be a list of tables")
    out = []
    for k, c in enumerate(rows, start=1):
        w = f"coupling {k}: "
        _table(c, source, w, "coupling")
        joint, on = (_get(c, key, source, float, w) for key in ("joint", "on"))
        for key, v in (("joint", joint), ("on", on)):
            if v != int(v) or not 1 <= v <= 6:
                raise DescriptionError(f"{source}: {w}'{key}' must be a joint 1..6, got {v:g}")
        out.append((int(joint), int(on), _get(c, "factor", source, float, w)))
    return tuple(out)


def _extra_doc(j: ExtraJoint, L: float, A: float) -> dict:
    """An extra joint as its ``[[extra_joints]]`` table, in the file's units."""
    unit = L if j.kind == "prismatic" else A
    row: dict = {
        "name": j.name,
        "type": j.kind,
        "axis": list(j.axis),
        "translation": [c / L for c in j.translation],
        "rotation_vector": [c / A for c in j.rotation],
    }
    if j.default is not None:
        row["default"] = j.default / unit
    return row


def _extra_joints(doc: dict, source: str, L: float, A: float) -> tuple[ExtraJoint, ...]:
    """The ``[[extra_joints]]`` of a description, SI; a data column named after one is in the
    file's length (prismatic) or angle (revolute) unit."""
    rows = doc.get("extra_joints", [])
    if not isinstance(rows, list):
        raise DescriptionError(f"{source}: [[extra_joints]] must be a list of tables")
    out = []
    for k, r in enumerate(rows, start=1):
        w = f"extra joint {k}: "
        _table(r, source, w, "extra_joint")
        kind = _get(r, "type", source, str, w)
        if kind not in ("prismatic", "revolute"):
            raise DescriptionError(f"{source}: {w}type {kind!r} is not 'prismatic' or 'revolute'")
        unit = L if kind == "prismatic" else A
        default = r.get("default")
        try:
            out.append(
                ExtraJoint(
                    name=_get(r, "name", source, str, w),
                    kind=kind,
                    axis=vec3(_get(r, "axis", source, "vec3", w)),
                    translation=vec3(
                        c * L for c in _get(r, "translation", source, "vec3", w, (0.0, 0.0, 0.0))
                    ),
                    rotation=vec3(
                        c * A
                        for c in _get(r, "rotation_vector", source, "vec3", w, (0.0, 0.0, 0.0))
                    ),
                    default=None
                    if default is None
                    else _get(r, "default", source, float, w) * unit,
                    unit=unit,
                )
            )
        except DescriptionError as exc:
            raise DescriptionError(f"{source}: {w}{exc}") from None
    return tuple(out)


def _joint(r: Any, i: int, source: str, lu: str, au: str) -> Joint:
    """Joint ``i`` of a robot TOML's [[joints]] (its row ``r``) in SI units."""
    L, A = _LENGTH[lu], _ANGLE[au]
    half_turn = 180.0 if au == "deg" else math.pi
    w = f"joint {i}: "
    _table(r, source, w, "joint")
    limits = r.get("limits", [-half_turn, half_turn])
    if not isinstance(limits, list) or len(limits) != 2:
        raise DescriptionError(f"{source}: {w}'limits' must be [lower, upper]")
    lo = _get({"v": limits[0]}, "v", source, float, w + "limits: ")
    hi = _get({"v": limits[1]}, "v", source, float, w + "limits: ")
    if max(abs(lo), abs(hi)) * A > MAX_JOINT_TRAVEL:
        turns = f"two turns either way ({MAX_JOINT_TRAVEL / A:.4g} {au})"
        likely = (
            'degrees? say angle_unit = "deg"'
            if au == "rad" and max(abs(lo), abs(hi)) <= 720.0
            else "no arm turns that far"
        )
        raise DescriptionError(
            f"{source}: {w}limits [{lo:g}, {hi:g}] under angle_unit = {au!r} reach beyond "
            f"{turns}: {likely}"
        )
    return Joint(
        alpha=_get(r, "alpha", source, float, w) * A,
        a=_get(r, "a", source, float, w) * L,
        d=_get(r, "d", source, float, w) * L,
        theta_offset=_get(r, "theta_offset", source, float, w, 0.0) * A,
        lower=lo * A,
        upper=hi * A,
        mass=_get(r, "mass", source, float, w, 0.0),
        com=tuple(c * L for c in _get(r, "com", source, "vec3", w, (0.0, 0.0, 0.0))),
        beta=_get(r, "beta", source, float, w, 0.0) * A,
    )


def _from_dict(doc: dict, source: str, nested: bool = False) -> RobotDescription:
    _table(doc, source, "", "")
    nominal = None
    if "nominal" in doc:
        if nested:
            raise DescriptionError(f"{source}: [nominal] has a [nominal] of its own")
        nominal = _from_dict(
            _table(doc["nominal"], source, "[nominal] ", ""), f"{source} [nominal]", nested=True
        )
    lu = _get(doc, "length_unit", source, str, "", "m")
    au = _get(doc, "angle_unit", source, str, "", "rad")
    if lu not in _LENGTH:
        raise DescriptionError(
            f"{source}: length_unit must be one of {sorted(_LENGTH)}, got {lu!r}"
        )
    if au not in _ANGLE:
        raise DescriptionError(f"{source}: angle_unit must be one of {sorted(_ANGLE)}, got {au!r}")
    L, A = _LENGTH[lu], _ANGLE[au]
    conv = _get(doc, "convention", source, str, "", "modified")
    if conv not in ("modified", "standard"):
        raise DescriptionError(
            f"{source}: convention must be 'modified' or 'standard', got {conv!r}"
        )
    rows = doc.get("joints")
    if not isinstance(rows, list) or len(rows) != 6:
        raise DescriptionError(f"{source}: [[joints]] must appear exactly 6 times")
    joints = [_joint(r, i, source, lu, au) for i, r in enumerate(rows, start=1)]
    tools_doc = doc.get("tools", [{"point": [0.0, 0.0, 0.0]}])
    if not isinstance(tools_doc, list) or not tools_doc:
        raise DescriptionError(f"{source}: [[tools]] must be a non-empty list of tables")
    tools = tuple(
        tuple(
            c * L
            for c in _get(
                _table(t, source, f"tool {k}: ", "tool"), "point", source, "vec3", f"tool {k}: "
            )
        )
        for k, t in enumerate(tools_doc, start=1)
    )
    base = _table(doc.get("base", {}), source, "[base] ", "base")
    bt = tuple(c * L for c in _get(base, "translation", source, "vec3", "base: ", (0.0, 0.0, 0.0)))
    br = tuple(
        c * A for c in _get(base, "rotation_vector", source, "vec3", "base: ", (0.0, 0.0, 0.0))
    )
    flange_doc = _table(doc.get("flange", {}), source, "[flange] ", "flange")
    flange = (
        _get(flange_doc, "a", source, float, "flange: ", 0.0) * L,
        _get(flange_doc, "alpha", source, float, "flange: ", 0.0) * A,
    )
    ft = tuple(
        c * L for c in _get(flange_doc, "translation", source, "vec3", "flange: ", (0.0, 0.0, 0.0))
    )
    fr = tuple(
        c * A
        for c in _get(flange_doc, "rotation_vector", source, "vec3", "flange: ", (0.0, 0.0, 0.0))
    )
    effects_doc = doc.get("effects", {})
    if not isinstance(effects_doc, dict):
        raise DescriptionError(f"{source}: [effects] must be a table of effect tables")
    effects = {}
    for name, vals in effects_doc.items():
        if not isinstance(vals, dict):
            raise DescriptionError(
                f"{source}: [effects.{name}] must be a table of parameter values"
            )
        effects[name] = {k: _get(vals, k, source, float, f"effects.{name}: ") for k in vals}
    stations = _stations(doc, source, L, A)
    mount = _table(doc.get("mount", {}), source, "[mount] ", "mount")
    mt = vec3(c * L for c in _get(mount, "translation", source, "vec3", "mount: ", (0.0, 0.0, 0.0)))
    mr = vec3(
        c * A for c in _get(mount, "rotation_vector", source, "vec3", "mount: ", (0.0, 0.0, 0.0))
    )
    domain = _domain(doc.get("domain", {}), source)
    uncertainty = doc.get("uncertainty", {})
    if not isinstance(uncertainty, dict):
        raise DescriptionError(f"{source}: [uncertainty] must be a table")
    try:
        return RobotDescription(
            name=_get(doc, "name", source, str, "", Path(source).stem),
            joints=tuple(joints),
            tools=tools,
            convention=conv,
            payload=_get(doc, "payload", source, float, "", 0.0),
            gravity=_get(doc, "gravity", source, "vec3", "", (0.0, 0.0, -9.81)),
            base_translation=bt,
            base_rotation=br,
            effects=effects,
            flange=flange,
            flange_translation=ft,
            flange_rotation=fr,
            stations=stations,
            nominal=nominal,
            domain=domain,
            couplings=_couplings(doc, source),
            uncertainty=uncertainty,
            extra_joints=_extra_joints(doc, source, L, A),
            mount_translation=mt,
            mount_rotation=mr,
            source="" if source.startswith("<") else source,
        )
    except DescriptionError as exc:
        raise DescriptionError(f"{source}: {exc}") from None


def as_robot(robot: RobotDescription | str | Path | None) -> RobotDescription:
    """``robot`` itself if it is a description, else :func:`load_robot` of it."""
    return robot if isinstance(robot, RobotDescription) else load_robot(robot)


def from_urdf(arm: UrdfArm) -> RobotDescription:
    """The description of a URDF's arm (:func:`arm.urdf.read_urdf`): modified DH with Hayati's
    beta, the URDF's base link <- frame 0 as the base transform, frame 6 <- tip link as the flange,
    one tool point at the tip link's origin, masses and centres of mass from the inertials."""
    clean = lambda v: float(v) + 0.0  # noqa: E731 -- no -0.0 in files written from it
    joints = tuple(
        Joint(
            alpha=clean(arm.alpha[i]),
            a=clean(arm.a[i]),
            d=clean(arm.d[i]),
            theta_offset=clean(arm.theta_offset[i]),
            lower=float(arm.lower[i]),
            upper=float(arm.upper[i]),
            mass=float(arm.masses[i]),
            com=vec3(clean(c) for c in arm.coms[i]),
            beta=clean(arm.beta[i]),
        )
        for i in range(6)
    )
    flange = arm.flange
    placed: dict[str, Any] = {
        "base_translation": vec3(clean(c) for c in arm.base[:3, 3]),
        "base_rotation": vec3(clean(c) for c in rotation_vector(arm.base[:3, :3])),
    } | _urdf_extras(arm)
    try:
        return RobotDescription(
            name=arm.name,
            joints=joints,
            tools=(vec3(clean(c) for c in flange[:3, 3]),),
            gravity=vec3(clean(c) for c in arm.gravity),
            flange_translation=vec3(clean(c) for c in flange[:3, 3]),
            flange_rotation=vec3(clean(c) for c in rotation_vector(flange[:3, :3])),
            urdf=arm.source,
            couplings=arm.couplings,
            source=arm.source.path,
            **placed,
        )
    except DescriptionError as exc:
        raise DescriptionError(f"{arm.source.path}: {exc}") from None


def _urdf_extras(arm: UrdfArm) -> dict[str, Any]:
    """A URDF's extra joints (:attr:`arm.urdf.UrdfArm.extra`) as a description's fields: the
    joints, the arm's frame 0 in the last one's frame as the mount (the base then the identity:
    the URDF's base link is the measurement frame's robot end)."""
    if not arm.extra:
        return {}
    clean = lambda v: float(v) + 0.0  # noqa: E731
    joints = tuple(
        ExtraJoint(
            name=name,
            kind="prismatic" if kind == "prismatic" else "revolute",
            axis=vec3(clean(c) for c in axis),
            translation=vec3(clean(c) for c in origin[:3, 3]),
            rotation=vec3(clean(c) for c in rotation_vector(origin[:3, :3])),
            default=arm.extra_defaults.get(name),
        )
        for name, kind, axis, origin in arm.extra
    )
    return {
        "extra_joints": joints,
        "mount_translation": vec3(clean(c) for c in arm.base[:3, 3]),
        "mount_rotation": vec3(clean(c) for c in rotation_vector(arm.base[:3, :3])),
        "base_translation": (0.0, 0.0, 0.0),
        "base_rotation": (0.0, 0.0, 0.0),
    }


def load_robot(
    name_or_path: str | Path | None = None, *, tip: str | None = None, base: str | None = None
) -> RobotDescription:
    """A shipped robot by name (``"seed"``, ``"ur5"``; the URDFs ``"ur3_robot"``, ``"ur5_robot"``,
    ``"ur10_robot"``, ``"z1"``), a robot TOML file or a URDF file by path; ``None`` gives the seed
    arm. A bare ``"ur5_robot.urdf"`` that is no file here is the shipped one.

    A URDF (a ``.urdf`` file) gives the serial chain of six revolute joints from link ``base``
    (default the root) to link ``tip`` (default: found when one such chain hangs below the base),
    converted exactly by :func:`arm.urdf.read_urdf`. ``tip`` and ``base`` are refused for a TOML.
    In a string they may follow the file after ``#``, as on the command line:
    ``"ur5_robot.urdf#tip=tool0,base=base"`` (``--robot 'ur5_robot.urdf#tip=tool0'``).
    """
    if name_or_path is None:
        name_or_path = "seed"
    if isinstance(name_or_path, str) and "#" in name_or_path and not os.path.lexists(name_or_path):
        name_or_path, tip, base = _chain_spec(name_or_path, tip, base)
    p = Path(name_or_path)
    shipped = resources.files("arm") / "robots"
    if p.suffix.lower() != ".urdf" and not os.path.lexists(p) and is_file(shipped / f"{p}.urdf"):
        p = Path(f"{p}.urdf")  # a shipped URDF by name: "ur5_robot", "z1"
    if p.suffix.lower() == ".urdf":
        if not os.path.lexists(p) and p.name == str(p) and is_file(shipped / p.name):
            text, where = (shipped / p.name).read_text(encoding="utf-8"), f"robots/{p.name}"
        else:
            text, where = read_input_text(p, "URDF file", "urdf", DescriptionError), str(p)
        try:
            return from_urdf(read_urdf(where, tip=tip, base=base, text=text))
        except UrdfError as exc:
            raise DescriptionError(str(exc)) from None
    if tip is not None or base is not None:
        raise DescriptionError(
            f"{p}: a tip or base link is chosen in a URDF; this is a robot TOML or a shipped name"
        )
    if p.suffix == ".toml" or os.path.lexists(p):
        text = read_input_text(p, "robot description", "toml", DescriptionError)
        return RobotDescription.from_toml(text, source=str(p))
    toml = shipped / f"{name_or_path}.toml"
    if not is_file(toml):
        names = sorted(f.name.rsplit(".", 1)[0] for f in shipped.iterdir() if "." in f.name[1:])
        raise DescriptionError(
            f"unknown robot {shown(str(name_or_path))!r}: not a file nor a shipped name "
            f"({', '.join(n for n in names if not n.startswith('LICENSE') and n != 'README')})"
        )
    return RobotDescription.from_toml(toml.read_text(), source=f"robots/{name_or_path}.toml")


def _chain_spec(spec: str, tip: str | None, base: str | None) -> tuple[str, str | None, str | None]:
    """``"arm.urdf#tip=tool0,base=base"`` -> (``"arm.urdf"``, ``"tool0"``, ``"base"``)."""
    path, _, fragment = spec.partition("#")
    chosen: dict[str, str] = {}
    for item in filter(None, (f.strip() for f in fragment.replace("&", ",").split(","))):
        key, eq, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not eq or key not in ("tip", "base") or not value:
            raise DescriptionError(
                f"{spec}: after '#' give tip=LINK and/or base=LINK (e.g. {path}#tip=tool0), "
                f"got {item!r}"
            )
        if key in chosen:
            raise DescriptionError(f"{spec}: {key} given twice")
        chosen[key] = value
    for key, given in (("tip", tip), ("base", base)):
        if given is not None and key in chosen and chosen[key] != given:
            raise DescriptionError(f"{spec}: {key}={chosen[key]!r} there, {key}={given!r} given")
    return path, chosen.get("tip", tip), chosen.get("base", base)


def seed_robot() -> RobotDescription:
    """The seed arm (docs/format.md, the seed arm)."""
    return load_robot("seed")
