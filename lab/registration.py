"""Registration: where the measurements say the nominal arm stands, in closed form.

A large unknown base transform (a laser tracker stands metres away, rotated anyhow) and tool
offsets (a reflector hundreds of millimetres off the flange) are initialised before any
iteration: alternately, Kabsch's rotation of the nominal chain's points onto the measured ones
(:meth:`scipy.spatial.transform.Rotation.align_vectors`) and linear least squares for the base
translation and every target's tool offset given that rotation. Each step lowers the sum of
squares, so it converges from a tool hundreds of millimetres off.

    p = register_base(model, inputs, xyz, model.nominal())
    p0 = nominal_parameters(model, inputs, xyz)     # the "before" of a calibration

With several tracker stations each station's base is registered on its own rows, the tool offsets
shared; where the tool frame's orientation is measured, its rotation (``trx try trz``) is the
rotation that best maps the arm's last frame onto the measured frames, given the bases
(:func:`register_tool_rotation`, the orthogonal Procrustes solution).

**A station the calibration has not seen** (:func:`register_station`): a calibrated arm is
placed in a new tracker station's frame by reference points measured there (at least three not
on one line, or rows with the tool frame's orientation), the arm as calibrated and only the
station's six parameters fitted; compensation of a program given in that station's frame and
validation of measurements made there both use it, and neither fits anything on the rows it
serves::

    reg = register_station(model, params, references)   # the references: a MeasurementSet
    reg.rms_mm, reg.max_mm         # how far the registered arm lies from the references
    reg.R, reg.t                   # the station's frame <- the calibration's (first station's)
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from arm.description import RobotDescription
from arm.effect_api import ModelInputs
from arm.errormodel import ErrorModel
from arm.kinematics import link_frames
from arm.measurements import MeasurementSet
from arm.so3 import rotation_matrix, rotation_vector
from lab.blocks import Blocks
from lab.errors import RegistrationError

__all__ = [
    "StationRegistration",
    "register_base",
    "register_points",
    "register_station",
    "register_stations",
]

#: m: a 6-DoF reference row counts as its point and three more this far along its tool frame's
#: axes (a rotation error of 1 mrad weighs as 0.1 mm of a point)
FRAME_ARM = 0.1
#: m: reference points whose spread off their best line is below this are collinear: the
#: rotation about that line is not determined
COLLINEAR = 1e-3


def register_base(
    model: ErrorModel,
    inputs: ModelInputs,
    xyz: np.ndarray,
    params: np.ndarray,
    tools: bool = True,
    iterations: int = 100,
) -> np.ndarray:
    """Closed-form initial base transform (and tool offsets) for a geometric model.

    Alternates Kabsch's rotation of the chain's points onto ``xyz`` and linear least squares for
    the base translation and each target's tool point given the rotation; each step lowers the sum
    of squares, so it converges from a tool hundreds of millimetres off. Returns ``params`` with the
    base (and tool) parameters replaced. On an arm with extra joints the chain's points are placed
    through them at each row's values first (the base is the frame they start from)."""
    lay = model.layout
    p = np.array(params, dtype=float)
    st = model.state(inputs, p)
    # the last frame of every pose, block by block (all seven frames of 200k poses: 130 MB)
    o6, R6 = np.empty((inputs.n, 3)), np.empty((inputs.n, 3, 3))
    for sl, part in Blocks(model, inputs):
        st_b = model.state(part, p)
        f = link_frames(st_b.chain, model.joint_angles(part, p))
        o6[sl], R6[sl] = f.o[:, 6], f.R[:, 6]
    extra = st.extra_placement()
    if extra is not None:  # frame 0 placed per row by the extra joints: the base is before them
        o6 = np.einsum("nij,nj->ni", extra.R, o6) + extra.t
        R6 = extra.R @ R6
    tool = st.tools.copy()
    tgt = inputs.target
    n, K = inputs.n, len(model.targets)
    rows = np.arange(n)
    if len(model.stations) > 1:
        return _register_stations(model, inputs, xyz, p, o6, R6, tools, iterations)
    R = st.base_R
    t = st.base_t
    for _ in range(iterations):
        pts = o6 + np.einsum("nij,nj->ni", R6, tool[tgt])
        pc, mc = pts.mean(axis=0), xyz.mean(axis=0)
        rot, _ = Rotation.align_vectors(xyz - mc, pts - pc)
        R = rot.as_matrix()
        t = mc - R @ pc
        if not tools:
            break
        # xyz - R o6 = R R6 tool[target] + t, linear in (t, tools)
        A = np.zeros((n, 3, 3 + 3 * K))
        A[:, :, :3] = np.eye(3)
        RR6 = np.einsum("ij,njk->nik", R, R6)
        for k in range(K):
            A[rows[tgt == k], :, 3 + 3 * k : 6 + 3 * k] = RR6[tgt == k]
        b = xyz - o6 @ R.T
        # solve for the change from the current tools so that unseen directions stay put
        b = b - np.einsum("nij,nj->ni", RR6, tool[tgt])
        A2 = A.reshape(-1, 3 + 3 * K)
        sol, *_ = np.linalg.lstsq(A2.T @ A2, A2.T @ b.reshape(-1), rcond=None)
        t = sol[:3]
        step = sol[3:].reshape(K, 3)
        tool = tool + step
        if np.max(np.abs(step)) < 1e-10:
            break
    names = lay.names
    geo = lay.slice("geometric")
    for name, v in zip(("bx", "by", "bz"), t, strict=True):
        p[lay.index(name)] = v
    for name, v in zip(("brx", "bry", "brz"), rotation_vector(R), strict=True):
        p[lay.index(name)] = v
    if tools:
        tool_names = [x for x in names[geo] if x[:1] == "t" and x[1:2] in ("x", "y", "z")]
        idx = lay.indices(tool_names).reshape(K, 3)
        p[idx] += tool - st.tools
    return p


