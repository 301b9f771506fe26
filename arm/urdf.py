"""URDF in and out: the serial chain of six revolute joints of a URDF, converted exactly to the
lab's modified-DH model, and a calibrated model written back into the same URDF.

**In.** :func:`read_urdf` reads the file with yourdfpy (a strict XML parse first, so a broken file
is refused with its line instead of being "recovered"), finds the chain from the base link to the
tip link (the tip named, or found when exactly one link ends a chain of six revolute joints after
any extra joints: where a seventh revolute joint allows two readings, the arm is the one whose
joints 1 and 2 are not parallel: on ``z1.urdf`` the gripper's joint is a seventh and not part of
the arm, on a rotary table the table's is; ``<extra_joint joint default/>`` under ``<robot>``
declares a joint before the arm and its default) and converts the joint placements at q = 0 into

* modified DH rows ``RotX(alpha_{i-1}) RotY(beta_{i-1}) TransX(a_{i-1}) RotZ(theta_i) TransZ(d_i)``
  with ``theta_i = q_i + theta_offset_i``: the x axis of frame i is the common normal of joint
  axes i and i+1, and where the two are parallel (within :data:`PARALLEL_TOL`) Hayati's ``beta``
  takes the tilt (zero on a nominal arm), the origin staying where the previous row arrives
  (``d_i = 0``);
* a fixed **base** transform (base link <- frame 0): frame 0's z is joint 1's axis, through the
  point of that axis nearest the base link's origin (the identity when joint 1 turns about the
  base link's z through its origin, as on the UR arms and the Z1);
* a fixed **flange** transform (frame 6 <- tip link): frame 6's origin is the foot of the tip
  link's origin on joint 6's axis and ``theta_offset_6 = 0``;
* the masses and centres of mass of the links each joint moves (links fixed to them, and links
  beyond the arm such as a gripper at its zero position, included), in the DH frames; gravity
  -9.81 m/s² along the root link's -z.

The x axes are signed so that every ``theta_offset`` lies in (-90°, 90°]: UR's own DH table comes
out of ``ur5_robot.urdf`` read from its ``base`` link to ``tool0``.

**Out.** :func:`calibrated_urdf` takes a calibrated chain (rows and base) and rewrites, in the
original text, the ``<origin xyz rpy>`` of the six arm joints only: each link keeps its pose
relative to its DH frame (so its inertial, visuals and collisions, and every fixed joint hanging
off it, move with it), and nothing else in the file changes.

This module imports neither the description nor the kinematics (``arm.description`` builds a
:class:`~arm.description.RobotDescription` from a :class:`UrdfArm`), and no simulator.
"""

from __future__ import annotations

import io
import logging
import math
import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arm.errors import UrdfError
from arm.so3 import rot_x, rot_y, rot_z, rotation_matrix

__all__ = [
    "PARALLEL_TOL",
    "UrdfArm",
    "UrdfError",
    "UrdfSource",
    "calibrated_urdf",
    "joint_origins",
    "mdh_frames",
    "read_urdf",
    "rpy_matrix",
    "rpy_of",
    "urdf_of_chain",
]

log = logging.getLogger(__name__)

# rad: consecutive joint axes closer than this to parallel take Hayati's beta (a common normal
# of axes 0.05 rad apart may lie metres away; Hayati's row stays well conditioned)
PARALLEL_TOL = 0.05
GRAVITY = (0.0, 0.0, -9.81)  # m/s², in the root link's frame
ARM_JOINTS = ("revolute", "continuous")
EXTRA_JOINTS = ("prismatic", "revolute", "continuous")  # before the arm: a column, a table


@dataclass(frozen=True)
class UrdfSource:
    """Where a description read from a URDF came from: the file's text and the chain chosen in it
    (what :func:`calibrated_urdf` needs to write a calibrated copy)."""

    text: str
    path: str
    base_link: str
    tip_link: str


@dataclass(frozen=True)
class UrdfArm:
    """A URDF's arm as modified-DH arrays (m, rad, kg; every (6,) array row by row).

    ``base`` (4x4): base link <- frame 0; ``flange`` (4x4): frame 6 <- tip link; ``link_offsets``
    (6, 4, 4): frame i <- the child link of arm joint i (fixed at any q); ``origins`` (6, 4, 4): the
    arm joints' own ``<origin>``; ``gravity``: in frame 0, or with extra joints in the frame they
    start from (the base link's).
    """

    name: str
    source: UrdfSource
    joint_names: tuple[str, ...]
    alpha: np.ndarray
    a: np.ndarray
    beta: np.ndarray
    d: np.ndarray
    theta_offset: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    masses: np.ndarray
    coms: np.ndarray
    base: np.ndarray
    flange: np.ndarray
    link_offsets: np.ndarray
    origins: np.ndarray
    gravity: np.ndarray
    # <coupling joint="joint3" on="joint2" factor="-1"/> under <robot>: (joint, on, factor) by
    # the arm's joint numbers 1..6, theta_joint = q_joint + factor q_on
    couplings: tuple[tuple[int, int, float], ...] = ()
    # joints before the arm's base (a lifting column, a track, a rotary table; arm.extra_joints):
    # (name, "prismatic" | "revolute", unit axis in its frame, origin 4x4 in the previous
    # extra joint's frame, the first's in the base link's); ``base`` is then the last one's
    # frame <- frame 0 (the description's mount), the base link its frame at value 0
    extra: tuple[tuple[str, str, np.ndarray, np.ndarray], ...] = ()
    # <extra_joint joint="column" default="0.35"/> under <robot>: the value (m or rad) a row
    # without its own holds, by the extra joint's name (a joint so declared is never the arm's)
    extra_defaults: dict[str, float] = field(default_factory=dict)


