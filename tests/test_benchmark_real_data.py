"""benchmarks/real_data.py and ur10_sessions.py: a UR10 series of a station the calibration has
not seen is scored through a frame registered on separate reference poses, never on the rows
scored (issue 38, Deliver 6), and the targets are judged as the issue states them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

import lab
from benchmarks.real_data import UR10, UR10_REFERENCES, _read, reference_split, validated
from benchmarks.ur10_physics import similarity
from benchmarks.ur10_sessions import summarise, targets


@pytest.fixture(scope="module")
def b_and_d():
    b = _read(UR10 / "series_B.csv", "B").subset(np.arange(0, 1495, 5))
    d = _read(UR10 / "series_D.csv", "D").subset(np.arange(0, 632, 3))
    return b, d


def test_a_new_station_is_registered_on_references_that_are_not_scored(b_and_d):
    b, d = b_and_d
    res = lab.fit(b, "ur10_robot", "geometric", noise_mm=0.015, noise_ppm=6.0)
    v = validated(res, d)
    refs, rest = reference_split(d)
    assert v.validation_registered == (4,)
    assert len(refs) == UR10_REFERENCES and len(v.validation_residuals) == len(rest)
    # the scored rows are the rest, not the references: their measured points, residual added,
    # are the predictions of the arm registered on the references alone
    assert not np.isin(refs.xyz[:, 0], rest.xyz[:, 0]).any()
    same = res.validate(rest, references=refs)
    np.testing.assert_allclose(v.validation_residuals, same.validation_residuals)
    # a station the fit has: every row scored, through its fitted base
    own = validated(res, b)
    assert own.validation_registered == () and len(own.validation_residuals) == len(b)


def test_the_rigid_motion_is_the_least_squares_one():
    rng = np.random.default_rng(2)
    pred = rng.uniform(-1.0, 1.0, (100, 3))
    meas = 0.9997 * Rotation.from_rotvec([0.3, 0.1, -0.2]).apply(pred) + 0.4
    meas = meas + 1e-3 * rng.standard_normal(meas.shape)
    s, e = similarity(pred, meas, scale=False)

    def residual(x):
        return (Rotation.from_rotvec(x[:3]).apply(pred) + x[3:] - meas).ravel()

    ref = least_squares(residual, np.zeros(6), xtol=1e-15)
    assert s == 1.0
    assert np.sum(e**2) == pytest.approx(np.sum(ref.fun**2), rel=1e-9)


def _draw(update, prior, alone, measured=None, predicted=0.2):
    return {
        "geometric": 0.5,
        "prior": prior,
        "update": update,
        "update_geometric": 0.4,
        "geometric_alone": 0.45,
        "lab_alone": alone,
        "predicted": predicted,
        "measured": update if measured is None else measured,
    }


def test_the_targets_are_judged_on_the_medians_as_the_issue_states():
    fold = {
        "k": {
            "20": {"summary": summarise([_draw(0.20, 0.30, 0.25)] * 3)},  # 0.8x: both met
            "50": {"summary": summarise([_draw(0.24, 0.30, 0.25)] * 3)},  # 0.96x: within 5 %
            "100": {"summary": summarise([_draw(0.27, 0.30, 0.25, predicted=0.1)] * 3)},
        }
    }
    t = targets(fold)
    assert t["20"]["update_within_5pct"] and t["20"]["update_15pct_better_than_both"]
    assert t["50"]["update_within_5pct"] and not t["50"]["update_15pct_better_than_both"]
    assert not t["100"]["update_within_5pct"] and "update_15pct_better_than_both" not in t["100"]
    assert t["20"]["prediction_in_band"] and not t["100"]["prediction_in_band"]  # 1.0 and 2.7


def test_a_calibration_refitted_once_per_set_of_terms_validates_as_it_is(b_and_d):
    """ur10_sessions reuses the refit without out-of-domain terms across draws: the same
    figures as the result itself (D's temperatures lie outside B's: the thermal line drops)."""
    from benchmarks.ur10_sessions import _refits_once

    b, d = b_and_d
    res = lab.fit(b, "ur10_robot", "geometric,thermal", noise_mm=0.015, noise_ppm=6.0)
    calls = []
    original = res.refit
    assert original is not None

    def counted(names):
        calls.append(tuple(names))
        return original(names)

    once = _refits_once(dataclasses.replace(res, refit=counted))
    refs, rest = reference_split(d)
    want = res.validate(rest, references=refs)
    assert want.validation_dropped  # the thermal line is left out there
    for _ in range(2):
        got = once.validate(rest, references=refs)
        np.testing.assert_allclose(got.validation_residuals, want.validation_residuals)
    assert len(calls) == len(set(calls)) >= 1
