"""Reference trajectories of the tool point: circle, lemniscate, line segments and random smooth
splines, in the measurement frame (the nominal robot base frame), inside the reachable workspace
above the floor.

    traj, q_start = sample_trajectory(seed_robot(), rng, kind="circle", duration=10.0)
    p = traj.positions(np.arange(501) * 0.02)      # (501, 3), m

A trajectory starts at rest: curves speed up over ``ramp`` seconds with a smooth (C2) time
scaling, line segments are minimum-jerk from corner to corner. :func:`sample_trajectory` draws one
around a comfortable configuration of the *nominal* arm and keeps it only if the nominal arm can
follow it: inverse kinematics converges along it, within the joint limits (with a margin), with
joint speeds well below the velocity limits, away from singular configurations, and the tool point
stays above ``MIN_TOOL_HEIGHT``. It also returns the encoder angles that put the nominal arm's tool
at the trajectory's start.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from arm.description import RobotDescription
from arm.ik import solve_point
from arm.kinematics import Chain, link_frames
from arm.sampling import MIN_TOOL_HEIGHT
from envs.errors import TrajectoryError

__all__ = [
    "KINDS",
    "Trajectory",
    "TrajectoryError",
    "check_posture",
    "sample_trajectory",
    "solve_tool_points",
]

log = logging.getLogger(__name__)

KINDS = ("circle", "lemniscate", "lines", "spline")
RAMP = 1.0  # s, the smooth start of curves
SPEED = (0.05, 0.15)  # m/s, tool speed
CHECK_DT = 0.1  # s between the points that the reachability check solves
JOINT_MARGIN = 0.1  # rad kept from the joint limits
SPEED_FRACTION = 0.5  # of v_max that the nominal joint speeds may use
MIN_SINGULAR = 0.05  # m/rad, smallest singular value of the position Jacobian


def _ramp_phase(t: np.ndarray, ramp: float) -> np.ndarray:
    """Time scaling with zero speed and acceleration at t=0, unit speed after ``ramp``:
    speed 3x^2 - 2x^3 (x = t/ramp), integrated."""
    t = np.asarray(t, dtype=float)
    if ramp <= 0:
        return t
    x = np.clip(t / ramp, 0.0, 1.0)
    inside = ramp * (x**3 - 0.5 * x**4)
    return np.where(t < ramp, inside, t - 0.5 * ramp)


def _min_jerk(s: np.ndarray) -> np.ndarray:
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A periodic reference path of the tool point; ``positions(t)`` for any times t >= 0 (s).

    ``centre`` and the plane ``axes`` (2, 3) place circle and lemniscate; ``waypoints`` (K, 3) are
    the corners of ``lines`` and the knots of ``spline``; ``size`` (m) is the radius,
    ``speed`` (m/s) the tool speed once started, ``period`` (s) one loop.
    """

    kind: str
    centre: np.ndarray
    axes: np.ndarray
    size: float
    speed: float
    period: float
    waypoints: np.ndarray | None = None
    ramp: float = RAMP

    def positions(self, t: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        c, (e1, e2) = self.centre, self.axes
        if self.kind == "lines":
            return self._lines(t)
        u = 2.0 * math.pi * _ramp_phase(t, self.ramp) / self.period
        if self.kind == "circle":
            x, y = np.cos(u) - 1.0, np.sin(u)
            return c + self.size * (x[:, None] * e1 + y[:, None] * e2)
        if self.kind == "lemniscate":
            x, y = np.sin(u), np.sin(u) * np.cos(u)
            return c + self.size * (x[:, None] * e1 + y[:, None] * e2)
        if self.kind == "spline":
            return self._spline()(np.mod(u / (2.0 * math.pi), 1.0) * self._spline_length())
        raise TrajectoryError(f"unknown trajectory kind {self.kind!r}")

    def _points(self) -> np.ndarray:
        if self.waypoints is None:
            raise TrajectoryError(f"a {self.kind!r} trajectory needs waypoints")
        return self.waypoints

    def _lines(self, t: np.ndarray) -> np.ndarray:
        w = self._points()
        seg = np.roll(w, -1, axis=0) - w
        durations = 1.875 * np.linalg.norm(seg, axis=1) / self.speed  # peak speed = speed
        ends = np.cumsum(durations)
        tm = np.mod(t, ends[-1])
        k = np.minimum(np.searchsorted(ends, tm, side="right"), len(w) - 1)
        start = ends[k] - durations[k]
        s = _min_jerk(np.clip((tm - start) / durations[k], 0.0, 1.0))
        return w[k] + s[:, None] * seg[k]

    def _spline_length(self) -> float:
        w = self._points()
        return float(np.linalg.norm(np.roll(w, -1, axis=0) - w, axis=1).sum())

    def _spline(self) -> CubicSpline:
        cached = self.__dict__.get("_cs")
        if cached is None:
            w = self._points()
            closed = np.vstack([w, w[:1]])
            knots = np.concatenate(
                [[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))]
            )
            cached = CubicSpline(knots, closed, bc_type="periodic", axis=0)
            object.__setattr__(self, "_cs", cached)
        return cached