def register_points(pred: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid transform (R, t) that best maps the points ``pred`` (N, 3) onto ``xyz``
    (Kabsch's rotation about the centroids): a base registered on given points."""
    pc, mc = pred.mean(axis=0), xyz.mean(axis=0)
    rot, _ = Rotation.align_vectors(xyz - mc, pred - pc)
    R = rot.as_matrix()
    return R, mc - R @ pc


def register_stations(
    pred: np.ndarray,
    xyz: np.ndarray,
    groups: list[np.ndarray],
    columns: np.ndarray | None = None,
    iterations: int = 100,
) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """Each group of rows' rigid transform (R, t) that best maps the points ``pred + columns @
    delta`` (N, 3) onto ``xyz``, and ``delta`` (k,), shared by the groups: stations the arm has
    not seen placed together with the parameters ``columns`` (N, 3, k: d point / d parameter)
    move, e.g. a tool offset a fit could not identify. Alternately Kabsch's rotation of each
    group (:func:`register_points`) and linear least squares for ``delta`` with each group's
    translation given the rotations; each step lowers the sum of squares. Without ``columns``
    each group is registered rigidly alone and ``delta`` is empty."""
    if columns is None:
        return [register_points(pred[g], xyz[g]) for g in groups], np.zeros(0)
    k = columns.shape[2]
    delta = np.zeros(k)
    for _ in range(iterations):
        pts = pred + columns @ delta
        placed = [register_points(pts[g], xyz[g]) for g in groups]
        # sum over groups of |R_g (C_i - mean C) delta - (x_i - mean x - R_g (p_i - mean p))|^2
        A, b = [], []
        for (R, _), g in zip(placed, groups, strict=True):
            C, p, x = columns[g], pred[g], xyz[g]
            A.append(np.einsum("ij,njk->nik", R, C - C.mean(axis=0)).reshape(-1, k))
            b.append(((x - x.mean(axis=0)) - (p - p.mean(axis=0)) @ R.T).reshape(-1))
        new, *_ = np.linalg.lstsq(np.vstack(A), np.concatenate(b), rcond=None)
        step, delta = new - delta, new
        if np.max(np.abs(step)) < 1e-12:
            break
    pts = pred + columns @ delta
    placed = [register_points(pts[g], xyz[g]) for g in groups]
    return placed, delta


def tool_columns(
    model: ErrorModel, inputs: ModelInputs, params: np.ndarray, names: list[str]
) -> np.ndarray:
    """(N, 3, k): how each predicted point moves with the tool-point parameters ``names`` (per
    unit, m/m). The tool point enters the chain linearly (the base, the flange's frame, then
    the offset), so a finite difference of one metre is exact but for rounding."""
    blocks = Blocks(model, inputs)
    base = blocks.predict(params)
    out = np.empty((inputs.n, 3, len(names)))
    for j, i in enumerate(model.layout.indices(names)):
        p = np.array(params, dtype=float)
        p[i] += 1.0
        out[:, :, j] = blocks.predict(p) - base
    return out


def _register_stations(
    model: ErrorModel,
    inputs: ModelInputs,
    xyz: np.ndarray,
    p: np.ndarray,
    o6: np.ndarray,
    R6: np.ndarray,
    tools: bool,
    iterations: int,
) -> np.ndarray:
    """:func:`register_base` with one base per station (``bx{s}`` ...) and the tools shared."""
    lay = model.layout
    st = model.state(inputs, p)
    tool = st.tools.copy()
    tgt, which = inputs.target, inputs.stations
    n, K, S = inputs.n, len(model.targets), len(model.stations)
    Rs = np.repeat(np.eye(3)[None], S, axis=0)
    ts = np.zeros((S, 3))
    for _ in range(iterations):
        pts = o6 + np.einsum("nij,nj->ni", R6, tool[tgt])
        for s in range(S):
            on = which == s
            if on.sum() >= 3:
                Rs[s], ts[s] = register_points(pts[on], xyz[on])
        if not tools:
            break
        # xyz - R_s o6 = R_s R6 tool[target] + t_s, linear in (t_1..t_S, tools)
        A = np.zeros((n, 3, 3 * S + 3 * K))
        RR6 = np.einsum("nij,njk->nik", Rs[which], R6)
        for s in range(S):
            A[which == s, :, 3 * s : 3 * s + 3] = np.eye(3)
        for k in range(K):
            A[tgt == k, :, 3 * S + 3 * k : 3 * S + 3 * k + 3] = RR6[tgt == k]
        b = xyz - np.einsum("nij,nj->ni", Rs[which], o6)
        b = b - np.einsum("nij,nj->ni", RR6, tool[tgt])
        A2 = A.reshape(-1, 3 * S + 3 * K)
        sol, *_ = np.linalg.lstsq(A2.T @ A2, A2.T @ b.reshape(-1), rcond=None)
        ts = sol[: 3 * S].reshape(S, 3)
        step = sol[3 * S :].reshape(K, 3)
        tool = tool + step
        if np.max(np.abs(step)) < 1e-10:
            break
    for s, sid in enumerate(model.stations):
        for c, v in zip("xyz", ts[s], strict=True):
            p[lay.index(f"b{c}{sid}")] = v
        for c, v in zip("xyz", rotation_vector(Rs[s]), strict=True):
            p[lay.index(f"br{c}{sid}")] = v
    if tools:
        idx = tool_indices(model).reshape(K, 3)
        p[idx] += tool - st.tools
    return p


def register_tool_rotation(
    model: ErrorModel,
    inputs: ModelInputs,
    params: np.ndarray,
    rotations: np.ndarray,
    seen: np.ndarray,
) -> np.ndarray:
    """``params`` with the tool frame's rotation (``trx try trz``) that best maps the model's last
    frame onto the measured orientations ``rotations`` (N, 3, 3) of the rows ``seen``, given the
    bases in ``params``: R_tool = argmin sum |R_b R6 R_tool - R_measured|^2, the orthogonal
    Procrustes solution (the SVD of sum R6^T R_b^T R_measured)."""
    p = np.array(params, dtype=float)
    lay = model.layout
    if not seen.any() or "trx" not in lay:
        return p
    idx = lay.indices(["trx", "try", "trz"])
    q = p.copy()
    q[idx] = 0.0
    _, R = model.predict_pose(inputs, q)  # the last frame, with the bases, no tool rotation
    M = np.einsum("nji,njk->ik", R[seen], rotations[seen])
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    p[idx] = rotation_vector(U @ D @ Vt)
    return p


def tool_indices(model: ErrorModel) -> np.ndarray:
    """The indices of the geometric model's tool-point parameters (``tx``, ``ty``, ``tz``, per
    target)."""
    names = model.layout.names[model.layout.slice("geometric")]
    return model.layout.indices([n for n in names if n[:1] == "t" and n[1:2] in ("x", "y", "z")])


def nominal_parameters(model: ErrorModel, inputs: ModelInputs, xyz: np.ndarray) -> np.ndarray:
    """The nominal parameter vector with the base transform and tool offsets registered in closed
    form (:func:`register_base`): the "before" of a calibration, the nominal arm placed where the
    measurements say it stands (without it, data in a laser tracker's frame would be metres off).
    The registration is kept only where it lowers the RMS."""
    p = model.nominal()
    if "geometric" not in model.layout.effects:
        return p
    p_reg = register_base(model, inputs, xyz, p)
    before = np.sum((model.predict(inputs, p) - xyz) ** 2)
    after = np.sum((model.predict(inputs, p_reg) - xyz) ** 2)
    return p_reg if after < before else p


@dataclass(frozen=True)
class StationRegistration:
    """A new station's frame found from reference points measured there (:func:`register_station`):
    ``R``, ``t``: the station's frame <- the calibration's measurement frame (its first
    station's); ``residuals`` (N, 3): the registered arm's points minus the references', m;
    ``station``: the references' station id (None: they have no station column); ``tool``: the
    tool-point parameters placed with it, {name: change, m} (those the calibration could not
    identify, :meth:`lab.FitResult.unidentified_tool`); ``source``: the references' file."""

    R: np.ndarray
    t: np.ndarray
    residuals: np.ndarray
    station: int | None = None
    source: str = "<memory>"
    tool: dict[str, float] | None = None

    @property
    def n_points(self) -> int:
        return len(self.residuals)

    @property
    def rms_mm(self) -> float:
        return 1e3 * float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))

    @property
    def max_mm(self) -> float:
        return 1e3 * float(np.max(np.linalg.norm(self.residuals, axis=1)))

    def base(self, first: np.ndarray) -> np.ndarray:
        """The station's 4x4 frame <- robot base, given the calibration's ``first`` (4x4)."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.t
        return T @ first

    def text(self) -> str:
        """``station 3 registered on 4 reference points of refs.csv: residual RMS ... mm``."""
        which = "a new station" if self.station is None else f"station {self.station}"
        return (
            f"{which} registered on {self.n_points} reference points of {self.source} (the "
            f"calibrated arm, its base alone fitted): residual RMS {self.rms_mm:.4f} mm, max "
            f"{self.max_mm:.4f} mm"
        )

    def to_dict(self) -> dict:
        return {
            "station": self.station,
            "source": self.source,
            "n_points": self.n_points,
            "rms_mm": self.rms_mm,
            "max_mm": self.max_mm,
            "translation": [float(v) for v in self.t],
            "rotation_vector": [float(v) for v in rotation_vector(self.R)],
            "tool_placed_mm": {k: 1e3 * v for k, v in (self.tool or {}).items()},
        }


def _frame_points(xyz: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Each 6-DoF row's point and three points along its frame's axes (4 N, 3)."""
    axes = FRAME_ARM * np.swapaxes(R, 1, 2)  # row k of R^T: the frame's axis k
    return np.concatenate([xyz[:, None, :], xyz[:, None, :] + axes], axis=1).reshape(-1, 3)