# -- small transforms -------------------------------------------------------------------------------
def _h(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    R = T[:3, :3].T
    return _h(R, -R @ T[:3, 3])


def rpy_matrix(rpy) -> np.ndarray:
    """URDF's fixed-axis roll-pitch-yaw: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (float(v) for v in rpy)
    return rot_z(y) @ rot_y(p) @ rot_x(r)


def rpy_of(R: np.ndarray) -> np.ndarray:
    """The URDF roll-pitch-yaw (3,) of a rotation matrix (scipy's extrinsic xyz Euler angles,
    accurate at pitch ±90° too, where the split between roll and yaw is arbitrary)."""
    from scipy.spatial.transform import Rotation

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "gimbal lock detected": still exact
        return Rotation.from_matrix(R).as_euler("xyz")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _z_to(v: np.ndarray) -> np.ndarray:
    """The smallest rotation taking +z to the unit vector ``v`` (pi about x for -z)."""
    c = np.cross((0.0, 0.0, 1.0), v)
    s = np.linalg.norm(c)
    if s < 1e-15:
        return np.eye(3) if v[2] > 0 else rot_x(math.pi)
    return rotation_matrix(c / s * math.atan2(s, v[2]))


def _angle_about(u: np.ndarray, v: np.ndarray, axis: np.ndarray) -> float:
    """The angle about ``axis`` from ``u`` to ``v`` (both perpendicular to it)."""
    return math.atan2(float(np.cross(u, v) @ axis), float(u @ v))


def mdh_frames(
    alpha: np.ndarray,
    a: np.ndarray,
    beta: np.ndarray,
    d: np.ndarray,
    theta: np.ndarray,
    base: np.ndarray | None = None,
) -> np.ndarray:
    """Frames 0..6 (7, 4, 4) of one pose of a modified-DH chain (``theta`` the full joint angles),
    frame 0 at ``base`` (default the identity): the chain of :mod:`arm.kinematics`, written as 4x4
    products for the URDF conversion's own check and its writer."""
    F = [np.eye(4) if base is None else np.asarray(base, dtype=float)]
    for i in range(6):
        Q = rot_x(alpha[i]) @ rot_y(beta[i])
        row = _h(Q, Q @ np.array([a[i], 0.0, 0.0]))
        F.append(F[-1] @ row @ _h(rot_z(theta[i]), np.array([0.0, 0.0, d[i]])))
    return np.array(F)


# -- reading ---------------------------------------------------------------------------------------
def _parse(text: str, source: str):
    """The yourdfpy model of a URDF text, after a strict XML parse (yourdfpy alone would recover
    a broken file silently)."""
    from lxml import etree

    try:
        etree.fromstring(text.encode("utf-8"), parser=etree.XMLParser(resolve_entities=False))
    except etree.XMLSyntaxError as exc:
        raise UrdfError(f"{source}: not well-formed XML: {exc}") from None
    import yourdfpy

    try:
        model = yourdfpy.URDF.load(
            io.BytesIO(text.encode("utf-8")),
            build_scene_graph=False,
            build_collision_scene_graph=False,
            load_meshes=False,
            load_collision_meshes=False,
        )
    except Exception as exc:  # yourdfpy raises whatever its parser met: name the file
        raise UrdfError(f"{source}: not a URDF that yourdfpy can read ({exc!r})") from None
    return model.robot


def _origin(joint, source: str) -> np.ndarray:
    T = np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)
    if not np.all(np.isfinite(T)):
        raise UrdfError(f"{source}: joint {joint.name!r}: <origin> is not finite")
    return T


