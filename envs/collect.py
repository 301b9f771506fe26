"""Measurements for the lab from the simulated arm: drive the MuJoCo plant to a list of poses, each
approached from a random direction so that dir1..dir6 vary, let it settle, and measure the tool
point with the laser tracker. The result is a measurement set (docs/format.md, the measurement
CSV) with every optional column (t, temperature, payload, dir1..dir6).

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

from arm.description import RobotDescription, load_robot
from arm.errors import SixAxisError
from arm.measurements import MeasurementSet, write_measurements
from arm.sampling import sample_poses

if TYPE_CHECKING:
    from envs.scenarios import EpisodeTruth

__all__ = ["CollectError", "collect_measurements"]

log = logging.getLogger(__name__)


class CollectError(SixAxisError, ValueError):
    """Poses or payloads that cannot be measured: a wrong shape, NaN, outside the joint limits."""


APPROACH = 0.03  # rad: each joint's last move towards the pose
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
) -> MeasurementSet:
    """Simulate a calibration measurement campaign and return (and, with ``path``, write) it.

    ``truth``: an :class:`envs.scenarios.EpisodeTruth` to measure; without one it is drawn from
    ``scenario`` (and ``overrides``) for ``robot`` with ``seed``. ``poses`` (N, 6) encoder
    targets; without them ``n`` random poses within the limits with the tool above the floor.
    Each pose is reached by a transit to a point ``APPROACH`` rad before it on a random side,
    then a slow approach and ``settle`` seconds at rest; where the encoders missed the pose (the
    position loop sags under gravity) the reference is corrected and the pose approached again
    from the same side, until they read it within ``LANDING_TOL``; then a measurement with
    ``noise_mm`` per axis. ``payloads`` (kg per pose) overrides the truth's payload. ``progress(i, n)`` is called
    after each pose. Deterministic for a given seed.

    The returned set has columns q1..q6 (the encoder readings at the measurement), x, y, z,
    t, temperature, payload and dir1..dir6 (the sign of each joint's last commanded motion).
    """
    from envs.plant import Plant
    from envs.scenarios import draw_truth

    rng = np.random.default_rng(seed)
    truth_rng, pose_rng, motion_rng, noise_rng = rng.spawn(4)
    nominal = (robot if isinstance(robot, RobotDescription) else load_robot(robot)).to_modified()
    if truth is None:
        truth = draw_truth(scenario, nominal, truth_rng, overrides)
    nominal = truth.model.robot
    if poses is None:
        poses = sample_poses(nominal, int(n), pose_rng)
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    if poses.ndim != 2 or poses.shape[1] != 6:
        raise CollectError(f"poses must have shape (N, 6), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise CollectError("poses contain NaN or inf")
    outside = ~nominal.within_limits(poses)
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        raise CollectError(f"pose {i} is outside the joint limits: {poses[i]}")
    if payloads is not None and len(payloads) != len(poses):
        raise CollectError(f"{len(payloads)} payloads for {len(poses)} poses")

    plant = Plant(nominal, elastic=truth.hidden.needs_elastic)
    plant.configure(truth.true_robot, truth.hidden)
    lo, hi = nominal.lower, nominal.upper
    v_transit = TRANSIT_FRACTION * plant.drive.v_max
    d_transit = TRANSIT_FRACTION * plant.drive.a_max
    v_slow = np.full(6, APPROACH_SPEED)
    d_slow = np.full(6, APPROACH_DECEL)
    sigma = noise_mm * 1e-3

    n_poses = len(poses)
    q_out = np.empty((n_poses, 6))
    xyz = np.empty((n_poses, 3))
    cols = {c: np.empty(n_poses) for c in ("t", "temperature", "payload")}
    dirs = np.empty((n_poses, 6))
    plant.place(np.clip(poses[0] - APPROACH, lo, hi), dirs=np.ones(6))
    for i, q in enumerate(poses):
        side = motion_rng.choice((-1.0, 1.0), 6)
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
            raise RuntimeError(f"the simulation diverged at pose {i}: {q}")
        q_out[i] = plant.q
        xyz[i] = plant.tool_point() + sigma * noise_rng.normal(size=3)
        cols["t"][i] = plant.time
        cols["temperature"][i] = plant.temperature
        cols["payload"][i] = plant.payload
        dirs[i] = plant.dirs
        if progress is not None:
            progress(i + 1, n_poses)
    columns = dict(cols)
    columns |= {f"dir{k + 1}": dirs[:, k] for k in range(6)}
    source = str(path) if path is not None else f"<simulated {truth.scenario} seed {seed}>"
    data = MeasurementSet(q_out, xyz, columns, source=source)
    if path is not None:
        write_measurements(data, path)
        log.info("wrote %d simulated measurements to %s", n_poses, path)
    return data