def _reference_rows(
    references: MeasurementSet, pred: np.ndarray, pred_R: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points a registration maps (predicted, measured) and which row each comes from: every
    reference point, and for a row with a measured orientation three more along its frame."""
    six = np.zeros(len(references), dtype=bool)
    if pred_R is not None and references.has_orientation:
        six = np.asarray(references.measured[:, 3:].all(axis=1))
    if not six.any() or references.orientation is None or pred_R is None:
        return pred, references.xyz, np.arange(len(references))
    Rm = rotation_matrix(references.orientation[six])
    p = np.vstack([pred[~six], _frame_points(pred[six], pred_R[six])])
    m = np.vstack([references.xyz[~six], _frame_points(references.xyz[six], Rm)])
    rows = np.concatenate([np.flatnonzero(~six), np.repeat(np.flatnonzero(six), 4)])
    return p, m, rows


def check_references(references: MeasurementSet, points: np.ndarray) -> None:
    """Refuse references that cannot place a station: fewer than 3 points, or points on a line
    (the rotation about it is free), with the file and what to measure."""
    where = references.source
    if len(points) < 3:
        raise RegistrationError(
            f"{where}: {len(references)} reference point(s): a station's frame needs at least 3 "
            "points not on one line (or one row with the tool frame's orientation, 6-DoF)"
        )
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    spread = float(s[1]) / np.sqrt(len(points))
    if spread < COLLINEAR:
        raise RegistrationError(
            f"{where}: the {len(references)} reference points lie on one line (within "
            f"{spread * 1e3:.3g} mm): the rotation about it is not determined; measure at least "
            "3 points not on one line, metres apart where the arm reaches"
        )


def register_station(
    model: ErrorModel,
    params: np.ndarray,
    references: MeasurementSet,
    tool: list[str] | None = None,
) -> StationRegistration:
    """The frame of the station where ``references`` were measured, relative to the calibration's
    measurement frame: the calibrated arm (``model`` at ``params``, as measured from its first
    station) predicts each reference pose, and the rigid transform that best maps those points
    onto the measured ones is the station's (Kabsch; a row with a measured orientation adds three
    points along its tool frame, :data:`FRAME_ARM`). ``tool``: tool-point parameters the
    calibration did not identify, placed with the station (:func:`register_stations`). Refuses
    references that cannot determine it (:func:`check_references`)."""
    which = references.columns.get("station")
    ids = sorted({int(v) for v in which}) if which is not None else []
    if len(ids) > 1:
        raise RegistrationError(
            f"{references.source}: reference points of stations {ids}: give one station's "
            "references at a time"
        )
    cols = {k: v for k, v in references.columns.items() if k != "station"}
    if len(model.stations) > 1:  # as measured from the calibration's first station
        cols["station"] = np.full(len(references), float(model.stations[0]))
    inputs = model.inputs(references.q, cols, source=references.source)
    pred, pred_R = model.predict_pose(inputs, params)
    columns = tool_columns(model, inputs, params, tool) if tool else None
    if columns is not None:  # a tool offset the calibration could not identify: placed here
        check_references(references, references.xyz)
        placed, delta = register_stations(pred, references.xyz, [np.arange(len(pred))], columns)
        pred = pred + columns @ delta
        (R, t), shift = placed[0], dict(zip(tool or (), map(float, delta), strict=True))
    else:
        p, m, _ = _reference_rows(references, pred, pred_R)
        check_references(references, m)
        R, t = register_points(p, m)
        shift = None
    residuals = pred @ R.T + t - references.xyz
    return StationRegistration(R, t, residuals, ids[0] if ids else None, references.source, shift)


#: another reading of the robot file (a coupling, the other DH convention) is named when it
#: brings the registered arm's median miss below this share of the file's own reading's, and
#: under COUPLING_MISS: the rows are then of the arm so read
COUPLING_GAIN = 0.2
COUPLING_MISS = 0.02  # m


def registered_miss(
    robot: RobotDescription,
    q: np.ndarray,
    xyz: np.ndarray,
    columns: Mapping[str, np.ndarray] | None = None,
) -> float:
    """The median miss (m) of the nominal ``robot``, its base and tool registered on the rows
    (its extra joints at the values ``columns`` give them, else their defaults)."""
    model = ErrorModel(robot, "geometric")
    held = {k: v for k, v in (columns or {}).items() if k in robot.extra_names}
    inputs = model.inputs(q, held)
    p = register_base(model, inputs, xyz, model.nominal())
    return float(np.median(np.linalg.norm(model.predict(inputs, p) - xyz, axis=1)))


def _coupling_readings(
    robot: RobotDescription,
) -> Iterator[tuple[RobotDescription, tuple[int, int, float], bool]]:
    """The arm read otherwise: with a coupling of two consecutive parallel joints added (either
    sign), or without one the robot file states; each with that coupling and whether it was
    stated (so removed)."""
    for row in robot.parallel_rows():
        for factor in (-1.0, 1.0):
            c = (row, row - 1, factor)
            if any((j, o) == c[:2] for j, o, _ in robot.couplings):
                continue
            try:
                yield replace(robot, couplings=(*robot.couplings, c)), c, False
            except ValueError:  # dependent couplings
                continue
    for c in robot.couplings:
        yield replace(robot, couplings=tuple(x for x in robot.couplings if x != c)), c, True


def _convention_readings(
    robot: RobotDescription,
) -> Iterator[tuple[RobotDescription, str]]:
    """The robot file's DH table read in the other convention (a data sheet's standard table in a
    file that says modified, or says nothing: modified is the default), with that convention;
    none for a URDF's arm or a calibrated one (Hayati's beta is modified DH's alone)."""
    if robot.urdf is not None or any(j.beta for j in robot.joints):
        return
    other: Literal["modified", "standard"] = (
        "standard" if robot.convention == "modified" else "modified"
    )
    try:
        yield replace(robot, convention=other), other
    except ValueError:  # not an arm in that reading
        return