def _tree(robot, source: str):
    """(links, parent joint of each child link, child joints of each link, the root)."""
    links = {lk.name: lk for lk in robot.links}
    up: dict[str, Any] = {}
    down: dict[str, list] = {name: [] for name in links}
    for j in robot.joints:
        for end in (j.parent, j.child):
            if end not in links:
                raise UrdfError(
                    f"{source}: joint {j.name!r} names link {end!r}, which is not defined"
                )
        if j.child in up:
            raise UrdfError(
                f"{source}: link {j.child!r} is the child of two joints ({up[j.child].name!r}, "
                f"{j.name!r}): not a tree"
            )
        up[j.child] = j
        down[j.parent].append(j)
    roots = [name for name in links if name not in up]
    if len(roots) != 1:
        raise UrdfError(f"{source}: a URDF has one root link, found {roots or 'none (a loop)'}")
    return links, up, down, roots[0]


def _ancestors(link: str, up: dict) -> list:
    """The joints from the root down to ``link``."""
    path = []
    while link in up:
        path.append(up[link])
        link = up[link].parent
    return path[::-1]


def _arm_joints(path: list) -> list:
    return [j for j in path if j.type != "fixed"]


def _declared_extra(text: str, src: str) -> dict[str, float | None]:
    """The ``<extra_joint joint="NAME" default="VALUE"/>`` elements under ``<robot>`` (an
    extension of this project, as ``<coupling>``): joints declared to stand before the arm, each
    with the value (m or rad) a row without its own holds, or None."""
    from lxml import etree

    root = etree.fromstring(text.encode("utf-8"), parser=etree.XMLParser(resolve_entities=False))
    out: dict[str, float | None] = {}
    for el in root.findall("extra_joint"):
        name, default = el.get("joint"), el.get("default")
        where = f"{src}: <extra_joint joint={name!r}>"
        if not name:
            raise UrdfError(f'{src}: <extra_joint> without joint="NAME"')
        if name in out:
            raise UrdfError(f"{where}: declared twice")
        value = None
        if default is not None:
            try:
                value = float(default)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise UrdfError(f"{where}: default {default!r} is not a finite number (m or rad)")
        out[name] = value
    return out


def _reads_as_arm(path: list, declared: Mapping[str, Any]) -> bool:
    """Whether the moving joints of ``path`` (from the base to a link) read as extra joints then
    an arm of six ending at the link: not where there are fewer than six, the path ends on no
    revolute joint, an arm joint is not revolute, mimics or is declared extra, or a joint before
    the arm is no extra joint's kind or mimics another."""
    moving = _arm_joints(path)
    if len(moving) < 6 or not path or path[-1].type not in ARM_JOINTS:
        return False
    extra, arm = moving[:-6], moving[-6:]
    if any(j.type not in ARM_JOINTS or j.mimic is not None or j.name in declared for j in arm):
        return False
    return all(j.type in EXTRA_JOINTS and j.mimic is None for j in extra)


def _first_axes_parallel(path: list, src: str) -> bool:
    """Whether the axes of the arm's joints 1 and 2 on ``path`` (its last six moving joints) are
    parallel (within :data:`PARALLEL_TOL`): no 6R arm's are, a rotary table's and the arm's joint
    1 are (consecutive axes keep their angle at every value of the joints)."""
    R = np.eye(3)
    axes = []
    first_two = {id(j) for j in _arm_joints(path)[-6:-4]}
    for j in path:
        R = R @ _origin(j, src)[:3, :3]
        if id(j) in first_two:
            axes.append(R @ _axis(j, src))
    return float(np.linalg.norm(np.cross(axes[0], axes[1]))) < math.sin(PARALLEL_TOL)


def _find_tip(
    links: dict, up: dict, anchor: str, src: str, base: str, declared: Mapping[str, Any]
) -> str:
    """The one link that ends a chain of six revolute joints below ``anchor``, after any extra
    joints (prismatic or revolute: a column, a track, a rotary table). Where a seventh revolute
    joint makes two readings (a table under the arm, or a gripper's joint after it), the one
    whose first two arm axes are not parallel is the arm; the joints declared ``<extra_joint>``
    are never the arm's."""
    found = []
    for name in links:
        path = _ancestors(name, up)
        names = [j.parent for j in path]
        if anchor not in names:
            continue
        below = path[names.index(anchor) :]
        if _reads_as_arm(below, declared):
            found.append((name, below))
    if len(found) > 1:  # a seventh revolute joint: the reading whose joints 1 and 2 cross
        crossing = [(n, b) for n, b in found if not _first_axes_parallel(b, src)]
        found = crossing or found
    if len(found) == 1:
        return found[0][0]
    if not found:
        longest = max(
            (len(_arm_joints(_ancestors(n, up))) for n in links), default=0
        )  # a hint only
        raise UrdfError(
            f"{src}: no chain of 6 revolute joints below base link {base!r} (the longest chain "
            f"has {longest} moving joints); name the tip link (tip=..., --tip)"
        )
    raise UrdfError(
        f"{src}: several chains of 6 revolute joints below base link {base!r}, ending at "
        f"{', '.join(sorted(n for n, _ in found))}: name the tip link (tip=..., --tip), or "
        'declare a joint before the arm (a rotary table) with <extra_joint joint="NAME"/> '
        "under <robot>"
    )


