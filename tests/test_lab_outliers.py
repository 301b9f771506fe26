"""Verdicts that hold on imperfect data (issue 11, item 2; issue 13, items 1 and 6), through the
Python API: gross outliers left out by a stated rule, and only they; exact duplicates counted
once; one pose on the far side of a load-dependent gap; the block-wise evaluation equal to the
whole; the identifiability of a Jacobian equal to that of its R factor."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import erfc

from arm.effects import LoadBacklash
from arm.errormodel import ErrorModel
from arm.kinematics import gravity_torques
from arm.measurements import MeasurementSet
from arm.sampling import sample_parameters, sample_poses
from arm.sessions import join_sessions
from lab import FitError, blocks, diagnose, fit, screen
from lab.identifiability import analyse
from lab.screening import OUTLIER_ALPHA, outlier_radius
from tests._lab_data import FLOOR_MM, SIGMA, campaign, drifting_session, with_gross_outliers

NOISE_MM = 1e3 * SIGMA


# -- the rule -----------------------------------------------------------------------------------
def _two_sessions(seed: int) -> MeasurementSet:
    """Two sessions of one arm: each its own tracker station (the base metres away, turned any
    angle about z), each joint re-homed by up to 2 mrad, 150 and 210 poses."""
    return join_sessions(
        [drifting_session({}, 150, 1, 10 * seed), drifting_session({}, 210, 2, 10 * seed + 1)]
    )


@pytest.mark.parametrize("seed", [0, 4, 5])
def test_two_re_homed_sessions_are_screened_pose_by_pose_not_session_by_session(seed):
    """A trimmed fit of the best half of all poses took the larger session alone, the other's
    base placed by two of its poses (turned degrees off): the default screen called the other
    session gross errors of 10 mm to metres and refused the data (issue 38's benchmark, 14 of
    40 campaigns). Trimmed station by station, no row of the clean sessions is left out, and
    gross errors planted in them are left out, exactly those."""
    data = _two_sessions(seed)
    assert not fit(data, "seed", noise_mm=NOISE_MM).outlier_list
    dirty, moved = with_gross_outliers(data, np.random.default_rng(seed), 0.02, (10e-3, 50e-3))
    with pytest.warns(UserWarning, match="outlier"):
        result = fit(dirty, "seed", noise_mm=NOISE_MM)
    assert [o.index for o in result.outlier_list] == list(moved)


@pytest.mark.parametrize("n", [30, 200, 2000, 200_000])
def test_the_radius_is_exceeded_by_noise_with_the_stated_probability(n):
    """The 3-D radius against the closed form of a chi distribution with 3 degrees of freedom:
    P(|x| > r) = erfc(r / sqrt 2) + sqrt(2 / pi) r exp(-r^2 / 2) for unit Gaussian noise."""
    r = outlier_radius(n)
    tail = erfc(r / math.sqrt(2)) + math.sqrt(2 / math.pi) * r * math.exp(-(r**2) / 2)
    assert n * tail == pytest.approx(OUTLIER_ALPHA, rel=1e-9)


def test_diagnosis_is_right_on_compliance_with_two_percent_gross_outliers(seed):
    """The issue's case: least squares with the outliers says unexplained; the default leaves
    them out, names them by row, and names compliance."""
    for s in range(3):
        c = campaign(seed, "geometric,compliance", seed=500 + s)
        data, planted = with_gross_outliers(c.measure(200), np.random.default_rng(s))
        d = diagnose(data, seed, "geometric", noise_mm=NOISE_MM)
        assert d.verdict == "compliance", (s, d.summary())
        assert list(d.outliers) == list(planted)
        assert [o["row"] for o in d.to_dict()["outliers"]] == [int(i) + 1 for i in planted]
        if s == 0:
            keep = diagnose(data, seed, "geometric", noise_mm=NOISE_MM, outliers="keep")
            assert keep.verdict == "unexplained" and not len(keep.outliers)


def test_the_fit_without_its_outliers_is_the_fit_of_the_other_rows(seed):
    c = campaign(seed, "geometric", seed=12)
    data, planted = with_gross_outliers(c.measure(200), np.random.default_rng(13))
    auto = fit(data, seed, "geometric")
    assert list(auto.outliers) == list(planted) and auto.n_points == 200 - len(planted)
    rest = np.setdiff1d(np.arange(200), planted)
    plain = fit(data.subset(rest), seed, "geometric", outliers="keep")
    np.testing.assert_array_equal(auto.params, plain.params)
    assert auto.rms_mm == plain.rms_mm
    for o in auto.outlier_list:
        assert o.residual_mm > 0.15 and o.sigmas > outlier_radius(200)
    out = auto.to_dict()
    assert out["n_points"] == 196 and out["n_rows"] == 200 and out["outliers_mode"] == "auto"
    assert "4.75 robust sigmas" in out["outlier_rule"]


@pytest.mark.parametrize("typo_m", [1.0, 0.05])
def test_a_typo_in_one_cell_is_an_outlier_not_a_failed_fit(seed, typo_m):
    """x of one row off by a metre (a digit typed twice): without noise_mm the fit's first noise
    estimate would be 40 mm and fix every parameter; the robust scale keeps the fit, and the row
    is left out by line."""
    d = campaign(seed, "geometric", seed=5).measure(200)
    xyz = d.xyz.copy()
    xyz[17, 0] += typo_m
    lines = np.arange(2, 202)
    res = fit(MeasurementSet(d.q, xyz, d.columns, "typo.csv", lines), seed, "geometric")
    assert list(res.outliers) == [17] and res.outlier_list[0].line == 19
    assert res.rank == 25 and res.rms_mm < FLOOR_MM


def test_no_outliers_where_the_model_misses_an_effect(seed):
    """A geometric fit of data with a hidden effect has a residual with heavy tails; its largest
    deviations are the effect, not outliers: judged beyond what every catalogued effect could
    explain, none is flagged."""
    for effects, s in (
        ("geometric,compliance", 500),
        ("geometric,compliance", 502),
        ("geometric,transmission[1]", 501),
        ("geometric,joint_scale[2,3]", 502),
    ):
        data = campaign(seed, effects, seed=s).measure(200)
        assert len(fit(data, seed, "geometric").outliers) == 0, effects
        assert len(diagnose(data, seed, "geometric", noise_mm=NOISE_MM).outliers) == 0, effects


def test_clean_data_have_no_outliers(seed):
    for s in range(10):
        data = campaign(seed, "geometric", seed=3000 + s).measure(200)
        res = fit(data, seed, "geometric")
        assert len(res.outliers) == 0 and res.fitted_rows is None, s


@pytest.mark.parametrize("form", ["harmonic2_q2", "harmonic3_q1", "thermal_zero_q3"])
def test_an_effect_outside_the_catalogue_is_not_taken_for_outliers(seed, form):
    """1,000 poses with a form no candidate has: the residual's spread is peeled round after
    round by the rule, never settling as gross errors do; nothing is left out."""
    from tests import _hidden_forms as hidden

    data = hidden.campaign(seed, form, seed=0, n=1000, n_validation=1).data
    rows = screen(data, seed, "geometric", noise_mm=NOISE_MM)
    assert len(fit(rows).outliers) == 0, form
    assert len(diagnose(rows).outliers) == 0


@pytest.mark.slow
def test_the_false_flag_rate_on_clean_data_is_small(seed):
    """The rule's family-wise rate is 1 % per data set by design (Bonferroni on Gaussian noise);
    measured over 300 clean campaigns of 200 poses (benchmarks/lab.py states the rate)."""
    flagged = []
    for s in range(300):
        data = campaign(seed, "geometric", seed=4000 + s).measure(200)
        if len(fit(data, seed, "geometric").outliers):
            flagged.append(s)
    assert len(flagged) <= 9, flagged  # 3 %: the design's 1 % with room for chance (p < 0.001)


# -- duplicates ---------------------------------------------------------------------------------
def test_duplicates_are_counted_once_and_named(seed):
    c = campaign(seed, "geometric", seed=14)
    data = c.measure(60)
    lines = np.arange(2, 62)
    data = MeasurementSet(data.q, data.xyz, data.columns, "log.csv", lines)
    tenfold = data.subset(np.repeat(np.arange(60), 10))
    tenfold.lines = np.arange(2, 602)
    once, ten = fit(data, seed, "geometric"), fit(tenfold, seed, "geometric")
    np.testing.assert_array_equal(ten.params, once.params)
    np.testing.assert_array_equal(ten.std, once.std)
    assert ten.condition_number == once.condition_number
    assert len(ten.duplicates) == 540 and ten.n_points == 60
    first = ten.to_dict()["duplicates"][0]
    assert first == {"row": 2, "line": 3, "first_row": 1, "first_line": 2}
    assert "line 2 (copied on lines 3-11)" in ten.summary()
    same = data.subset(np.zeros(200, dtype=int))
    with pytest.raises(FitError, match=r"1 poses.*199 duplicate row"):
        fit(same, seed, "geometric")
    with pytest.raises(FitError, match="199 duplicate row"):
        diagnose(same, seed, "geometric", noise_mm=NOISE_MM)


# -- load_backlash near zero torque -------------------------------------------------------------
def pose_with_torque(robot, q0: np.ndarray, joint: int, tau: float) -> np.ndarray | None:
    """``q0`` with joint ``joint``'s own angle moved so that its gravity torque is ``tau``."""
    lo, hi = robot.lower[joint - 1] + 0.05, robot.upper[joint - 1] - 0.05

    def f(x):
        q = q0.copy()
        q[joint - 1] = x
        return gravity_torques(robot, q[None])[0, joint - 1] - tau

    xs = np.linspace(lo, hi, 200)
    v = np.array([f(x) for x in xs])
    k = np.flatnonzero(v[:-1] * v[1:] < 0)
    if not k.size:
        return None
    q = q0.copy()
    q[joint - 1] = brentq(f, xs[k[0]], xs[k[0] + 1], xtol=1e-14)
    return q


