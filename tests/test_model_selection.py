"""The sequential test of agents.model_selection: its predictive densities against numpy's
(the lab's analytic Jacobian, not CasADi's), its summed log density against the batch marginal
likelihood in closed form, no selection on data from the null model, and backlash selected within
a few points of a joint's reversal."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.model_selection import SequentialSelection, ShadowEstimator, candidate_families
from agents.online_calibration import prior_scales
from arm.description import seed_robot
from arm.errormodel import ErrorModel
from arm.sampling import sample_poses

SIGMA = 15e-6


def _columns(n: int, rng: np.random.Generator, dirs: np.ndarray | None = None) -> dict:
    cols = {"temperature": np.full(n, 20.0), "payload": np.zeros(n), "t": np.arange(n) * 0.1}
    d = rng.choice((-1.0, 1.0), (n, 6)) if dirs is None else dirs
    for i in range(6):
        cols[f"dir{i + 1}"] = d[:, i]
    return cols


def _row(cols: dict, k: int) -> dict[str, float]:
    return {c: float(v[k]) for c, v in cols.items()}


def _truth(model: ErrorModel, rng: np.random.Generator, factor: float = 1.0) -> np.ndarray:
    """Parameters drawn from the estimator's prior (nominal, typical sizes)."""
    return model.nominal() + factor * prior_scales(model) * rng.standard_normal(len(model.layout))


def test_predictive_density_matches_numpy_and_the_batch_marginal_likelihood():
    rng = np.random.default_rng(3)
    robot = seed_robot()
    model = ErrorModel(robot, "geometric,backlash")
    sh = ShadowEstimator(model, SIGMA)
    n = 12
    q = sample_poses(robot, n, rng)
    cols = _columns(n, rng)
    # tiny true errors: the model is linear over them to far below the noise
    p_true = model.nominal()
    p_true[sh.idx] += 0.01 * sh.scale * rng.standard_normal(len(sh.idx))
    y = model.predict(model.inputs(q, cols), p_true) + SIGMA * rng.standard_normal((n, 3))
    # the batch marginal likelihood of the model linearised at the prior mean: y ~ N(x0, J P0 J'
    # + sigma^2 I), J the lab's analytic Jacobian of the free (scaled) parameters
    x0, J = model.predict(model.inputs(q, cols), sh.p0, jacobian=True)
    Js = (J[:, :, sh.idx] * sh.scale).reshape(3 * n, -1)
    S = Js @ Js.T + SIGMA**2 * np.eye(3 * n)
    r = (y - x0).reshape(-1)
    L = np.linalg.cholesky(S)
    w = np.linalg.solve(L, r)
    batch = -0.5 * w @ w - np.log(np.diag(L)).sum()
    total = 0.0
    info = np.eye(len(sh.idx))
    for k in range(n):
        # the point's own predictive density in numpy, at the shadow's current estimate
        inputs = model.inputs(q[k : k + 1], {c: v[k : k + 1] for c, v in cols.items()})
        xk, Jk = model.predict(inputs, sh.params, jacobian=True)
        H = Jk[0][:, sh.idx] * sh.scale
        Sk = H @ np.linalg.solve(info, H.T) + SIGMA**2 * np.eye(3)
        e = y[k] - xk[0]
        nis, logdet, out = sh.score(q[k], y[k], _row(cols, k))
        assert nis == pytest.approx(float(e @ np.linalg.solve(Sk, e)), rel=1e-6)
        assert logdet == pytest.approx(float(np.linalg.slogdet(Sk)[1]), rel=1e-9)
        sh.take(out)
        info = info + H.T @ H / SIGMA**2
        total += -0.5 * (nis + logdet)
    # exact for a linear model; here the estimator re-linearises at each estimate: 1e-5 relative
    assert total == pytest.approx(batch, abs=1e-2)


def test_candidate_families_leave_out_what_the_model_has_and_what_the_data_lack():
    model = ErrorModel(seed_robot(), "geometric,backlash[1,5]")
    fams = candidate_families(model)
    assert "backlash" not in fams and "geometric" not in fams
    assert {"compliance", "transmission", "joint_scale", "load_backlash", "thermal"} <= set(fams)
    assert "thermal" not in candidate_families(model, columns=("dir1", "payload"))
    assert candidate_families(model, ["compliance", "backlash"]) == ["compliance"]


def test_no_selection_on_data_from_the_null_model():
    """20 streams of 80 points from the geometric model with errors drawn from its prior: the
    false-selection rate is at most alpha (2 %) by Ville's inequality; none is expected."""
    robot = seed_robot()
    model = ErrorModel(robot, "geometric")
    fams = ["backlash", "compliance", "thermal"]
    selected = []
    for s in range(20):
        rng = np.random.default_rng(100 + s)
        q = sample_poses(robot, 80, rng)
        cols = _columns(80, rng)
        y = model.predict(model.inputs(q, cols), _truth(model, rng))
        y += SIGMA * rng.standard_normal(y.shape)
        sel = SequentialSelection(model, fams, SIGMA, alpha=0.02, burn_in=5)
        for k in range(80):
            sel.feed(q[k], y[k], _row(cols, k))
        if sel.selected is not None:
            selected.append((s, sel.selected, sel.evidence()))
        assert max(sel.evidence().values()) < sel.threshold
    assert not selected, selected


def test_backlash_is_selected_within_a_few_points_of_a_reversal():
    robot = seed_robot()
    truth = ErrorModel(robot, "geometric,backlash")
    rng = np.random.default_rng(7)
    n = 60
    # a slow sweep of every joint that reverses at point 30
    t = np.linspace(-1.0, 1.0, n)
    q0 = sample_poses(robot, 1, rng)[0]
    q = q0 + 0.3 * (1.0 - t[:, None] ** 2) * np.linspace(0.5, 1.0, 6)
    dirs = np.where(t[:, None] < 0.0, 1.0, -1.0) * np.ones((1, 6))
    cols = _columns(n, rng, dirs)
    p = _truth(truth, rng)
    bl = truth.layout.slice("backlash")
    p[bl] = 5e-4  # gaps of 0.5 mrad
    y = truth.predict(truth.inputs(q, cols), p) + SIGMA * rng.standard_normal((n, 3))
    sel = SequentialSelection(
        ErrorModel(robot, "geometric"), ["backlash", "compliance", "thermal"], SIGMA
    )
    at = None
    for k in range(n):
        if sel.feed(q[k], y[k], _row(cols, k)) is not None:
            at = k
    assert sel.selected == "backlash"
    assert at is not None and 30 <= at <= 34, at
    assert sel.threshold == pytest.approx(math.log(3 / 0.02))


def test_bad_settings_are_refused():
    model = ErrorModel(seed_robot(), "geometric")
    with pytest.raises(ValueError, match="alpha"):
        SequentialSelection(model, ["backlash"], SIGMA, alpha=1.5)
    with pytest.raises(ValueError, match="burn_in"):
        SequentialSelection(model, ["backlash"], SIGMA, burn_in=-1)
    with pytest.raises(ValueError, match="sigma"):
        ShadowEstimator(model, 0.0)
