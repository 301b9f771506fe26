"""Diagnosis: a hidden effect at the low end of its typical magnitude (docs/format.md) is named, and
fitting what the diagnosis suggests brings held-out poses to the noise floor; clean data get "none"
at most 5 % of the time; an effect outside the catalogue is never called "none", the hints point at
its joint, and the user's own effect class explains it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from arm.effects import CATALOGUE, load_effect_module
from arm.measurements import MeasurementSet
from lab import diagnose, fit
from tests._lab_data import DIAGNOSE_KEYS, FLOOR_MM, SIGMA, campaign

NOISE_MM = 1e3 * SIGMA
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "second_harmonic.py"

HIDDEN = [
    ("compliance", (2, 3)),
    ("transmission", (1,)),
    ("joint_scale", (2, 3)),
    ("backlash", (2, 3)),
    ("load_backlash", (2, 3)),
    ("thermal", None),
]


@pytest.mark.parametrize(("effect", "joints"), HIDDEN, ids=[h[0] for h in HIDDEN])
@pytest.mark.parametrize("seed_", [0, 1])
def test_a_hidden_effect_is_named_and_fitting_it_reaches_the_floor(seed, effect, joints, seed_):
    spec = effect if joints is None else f"{effect}[{','.join(map(str, joints))}]"
    c = campaign(seed, f"geometric,{spec}", seed=100 + seed_)
    data, val = c.measure(200), c.measure(300)
    d = diagnose(data, seed, "geometric", noise_mm=NOISE_MM)
    assert d.verdict == effect
    assert d.candidates[0].effect == effect and d.candidates[0].significant
    assert d.candidates[0].p_value < 1e-50  # far from the 2 % / 30 candidates threshold
    first = d.explanation[0]
    assert first.effect == effect
    if joints is not None:
        assert set(joints) <= set(first.joints)
    geometric_only = fit(data, seed, "geometric", validate=val)
    assert geometric_only.validation_rms_mm > 1.3 * FLOOR_MM  # the effect matters at this size
    res = fit(data, seed, d.suggestion, validate=val)
    assert res.validation_rms_mm < 1.2 * FLOOR_MM


def test_clean_data_verdict_none(seed):
    for s in range(5):
        c = campaign(seed, "geometric", seed=200 + s)
        d = diagnose(c.measure(200), seed, "geometric", noise_mm=NOISE_MM)
        assert d.verdict == "none", (s, d.summary())


@pytest.mark.slow
def test_false_alarm_rate_on_clean_data_is_at_most_five_percent(seed):
    seeds = range(1000, 1200)
    alarms = []
    for s in seeds:
        c = campaign(seed, "geometric", seed=s)
        d = diagnose(c.measure(200), seed, "geometric", noise_mm=NOISE_MM)
        if d.verdict != "none":
            alarms.append((s, d.verdict))
    assert len(alarms) <= 0.05 * len(seeds), alarms


@pytest.mark.parametrize("joint", [2, 3, 5])
def test_an_effect_outside_the_catalogue(seed, joint, user_effects):
    """A second-harmonic transmission error on one joint: the catalogue cannot name it (or can
    only approximate it), the hints point at the joint, and the user's effect class fits it."""
    load_effect_module(EXAMPLE)
    c = campaign(seed, f"geometric,second_harmonic[{joint}]", seed=300 + joint)
    data, val = c.measure(200), c.measure(300)
    d = diagnose(data, seed, "geometric", noise_mm=NOISE_MM, candidates=CATALOGUE)
    assert d.verdict != "none"
    assert d.hints[0].variable == f"q{joint}"
    assert d.hints[0].p_value < 1e-6
    # with the user's effect among the candidates, it is the explanation
    d2 = diagnose(data, seed, "geometric", noise_mm=NOISE_MM)
    assert d2.verdict == "second_harmonic"
    assert d2.explanation[0].joints == (joint,)
    res = fit(data, seed, f"geometric,second_harmonic[{joint}]", validate=val)
    assert res.validation_rms_mm < 1.2 * FLOOR_MM


def test_unexplained_when_nothing_in_the_catalogue_fits(seed, user_effects):
    """A 2nd harmonic on joint 1 (the example module's effect): no effect tested whole explains
    it, and the cyclic errors' scan names its joint and order."""
    load_effect_module(EXAMPLE)
    c = campaign(seed, "geometric,second_harmonic[1]", seed=310)
    data = c.measure(200)
    whole = [n for n in CATALOGUE if n != "cyclic"]
    d = diagnose(data, seed, "geometric", noise_mm=NOISE_MM, candidates=whole)
    assert d.verdict == "unexplained"
    assert d.chi2_p_value < 1e-6
    assert d.hints[0].variable == "q1"
    scanned = diagnose(data, seed, "geometric", noise_mm=NOISE_MM, candidates=CATALOGUE)
    assert scanned.verdict == "cyclic", scanned.summary()
    assert scanned.suggestion == "geometric,cyclic[1:2]"