def gravity_loaded_campaign(robot, seed_: int, n: int, odd_tau: float | None):
    """Gravity-loaded backlash of 0.3 mrad on joints 2 and 3 and random geometric errors, made
    without the lab's effect: each link turned by half the gap to the side its gravity torque
    pushes it, the geometric model fed the turned angles. With ``odd_tau``, the first pose has
    that torque about joint 2 and rests on the *other* side of the gap."""
    rng = np.random.default_rng(seed_)
    geo = ErrorModel(robot, "geometric")
    p = sample_parameters(geo, rng)

    def measure(n, odd):
        q = sample_poses(robot, n, rng)
        if odd is not None:
            q[0] = next(
                x for x in (pose_with_torque(robot, qi, 2, odd) for qi in q) if x is not None
            )
        side = np.sign(gravity_torques(robot, q))
        if odd is not None:
            side[0, 1] = -np.sign(odd)
        theta = q.copy()
        theta[:, 1:3] += 0.5 * 3e-4 * side[:, 1:3]
        xyz = geo.predict(geo.inputs(theta, {}), p) + rng.normal(0, SIGMA, (n, 3))
        return MeasurementSet(q, xyz)

    return measure(n, odd_tau), measure(300, None)


def test_one_pose_at_near_zero_torque_does_not_flip_the_verdict(seed):
    """The issue's case: one pose at -0.05 N·m about joint 2 landed on the other side of the
    gap. The default diagnosis leaves it out, says why (ambiguous: gravity picks no side there),
    names load_backlash, and the fit it suggests reaches the noise floor on held-out poses."""
    for s in (0, 1, 2):
        data, val = gravity_loaded_campaign(seed, 900 + s, 200, odd_tau=-0.05)
        d = diagnose(data, seed, "geometric", noise_mm=NOISE_MM)
        assert d.verdict == "load_backlash", (s, d.summary())
        assert 0 in d.outliers
        note = next(o.note for o in d.outlier_list if o.index == 0)
        assert "ambiguous for load_backlash" in note and "tau2 = -0.05 N·m" in note
        res = fit(data, seed, d.suggestion, validate=val)
        assert res.validation_rms_mm < 1.2 * FLOOR_MM
        assert 0 in res.outliers
    keep = diagnose(data, seed, "geometric", noise_mm=NOISE_MM, outliers="keep")
    assert keep.verdict == "unexplained"  # what the issue saw: the one pose flips it


