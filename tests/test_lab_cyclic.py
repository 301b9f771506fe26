"""Cyclic joint errors through the lab: found by joint and order (diagnose and discover), fitted
to the noise floor, and the lab's honest verdicts about the noise (repeated poses, a stated noise
below the real one)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arm import seed_robot
from arm.effects import load_effect_module
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from arm.sampling import sample_parameters, sample_poses
from lab import diagnose, discover, fit

SEED = seed_robot()
SIGMA = 15e-6
FLOOR_MM = 1e3 * SIGMA * math.sqrt(3)


def _campaign(spec: str, seed: int, n: int = 300, sigma: float = SIGMA, n_val: int = 500):
    rng = np.random.default_rng(seed)
    truth = ErrorModel(SEED, spec)
    p = sample_parameters(truth, rng)

    def measure(m):
        q = sample_poses(SEED, m, rng)
        xyz = truth.predict(truth.inputs(q), p) + rng.normal(0.0, sigma, (m, 3))
        return MeasurementSet(q, xyz, {}, "simulated")

    return measure(n), measure(n_val), truth, p


@pytest.mark.parametrize(
    "hidden, seed",
    [
        ("cyclic[2:37;4:23]", 1),
        pytest.param("cyclic[1:11;3:40]", 2, marks=pytest.mark.slow),
        pytest.param("cyclic[3:29;5:6]", 3, marks=pytest.mark.slow),
    ],
)
def test_high_orders_are_found_exactly_and_fitted_to_the_noise_floor(
    hidden, seed, tmp_path, user_effects
):
    """Orders up to 40 on two joints, 15 um noise, 300 random poses: discover finds the joints
    and orders, its module reaches the floor on held-out poses and leaves nothing to diagnose;
    the diagnosis names the same cyclic errors, and its suggestion fits as well."""
    data, val, _, _ = _campaign(f"geometric,{hidden}", seed)
    dg = diagnose(data, SEED, "geometric", noise_mm=1e3 * SIGMA)
    assert dg.verdict == "cyclic" and dg.suggestion == f"geometric,{hidden}", dg.summary()
    assert dg.readings  # what such orders usually are
    res = fit(data, SEED, dg.suggestion, validate=val, noise_mm=1e3 * SIGMA)
    assert res.validation_rms_mm <= 1.2 * FLOOR_MM
    d = discover(data, SEED, "geometric", noise_mm=1e3 * SIGMA, validate=val)
    assert d.verdict == "discovered", d.summary()
    assert d.scan is not None and d.scan.spec == hidden
    assert d.validation_rms_mm <= 1.2 * FLOOR_MM
    load_effect_module(d.write_module(tmp_path / "found.py"))
    again = diagnose(data, SEED, d.suggestion, noise_mm=1e3 * SIGMA)
    assert again.verdict == "none", again.summary()


def test_a_stated_noise_below_the_real_one_is_said_with_the_noise_the_data_imply():
    """Nothing missing, but 15.9 um of real noise against 15 um stated: the verdict is noise
    (not unexplained), with the per-axis noise the residual implies."""
    data, _, _, _ = _campaign("geometric", 0, n=1000, sigma=15.9e-6, n_val=1)
    d = diagnose(data, SEED, "geometric", noise_mm=0.015)
    assert d.verdict == "noise", d.summary()
    assert d.implied_noise_mm == pytest.approx(0.0159, rel=0.03)
    assert "above the stated 0.015 mm" in (d.noise_note or "")
    assert d.to_dict()["implied_noise_mm"] == d.implied_noise_mm
    disc = discover(data, SEED, "geometric", noise_mm=0.015)
    assert disc.verdict == "noise" and disc.terms == []
    assert disc.implied_noise_mm == pytest.approx(0.0159, rel=0.03)
    # the right noise: nothing to say
    assert diagnose(data, SEED, "geometric", noise_mm=0.0159).verdict == "none"


def test_repeated_poses_give_the_noise_floor_when_none_is_stated():
    """100 poses measured three more times: their scatter is the noise the tests use without
    --noise-mm (an F-test, since it is estimated too); stated, it is shown beside it."""
    data, _, truth, p = _campaign("geometric", 5, n=300, sigma=SIGMA, n_val=1)
    rng = np.random.default_rng(6)
    qr = np.repeat(data.q[:100], 3, axis=0)
    xyz = truth.predict(truth.inputs(qr), p) + rng.normal(0.0, SIGMA, (300, 3))
    both = MeasurementSet(np.vstack([data.q, qr]), np.vstack([data.xyz, xyz]), {}, "simulated")
    d = diagnose(both, SEED, "geometric")
    assert d.noise_source == "repeated poses" and d.verdict == "none", d.summary()
    rep = d.repeatability
    assert rep is not None and rep.groups == 100 and rep.repeats == 400 and rep.dof == 900
    lo, hi = rep.interval_mm()
    assert lo <= 1e3 * SIGMA <= hi and d.noise_mm == rep.sigma_mm
    assert d.to_dict()["repeatability"]["groups"] == 100
    stated = diagnose(both, SEED, "geometric", noise_mm=0.015)
    assert stated.noise_source == "stated" and stated.repeatability == rep
    disc = discover(both, SEED, "geometric")
    assert disc.noise_source == "repeated poses" and disc.verdict == "none"
    # no pose repeated: no repeatability, no noise
    assert diagnose(data, SEED, "geometric").repeatability is None
