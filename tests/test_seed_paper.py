"""The seed paper's experiment (examples/seed_paper.py): Table 2's errors identified from 20
Sobol poses meet the issue's targets, and the mapping of the paper's rods is the one stated."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from arm.description import seed_robot
from arm.errormodel import ErrorModel

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "seed_paper.py"


def _module():
    spec = importlib.util.spec_from_file_location("seed_paper", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_true_arm_carries_table_2_by_the_stated_mapping():
    """Checked against the geometric effect's own parameters (an independent route): the
    true arm's points equal the seed arm's with Table 2's errors as dd, dtheta, da, dalpha and
    rod 6's as the tool offset."""
    sp = _module()
    robot = seed_robot()
    truth = sp.true_arm(robot)
    m = ErrorModel(robot, "geometric")
    p = m.nominal()
    for rod, (dxi, dbeta, dD, domega) in sp.TABLE2.items():
        if rod != 3:
            p[m.layout.index(f"dd{rod}")] += dD * 1e-3
        p[m.layout.index(f"dtheta{rod}")] += domega
        if rod < 6:
            p[m.layout.index(f"da{rod + 1}")] += dxi * 1e-3
            p[m.layout.index(f"dalpha{rod + 1}")] += dbeta
    p[m.layout.index("dd2")] += sp.TABLE2[3][2] * 1e-3  # d3 on the parallel pair
    dxi6, dbeta6 = sp.TABLE2[6][0], sp.TABLE2[6][1]
    p[m.layout.indices(["tx", "ty", "tz"])] += [
        dxi6 * 1e-3,
        -0.05 * math.sin(dbeta6),
        0.05 * (math.cos(dbeta6) - 1),
    ]
    q = sp.sobol_poses(robot, 50)
    a = sp.points(truth, q)
    b = m.predict(m.inputs(q), p)
    # d3 along z3 instead of z2 differs by d3 * dalpha3 (0.12 mm x 0.9 mrad)
    assert np.max(np.abs(a - b)) < 2e-7


def test_sobol_poses_are_within_the_limits_and_above_the_floor():
    sp = _module()
    robot = seed_robot()
    q = sp.sobol_poses(robot, 20)
    assert q.shape == (20, 6)
    assert robot.within_limits(q).all()
    assert (sp.points(robot, q)[:, 2] > 0.15).all()
    np.testing.assert_array_equal(q, sp.sobol_poses(robot, 20))  # same seed, same poses


@pytest.mark.slow
def test_the_seed_paper_reproduced_meets_its_targets(tmp_path):
    sp = _module()
    r = sp.run(tmp_path)
    on_disk = json.loads((tmp_path / "seed_paper.json").read_text())
    assert on_disk["peak_after_mm"] == r["peak_after_mm"]
    assert (tmp_path / "seed_paper.png").stat().st_size > 10_000
    assert "Fig. 8" in (tmp_path / "seed_paper.md").read_text()
    assert set(r["peak_before_mm"]) == set(r["peak_after_mm"]) == {"x", "y", "z"}
    assert max(r["peak_before_mm"].values()) > 1.0  # Table 2's errors matter
    assert max(r["peak_after_mm"].values()) <= 0.1  # with 15 um noise (the paper: 0.42)
    assert max(r["peak_after_without_noise_mm"].values()) < 1e-3  # under 1 um
    for p in r["parameters"]:
        assert {"name", "preset", "identified", "std", "identifiable"} <= set(p)
        if p["identifiable"]:
            assert abs(p["identified"] - p["equivalent_preset"]) <= 3 * p["std"], p
    fixed = {p["name"] for p in r["parameters"] if not p["identifiable"]}
    assert {"dd3", "dd6", "dtheta6"} <= fixed
    assert set(r["unidentifiable"]) == fixed