def read_urdf(
    source: str | Path,
    tip: str | None = None,
    base: str | None = None,
    text: str | None = None,
) -> UrdfArm:
    """The arm of a URDF file (or of ``text``, named ``source`` in messages) from link ``base``
    (default the root link) to link ``tip`` (default: found when one chain of six revolute joints
    hangs below the base). See the module docstring for the frames chosen."""
    src = str(source)
    if text is None:
        text = _read_text(source)
    robot = _parse(text, src)
    links, up, down, root = _tree(robot, src)
    base = root if base is None else base
    declared = _declared_extra(text, src)
    anchor, tip, joints = _arm_chain(links, up, base, tip, src, declared)
    extra, joints = joints[:-6], joints[-6:]

    # every link's pose at q = 0 relative to the anchor, the arm's subtree included
    pose = {anchor: np.eye(4)}
    stack = [anchor]
    while stack:
        parent = stack.pop()
        for j in down[parent]:
            pose[j.child] = pose[parent] @ _origin(j, src)
            stack.append(j.child)
    extras = _extras(extra, pose, base, src)
    chain_base = base  # what a re-reading starts from (the extra joints found again)
    if extra:  # the arm's frames in its own base link's: the last extra joint's child
        base = extra[-1].child
    to_base = _inv(pose[base])
    world = {name: to_base @ T for name, T in pose.items()}  # in the base link's frame
    lines = []
    for j in joints:
        J = world[j.child]
        lines.append((J[:3, 3].copy(), J[:3, :3] @ _axis(j, src)))
    F = _dh_frames(lines, world[tip])
    rows = _rows(F)
    check = mdh_frames(*rows, base=F[0])
    err = float(np.max(np.abs(check - F)))
    if not err < 1e-9:  # the construction is exact; this guards the code, not the file
        raise UrdfError(f"{src}: internal error converting the chain ({err:.2g} m)")
    lower, upper = _limits(joints, src)
    masses, coms = _mass_model(joints, links, down, world, F, src)
    # gravity in frame 0 (the root's -z); with extra joints, in the frame they start from (the
    # chain's base link), frame 0 turning with them per row (RobotDescription.frame0_gravity)
    R_gravity = pose[chain_base][:3, :3] if extra else pose[base][:3, :3] @ F[0][:3, :3]
    offsets = np.array([_inv(F[i + 1]) @ world[j.child] for i, j in enumerate(joints)])
    arm = UrdfArm(
        name=robot.name or Path(src).stem,
        source=UrdfSource(text=text, path=src, base_link=chain_base, tip_link=tip),
        joint_names=tuple(j.name for j in joints),
        alpha=rows[0],
        a=rows[1],
        beta=rows[2],
        d=rows[3],
        theta_offset=rows[4],
        lower=np.array(lower),
        upper=np.array(upper),
        masses=masses,
        coms=coms,
        base=F[0],
        flange=_inv(F[6]) @ world[tip],
        link_offsets=offsets,
        origins=np.array([_origin(j, src) for j in joints]),
        gravity=R_gravity.T @ np.array(GRAVITY),
        couplings=_couplings(text, [j.name for j in joints], src),
        extra=extras,
        extra_defaults={k: v for k, v in declared.items() if v is not None},
    )
    log.info(
        "%s: arm %r from %r to %r, joints %s", src, arm.name, base, tip, ", ".join(arm.joint_names)
    )
    return arm


def _axis(j, src: str) -> np.ndarray:
    """A joint's unit ``<axis xyz>`` (URDF's default x)."""
    axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), dtype=float)
    n = float(np.linalg.norm(axis))
    if not (math.isfinite(n) and n > 1e-9):
        raise UrdfError(f"{src}: joint {j.name!r}: <axis xyz> is zero or not finite")
    return axis / n


def _extras(extra: Sequence[Any], pose: dict, base: str, src: str) -> tuple:
    """The extra joints before the arm (:attr:`UrdfArm.extra`): each one's origin in the
    previous one's frame (the first's in the base link's), at every value zero."""
    out, prev = [], pose[base]
    for j in extra:
        kind = "prismatic" if j.type == "prismatic" else "revolute"
        out.append((j.name, kind, _axis(j, src), _inv(prev) @ pose[j.child]))
        prev = pose[j.child]
    return tuple(out)


