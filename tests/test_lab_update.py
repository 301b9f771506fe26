"""A calibration updated with a few poses of a new session (lab.update), and what a calibration
file carries for it (lab.uncertainty): the parameters' covariance and the spread between the
sessions it was fitted on.

The campaigns are drawn from the error model: the physics (geometry, compliance) stays, and each
session is measured from its own station, the joints re-homed by up to 2 mrad, in its own region
of the joint space (tests/_lab_data.py, drifting_session)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import lab
from arm.description import load_robot
from arm.params import BASE_NAMES
from arm.sessions import join_sessions
from lab.errors import FitError, LabWarning
from lab.export import export_robot
from lab.uncertainty import (
    Uncertainty,
    UncertaintyError,
    conditioned_refit,
    covariance_of,
    least_spread,
    predicted_rms,
    uncertainty_of,
)
from lab.update import CHANGE, UpdateWarning, geometric_prior, prior_of, update
from tests._lab_data import drifting_session, session

EFFECTS = "geometric,compliance"
LO = np.array([-2.0, -1.8, -0.8, -2.0, -1.4, -2.5])
HI = np.array([2.0, -0.7, 0.8, 2.0, 1.4, 2.5])


def _truth(rng: np.random.Generator) -> dict[str, float]:
    values = {
        f"{f}{j}": rng.normal(0.0, s)
        for j in range(1, 7)
        for f, s in (("dalpha", 3e-4), ("da", 3e-4), ("dtheta", 1e-3))
    }
    return values | {"c2": 6e-6, "c3": 4e-6}


def _campaign(seed: int):
    """Three sessions to calibrate on and a fourth, new one (its own station, re-homed, in its
    own region), as (calibration, new session)."""
    rng = np.random.default_rng(100 + seed)
    values = _truth(rng)
    sessions = [
        drifting_session(values, 300, s, 10 * seed + s, region=(rng.uniform(LO, HI), 0.9))
        for s in (1, 2, 3)
    ]
    new = drifting_session(values, 400, 9, 10 * seed + 9, region=(rng.uniform(LO, HI), 0.9))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LabWarning)
        cal = lab.fit(join_sessions(sessions), "seed", EFFECTS)
    return cal, new


@pytest.fixture(scope="module")
def campaigns():
    """(new session, the calibration's prior) of two campaigns."""
    out = []
    for seed in (0, 1):
        cal, new = _campaign(seed)
        out.append((new, prior_of(cal)))
    return out


def _held_out(result, data) -> float:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LabWarning)
        return float(result.validate(data).validation_rms_mm)


def _alone(data, test, effects) -> float:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LabWarning)
            return _held_out(lab.fit(data, "seed", effects), test)
    except FitError:  # too few poses to fit alone
        return float("inf")


# -- what a calibration carries -------------------------------------------------------------------
def test_the_covariance_is_the_one_the_standard_errors_come_from():
    data = session({"da2": 3e-4, "c2": 5e-6}, 200, 1, 1)
    result = lab.fit(data, "seed", "geometric,compliance[2,3]")
    names, cov = covariance_of(result)
    std = result.standard_errors()
    assert not set(names) & set(BASE_NAMES)  # each session's own base: not carried
    for i, n in enumerate(names):
        assert np.sqrt(cov[i, i]) == pytest.approx(std[n], rel=1e-8)
    # one session: it says it has no spread, and its file says so
    u = uncertainty_of(result)
    assert u.sessions == 1 and u.spread is None