def test_a_robust_diagnosis_leaves_outliers_out(seed):
    c = campaign(seed, "geometric,compliance[2,3]", seed=404)
    d = c.measure(200)
    planted = np.array([3, 50, 120, 177])
    xyz = d.xyz.copy()
    xyz[planted] += [1e-3, -0.6e-3, 0.8e-3]
    data = MeasurementSet(d.q, xyz, d.columns)
    plain = diagnose(data, seed, "geometric", noise_mm=NOISE_MM, outliers="keep")
    assert plain.verdict == "unexplained"  # least squares: the outliers swamp the tests
    robust = diagnose(data, seed, "geometric", noise_mm=NOISE_MM, loss="huber", outliers="keep")
    assert set(planted) <= set(robust.outliers) and len(robust.outliers) <= 6
    assert robust.verdict == "compliance"
    assert [o["row"] for o in robust.to_dict()["outliers"]] == [int(i) + 1 for i in robust.outliers]
    # the default leaves them out of the fit and the tests: exactly those, by row
    auto = diagnose(data, seed, "geometric", noise_mm=NOISE_MM)
    assert auto.verdict == "compliance"
    assert list(auto.outliers) == list(planted)
    assert [o["row"] for o in auto.to_dict()["outliers"]] == [int(i) + 1 for i in planted]


def test_json_shape(seed):
    c = campaign(seed, "geometric,compliance[2,3]", seed=400)
    d = diagnose(c.measure(200), seed, "geometric", noise_mm=NOISE_MM)
    out = json.loads(json.dumps(d.to_dict(), allow_nan=False))
    assert DIAGNOSE_KEYS <= set(out)
    assert out["verdict"] == "compliance"
    assert out["noise_floor_mm"] == pytest.approx(FLOOR_MM)
    assert out["effects"] == ["geometric"]
    for cand in out["candidates"]:
        assert {"effect", "joints", "rms_mm", "p_value", "significant"} <= set(cand)
        assert cand["joints"] is None or all(1 <= j <= 6 for j in cand["joints"])
    assert out["candidates"][0]["rms_mm"] < out["rms_mm"]
    names = [h["variable"] for h in out["hints"]]
    assert {"q1", "tau2", "dir3", "temperature"} <= set(names)
    assert all(set(h) >= {"variable", "score"} for h in out["hints"])
    scores = [h["score"] for h in out["hints"]]
    assert scores == sorted(scores, reverse=True)
    # the model to fit next starts with the effect found (a chance addition after it is possible
    # at the family-wise level; this data set has one, backlash at p = 0.0007 over 30 candidates)
    assert out["suggestion"].startswith("geometric,compliance[2,3]")


def test_candidates_that_cannot_be_tested_are_skipped_with_the_reason(seed):
    c = campaign(seed, "geometric", seed=401)
    full = c.measure(200)
    data = MeasurementSet(full.q, full.xyz)  # no dir, no temperature
    d = diagnose(data, seed, "geometric")
    assert "dir1" in d.skipped["backlash"] and "temperature" in d.skipped["thermal"]
    tested = {(x.effect, x.joints) for x in d.candidates}
    assert ("compliance", (1,)) not in tested and ("compliance", (6,)) not in tested
    assert "compliance[1]" in d.skipped  # no gravity torque about joint 1: nothing to test
    assert d.noise_floor_mm is None and d.chi2_p_value is None
    assert d.verdict == "none"


def test_diagnosing_a_model_that_has_part_of_an_effect(seed):
    """Compliance fitted on joint 2 only: the diagnosis finds joint 3 missing."""
    c = campaign(seed, "geometric,compliance[2,3]", seed=402)
    d = diagnose(c.measure(200), seed, "geometric,compliance[2]", noise_mm=NOISE_MM)
    assert d.verdict == "compliance"
    assert d.explanation[0].joints == (3,)
    assert d.suggestion == "geometric,compliance[2,3]"


def test_same_data_same_diagnosis(seed):
    c = campaign(seed, "geometric,load_backlash[2,3]", seed=403)
    data = c.measure(150)
    a = diagnose(data, seed, "geometric", noise_mm=NOISE_MM).to_dict()
    b = diagnose(data, seed, "geometric", noise_mm=NOISE_MM).to_dict()
    assert a == b
    assert np.isfinite(a["cv_rms_mm"])