def _couplings(text: str, names: Sequence[str], src: str) -> tuple[tuple[int, int, float], ...]:
    """The ``<coupling joint= on= factor=/>`` elements under ``<robot>`` (an extension of this
    project: URDF itself has no additive coupling of two actuated joints, and its readers skip
    an element they do not know), by the arm's joint numbers."""
    from lxml import etree

    root = etree.fromstring(text.encode("utf-8"), parser=etree.XMLParser(resolve_entities=False))
    out = []
    for el in root.findall("coupling"):
        joint, on, factor = (el.get(k) for k in ("joint", "on", "factor"))
        where = f"{src}: <coupling joint={joint!r} on={on!r}>"
        for jn in (joint, on):
            if jn not in names:
                raise UrdfError(
                    f"{where}: {jn!r} is not one of the arm's joints ({', '.join(names)})"
                )
        try:
            value = float(factor if factor is not None else "")
        except ValueError:
            raise UrdfError(f"{where}: factor {factor!r} is not a number") from None
        out.append((names.index(joint) + 1, names.index(on) + 1, value))
    return tuple(out)


def _read_text(source: str | Path) -> str:
    """A URDF file's text; a file that cannot be read is a one-line error."""
    src = str(source)
    try:
        return Path(source).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise UrdfError(f"{src}: URDF file not found") from None
    except UnicodeDecodeError as exc:
        raise UrdfError(f"{src}: not UTF-8 text ({exc.reason})") from None
    except OSError as exc:
        raise UrdfError(f"{src}: cannot be read ({exc.strerror})") from None


def _arm_chain(
    links: Any, up: Any, base: str, tip: str | None, src: str, declared: Mapping[str, Any]
) -> tuple[str, str, list[Any]]:
    """The chain from the base to the tip (found where not given): the link it starts at (the
    base, or the link it hangs off by fixed joints), the tip, and its moving joints (the extra
    joints, then the arm's six); a joint declared ``<extra_joint>`` must be one of the extra."""
    for what, name in (("base", base), ("tip", tip)):
        if name is not None and name not in links:
            raise UrdfError(
                f"{src}: no link {name!r} for the {what}; links: {', '.join(sorted(links))}"
            )
    # the base may hang off the chain's start by fixed joints (UR's `base` beside `base_link`)
    anchor = base
    while anchor in up and up[anchor].type == "fixed":
        anchor = up[anchor].parent
    if tip is None:
        tip = _find_tip(links, up, anchor, src, base, declared)
    path = _ancestors(tip, up)
    parents = [j.parent for j in path]
    if anchor not in parents:
        raise UrdfError(
            f"{src}: tip link {tip!r} does not hang below base link {base!r} through fixed and "
            "revolute joints only"
        )
    path = path[parents.index(anchor) :]
    moving = _arm_joints(path)
    extra, joints = moving[:-6], moving[-6:]
    for j in extra:
        if j.type not in EXTRA_JOINTS or j.mimic is not None:
            raise UrdfError(
                f"{src}: joint {j.name!r} before the arm's six is {j.type}"
                f"{' and mimics another' if j.mimic is not None else ''}: an extra joint before "
                "the arm is prismatic or revolute"
            )
    for j in joints:
        if j.type not in ARM_JOINTS:
            raise UrdfError(
                f"{src}: joint {j.name!r} between {base!r} and {tip!r} is {j.type}: the arm's "
                "joints must be revolute (or continuous)"
            )
        if j.mimic is not None:
            raise UrdfError(f"{src}: joint {j.name!r} mimics another joint: not an arm joint")
    if len(joints) != 6:
        raise UrdfError(
            f"{src}: {len(joints)} revolute joints between {base!r} and {tip!r} "
            f"({', '.join(j.name for j in joints) or 'none'}); the lab's arms have 6"
        )
    before = [j.name for j in extra]
    for name in declared:
        if name not in before:
            raise UrdfError(
                f"{src}: <extra_joint joint={name!r}> is not a joint before the arm's six "
                f"between {base!r} and {tip!r} (those are: {', '.join(before) or 'none'})"
            )
    return anchor, tip, [*extra, *joints]


def _limits(joints: Sequence[Any], src: str) -> tuple[list[float], list[float]]:
    """The joints' lower and upper limits (a continuous joint's: one turn)."""
    lower, upper = [], []
    for j in joints:
        lim = j.limit
        if j.type == "continuous":
            lower.append(-math.pi)
            upper.append(math.pi)
            continue
        lo = None if lim is None else lim.lower
        hi = None if lim is None else lim.upper
        if lo is None or hi is None or not float(lo) < float(hi):
            raise UrdfError(
                f"{src}: joint {j.name!r}: a revolute joint needs <limit lower=... upper=...> "
                f"with lower < upper, got lower={lo} upper={hi}"
            )
        lower.append(float(lo))
        upper.append(float(hi))
    return lower, upper