def _aligned_rms(a: np.ndarray, b: np.ndarray) -> float:
    """The RMS (m) of ``a`` against ``b`` after the rigid motion that best aligns them (Kabsch):
    what a base placed again takes up does not count."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return float(np.sqrt(np.mean(np.sum(((a - ca) @ R - (b - cb)) ** 2, axis=1))))


def test_a_term_left_out_moves_the_others_as_a_refit_does():
    # where the rows are not at hand (an update), the terms that do not hold outside the domain
    # are left out by the covariance (lab.uncertainty.conditioned_refit): checked against the
    # refit on the rows (lab.fit's), which moves the geometry by 100 sigma to take up c2
    data = session({"da2": 3e-4, "dalpha3": -2e-4, "c2": 6e-6, "c3": 4e-6}, 200, 1, 1)
    result = lab.fit(data, "seed", "geometric,compliance[2,3]", noise_mm=0.015)
    names, cov = covariance_of(result)
    exact = result.refit(("c2",))
    approx = conditioned_refit(result.model.layout.names, result.params, names, cov)(("c2",))
    zeroed = result.params.copy()
    zeroed[result.model.layout.index("c2")] = 0.0
    predict = lambda p: result.model.predict(result.inputs, p)  # noqa: E731
    assert _aligned_rms(predict(approx), predict(exact)) < 1e-6  # m
    assert _aligned_rms(predict(zeroed), predict(exact)) > 1e-4  # zeroing alone: 0.3 mm


def test_the_spread_is_what_changed_between_the_sessions(tmp_path):
    # three sessions whose joint 3 was re-homed to 1, 2, 3 mrad: the spread of dtheta3 is their
    # scatter (1 mrad, each session's own offset in the fit, lab.uncertainty.rehoming_of), that
    # of a new session about the calibration's mean of three: sqrt(1 + 1/3) mrad
    base = {"da2": 3e-4, "c2": 5e-6}
    parts = [session(base | {"dtheta3": 1e-3 * s}, 200, s, s) for s in (1, 2, 3)]
    result = lab.fit(join_sessions(parts), "seed", "geometric,compliance[2,3]")
    u = uncertainty_of(result)
    spread = dict(zip(u.names, u.spread, strict=True))
    assert u.sessions == 3
    assert spread["dtheta3"] == pytest.approx(1e-3 * np.sqrt(4 / 3), rel=0.2)
    # sessions of one unchanged arm: no spread beyond each session's estimation noise
    same = [session(base | {"dtheta3": 2e-3}, 200, s, s) for s in (1, 2, 3)]
    still = uncertainty_of(lab.fit(join_sessions(same), "seed", "geometric,compliance[2,3]"))
    assert dict(zip(still.names, still.spread, strict=True))["dtheta3"] < 0.05e-3
    # written with the calibrated arm and read back as it was
    export_robot(result, tmp_path / "cal.toml")
    back = Uncertainty.from_dict(load_robot(tmp_path / "cal.toml").uncertainty)
    assert back.names == u.names and back.sessions == 3
    np.testing.assert_allclose(back.covariance, u.covariance, rtol=1e-12)
    np.testing.assert_allclose(back.prior_covariance(), u.prior_covariance(), rtol=1e-12)


# -- the update -----------------------------------------------------------------------------------
@pytest.mark.parametrize("k", [10, 20, 50])
def test_the_update_beats_the_prior_and_the_poses_alone(campaigns, k):
    for new, prior in campaigns:
        test = new.subset(np.arange(100, 400))
        poses = new.subset(np.arange(k))
        u = update(prior, poses)
        updated = _held_out(u.result, test)
        prior_alone = _held_out(u.prior_result, test)
        geometric = _alone(poses, test, "geometric")
        same_model = _alone(poses, test, EFFECTS)
        assert updated < 0.5 * prior_alone
        assert updated < 0.8 * geometric
        # the same model fitted on the k poses alone (at k = 10 it cannot be): the update is
        # never worse by more than 5 %
        assert updated <= 1.05 * same_model
        # mm; the noise floor of a perfect model is 0.026, the prior alone 0.4-0.6
        assert updated < (0.15 if k == 10 else 0.06)


@pytest.mark.parametrize("k", [20, 50])
def test_the_accuracy_predicted_for_the_new_session_is_the_one_measured(campaigns, k):
    # measured / predicted within [0.67, 1.5] (issue 38's target for the prediction)
    for new, prior in campaigns:
        test = new.subset(np.arange(100, 400))
        u = update(prior, new.subset(np.arange(k)))
        predicted = predicted_rms(u.result, test, unseen=False)
        assert 0.67 <= _held_out(u.result, test) / predicted.rms_mm <= 1.5
        # the discrepancy is what the new poses measured (each left out in turn), at least the
        # calibration's own; the updated calibration states it (an export carries it)
        assert predicted.discrepancy_mm >= np.sqrt(3) * 1e3 * prior.uncertainty.sigma * (1 - 1e-9)
        own = uncertainty_of(u.result).sigma
        assert predicted.discrepancy_mm == pytest.approx(np.sqrt(3) * 1e3 * own)
        # a program's joints (nothing measured) get the same prediction as its measured poses
        again = predicted_rms(u.result, test.q, unseen=False)
        assert again.rms_mm == pytest.approx(predicted.rms_mm, rel=1e-9)


def test_the_prediction_carries_what_the_calibration_misses_in_the_new_region(campaigns):
    # the calibration without its compliance, updated with poses of the compliant arm: the
    # calibration's own residual (26 um) says nothing of the compliance the new region shows;
    # the poses left out in turn do, and the prediction adds what they measured
    for new, prior in campaigns:
        test = new.subset(np.arange(100, 400))
        u = update(geometric_prior(prior), new.subset(np.arange(50)))
        predicted = predicted_rms(u.result, test, unseen=False)
        assert predicted.discrepancy_mm > 5 * np.sqrt(3) * 1e3 * prior.uncertainty.sigma
        assert 0.67 <= _held_out(u.result, test) / predicted.rms_mm <= 1.5


def test_a_calibration_the_new_poses_cannot_improve_is_kept_as_it_is():
    # one session calibrated, and the same arm measured again from another station, nothing
    # re-homed: moving the calibration's terms on 20 poses predicts each left out no better, so
    # the update is the calibration as it is, its base placed, and it says so
    values = _truth(np.random.default_rng(7))
    cal = lab.fit(drifting_session(values, 400, 1, 71, rehome_mrad=0.0), "seed", EFFECTS)
    again = drifting_session(values, 300, 2, 72, rehome_mrad=0.0)
    # the same offsets as the calibration's session: drifting_session draws them from its seed
    u = update(prior_of(cal), again.subset(np.arange(20)))
    assert not u.moved
    np.testing.assert_array_equal(u.result.params, u.prior_result.params)
    assert u.choices["calibration"]["updated"] >= CHANGE * u.choices["calibration"]["placed"]
    assert "kept as they are" in u.summary() and u.to_dict()["moved"] is False
    test = again.subset(np.arange(100, 300))
    assert _held_out(u.result, test) < 0.035  # mm: the noise floor is 0.026
    # its terms hold where the calibration found them (the new poses fitted none of them)
    assert u.result.domain == prior_of(cal).domain
    # re-homed by 2 mrad, the same 20 poses move it (the campaigns' updates: moved)
    moved = update(prior_of(cal), drifting_session(values, 20, 2, 73, rehome_mrad=2.0))
    assert moved.moved


def test_the_update_is_a_calibration_like_any_other(campaigns, tmp_path):
    new, prior = campaigns[0]
    u = update(prior, new.subset(np.arange(30)))
    path = tmp_path / "updated.toml"
    arm = export_robot(u.result, path)
    carried = Uncertainty.from_dict(arm.uncertainty)
    # the posterior: narrower than the prior where the new poses said something
    before = dict(
        zip(prior.uncertainty.names, np.diag(prior.uncertainty.prior_covariance()), strict=True)
    )
    after = dict(zip(carried.names, np.diag(carried.covariance), strict=True))
    assert after["dtheta3"] < before["dtheta3"]
    # and it can be updated in turn
    again = update(path, new.subset(np.arange(30, 60)))
    assert _held_out(again.result, new.subset(np.arange(100, 400))) < 0.1


def test_a_term_the_new_poses_refute_is_dropped_or_refitted(campaigns):
    new, prior = campaigns[0]
    u0 = prior.uncertainty
    values = dict(u0.values) | {"c2": 10 * u0.values["c2"]}  # a compliance no session has
    tight = Uncertainty(u0.names, values, u0.covariance, u0.sigma)  # and held tightly
    wrong = type(prior)(prior.nominal, prior.effects, tight, prior.domain, "wrong.toml")
    u = update(wrong, new.subset(np.arange(40)))
    assert "compliance" in u.dropped + u.released
    assert u.choices["compliance"]["kept"] > min(u.choices["compliance"].values())
    assert _held_out(u.result, new.subset(np.arange(100, 400))) < 0.1


def test_few_poses_free_fewer_parameters_and_say_which(campaigns):
    new, prior = campaigns[0]
    with pytest.warns(UpdateWarning, match="held at the calibration's values: brx, bry, brz"):
        u = update(prior, new.subset(np.arange(2)))
    assert u.free == ("bx", "by", "bz") and u.held == ("brx", "bry", "brz")


def test_a_prior_and_data_of_different_robots_are_refused(campaigns):
    new, prior = campaigns[0]
    with pytest.raises(FitError, match=r"measured on 'ur5'.*of 'seed'"):
        update(prior, new.subset(np.arange(20)), robot="ur5")


def test_a_calibration_without_its_uncertainty_is_refused(tmp_path):
    arm = load_robot("seed")
    with pytest.raises(UncertaintyError, match="no \\[nominal\\]"):
        update(arm, session({}, 20, 1, 1))


# -- what moves between sessions even when one session measured no spread --------------------------
@pytest.fixture(scope="module")
def one_session():
    """A calibration of one session (no spread measured) and a new session of the same physics,
    re-homed by up to 3 mrad a joint, from its own station, in its own region."""
    rng = np.random.default_rng(500)
    values = _truth(rng)
    one = drifting_session(values, 300, 1, 1, rehome_mrad=3.0, region=(rng.uniform(LO, HI), 0.9))
    new = drifting_session(values, 400, 9, 9, rehome_mrad=3.0, region=(rng.uniform(LO, HI), 0.9))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LabWarning)
        cal = lab.fit(one, "seed", EFFECTS)
    return prior_of(cal), new


def test_the_least_spread_names_the_zero_offsets_and_the_tool():
    least = least_spread(["dtheta2", "da2", "tx", "tz2", "c3", "dtheta6"])
    assert least == {"dtheta2": 2e-3, "dtheta6": 2e-3, "tx": 0.5e-3, "tz2": 0.5e-3}
    assert least_spread(["dtheta1"], rehome_mrad=3.0) == {"dtheta1": pytest.approx(3e-3)}
    # a measured spread larger than the least is kept
    u = Uncertainty(
        ("dtheta2", "da2"),
        {"dtheta2": 0.0, "da2": 0.0},
        np.zeros((2, 2)),
        1e-5,
        2,
        np.array([5e-3, 1e-4]),
    )
    np.testing.assert_allclose(np.diag(u.prior_covariance(least)), [25e-6, 1e-8])


@pytest.mark.parametrize("k", [20, 50])
def test_a_one_session_prior_learns_the_re_homing(one_session, k):
    prior, new = one_session
    assert prior.uncertainty.spread is None  # one session: nothing measured between sessions
    test = new.subset(np.arange(100, 400))
    poses = new.subset(np.arange(k))
    u = update(prior, poses)
    # without the least spread the prior holds the zero offsets at the old session's values
    # to within their (tiny) standard errors: the update cannot learn the re-homing
    stuck = update(prior, poses, rehome_mrad=0.0, remount_mm=0.0)
    updated = _held_out(u.result, test)
    assert _held_out(stuck.result, test) > 0.3  # mm
    assert updated < 0.1 * _held_out(u.prior_result, test)
    assert updated < 0.06  # the floor of a perfect model is 0.026


def test_a_negative_least_spread_is_refused(one_session):
    prior, new = one_session
    with pytest.raises(FitError, match="rehome_mrad"):
        update(prior, new.subset(np.arange(20)), rehome_mrad=-1.0)