def reading_hint(
    robot: RobotDescription,
    q: np.ndarray,
    xyz: np.ndarray,
    columns: Mapping[str, np.ndarray] | None = None,
) -> str:
    """A sentence naming the joint coupling or the DH convention that would explain rows the arm
    cannot follow, or ``""`` (``robot`` as its file states it: :attr:`ErrorModel.described`).
    Where two consecutive axes are parallel (FANUC's J2 and J3), a controller may report the
    second from the horizon (``theta_3 = q_3 - q_2``) or relative (``+ q_2``), and a robot file
    may state a coupling the rows do not have; a data sheet's DH table may be standard where the
    file reads it as modified, or the reverse. The arm read so, registered on the rows, misses
    them by a fraction of the arm's own miss."""
    if len(q) < 6:
        return ""
    plain = registered_miss(robot, q, xyz, columns)
    best: tuple[float, str] | None = None
    readings = [
        *((arm, _coupling_sentence(c, stated)) for arm, c, stated in _coupling_readings(robot)),
        *((arm, _convention_sentence(conv)) for arm, conv in _convention_readings(robot)),
    ]
    for arm, sentence in readings:
        miss = registered_miss(arm, q, xyz, columns)
        if (
            miss < COUPLING_GAIN * plain
            and miss < COUPLING_MISS
            and (best is None or miss < best[0])
        ):
            best = (miss, sentence)
    if best is None:
        return ""
    miss, sentence = best
    return sentence.format(miss=f"{miss * 1e3:.3g}", plain=f"{plain * 1e3:.3g}")