def _dh_frames(lines: list, tip: np.ndarray) -> list[np.ndarray]:
    """DH frames 0..6 (4x4, in the base link's frame) at q = 0 of six joint axes (point, unit
    direction), the last frame placed by the tip link's pose."""
    p = [ln[0] for ln in lines]
    z = [ln[1] for ln in lines]

    def foot(point, k):  # the point of axis k nearest ``point``
        return p[k] + ((point - p[k]) @ z[k]) * z[k]

    def parallel(k):  # axes k and k+1
        return float(np.linalg.norm(np.cross(z[k], z[k + 1]))) < math.sin(PARALLEL_TOL)

    def normal_feet(k):  # the common normal's feet on axes k and k+1 (not parallel)
        w = p[k] - p[k + 1]
        b = float(z[k] @ z[k + 1])
        dk, dk1 = float(z[k] @ w), float(z[k + 1] @ w)
        den = 1.0 - b * b
        s = (b * dk1 - dk) / den
        t = (dk1 - b * dk) / den
        return p[k] + s * z[k], p[k + 1] + t * z[k + 1]

    R0 = _z_to(z[0])
    o0 = foot(np.zeros(3), 0)
    F = [_h(R0, o0)]
    x_prev, h = R0[:, 0], o0  # x after the previous row's RotX RotY; where it reaches axis k
    for k in range(6):
        if k == 5:  # the last frame: theta_offset 0, origin at the tip's foot on the axis
            o, x = foot(tip[:3, 3], 5), x_prev
            F.append(_h(np.column_stack([x, np.cross(z[k], x), z[k]]), o))
            break
        if not parallel(k):
            o, target = normal_feet(k)
            n = np.cross(z[k], z[k + 1])
            x = _unit(n)
            if _theta_out_of_range(x_prev, x, z[k]):
                x = -x
            x_next, h_next = x, target
        else:
            o = h  # d_k = 0: the origin stays where the previous row arrives
            if k + 1 == 5:
                target = foot(tip[:3, 3], 5)
            elif not parallel(k + 1):
                target = normal_feet(k + 1)[0]
            else:
                target = foot(o, k + 1)
            v = target - o
            perp = v - (v @ z[k + 1]) * z[k + 1]
            if np.linalg.norm(perp) < 1e-12:  # coincident axes: keep the previous direction
                perp = x_prev - (x_prev @ z[k + 1]) * z[k + 1]
            xp = _unit(perp)
            # x _|_ z_k and RotX(alpha)'s y = z_{k+1} x xp; x along xp keeps beta small (alpha
            # near 180 deg for antiparallel axes)
            x = _unit(np.cross(np.cross(z[k + 1], xp), z[k]))
            if x @ xp < 0:
                x = -x
            if _theta_out_of_range(x_prev, x, z[k]):
                x, xp = -x, -xp
            x_next, h_next = xp, o + (perp @ xp) * xp
        F.append(_h(np.column_stack([x, np.cross(z[k], x), z[k]]), o))
        x_prev, h = x_next, h_next
    return F


def _theta_out_of_range(x_prev: np.ndarray, x: np.ndarray, z: np.ndarray) -> bool:
    """True when the angle about z from x_prev to x is outside (-90°, 90°] (flip x)."""
    c = float(x_prev @ x)
    if abs(c) > 1e-9:
        return c < 0
    return float(np.cross(x_prev, x) @ z) < 0


Rows = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _rows(F: list[np.ndarray]) -> Rows:
    """(alpha, a, beta, d, theta_offset) taking frame i-1 to frame i, i = 1..6."""
    out = np.zeros((5, 6))
    for i in range(6):
        A, B = F[i], F[i + 1]
        R = A[:3, :3].T @ B[:3, :3]  # = RotX(alpha) RotY(beta) RotZ(theta)
        t = A[:3, :3].T @ (B[:3, 3] - A[:3, 3])  # = RotX RotY (a, 0, 0) + R (0, 0, d)
        zb = R[:, 2]  # (sin b, -sin a cos b, cos a cos b)
        alpha = math.atan2(-zb[1], zb[2])
        beta = math.atan2(zb[0], math.hypot(zb[1], zb[2]))
        Q = rot_x(alpha) @ rot_y(beta)
        Rz = Q.T @ R
        theta = math.atan2(Rz[1, 0], Rz[0, 0])
        u = Q.T @ t  # (a, 0, 0) + RotZ(theta) (0, 0, d) = (a, 0, d)
        out[:, i] = (alpha, u[0], beta, u[2], theta)
    return out[0], out[1], out[2], out[3], out[4]


