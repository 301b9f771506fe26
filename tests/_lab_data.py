"""Simulated calibration campaigns for the lab's tests: a "true" arm (random geometric errors of
their typical size, docs/format.md; optionally a hidden effect at the low end of its range),
poses within the limits with the tool above the floor, instrument noise of 15 um per axis.

A campaign records what a real one would: each pose approached from a random direction
(``dir1..dir6``), the arm's temperature over a working day that warms the shop from 15 to 35 degC,
no payload (the catalogue's effects are all visible without one)."""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from arm.description import Joint, RobotDescription, load_robot
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from arm.sampling import sample_parameters, sample_poses

SIGMA = 15e-6  # m, per axis
FLOOR_MM = SIGMA * math.sqrt(3) * 1e3  # 3-D RMS of a perfect model on held-out points
MEDIAN_FLOOR_MM = 1.54 * SIGMA * 1e3  # median 3-D error of a perfect model

# docs/format.md, the lab's JSON output: keys every fit and diagnosis JSON object carries
FIT_KEYS = {
    "effects",
    "n_points",
    "rms_mm",
    "max_mm",
    "validation_rms_mm",
    "validation_median_mm",
    "parameters",
    "std",
    "rank",
    "n_parameters",
    "unidentifiable",
    "condition_number",
    "schema_version",
}
DIAGNOSE_KEYS = {
    "schema_version",
    "effects",
    "rms_mm",
    "noise_floor_mm",
    "verdict",
    "candidates",
    "hints",
}

# Real laser-tracker data of another arm: not redistributed (no licence). The folder that
# examples/convert_lm_pytorch.py writes from the public repository (README, "Real data"), named by
# the environment variable SIXAXIS_REAL_DATA; the tests that use it skip, saying why, without it.
REAL_DATA_ENV = "SIXAXIS_REAL_DATA"
REAL = Path(os.environ.get(REAL_DATA_ENV, "")) if os.environ.get(REAL_DATA_ENV) else None
if REAL is None:
    _REAL_REASON = (
        f"real laser-tracker data not configured: set {REAL_DATA_ENV} to the folder that "
        "examples/convert_lm_pytorch.py wrote (README, 'Real data')"
    )
elif not (REAL / "measurements.csv").is_file():
    _REAL_REASON = f"{REAL_DATA_ENV}={REAL} has no measurements.csv"
else:
    _REAL_REASON = ""
requires_real_data = pytest.mark.skipif(bool(_REAL_REASON), reason=_REAL_REASON)


def real_arm() -> RobotDescription:
    """The real data's arm: the converter's robot.toml, else its own tables (dh_mdh_deg_mm.csv,
    joint_limits_deg.csv); the tool is unknown: at the flange."""
    if (REAL / "robot.toml").is_file():
        return load_robot(REAL / "robot.toml")
    with open(REAL / "dh_mdh_deg_mm.csv") as fh:
        rows = [[float(x) for x in r] for r in list(csv.reader(fh))[1:]]
    with open(REAL / "joint_limits_deg.csv") as fh:
        limits = [[float(x) for x in r] for r in list(csv.reader(fh))[1:]]
    joints = tuple(
        Joint(
            alpha=math.radians(al),
            a=a / 1e3,
            d=d / 1e3,
            theta_offset=math.radians(th),
            lower=math.radians(lo),
            upper=math.radians(hi),
        )
        for (al, a, d, th), (hi, lo) in zip(rows, limits, strict=True)
    )
    return RobotDescription("rokae", joints)


@dataclass
class Campaign:
    truth: ErrorModel
    params: np.ndarray
    rng: np.random.Generator
    robot: RobotDescription
    sigma: float = SIGMA

    def measure(self, n: int | np.ndarray) -> MeasurementSet:
        """Measure ``n`` random poses (or the given joint angles (n, 6))."""
        rng = self.rng
        q = sample_poses(self.robot, n, rng) if np.isscalar(n) else np.asarray(n, dtype=float)
        m = len(q)
        cols = {f"dir{j}": rng.choice([-1.0, 1.0], m) for j in range(1, 7)}
        cols["temperature"] = rng.uniform(15.0, 35.0, m)
        if len(self.truth.targets) > 1:
            cols["target"] = rng.choice(np.array(self.truth.targets, dtype=float), m)
        xyz = self.truth.predict(self.truth.inputs(q, cols), self.params)
        return MeasurementSet(q, xyz + rng.normal(0.0, self.sigma, (m, 3)), cols, "simulated")