def test_a_candidates_ambiguity_is_not_said_of_a_model_that_lacks_it(seed):
    """A gross outlier on clean geometric data is only an outlier: the note that gravity picks no
    side of a gap belongs to load_backlash, which neither the model nor the verdict has (it used
    to be said of every outlier whose pose had a small torque about some joint)."""
    band = LoadBacklash.torque_band
    said = 0
    for s in range(4):
        data, planted = with_gross_outliers(
            campaign(seed, "geometric", seed=700 + s).measure(200), np.random.default_rng(s)
        )
        tau = np.abs(gravity_torques(seed, data.q[planted]))
        said += int(np.any((tau > 1e-6) & (tau < band)))  # poses the old note spoke of
        d = diagnose(data, seed, "geometric", noise_mm=NOISE_MM)
        assert d.verdict == "none", (s, d.summary())
        assert list(d.outliers) == list(planted)
        assert not any("load_backlash" in (o.note or "") for o in d.outlier_list), d.summary()
    assert said > 0  # the case arose: some planted pose had a torque within the band


# -- block by block -----------------------------------------------------------------------------
def test_block_wise_fit_and_diagnosis_equal_the_whole(seed, monkeypatch):
    c = campaign(seed, "geometric,compliance[2,3]", seed=15)
    data = c.measure(300)
    whole_fit = fit(data, seed, "geometric,compliance")
    whole = diagnose(data, seed, "geometric", noise_mm=NOISE_MM)
    monkeypatch.setattr(blocks, "BLOCK", 37)  # 9 blocks, the last one short
    part_fit = fit(data, seed, "geometric,compliance")
    part = diagnose(data, seed, "geometric", noise_mm=NOISE_MM)
    np.testing.assert_allclose(part_fit.params, whole_fit.params, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(part_fit.std, whole_fit.std, rtol=1e-7)
    assert part_fit.unidentifiable == whole_fit.unidentifiable
    assert part_fit.condition_number == pytest.approx(whole_fit.condition_number, rel=1e-9)
    assert part.verdict == whole.verdict == "compliance"
    assert part.suggestion == whole.suggestion
    for a, b in zip(part.candidates, whole.candidates, strict=True):
        assert (a.effect, a.joints) == (b.effect, b.joints)
        assert a.rms_mm == pytest.approx(b.rms_mm, rel=1e-9)
        assert a.p_value == pytest.approx(b.p_value, rel=1e-6, abs=1e-300)
    for a, b in zip(part.hints, whole.hints, strict=True):
        assert a.variable == b.variable and a.score == pytest.approx(b.score, rel=1e-8, abs=1e-12)


def test_identifiability_of_the_r_factor_is_that_of_the_jacobian(seed):
    """Every quantity of the analysis is an inner product of columns, so the R of a QR
    decomposition (what the block-wise fit accumulates) gives the same answer as the tall
    Jacobian (an independent route: LAPACK's Householder QR)."""
    c = campaign(seed, "geometric,compliance", seed=16)
    model = ErrorModel(seed, "geometric,compliance")
    data = c.measure(120)
    _, J = model.predict(model.inputs(data.q, data.columns), c.params, jacobian=True)
    R = np.linalg.qr(J.reshape(-1, J.shape[2]), mode="r")
    a = analyse(J, model.layout.names)
    b = analyse(R, model.layout.names, n_poses=120)
    np.testing.assert_array_equal(a.identifiable, b.identifiable)
    assert a.labels == b.labels
    # from the Gram matrix (cond 1.6e4 here): the smallest ones to eps * cond^2
    np.testing.assert_allclose(a.singular_values, b.singular_values, rtol=1e-7)
