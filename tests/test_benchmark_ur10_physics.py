"""benchmarks/ur10_physics.py: the station's scale it reports is the similarity's, and the study
regenerates the tables docs/lab.md quotes (issue 32, Deliver 5)."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from benchmarks.ur10_physics import MODELS, main, similarity


def test_the_similarity_recovers_a_known_scale_rotation_and_shift():
    rng = np.random.default_rng(0)
    pred = rng.uniform(-1.0, 1.0, (200, 3))
    rot = Rotation.from_rotvec([0.1, -0.2, 0.3])
    meas = (1 + 400e-6) * rot.apply(pred) + np.array([2.0, -1.0, 0.5])
    s, e = similarity(pred, meas)
    assert s == pytest.approx(1 + 400e-6, abs=1e-12)
    assert np.abs(e).max() < 1e-12


def test_the_similarity_is_the_least_squares_one_with_noise():
    """Against a general least-squares solve of the seven parameters (scale, rotation vector,
    shift): the same scale and residual."""
    rng = np.random.default_rng(1)
    pred = rng.uniform(-1.0, 1.0, (100, 3))
    meas = 0.9997 * Rotation.from_rotvec([0.3, 0.1, -0.2]).apply(pred) + 0.4
    meas = meas + 1e-3 * rng.standard_normal(meas.shape)
    s, e = similarity(pred, meas)

    def residual(x):
        return (x[0] * Rotation.from_rotvec(x[1:4]).apply(pred) + x[4:] - meas).ravel()

    ref = least_squares(residual, np.r_[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], xtol=1e-15)
    assert s == pytest.approx(ref.x[0], abs=1e-9)
    assert np.sum(e**2) == pytest.approx(np.sum(ref.fun**2), rel=1e-9)


@pytest.mark.slow
def test_the_study_writes_every_table_docs_quote(tmp_path):
    loggers = [logging.getLogger(n) for n in ("lab", "arm")]
    levels = [g.level for g in loggers]
    try:
        assert main(["--out", str(tmp_path)]) == 0
    finally:  # the script quiets the lab's loggers; other tests read them
        for g, level in zip(loggers, levels, strict=True):
            g.setLevel(level)
    report = json.loads((tmp_path / "ur10_physics.json").read_text())
    assert [r["model"] for r in report["all_three"]] == list(MODELS)
    assert [f["left_out"] for f in report["leave_one_out"]] == ["A", "B", "D"]
    # compliance of the loaded joints transfers: every left-out series is predicted better
    for f in report["leave_one_out"]:
        geo = f["models"]["geometric"]["held_out_rms_mm"]
        assert f["models"]["geometric,compliance[2,3]"]["held_out_rms_mm"] < geo
        assert f["station"]["similarity_rms_mm"] <= f["station"]["rigid_rms_mm"]
    text = (tmp_path / "ur10_physics.md").read_text()
    assert "**The tracker's station**" in text and "**The geometry itself**" in text
    # what the left-out session changed: the nested refits never do worse than the base alone,
    # and every geometric row moved reaches the series' own fit of the model
    for m in report["what_moved"]:
        base = m["groups"]["the base alone"]["rms_mm"]
        rows = m["groups"]["every geometric row and the tool"]["rms_mm"]
        assert all(g["rms_mm"] <= base + 1e-4 for g in m["groups"].values())
        assert m["own_fit_rms_mm"] - 1e-3 <= rows <= base