def campaign(
    robot: RobotDescription,
    effects: str = "geometric",
    seed: int = 0,
    targets: tuple[int, ...] = (0,),
    hidden_level: str = "low",
) -> Campaign:
    """A true arm: geometric errors drawn from their typical ranges, every other effect of
    ``effects`` at ``hidden_level`` of its range (by default the low end of its typical magnitude,
    docs/format.md)."""
    rng = np.random.default_rng(seed)
    truth = ErrorModel(robot, effects, targets=targets)
    geo = truth.layout.names[truth.layout.slice("geometric")]
    p = sample_parameters(truth, rng, only=geo)
    others = [n for n in truth.layout.names if n not in set(geo)]
    if others:
        q = sample_parameters(truth, rng, level=hidden_level, only=others)
        idx = truth.layout.indices(others)
        p[idx] = q[idx]
    return Campaign(truth, p, rng, robot)


def with_gross_outliers(
    d: MeasurementSet,
    rng: np.random.Generator,
    share: float = 0.02,
    size_m: tuple[float, float] = (0.2e-3, 2e-3),
):
    """``d`` with ``share`` of its points (at least one) moved ``size_m`` (default 0.2-2 mm) in
    random directions (a reflector that lost lock, a pasted row); returns the data and the rows
    moved."""
    k = max(1, round(share * len(d)))
    idx = np.sort(rng.choice(len(d), k, replace=False))
    u = rng.normal(size=(k, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    xyz = d.xyz.copy()
    xyz[idx] += u * rng.uniform(*size_m, (k, 1))
    return MeasurementSet(d.q, xyz, d.columns, d.source), idx


def session(values: dict, n: int, session: int, seed: int) -> MeasurementSet:
    """``n`` poses of one session (a ``session`` column of that id) of the seed arm with
    ``values`` of its geometric, compliance and transmission parameters (the rest nominal), 15 um
    of noise per axis: the blocks of the lab's cross-session tests (transfer, bagging)."""
    from lab.result import inputs_of

    rng = np.random.default_rng(seed)
    lo = np.array([-2.5, -2.2, -1.2, -2.5, -1.8, -3.0])
    hi = np.array([2.5, -0.3, 1.2, 2.5, 1.8, 3.0])
    q = rng.uniform(lo, hi, size=(n, 6))
    model = ErrorModel(load_robot("seed"), "geometric,compliance,transmission")
    p = model.layout.vector(values, default=model.nominal())
    cols = {"session": np.full(n, float(session))}
    xyz = model.predict(inputs_of(model, MeasurementSet(q, np.zeros((n, 3)), cols)), p)
    xyz = xyz + SIGMA * rng.standard_normal(xyz.shape)
    return MeasurementSet(q, xyz, cols, source=f"session{session}.csv")


def drifting_session(
    values: dict,
    n: int,
    station: int,
    seed: int,
    *,
    rehome_mrad: float = 2.0,
    remount_mm: float = 0.0,
    region: tuple[np.ndarray, float] | None = None,
) -> MeasurementSet:
    """``n`` poses of one session of the seed arm whose physics (``values``: geometric and
    compliance parameters) stays, as a new session finds it: measured from a tracker station of
    its own (id ``station``; the base metres away, turned), each joint re-homed (its zero offset
    shifted by up to ``rehome_mrad``), the tool re-mounted (each coordinate shifted by up to
    ``remount_mm``), the shop at another temperature (a column no effect reads), the poses in
    ``region`` (a centre (6,) and a half-width, rad) or anywhere; 15 um of noise per axis."""
    from lab.result import inputs_of

    rng = np.random.default_rng(seed)
    lo = np.array([-2.5, -2.2, -1.2, -2.5, -1.8, -3.0])
    hi = np.array([2.5, -0.3, 1.2, 2.5, 1.8, 3.0])
    if region is not None:
        centre, half = region
        lo, hi = np.maximum(lo, centre - half), np.minimum(hi, centre + half)
    q = rng.uniform(lo, hi, size=(n, 6))
    model = ErrorModel(load_robot("seed"), "geometric,compliance", stations=(station,))
    p = model.layout.vector(values, default=model.nominal())
    lay = model.layout
    for j in range(1, 7):
        p[lay.index(f"dtheta{j}")] += 1e-3 * rehome_mrad * rng.uniform(-1.0, 1.0)
    for c in ("tx", "ty", "tz"):
        p[lay.index(c)] += 1e-3 * remount_mm * rng.uniform(-1.0, 1.0)
    p[lay.indices(["bx", "by", "bz"])] = rng.uniform(-3.0, 3.0, 3)
    p[lay.index("brz")] = rng.uniform(-np.pi, np.pi)
    p[lay.indices(["brx", "bry"])] = rng.normal(0.0, 0.01, 2)
    cols = {
        "station": np.full(n, float(station)),
        "temperature": 20.0 + rng.uniform(-5.0, 5.0) + rng.normal(0.0, 0.2, n),
    }
    xyz = model.predict(inputs_of(model, MeasurementSet(q, np.zeros((n, 3)), cols)), p)
    xyz = xyz + SIGMA * rng.standard_normal(xyz.shape)
    return MeasurementSet(q, xyz, cols, source=f"station{station}.csv")