def _plane(rng: np.random.Generator) -> np.ndarray:
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return np.stack([e1, e2])


def _shape(kind: str, centre: np.ndarray, rng: np.random.Generator) -> Trajectory:
    axes = _plane(rng)
    speed = float(rng.uniform(*SPEED))
    if kind == "circle":
        r = float(rng.uniform(0.05, 0.15))
        return Trajectory(kind, centre, axes, r, speed, 2 * math.pi * r / speed)
    if kind == "lemniscate":
        a = float(rng.uniform(0.08, 0.18))
        return Trajectory(kind, centre, axes, a, speed, 6.1 * a / speed)  # length ~6.1 a
    if kind == "lines":
        n = int(rng.integers(3, 6))
        r = float(rng.uniform(0.06, 0.15))
        ang = np.sort(rng.uniform(0, 2 * math.pi, n))
        pts = centre + r * (np.cos(ang)[:, None] * axes[0] + np.sin(ang)[:, None] * axes[1])
        pts = pts - pts[0] + centre  # start at the centre point
        seg = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
        period = float((1.875 * seg / speed).sum())
        return Trajectory(kind, centre, axes, r, speed, period, waypoints=pts, ramp=0.0)
    if kind == "spline":
        n = int(rng.integers(5, 8))
        r = float(rng.uniform(0.05, 0.12))
        ang = np.sort(rng.uniform(0, 2 * math.pi, n))
        rad = r * rng.uniform(0.5, 1.0, n)
        off = rng.uniform(-0.5, 0.5, n) * r
        normal = np.cross(axes[0], axes[1])
        pts = (
            centre
            + (rad * np.cos(ang))[:, None] * axes[0]
            + (rad * np.sin(ang))[:, None] * axes[1]
            + off[:, None] * normal
        )
        pts = pts - pts[0] + centre
        length = float(np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1).sum())
        return Trajectory(kind, centre, axes, r, speed, length / speed, waypoints=pts)
    raise TrajectoryError(f"unknown trajectory kind {kind!r}; known: {', '.join(KINDS)}")


def solve_tool_points(
    robot: RobotDescription, targets: np.ndarray, q0: np.ndarray, tol: float = 1e-10
) -> tuple[np.ndarray, np.ndarray]:
    """Encoder angles (N, 6) putting the nominal arm's tool point at ``targets`` (N, 3, in the
    measurement frame), all from ``q0`` (6,) by damped least squares (``arm.ik.solve_point``):
    minimum-norm steps, so the solutions stay close to ``q0`` in the redundant directions and vary
    smoothly along a path. Returns the angles and the final errors (N,) in m."""
    m = robot.to_modified()
    targets = np.asarray(targets, dtype=float).reshape(-1, 3)
    R = m.base_matrix[:3, :3]
    in_base = (targets - m.base_matrix[:3, 3]) @ R  # R^T (p - t), row-wise
    res = solve_point(m, in_base, np.asarray(q0, dtype=float), tol=tol, max_iter=60)
    return res.q, res.error


def _comfortable(robot: RobotDescription, rng: np.random.Generator) -> np.ndarray:
    """A configuration around the middle of the limits (joint 1 and 6 anywhere near zero)."""
    lo, hi = robot.lower, robot.upper
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    q = mid + rng.uniform(-0.35, 0.35, 6) * half
    q[0] = rng.uniform(-0.8, 0.8)
    q[5] = 0.0
    return q


