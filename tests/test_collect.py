"""Simulated lab collection: a valid measurement file (docs/format.md, the measurement CSV) with
every optional column, made by the plant's physics and explained by the truth's error model."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from arm import read_measurements, seed_robot
from arm.errormodel import ErrorModel
from arm.sampling import sample_poses
from envs.collect import collect_measurements
from envs.scenarios import draw_truth

ROBOT = seed_robot()
COLUMNS = {"t", "temperature", "payload", *(f"dir{k}" for k in range(1, 7))}


def test_collect_writes_a_spec_file_that_reads_back(tmp_path):
    path = tmp_path / "sim.csv"
    data = collect_measurements(n=12, scenario="all", seed=3, path=path)
    back = read_measurements(path)
    assert len(back) == len(data) == 12
    assert set(back.columns) == COLUMNS
    assert np.array_equal(back.q, data.q) and np.array_equal(back.xyz, data.xyz)
    for c in COLUMNS:
        assert np.array_equal(back.columns[c], data.columns[c])
    header = path.read_text().splitlines()[0].split(",")
    assert header[:9] == ["q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z"]
    dirs = np.column_stack([data.columns[f"dir{k}"] for k in range(1, 7)])
    assert set(np.unique(dirs)) == {-1.0, 1.0}
    assert np.all((dirs == 1).any(axis=0) & (dirs == -1).any(axis=0))  # every joint both ways
    t = data.columns["t"]
    assert np.all(np.diff(t) > 0)
    assert np.ptp(data.columns["temperature"]) > 0.1  # the arm warms up as it works
    assert np.all(data.xyz[:, 2] > 0.1)


def test_collect_is_deterministic_and_noise_is_as_asked():
    truth = draw_truth("geometric", ROBOT, np.random.default_rng(1))
    a = collect_measurements(truth, n=8, seed=5, noise_mm=0.0)
    b = collect_measurements(truth, n=8, seed=5, noise_mm=0.0)
    c = collect_measurements(truth, n=8, seed=5, noise_mm=0.05)
    assert np.array_equal(a.xyz, b.xyz) and np.array_equal(a.q, b.q)
    # noise-free rigid arm: the measured point is the true kinematic model's exactly
    pred = truth.model.predict(truth.model.inputs(a.q), truth.params)
    assert np.abs(pred - a.xyz).max() < 1e-9
    d = c.xyz - a.xyz
    assert 0.01e-3 < d.std() < 0.1e-3


@pytest.mark.parametrize(
    "scenario, tol_um",
    [
        ("compliance", 3.0),
        ("transmission", 3.0),
        ("thermal", 1e-3),
        ("payload", 3.0),
        ("cyclic", 3.0),
    ],
)
def test_truth_model_explains_what_the_plant_made(scenario, tol_um):
    """The lab's formulas (ErrorModel with the truth's parameters) reproduce the points that the
    plant's physics produced, while a geometric-only model cannot: the effect is really there,
    and the plant and the lab agree on it without sharing code."""
    truth = draw_truth(scenario, ROBOT, np.random.default_rng(4))
    data = collect_measurements(truth, n=10, seed=2, noise_mm=0.0)
    inputs = truth.model.inputs(data.q, data.columns)
    res = np.linalg.norm(truth.model.predict(inputs, truth.params) - data.xyz, axis=1)
    assert res.max() < tol_um * 1e-6
    geo = ErrorModel(ROBOT, "geometric")
    p_geo = truth.params[truth.model.layout.slice("geometric")]
    res_geo = np.linalg.norm(geo.predict(geo.inputs(data.q), p_geo) - data.xyz, axis=1)
    assert np.sqrt(np.mean(res_geo**2)) > 50e-6


def test_backlash_follows_the_last_direction_where_friction_holds():
    """Joints held by friction (1, 6 on the seed arm) lag their last motion: the backlash model
    with the recorded dir columns explains the points far better than without them."""
    truth = draw_truth(
        "backlash", ROBOT, np.random.default_rng(5), overrides={"backlash": {"bl": 6e-4}}
    )
    assert truth.magnitudes["backlash_kind"][1] == "friction"
    assert truth.magnitudes["backlash_kind"][2] == "load"
    data = collect_measurements(truth, n=12, seed=3, noise_mm=0.0)
    inputs = truth.model.inputs(data.q, data.columns)
    res = np.linalg.norm(truth.model.predict(inputs, truth.params) - data.xyz, axis=1)
    flipped = {k: -v for k, v in data.columns.items() if k.startswith("dir")}
    wrong = truth.model.inputs(data.q, data.columns | flipped)
    res_wrong = np.linalg.norm(truth.model.predict(wrong, truth.params) - data.xyz, axis=1)
    assert np.median(res) < 10e-6
    assert np.median(res_wrong) > 5 * np.median(res)


@pytest.mark.parametrize("scenario", ["geometric", "compliance", "backlash"])
def test_requested_poses_are_where_the_encoders_settle(scenario):
    """A planned pose is measured there: the servo's sag under gravity (mrad) is corrected, like
    an industrial servo's integral action, while each joint still arrives from its random side."""
    poses = sample_poses(ROBOT, 10, np.random.default_rng(11))
    data = collect_measurements(poses=poses, scenario=scenario, seed=2, noise_mm=0.0)
    assert np.max(np.abs(data.q - poses)) < 1e-4
    dirs = np.column_stack([data.columns[f"dir{j}"] for j in range(1, 7)])
    assert 0.2 < np.mean(dirs > 0) < 0.8  # both sides, as drawn


def test_a_stated_approach_is_the_side_each_joint_arrives_from():
    """A program states each joint's approach (benchmarks/compensation.py: dir1..dir6 = +1 for
    backlash): the recorded dir columns are it, and the encoders still land on the poses."""
    poses = sample_poses(ROBOT, 6, np.random.default_rng(12))
    inside = (poses > ROBOT.lower + 0.1) & (poses < ROBOT.upper - 0.1)
    poses = poses[inside.all(axis=1)]
    approach = np.where(np.arange(6) % 2, 1.0, -1.0) * np.ones((len(poses), 6))
    approach[0] = 1.0
    data = collect_measurements(poses=poses, scenario="backlash", seed=2, approach=approach)
    dirs = np.column_stack([data.columns[f"dir{j}"] for j in range(1, 7)])
    np.testing.assert_array_equal(dirs, approach)
    assert np.max(np.abs(data.q - poses)) < 1e-4
    with pytest.raises(ValueError, match="approach must be"):
        collect_measurements(poses=poses, scenario="geometric", approach=approach[:, :3])


def test_bad_poses_are_refused():
    bad = np.zeros((2, 6))
    bad[1, 1] = 3.0  # beyond joint 2's upper limit
    with pytest.raises(ValueError, match="pose 1 is outside the joint limits"):
        collect_measurements(poses=bad, scenario="geometric")
    with pytest.raises(ValueError, match="shape"):
        collect_measurements(poses=np.zeros((3, 5)), scenario="geometric")


def test_importing_collect_has_no_side_effects():
    code = "import sys, envs.collect; print('mujoco' in sys.modules)"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=os.environ
    )
    assert out.stdout.strip() == "False"
