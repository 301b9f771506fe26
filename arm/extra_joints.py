"""Extra joints before the arm's base: a prismatic lifting column, a linear track, a rotary table.

A robot as industry gives it often stands on an axis of its own. Such a joint is not one of the
arm's six: it is held at a value per row (a measurement column named after the joint, a value
given on the command line, or the robot file's default) and places the arm's base:

    measurement frame <- [base] <- E_1(v_1) <- ... <- E_k(v_k) <- [mount] <- arm frame 0

with ``E_j(v) = origin_j . motion_j(v)``: ``origin_j`` fixed (the joint's frame at value 0 in
the previous one), ``motion_j`` a translation ``v axis_j`` (prismatic) or a rotation by ``v``
about ``axis_j`` through the joint frame's origin (revolute); ``mount`` the arm's frame 0 in the
last extra joint's frame. SI inside (m, rad); every function is batched over rows (N,).

A calibration may correct them (the ``extra_joints`` effect, :mod:`arm.effects.extra`): each
joint's **scale** ``s`` (the value moved is ``v (1 + s)``: a column's encoder or screw pitch off by
a proportion) and, for a prismatic joint, its **tilt** ``(t1, t2)``, a small rotation of its axis
about the two directions :func:`normals` of it (a column that is not straight with the base's
frame, or leans).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from arm.errors import DescriptionError, ModelError
from arm.so3 import left_jacobian, rotation_matrix, skew

__all__ = [
    "ExtraJoint",
    "ExtraPlacement",
    "extra_values",
    "missing_value",
    "normals",
    "parse_joint_values",
    "place",
]

Vec3 = tuple[float, float, float]
ExtraKind = Literal["prismatic", "revolute"]


@dataclass(frozen=True)
class ExtraJoint:
    """One extra joint before the arm's base (SI): ``axis`` a unit vector in its own frame,
    ``translation``/``rotation`` its origin (the joint's frame at value 0 in the previous one, a
    rotation vector), ``default`` the value a row without one holds (None: none), ``unit`` the SI
    size of one unit of a measurement column named after it (the robot file's length or angle
    unit: 0.001 for a column in mm)."""

    name: str
    kind: ExtraKind
    axis: Vec3 = (0.0, 0.0, 1.0)
    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)
    default: float | None = None
    unit: float = 1.0

    def __post_init__(self) -> None:
        where = f"extra joint {self.name!r}"
        if self.kind not in ("prismatic", "revolute"):
            raise DescriptionError(f"{where}: type {self.kind!r} is not 'prismatic' or 'revolute'")
        n = math.sqrt(sum(c * c for c in self.axis))
        if not (math.isfinite(n) and n > 1e-9):
            raise DescriptionError(f"{where}: axis {self.axis} is zero or not finite")
        if abs(n - 1.0) > 1e-12:
            object.__setattr__(self, "axis", tuple(float(c) / n for c in self.axis))
        if self.default is not None and not math.isfinite(self.default):
            raise DescriptionError(f"{where}: default {self.default!r} is not finite")

    @property
    def origin(self) -> np.ndarray:
        """4x4: the previous frame <- this joint's frame at value 0."""
        T = np.eye(4)
        T[:3, :3] = rotation_matrix(np.array(self.rotation))
        T[:3, 3] = self.translation
        return T


def normals(axis: np.ndarray) -> np.ndarray:
    """Two unit vectors (2, 3) normal to ``axis`` and to each other, the directions about which a
    prismatic joint's tilt turns its axis: for a vertical axis, x then y."""
    a = np.asarray(axis, dtype=float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = helper - a * (helper @ a)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(a, u)])


def extra_values(
    joints: Sequence[ExtraJoint],
    columns: Mapping[str, np.ndarray],
    n: int,
    source: str,
    robot_file: str = "",
) -> np.ndarray:
    """Each row's value of each extra joint (N, k), SI: the column named after the joint (in the
    joint's ``unit``), else its default; a joint with neither is an error naming it, the data,
    the robot file (``robot_file``: a ``.urdf`` path says how a URDF declares a default) and the
    three ways to give it."""
    out = np.empty((n, len(joints)))
    for k, j in enumerate(joints):
        if j.name in columns:
            v = np.asarray(columns[j.name], dtype=float).reshape(-1)
            bad = np.flatnonzero(~np.isfinite(v))
            if bad.size:
                raise ModelError(
                    f"{source}: column {j.name!r} (extra joint {j.name!r}), row {bad[0] + 1}: "
                    "not a finite value"
                )
            out[:, k] = v * j.unit
        elif j.default is not None:
            out[:, k] = j.default
        else:
            raise ModelError(f"{source}: {missing_value(j, robot_file)}")
    return out