def _mass_model(joints, links, down, world, F, src):
    """The mass (6,) and centre of mass (6, 3) in frame i of everything joint i moves and joint
    i+1 does not (links beyond the arm, e.g. a gripper, at their zero position)."""
    masses, coms = np.zeros(6), np.zeros((6, 3))
    chain = {j.name for j in joints}
    for i, j in enumerate(joints):
        m, mc = 0.0, np.zeros(3)
        stack = [j.child]
        while stack:
            name = stack.pop()
            inertial = links[name].inertial
            if inertial is not None and inertial.mass:
                mass = float(inertial.mass)
                if not (math.isfinite(mass) and mass >= 0):
                    raise UrdfError(f"{src}: link {name!r}: mass {mass} is not a mass")
                origin = np.eye(4) if inertial.origin is None else np.asarray(inertial.origin)
                c = (world[name] @ origin)[:3, 3]
                m += mass
                mc += mass * c
            for child in down[name]:
                if child.name in chain:
                    continue
                if child.type != "fixed":
                    log.info(
                        "%s: joint %r is not part of the arm: its link %r counts at its zero "
                        "position in link %d's mass",
                        src,
                        child.name,
                        child.child,
                        i + 1,
                    )
                stack.append(child.child)
        masses[i] = m
        if m > 0:
            Fi = F[i + 1]
            coms[i] = Fi[:3, :3].T @ (mc / m - Fi[:3, 3])
    return masses, coms


# -- writing ---------------------------------------------------------------------------------------
def joint_origins(
    arm: UrdfArm,
    alpha: np.ndarray,
    a: np.ndarray,
    beta: np.ndarray,
    d: np.ndarray,
    theta_offset: np.ndarray,
) -> dict[str, np.ndarray]:
    """The ``<origin>`` (4x4, in its parent link) of each arm joint of ``arm``'s URDF that puts
    its links on the DH frames of the chain (alpha, a, beta, d, theta_offset) at q = 0, frame 0 at
    the URDF's own (``arm.base``). Each link keeps its pose in its DH frame; a joint's parent
    link is rigid with the previous arm joint's child (fixed joints between them unchanged), the
    first one's with the base."""
    nominal = mdh_frames(arm.alpha, arm.a, arm.beta, arm.d, arm.theta_offset, base=arm.base)
    F = mdh_frames(alpha, a, beta, d, theta_offset, base=arm.base)
    out = {}
    for i, name in enumerate(arm.joint_names):
        link_nom = nominal[i + 1] @ arm.link_offsets[i]
        link = F[i + 1] @ arm.link_offsets[i]
        parent = link_nom @ _inv(arm.origins[i])  # the parent link's nominal pose
        if i > 0:  # carried along by the previous arm link
            prev = arm.link_offsets[i - 1]
            parent = (F[i] @ prev) @ _inv(nominal[i] @ prev) @ parent
        out[name] = _inv(parent) @ link
    return out


_COMMENT = re.compile(r"<!--.*?-->|<!\[CDATA\[.*?\]\]>", re.S)


def _masked(text: str) -> str:
    """``text`` with comments and CDATA blanked (same length), so searches skip them."""
    return _COMMENT.sub(lambda m: " " * len(m.group(0)), text)


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _set_attr(tag: str, name: str, value: str) -> str:
    """The start tag ``tag`` with attribute ``name`` set to ``value`` (added before the end)."""
    m = re.search(rf"(\s{name}\s*=\s*)([\"'])(.*?)\2", tag, re.S)
    if m:
        return tag[: m.start(3)] + value + tag[m.end(3) :]
    end = len(tag) - (2 if tag.endswith("/>") else 1)
    return tag[:end].rstrip() + f' {name}="{value}"' + tag[end:]


def calibrated_urdf(arm: UrdfArm, origins: dict[str, np.ndarray]) -> str:
    """The URDF text of ``arm`` with the ``<origin>`` of each joint in ``origins`` (4x4) rewritten
    in place (xyz and rpy, every float to its last bit), all other text as it was."""
    text = arm.source.text
    masked = _masked(text)
    edits = []
    for name, T in origins.items():
        starts = [  # the robot's joint, not a <transmission>'s reference to it (no type)
            m
            for m in re.finditer(r"<joint\b[^>]*>", masked)
            if re.search(rf"\sname\s*=\s*([\"']){re.escape(name)}\1", m.group(0))
            and re.search(r"\stype\s*=", m.group(0))
        ]
        if len(starts) != 1:
            raise UrdfError(f"{arm.source.path}: joint {name!r} found {len(starts)} times")
        start = starts[0]
        close = masked.find("</joint>", start.end())
        if close < 0:
            raise UrdfError(f"{arm.source.path}: joint {name!r} has no </joint>")
        xyz, rpy = _fmt(T[:3, 3]), _fmt(rpy_of(T[:3, :3]))
        m = re.compile(r"<origin\b[^>]*>").search(masked, start.end(), close)
        if m:
            tag = text[m.start() : m.end()]
            new = _set_attr(_set_attr(tag, "xyz", xyz), "rpy", rpy)
            edits.append((m.start(), m.end(), new))
        else:  # no <origin>: the identity until now; add one as the joint's first child
            line_start = text.rfind("\n", 0, start.start()) + 1
            indent = re.match(r"[ \t]*", text[line_start:]).group(0)  # type: ignore[union-attr]
            new = f'\n{indent}  <origin xyz="{xyz}" rpy="{rpy}"/>'
            edits.append((start.end(), start.end(), new))
    for a, b, new in sorted(edits, reverse=True):
        text = text[:a] + new + text[b:]
    return text