def _convention_sentence(convention: str) -> str:
    other = "modified" if convention == "standard" else "standard"
    return (
        f"the rows fit the robot file's DH table read as {convention} DH: that arm misses by "
        f"{{miss}} mm (median), read as {other} by {{plain}} mm; say convention = "
        f'"{convention}" in the robot file (a data sheet\'s table is often standard DH, a file '
        "without the key is read as modified)"
    )


def _coupling_sentence(c: tuple[int, int, float], stated: bool) -> str:
    j, o, f = c
    law = f"theta_{j} = q_{j} {'-' if f < 0 else '+'} q_{o}"
    if stated:
        return (
            f"the rows fit as the arm's own angles, joint {j} not coupled on joint {o}: the "
            f"nominal arm without the robot file's coupling ({law}) misses by {{miss}} mm "
            f"(median), with it by {{plain}} mm; the rows are not the controller's angles it "
            f"states (remove [[couplings]] joint = {j}, on = {o}, or give the controller's)"
        )
    return (
        f"the rows fit as the controller's angles of coupled joints {o} and {j} ({law}, as "
        f"FANUC reports J3 from the horizon): the nominal arm so coupled misses by {{miss}} mm "
        f"(median), uncoupled by {{plain}} mm; state it in the robot file ([[couplings]] "
        f"joint = {j}, on = {o}, factor = {f:g})"
    )