def check_posture(robot: RobotDescription, posture: Sequence[float | None]) -> np.ndarray:
    """``posture`` as a (6,) float array with NaN for the joints left free (None in the input);
    a clear error for a wrong length, a non-number, NaN (a computation gone wrong, not a free
    joint: say None) or a value outside the joint limits less :data:`JOINT_MARGIN`."""
    try:
        vals = [math.nan if v is None else float(v) for v in posture]
    except (TypeError, ValueError) as exc:
        raise TrajectoryError(
            f"posture must be 6 joint angles (rad) or None per joint, got {posture!r}"
        ) from exc
    if len(vals) != 6:
        raise TrajectoryError(f"posture must have 6 entries (one per joint), got {len(vals)}")
    for i, v in enumerate(posture):
        if v is not None and math.isnan(vals[i]):
            raise TrajectoryError(
                f"posture of joint {i + 1} is NaN; give None to leave a joint free"
            )
    p = np.array(vals)
    lo, hi = robot.lower + JOINT_MARGIN, robot.upper - JOINT_MARGIN
    for i, v in enumerate(p):
        if np.isinf(v) or (np.isfinite(v) and not lo[i] <= v <= hi[i]):
            raise TrajectoryError(
                f"posture of joint {i + 1} is {v:g} rad, outside its limits "
                f"[{lo[i]:g}, {hi[i]:g}] (less a {JOINT_MARGIN:g} rad margin)"
            )
    return p


def _position_jacobian_ok(robot: RobotDescription, q: np.ndarray) -> bool:
    m = robot.to_modified()
    f = link_frames(Chain.from_description(m), q)
    p = f.point(m.tool_points[0])
    J = np.cross(f.z, p[:, None, :] - f.o[:, 1:])  # (N, 6, 3)
    s = np.linalg.svd(J, compute_uv=False)
    return bool(np.all(s[:, -1] > MIN_SINGULAR))


def sample_trajectory(
    robot: RobotDescription,
    rng: np.random.Generator,
    kind: str | None = None,
    duration: float = 10.0,
    v_max: np.ndarray | None = None,
    max_tries: int = 100,
    posture: Sequence[float | None] | None = None,
) -> tuple[Trajectory, np.ndarray]:
    """A reachable trajectory of ``kind`` (drawn from :data:`KINDS` when None) for ``duration``
    seconds, and the nominal arm's encoder angles (6,) at its start (see the module docstring).

    ``posture`` (6 joint angles in rad, None for a joint left free) places the trajectory in a
    chosen region of the workspace: the configuration around which the path is drawn takes these
    angles (the others are drawn as usual), so its centre is the nominal tool point there and the
    arm tracks it near that posture (e.g. shoulder and elbow angles set the gravity torques the
    joints carry). The random draws are the same with or without it, so ``None`` gives the same
    trajectory as before the option existed."""
    m = robot.to_modified()
    fixed = None if posture is None else check_posture(m, posture)
    if kind is None:
        kind = str(rng.choice(KINDS))
    if kind not in KINDS:
        raise TrajectoryError(f"unknown trajectory kind {kind!r}; known: {', '.join(KINDS)}")
    v_lim = SPEED_FRACTION * (np.full(6, np.inf) if v_max is None else np.asarray(v_max))
    chain = Chain.from_description(m)
    tool = m.tool_points[0]
    t_check = np.arange(0.0, duration + CHECK_DT / 2, CHECK_DT)
    t_fine = np.arange(0.0, duration + 0.01, 0.02)
    lo, hi = m.lower + JOINT_MARGIN, m.upper - JOINT_MARGIN
    for attempt in range(max_tries):
        qc = _comfortable(m, rng)
        if fixed is not None:
            qc = np.where(np.isnan(fixed), qc, fixed)
        base = m.base_matrix
        centre = base[:3, :3] @ link_frames(chain, qc[None]).point(tool)[0] + base[:3, 3]
        traj = _shape(kind, centre, rng)
        if traj.positions(t_fine)[:, 2].min() < MIN_TOOL_HEIGHT:
            continue
        path = traj.positions(t_check)
        q, err = solve_tool_points(m, path, qc)
        if err.max() > 1e-7:
            continue
        if np.any(q < lo) or np.any(q > hi):
            continue
        if np.any(np.abs(np.diff(q, axis=0)) / CHECK_DT > v_lim):
            continue
        if not _position_jacobian_ok(m, q):
            continue
        log.debug("%s trajectory after %d tries", kind, attempt + 1)
        return traj, q[0]
    where = "" if fixed is None else f" around posture {np.round(fixed, 3).tolist()}"
    raise TrajectoryError(
        f"no reachable {kind} trajectory found{where} in {max_tries} tries for robot {m.name!r}"
    )