def urdf_of_chain(
    name: str,
    alpha: np.ndarray,
    a: np.ndarray,
    beta: np.ndarray,
    d: np.ndarray,
    theta_offset: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    masses: np.ndarray,
    coms: np.ndarray,
    flange: np.ndarray | None = None,
    couplings: Sequence[tuple[int, int, float]] = (),
    extra_joints: Sequence[tuple[str, str, np.ndarray, np.ndarray]] = (),
    mount: np.ndarray | None = None,
    extra_defaults: Mapping[str, float] | None = None,
) -> str:
    """A URDF of a modified-DH chain: links ``base_link`` (frame 0), ``link1`` .. ``link6`` (the
    DH frames), ``flange`` (frame 6 . ``flange``, fixed), revolute joints ``joint1`` .. ``joint6``
    about their z with the rows as origins (``RotX(alpha) RotY(beta) TransX(a) RotZ(theta_offset)
    TransZ(d)``, every float to its last bit), the links' masses at their centres of mass (point
    masses: a DH table carries no inertia), and the joints' couplings as ``<coupling joint on
    factor/>`` elements. Extra joints before the arm (:attr:`UrdfArm.extra`) hang from a link
    ``root`` as joints of their own names and types, each moving a link ``NAME_link``, and the last
    carries ``base_link`` at ``mount`` (fixed); each is declared ``<extra_joint joint default/>``
    (its default from ``extra_defaults``, m or rad, where it has one). :func:`read_urdf` of it is
    the same chain (the same points: with extra joints its frame 0 may be placed otherwise along
    joint 1's axis)."""
    F = np.eye(4) if flange is None else np.asarray(flange, dtype=float)
    out = ['<?xml version="1.0" encoding="utf-8"?>', f'<robot name="{name}">']

    def link(lk: str, mass: float = 0.0, com=(0.0, 0.0, 0.0)) -> None:
        if mass > 0:
            out.append(
                f'  <link name="{lk}">\n    <inertial>\n      <mass value="{mass!r}"/>\n'
                f'      <origin xyz="{_fmt(com)}" rpy="0 0 0"/>\n'
                '      <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>\n'
                "    </inertial>\n  </link>"
            )
        else:
            out.append(f'  <link name="{lk}"/>')

    def joint(jn: str, kind: str, parent: str, child: str, T: np.ndarray, extra: str = "") -> None:
        out.append(
            f'  <joint name="{jn}" type="{kind}">\n    <parent link="{parent}"/>\n'
            f'    <child link="{child}"/>\n'
            f'    <origin xyz="{_fmt(T[:3, 3])}" rpy="{_fmt(rpy_of(T[:3, :3]))}"/>\n{extra}  </joint>'
        )

    parent = None
    for name, kind, axis, origin in extra_joints:
        if parent is None:
            link(parent := "root")
        link(f"{name}_link")
        limit = '    <limit lower="-1000.0" upper="1000.0" effort="0" velocity="0"/>\n'
        joint(
            name, kind, parent, f"{name}_link", origin, f'    <axis xyz="{_fmt(axis)}"/>\n' + limit
        )
        parent = f"{name}_link"
    link("base_link")
    if parent is not None:
        joint("mount", "fixed", parent, "base_link", np.eye(4) if mount is None else mount)
    for i in range(6):
        Q = rot_x(alpha[i]) @ rot_y(beta[i])
        T = _h(Q, Q @ np.array([a[i], 0.0, 0.0])) @ _h(
            rot_z(theta_offset[i]), np.array([0.0, 0.0, d[i]])
        )
        link(f"link{i + 1}", float(masses[i]), coms[i])
        extra = (
            '    <axis xyz="0 0 1"/>\n'
            f'    <limit lower="{float(lower[i])!r}" upper="{float(upper[i])!r}" effort="0" '
            'velocity="0"/>\n'
        )
        joint(
            f"joint{i + 1}",
            "revolute",
            "base_link" if i == 0 else f"link{i}",
            f"link{i + 1}",
            T,
            extra,
        )
    link("flange")
    joint("flange_joint", "fixed", "link6", "flange", F)
    for jn, on, factor in couplings:
        out.append(f'  <coupling joint="joint{jn}" on="joint{on}" factor="{float(factor)!r}"/>')
    defaults = extra_defaults or {}
    for name, *_ in extra_joints:
        value = f' default="{float(defaults[name])!r}"' if name in defaults else ""
        out.append(f'  <extra_joint joint="{name}"{value}/>')
    out.append("</robot>")
    return "\n".join(out) + "\n"