def missing_value(joint: ExtraJoint, robot_file: str = "") -> str:
    """What a row without a value of ``joint`` is told: the three ways to give one, in the robot
    file's own form (a URDF's ``<extra_joint>`` element, or a robot TOML's ``default``)."""
    name, unit = joint.name, "m" if joint.kind == "prismatic" else "rad"
    if robot_file.lower().endswith(".urdf"):
        declare = f'<extra_joint joint="{name}" default="VALUE"/> under <robot> (in {unit})'
    else:
        declare = "default = VALUE under its [[extra_joints]] (in the file's units)"
    return (
        f"no value for extra joint {name!r} ({joint.kind}) of {robot_file or 'the robot'}, "
        f"which states no default: give the data a column {name!r}, --joint-value {name}=VALUE "
        f"for every row, or a default in the robot file: {declare}"
    )


def parse_joint_values(specs: Sequence[str]) -> dict[str, float]:
    """``["column=0.35", ...]`` (``--joint-value``, repeatable) as ``{"column": 0.35}``, in the
    robot file's units; a malformed one, a value not finite or a joint given twice refused."""
    out: dict[str, float] = {}
    for spec in specs:
        name, eq, value = (part.strip() for part in spec.partition("="))
        try:
            v = float(value) if eq and name else math.nan
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise DescriptionError(
                f"--joint-value {spec!r}: give NAME=VALUE, an extra joint's name and a finite "
                "number in the robot file's units (column=0.35)"
            )
        if name in out:
            raise DescriptionError(f"--joint-value: joint {name!r} given twice")
        out[name] = v
    return out


@dataclass(frozen=True)
class ExtraPlacement:
    """The arm's frame 0 in the frame before the extra joints, per row: ``R`` (N, 3, 3), ``t``
    (N, 3); and for each joint j its frame after the origin, before its motion: ``joint_R``
    (k, N, 3, 3), ``joint_t`` (k, N, 3), the axis as moved there, ``axis`` (k, 3) (tilt
    included), and the value moved, ``moved`` (N, k) (scale included)."""

    R: np.ndarray
    t: np.ndarray
    joint_R: np.ndarray
    joint_t: np.ndarray
    axis: np.ndarray
    moved: np.ndarray


def tilted_axis(joint: ExtraJoint, tilt: np.ndarray) -> np.ndarray:
    """The joint's axis turned by ``tilt`` (2,) about its :func:`normals`."""
    a = np.array(joint.axis)
    return rotation_matrix(np.asarray(tilt, dtype=float) @ normals(a)) @ a


def tilt_axis_jacobian(joint: ExtraJoint, tilt: np.ndarray) -> np.ndarray:
    """d (tilted axis) / d tilt, (3, 2): ``-[R a]x J_l(r) [u1 u2]`` at ``r = tilt . normals``."""
    a = np.array(joint.axis)
    U = normals(a)
    r = np.asarray(tilt, dtype=float) @ U
    return -skew(rotation_matrix(r) @ a) @ left_jacobian(r) @ U.T


def place(
    joints: Sequence[ExtraJoint],
    mount: np.ndarray,
    values: np.ndarray,
    scale: np.ndarray | None = None,
    tilt: np.ndarray | None = None,
) -> ExtraPlacement:
    """The arm's frame 0 at each row's values (N, k), through the joints and ``mount`` (4x4);
    ``scale`` (k,) and ``tilt`` (k, 2) the calibration's corrections (zero: none)."""
    values = np.atleast_2d(np.asarray(values, dtype=float))
    n, k = values.shape
    scale = np.zeros(k) if scale is None else np.asarray(scale, dtype=float)
    tilt = np.zeros((k, 2)) if tilt is None else np.asarray(tilt, dtype=float)
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    t = np.zeros((n, 3))
    joint_R = np.empty((k, n, 3, 3))
    joint_t = np.empty((k, n, 3))
    axes = np.empty((k, 3))
    moved = values * (1.0 + scale)
    for j, joint in enumerate(joints):
        O = joint.origin
        t = t + R @ O[:3, 3]
        R = R @ O[:3, :3]
        joint_R[j], joint_t[j] = R, t
        a = tilted_axis(joint, tilt[j]) if joint.kind == "prismatic" else np.array(joint.axis)
        axes[j] = a
        if joint.kind == "prismatic":
            t = t + (R @ a) * moved[:, j, None]
        else:
            R = R @ rotation_matrix(a[None, :] * moved[:, j, None])
    t = t + R @ mount[:3, 3]
    R = R @ mount[:3, :3]
    return ExtraPlacement(R, t, joint_R, joint_t, axes, moved)
