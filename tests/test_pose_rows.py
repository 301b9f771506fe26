"""benchmarks/pose_rows.py: the weights of a 6-DoF fit without stated uncertainties, estimated
by variance components, recover the noise a simulated campaign was drawn with; the Rokae set's
6-DoF rows against its positions alone, both leave-one-out (with SIXAXIS_REAL_DATA)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arm.description import seed_robot
from arm.measurements import read_measurements
from arm.noise import InstrumentNoise
from benchmarks.pose_rows import pose_rows, summary_lines, variance_components
from tests._beyond_points import pose_campaign
from tests._lab_data import REAL, real_arm, requires_real_data


def test_variance_components_recover_the_noise_drawn():
    c = pose_campaign(seed_robot(), seed=2)
    c.noise = InstrumentNoise(mm=0.03, mrad=0.2)  # one sigma each, stated nowhere in the file
    data, _ = c.measure(80, stations=(1,), stds=False)
    s_mm, s_mrad, res = variance_components(data, seed_robot())
    assert s_mm == pytest.approx(0.03, rel=0.2) and s_mrad == pytest.approx(0.2, rel=0.2)
    assert res.orientation_rms_mrad is not None


def test_the_comparison_is_paired_and_leave_one_out():
    c = pose_campaign(seed_robot(), seed=3)
    c.noise = InstrumentNoise(mm=0.03, mrad=0.05)
    data, _ = c.measure(24, stations=(1,), stds=False)
    rows, s = pose_rows(data, seed_robot())
    assert s["folds"] == 24 and rows[0]["model"] == "geometric, 6-DoF rows"
    assert rows[0]["rms_mm"] == s["six_dof"]["rms_mm"]
    assert s["rank"]["six_dof"] > s["rank"]["positions_only"]
    assert math.isfinite(s["paired_se_mm2"]) and s["paired_se_mm2"] > 0
    assert any("leave-one-out" in line for line in summary_lines(s))


@requires_real_data
def test_the_rokae_set_with_its_orientation():
    assert REAL is not None
    data = read_measurements(REAL / "measurements.csv")
    if not data.has_orientation:
        pytest.skip(f"{REAL}/measurements.csv has no orientation (convert it again)")
    robot = real_arm()
    _, s = pose_rows(data, robot)
    # 30 poses: the orientation identifies more (the tool frame's rotation, dtheta6...)
    assert s["folds"] == 30 and s["rank"]["six_dof"] > s["rank"]["positions_only"]
    assert s["condition_number"]["six_dof"] < s["condition_number"]["positions_only"]
    # measured: 0.1229 mm against 0.1182 mm, no ordering resolved (paired)
    for k in ("six_dof", "positions_only"):
        assert 0.05 < s[k]["rms_mm"] < 0.3
    assert np.isfinite(s["held_out_orientation_rms_mrad"])
