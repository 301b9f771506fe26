"""Measurements for the lab from the simulated arm: drive the MuJoCo plant to a list of poses, each
approached from a random direction so that dir1..dir6 vary, let it settle, and measure the tool
point with the laser tracker. The result is a measurement set (docs/format.md, the measurement
CSV) with every optional column (t, temperature, payload, dir1..dir6).

A campaign can be measured as a real one is: from several tracker stations (each its own frame,
metres from the arm: a ``station`` column), with noise that grows with the distance from the
tracker (``noise_ppm``), with a 6-DoF probe on the flange that also measures the tool frame's
orientation in some of the rows (``orientation``, ``orientation_fraction``: the rows where the
probe was seen), and with each row's stated uncertainty (``stds``: the std_x... columns).

    from envs.collect import collect_measurements
    data = collect_measurements(n=200, scenario="compliance", seed=7, path="compliance.csv")

The plant, not a formula, makes the hidden effects: the lab sees what a real calibration would.
Importing this module starts nothing; MuJoCo is loaded by the plant when a collection runs.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from arm.constraints import Constraint, Interval, check, refuse
from arm.description import RobotDescription, load_robot
from arm.measurements import MeasurementSet, write_measurements
from arm.noise import NOISE_MM, NOISE_MRAD, NOISE_PPM
from arm.sampling import SamplingError, check_count, rng_from, sample_poses
from arm.so3 import rotation_matrix, rotation_vector
from envs.errors import CollectError, DivergedError
from envs.instrument import TrackerStation, place_stations

if TYPE_CHECKING:
    from envs.scenarios import EpisodeTruth

__all__ = ["CollectError", "check_poses", "collect_measurements"]

log = logging.getLogger(__name__)


#: the simulated instrument's settings: the quantities of :mod:`arm.noise` (0 draws no noise: a
#: perfect instrument) and the share of rows whose orientation is seen
CAMPAIGN_RULES: dict[str, tuple[list[Constraint], bool]] = {
    "noise_mm": ([NOISE_MM.rule], False),
    "noise_ppm": ([NOISE_PPM.rule], False),
    "noise_mrad": ([NOISE_MRAD.rule], False),
    "orientation_fraction": ([Interval(float, 0.0, 1.0, why="a fraction of the rows")], False),
}


APPROACH = 0.03  # rad: each joint's last move towards the pose
# the 6-DoF probe's mounting on the flange: 120 degrees about (1, 1, 1), as the Rokae set's is;
# the same for every campaign of an arm, so that a held-out campaign sees the same probe
PROBE_ROTATION = tuple(2.0 * math.pi / 3.0 / math.sqrt(3.0) for _ in range(3))
APPROACH_SPEED = 0.05  # rad/s
# rad/s^2: slow enough that friction keeps a heavy link against its driving flank when stopping
APPROACH_DECEL = 0.1
TRANSIT_FRACTION = 0.5  # of v_max and a_max, for the moves between poses
LANDING_TOL = 2e-5  # rad: how close the encoders settle to a requested pose
LANDING_PASSES = 3  # approaches per pose at most


def _move(plant, target: np.ndarray, v_cruise: np.ndarray, decel: np.ndarray) -> None:
    """Drive the servo's reference to ``target`` with a trapezoidal profile (the plant adds its
    own acceleration limit), landing exactly on it."""
    act = plant.data.act
    adr = plant._act_adr
    dt = plant.dt
    for _ in range(100000):
        r = target - act[adr]
        if np.all(np.abs(r) < 1e-12):
            break
        speed = np.minimum(np.minimum(v_cruise, np.sqrt(2.0 * decel * np.abs(r))), np.abs(r) / dt)
        plant.step(np.sign(r) * speed)
    plant.step(np.zeros(6))


def check_poses(
    poses: np.ndarray, robot: RobotDescription, source: str | None = None
) -> np.ndarray:
    """``poses`` (N, 6) as floats, refused unless finite and within ``robot``'s joint limits;
    ``source``: the file they came from, named (with the pose's line-free number) in the error."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    if poses.ndim != 2 or poses.shape[1] != 6:
        raise CollectError(f"poses must have shape (N, 6), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise CollectError("poses contain NaN or inf")
    outside = ~robot.within_limits(poses)
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        if source is not None:
            raise CollectError(
                f"{source}: pose {i + 1} is outside the joint limits of {robot.name}: {poses[i]}"
            )
        raise CollectError(f"pose {i} is outside the joint limits: {poses[i]}")
    return poses


def collect_measurements(
    truth: EpisodeTruth | None = None,
    poses: np.ndarray | None = None,
    n: int = 100,
    scenario: str = "geometric",
    overrides: Mapping[str, Mapping[str, Any]] | None = None,
    noise_mm: float = 0.015,
    seed: int = 0,
    robot: str | RobotDescription = "seed",
    settle: float = 0.5,
    payloads: Sequence[float] | None = None,
    path: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    noise_ppm: float = 0.0,
    stations: int | Sequence[TrackerStation] = 0,
    orientation: bool = False,
    noise_mrad: float = 0.1,
    orientation_fraction: float = 1.0,
    stds: bool = False,
    tool_rotation: Sequence[float] | None = None,
    first_station: int = 1,
    approach: np.ndarray | None = None,
) -> MeasurementSet:
    """Simulate a calibration measurement campaign and return (and, with ``path``, write) it.

    ``truth``: an :class:`envs.scenarios.EpisodeTruth` to measure; without one it is drawn from
    ``scenario`` (and ``overrides``) for ``robot`` with ``seed``. ``poses`` (N, 6) encoder
    targets; without them ``n`` random poses within the limits with the tool above the floor.
    Each pose is reached by a transit to a point ``APPROACH`` rad before it on a random side,
    then a slow approach and ``settle`` seconds at rest; where the encoders missed the pose (the
    position loop sags under gravity) the reference is corrected and the pose approached again
    from the same side, until they read it within ``LANDING_TOL``; then a measurement with
    ``noise_mm`` per axis, plus ``noise_ppm`` um per metre of distance from the tracker.
    ``payloads`` (kg per pose) overrides the truth's payload. ``progress(i, n)`` is called
    after each pose. Deterministic for a given seed. ``approach`` (N, 6) of +-1: the side each
    joint approaches each pose from (the sign of its last motion, dir1..dir6), as a program
    states it; without it a random side (a joint near a limit approaches from the other side).

    ``stations``: 0, the world frame (the truth's measurement frame) itself, no station column;
    a number, that many stations placed around the arm (:func:`envs.instrument.place_stations`), or the
    stations themselves; the poses are measured in consecutive blocks, one per station, each in
    its station's frame, and the set gets a ``station`` column (ids ``first_station``, the next,
    ...: a held-out campaign from other stations of the same arm takes other ids).
    ``orientation``: a 6-DoF probe, mounted on the last link turned by ``tool_rotation`` (a
    rotation vector; default :data:`PROBE_ROTATION`), also measures the tool frame's orientation with
    ``noise_mrad`` per axis, in a random ``orientation_fraction`` of the rows (the others leave it
    blank). ``stds``: each row states its uncertainty (the std_x... columns): the sigma its noise
    was drawn with.

    The returned set has columns q1..q6 (the encoder readings at the measurement), x, y, z,
    t, temperature, payload and dir1..dir6 (the sign of each joint's last commanded motion).
    """
    from envs.scenarios import draw_truth

    try:
        rng = rng_from(seed, "seed")
        if poses is None:
            n = check_count(n, "n (poses to measure)")
    except SamplingError as exc:
        raise CollectError(str(exc)) from None
    truth_rng, pose_rng, motion_rng, noise_rng = rng.spawn(4)
    nominal = (robot if isinstance(robot, RobotDescription) else load_robot(robot)).to_modified()
    if truth is None:
        truth = draw_truth(scenario, nominal, truth_rng, overrides)
    nominal = truth.model.robot
    if poses is None:
        poses = sample_poses(nominal, int(n), pose_rng)
    poses = check_poses(poses, nominal)
    if approach is not None:
        approach = np.asarray(approach, dtype=float)
    _check_campaign(
        poses, payloads, approach, noise_mm, noise_ppm, noise_mrad, orientation_fraction
    )
    # campaigns beyond one 3-D point draw from a stream of their own: a plain campaign's numbers
    # stay those of a seed
    (campaign_rng,) = rng.spawn(1)
    placed = _stations(stations, campaign_rng)
    q_out, world, frames, columns = _measure_poses(
        truth, poses, settle, payloads, approach, motion_rng, progress
    )
    noise = noise_rng.normal(size=(len(poses), 3))  # drawn pose by pose, the same numbers
    sigma = noise_mm * 1e-3
    source = str(path) if path is not None else f"<simulated {truth.scenario} seed {seed}>"
    if placed is None and not noise_ppm and not orientation and not stds:
        xyz = world + sigma * noise  # a plain campaign, in the world frame
        data = MeasurementSet(q_out, xyz, columns, source=source)
    else:
        data = _beyond_points(
            q_out,
            world,
            noise,
            frames,
            columns,
            source,
            placed,
            campaign_rng,
            sigma,
            noise_ppm,
            noise_mrad if orientation else None,
            orientation_fraction,
            stds,
            tool_rotation,
            first_station,
        )
    if path is not None:
        write_measurements(data, path)
        log.info("wrote %d simulated measurements to %s", len(poses), path)
    return data


def _check_campaign(
    poses: np.ndarray,
    payloads: Sequence[float] | None,
    approach: np.ndarray | None,
    noise_mm: float,
    noise_ppm: float,
    noise_mrad: float,
    orientation_fraction: float,
) -> None:
    """The campaign's options agree with its poses and lie in range."""
    if payloads is not None and len(payloads) != len(poses):
        raise CollectError(f"{len(payloads)} payloads for {len(poses)} poses")
    if approach is not None:
        if approach.shape != poses.shape or not np.all(np.abs(approach) == 1.0):
            raise CollectError(f"approach must be +-1 of shape {poses.shape}")
    values = {
        "noise_mm": noise_mm,
        "noise_ppm": noise_ppm,
        "noise_mrad": noise_mrad,
        "orientation_fraction": orientation_fraction,
    }
    refuse(check(values, CAMPAIGN_RULES), CollectError)


def _stations(
    stations: int | Sequence[TrackerStation], rng: np.random.Generator
) -> list[TrackerStation] | None:
    """The tracker stations: a number placed around the arm (none for 0: the world frame), or
    those given."""
    if isinstance(stations, int):
        if stations < 0:
            raise CollectError(f"stations must be >= 0, got {stations}")
        return place_stations(stations, rng) if stations > 0 else None
    placed = list(stations)
    if not placed:
        raise CollectError("stations: an empty list")
    return placed


def _measure_poses(
    truth: EpisodeTruth,
    poses: np.ndarray,
    settle: float,
    payloads: Sequence[float] | None,
    approach: np.ndarray | None,
    motion_rng: np.random.Generator,
    progress: Callable[[int, int], None] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Drive the plant to each pose and let it settle: the encoder readings, the true tool
    points and frames, and the columns t, temperature, payload and dir1..dir6."""
    from envs.plant import Plant

    nominal = truth.model.robot
    plant = Plant(nominal, elastic=truth.hidden.needs_elastic)
    plant.configure(truth.true_robot, truth.hidden)
    lo, hi = nominal.lower, nominal.upper
    v_transit = TRANSIT_FRACTION * plant.drive.v_max
    d_transit = TRANSIT_FRACTION * plant.drive.a_max
    v_slow = np.full(6, APPROACH_SPEED)
    d_slow = np.full(6, APPROACH_DECEL)
    n_poses = len(poses)
    q_out = np.empty((n_poses, 6))
    world = np.empty((n_poses, 3))
    frames = np.empty((n_poses, 3, 3))
    cols = {c: np.empty(n_poses) for c in ("t", "temperature", "payload")}
    dirs = np.empty((n_poses, 6))
    plant.place(np.clip(poses[0] - APPROACH, lo, hi), dirs=np.ones(6))
    for i, q in enumerate(poses):
        side = motion_rng.choice((-1.0, 1.0), 6)  # drawn either way: the same stream
        if approach is not None:
            side = approach[i].copy()
        before = q - side * APPROACH
        side = np.where((before < lo) | (before > hi), -side, side)  # near a limit: other side
        before = q - side * APPROACH
        if payloads is not None:
            plant.set_payload(float(payloads[i]))
        _move(plant, before, v_transit, d_transit)
        # Like an industrial servo with integral action, land the encoders on the pose: the
        # position loop sags under gravity by up to ~8 mrad, so correct the reference by what is
        # left and approach again from the same side (the last motion, dir1..dir6, is kept).
        ref = q.copy()
        for attempt in range(LANDING_PASSES):
            if attempt:
                _move(plant, before + (ref - q), v_slow, d_slow)
            _move(plant, ref, v_slow, d_slow)
            for _ in range(max(1, math.ceil(settle / plant.dt))):
                plant.step(np.zeros(6))
            miss = q - plant.q
            if np.max(np.abs(miss)) < LANDING_TOL:
                break
            ref = ref + miss
        if plant.diverged():
            raise DivergedError(f"the simulation diverged at pose {i}: {q}")
        q_out[i] = plant.q
        world[i] = plant.tool_point()
        frames[i] = plant.tool_frame()
        cols["t"][i] = plant.time
        cols["temperature"][i] = plant.temperature
        cols["payload"][i] = plant.payload
        dirs[i] = plant.dirs
        if progress is not None:
            progress(i + 1, n_poses)
    columns = dict(cols)
    columns |= {f"dir{k + 1}": dirs[:, k] for k in range(6)}
    return q_out, world, frames, columns


def _beyond_points(
    q: np.ndarray,
    world: np.ndarray,
    noise: np.ndarray,
    frames: np.ndarray,
    columns: dict[str, np.ndarray],
    source: str,
    stations: list[TrackerStation] | None,
    rng: np.random.Generator,
    sigma: float,
    ppm: float,
    mrad: float | None,
    fraction: float,
    stds: bool,
    tool_rotation: Sequence[float] | None,
    first_station: int = 1,
    approach: np.ndarray | None = None,
) -> MeasurementSet:
    """The measured set of a campaign from stations, with distance-dependent noise, a 6-DoF
    probe and stated uncertainties (see :func:`collect_measurements`)."""
    n = len(q)
    if stations is None:
        stations = [TrackerStation((0.0, 0.0, 0.0))]
        which = np.zeros(n, dtype=int)
    else:
        which = (np.arange(n) * len(stations)) // n  # consecutive blocks, one per station
        columns = columns | {"station": which + float(first_station)}
    xyz = np.empty((n, 3))
    point_sigma = np.empty(n)
    rotations = np.empty((n, 3, 3))
    turn = None
    if mrad is not None:
        given = PROBE_ROTATION if tool_rotation is None else tool_rotation
        turn = rotation_matrix(np.asarray(given, dtype=float))
    for k, st in enumerate(stations):
        rows = which == k
        point_sigma[rows] = sigma + ppm * 1e-6 * st.distance(world[rows])
        xyz[rows] = st.points(world[rows]) + point_sigma[rows, None] * noise[rows]
        if turn is not None:
            rotations[rows] = st.rotations(frames[rows] @ turn)
    std = None
    if stds:
        std = np.full((n, 6), np.nan)
        std[:, :3] = point_sigma[:, None]
    if mrad is None:
        return MeasurementSet(q, xyz, columns, source=source, std=std)
    seen = rng.random(n) < fraction
    wobble = rng.normal(0.0, mrad * 1e-3, (n, 3))
    measured = rotation_vector(rotation_matrix(wobble) @ rotations)
    mask = np.zeros((n, 6), dtype=bool)
    mask[:, :3] = True
    mask[:, 3:] = seen[:, None]
    if std is not None:
        std[seen, 3:] = mrad * 1e-3
    return MeasurementSet(q, xyz, columns, source=source, orientation=measured, mask=mask, std=std)
