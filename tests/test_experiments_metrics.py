"""Metrics of an episode and their summary over seeds, checked against hand computations, closed
forms (a pure base translation moves every tool point by exactly its length) and tabulated
Student-t quantiles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.runner import EpisodeResult
from arm.description import seed_robot
from arm.errormodel import ErrorModel
from experiments.metrics import (
    METRICS,
    calibration_error_mm,
    episode_metrics,
    identified_names,
    parameter_errors,
    summarize,
)


def result(err, judged=None, actions=None, solve=None, report=None, diverged=False, dt=0.02):
    err = np.asarray(err, dtype=float)
    n = len(err)
    return EpisodeResult(
        agent="x",
        seed=0,
        env_id="SixAxisTrack-v0",
        env_kwargs={},
        phases=[],
        time=dt * np.arange(1, n + 1),
        phase=np.zeros(n, dtype=int),
        judged=np.ones(n, dtype=bool) if judged is None else np.asarray(judged),
        true_error_mm=err,
        actions=np.zeros((n, 6)) if actions is None else np.asarray(actions, dtype=float),
        measurement=np.full((n, 3), np.nan),
        solve_time_s=np.zeros(n) if solve is None else np.asarray(solve, dtype=float),
        diverged=diverged,
        report=report or {},
    )


def test_tracking_metrics_by_hand():
    # 200 steps of 0.02 s (4 s): error 3 mm for the first 3 s, then 1 mm
    err = np.where(np.arange(200) < 150, 3.0, 1.0)
    m, timing = episode_metrics(result(err), METRICS, settle_seconds=3.0)
    assert m["rms_mm"] == pytest.approx(math.sqrt((150 * 9 + 50 * 1) / 200), rel=1e-12)
    assert m["max_mm"] == 3.0
    assert m["rms_settled_mm"] == pytest.approx(1.0, rel=1e-12)  # exactly the steps after 3 s
    assert m["diverged"] == 0.0
    assert math.isnan(m["calib_rms_mm"]) and m["calib_params"] == 0.0
    assert set(timing) == {"solve_time_median_ms", "solve_time_p95_ms"}
    assert not set(m) & set(timing)


def test_only_judged_steps_count_and_settling_starts_with_them():
    # a 1 s unjudged calibration phase with a huge error, then 2 s judged
    err = np.r_[np.full(50, 100.0), np.full(50, 2.0), np.full(50, 0.5)]
    judged = np.r_[np.zeros(50, bool), np.ones(100, bool)]
    m, _ = episode_metrics(
        result(err, judged), ["rms_mm", "max_mm", "rms_settled_mm"], settle_seconds=1.0
    )
    assert m["max_mm"] == 2.0
    assert m["rms_mm"] == pytest.approx(math.sqrt((50 * 4 + 50 * 0.25) / 100))
    assert m["rms_settled_mm"] == pytest.approx(0.5)


def test_effort_and_solve_times():
    n = 100
    a = np.zeros((n, 6))
    a[:, 0] = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)  # joint 1 at full speed, alternating
    solve = np.linspace(0.001, 0.100, n)
    m, t = episode_metrics(
        result(np.ones(n), actions=a, solve=solve),
        ["effort_rms", "effort_rate_rms", "solve_time_median_ms", "solve_time_p95_ms"],
    )
    assert m["effort_rms"] == pytest.approx(math.sqrt(1 / 6))
    # every step changes joint 1 by 2 in 0.02 s: rate 100 /s on one of six joints
    assert m["effort_rate_rms"] == pytest.approx(math.sqrt(100.0**2 / 6))
    assert t["solve_time_median_ms"] == pytest.approx(np.median(solve) * 1e3)
    assert t["solve_time_p95_ms"] == pytest.approx(np.percentile(solve, 95) * 1e3)


def test_unknown_metric_is_refused():
    with pytest.raises(KeyError, match="happiness"):
        episode_metrics(result(np.ones(3)), ["happiness"])


def test_identified_parameters_and_their_errors():
    report = {
        "parameter_names": ["da1", "dd2", "tx"],
        "parameters": [1e-4, -2e-4, 0.0],
        "fitted": ["da1", "dd2"],
    }
    assert identified_names(report) == ["da1", "dd2"]
    assert parameter_errors(report, {"da1": 0.5e-4, "dd2": -2e-4, "tx": 1.0}) == pytest.approx(
        {"da1": 0.5e-4, "dd2": 0.0}
    )
    assert identified_names({"parameter_names": ["a"], "parameters": [0.0], "fitted": []}) == []
    assert identified_names({"solve_time_median_s": 1.0}) == []
    m, _ = episode_metrics(result(np.ones(3), report=report), ["calib_params"])
    assert m["calib_params"] == 2.0


def test_calibration_error_is_exact_for_a_base_translation():
    model = ErrorModel(seed_robot(), "geometric")
    rng = np.random.default_rng(1)
    p_true = model.nominal() + rng.normal(0, 1e-4, len(model.layout))
    names = list(model.layout.names)
    # the estimate is the truth: zero
    assert calibration_error_mm(model, p_true, names, p_true) == pytest.approx(0.0, abs=1e-12)
    # the estimate is the truth with the base shifted 1 mm along x and 2 mm along z: every tool
    # point moves by sqrt(5) mm
    p_est = p_true.copy()
    p_est[model.layout.index("bx")] += 1e-3
    p_est[model.layout.index("bz")] += 2e-3
    assert calibration_error_mm(model, p_true, names, p_est) == pytest.approx(
        math.sqrt(5), rel=1e-9
    )
    # the same through the estimate's own model (another ErrorModel with more effects)
    est_model = ErrorModel(seed_robot(), "geometric,compliance")
    q = np.r_[p_est, est_model.nominal()[len(p_est) :]]
    assert calibration_error_mm(
        model, p_true, est_model.layout.names, q, est_model=est_model
    ) == pytest.approx(math.sqrt(5), rel=1e-9)
    # parameters the truth has not, and no model of the estimate: refused
    with pytest.raises(ValueError, match="not in the truth"):
        calibration_error_mm(model, p_true, ["c2"], [1e-6])


def test_summary_interval_is_the_bootstrap_of_the_mean_and_stays_positive():
    """20 skewed positive values (a tracking error's spread): the Student-t interval reaches
    below zero, the bootstrap interval does not, and it is the percentile-corrected (BCa)
    interval scipy computes on its own."""
    from scipy import stats

    x = np.r_[np.full(18, 0.05), 2.0, 3.0]
    t_half = stats.t.ppf(0.975, 19) * x.std(ddof=1) / math.sqrt(20)
    assert x.mean() - t_half < 0  # the old interval of a positive quantity
    s = summarize(x)
    assert s.n == 20 and s.mean == pytest.approx(x.mean())
    assert 0 < s.lo < s.mean < s.hi and s.has_ci
    ref = stats.bootstrap(
        (x,), np.mean, n_resamples=10_000, method="BCa", rng=np.random.default_rng(20_240_611)
    )
    assert (s.lo, s.hi) == pytest.approx(
        (ref.confidence_interval.low, ref.confidence_interval.high), rel=1e-9
    )


def test_summary_of_one_or_no_value_and_missing_values():
    one = summarize([2.0])
    assert one.mean == 2.0 and one.n == 1 and math.isnan(one.ci95)
    none = summarize([float("nan"), None])
    assert none.n == 0 and math.isnan(none.mean)
    assert summarize([1.0, None, 3.0]).n == 2


# -- the whole episode: convergence and the maximum after settling ------------------------------


def test_convergence_time_by_hand():
    # 0.02 s steps: 3 mm for 1 s (50 steps), then 0.1 mm, one 0.3 mm spike at step 100 (t = 2.02 s)
    err = np.where(np.arange(200) < 50, 3.0, 0.1)
    err[100] = 0.3
    m, _ = episode_metrics(
        result(err), ["converge_s", "max_settled_mm"], settle_seconds=1.0, converge_mm=0.25
    )
    # the error stays below 0.25 mm after the end of the spike's step
    assert m["converge_s"] == pytest.approx(101 * 0.02, rel=1e-12)
    assert m["never_converged"] == 0.0  # the companion comes with it
    assert m["max_settled_mm"] == 0.3  # the first 50 steps are the settling time
    # a looser threshold ignores the spike: converged at the end of step 50 (t = 1.0 s)
    m, _ = episode_metrics(result(err), ["converge_s"], converge_mm=0.5)
    assert m["converge_s"] == pytest.approx(1.0, rel=1e-12)
    # below the threshold from the first step: converged at once, a true zero
    m, _ = episode_metrics(result(np.full(10, 0.1)), ["converge_s"])
    assert m["converge_s"] == 0.0 and m["never_converged"] == 0.0


def test_never_converged_is_missing_and_counted_not_zero():
    err = np.r_[np.full(50, 0.1), np.full(5, 0.4)]  # converged, then lost it at the end
    m, _ = episode_metrics(result(err), ["converge_s"], converge_mm=0.25)
    assert math.isnan(m["converge_s"]) and m["never_converged"] == 1.0
    # a diverged episode (NaN error at the end) never converged either
    m, _ = episode_metrics(result(np.r_[np.full(5, 0.1), np.nan]), ["converge_s"])
    assert math.isnan(m["converge_s"]) and m["never_converged"] == 1.0
    # no judged step: nothing to say, neither converged nor not
    m, _ = episode_metrics(result(np.ones(3), judged=np.zeros(3, bool)), ["converge_s"])
    assert math.isnan(m["converge_s"]) and math.isnan(m["never_converged"])


def test_convergence_counts_from_the_start_of_the_judged_steps():
    # 1 s of unjudged calibration far off, then judged: 0.5 s at 1 mm, then 0.1 mm
    err = np.r_[np.full(50, 100.0), np.full(25, 1.0), np.full(75, 0.1)]
    judged = np.r_[np.zeros(50, bool), np.ones(100, bool)]
    m, _ = episode_metrics(result(err, judged), ["converge_s"], converge_mm=0.25)
    assert m["converge_s"] == pytest.approx(0.5, rel=1e-9)


def test_summary_keeps_the_range_and_shows_an_interval_only_from_three_values():
    two = summarize([1.0, 3.0])
    assert (two.min, two.max) == (1.0, 3.0) and not two.has_ci
    three = summarize([1.0, 3.0, 2.0])
    assert (three.min, three.max) == (1.0, 3.0) and three.has_ci
