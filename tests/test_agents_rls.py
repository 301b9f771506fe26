"""Online calibration: identifiability, convergence on noise-free data, noise, outliers, and what
the chosen effects let it learn."""

from __future__ import annotations

import numpy as np
import pytest

from agents.online_calibration import (
    RecursiveLeastSquares,
    identifiable_parameters,
    prior_scales,
    qr_identifiable,
    random_columns,
)
from arm import ErrorModel, seed_robot
from arm.sampling import sample_parameters, sample_poses


def _data(model, p, n, rng, noise=0.0, payload=0.0):
    q = sample_poses(model.robot, n, rng)
    cols = {"payload": np.full(n, payload)}
    y = model.predict(model.inputs(q, cols), p)
    return q, y + rng.normal(0.0, noise, y.shape) if noise else y


@pytest.mark.parametrize("effects", ["geometric", "geometric,compliance"])
def test_identifiable_set_has_the_rank_of_the_jacobian(effects):
    model = ErrorModel(seed_robot(), effects)
    rng = np.random.default_rng(0)
    q = sample_poses(model.robot, 200, rng)
    inputs = model.inputs(q, random_columns(model, 200, rng))
    _, J = model.predict(inputs, model.nominal(), jacobian=True)
    J = J.reshape(-1, J.shape[-1]) * prior_scales(model)
    s = np.linalg.svd(J / np.linalg.norm(J, axis=0).clip(1e-300), compute_uv=False)
    # independent rank: singular values of the scaled Jacobian, columns that move nothing dropped
    live = np.linalg.norm(J, axis=0) > 1e-12 * np.linalg.norm(J, axis=0).max()
    rank = np.linalg.matrix_rank(J[:, live] / np.linalg.norm(J[:, live], axis=0), tol=1e-7)
    for free in (identifiable_parameters(model), qr_identifiable(model, inputs)):
        assert len(free) == rank
        cols = J[:, model.layout.indices(free)]
        assert np.linalg.matrix_rank(cols / np.linalg.norm(cols, axis=0), tol=1e-7) == rank
    assert s[-1] < 1e-12  # there are unidentifiable combinations at all
    assert "dtheta6" not in identifiable_parameters(model)  # the target sits on joint 6's axis


def test_rls_converges_to_the_true_parameters_on_noise_free_data():
    model = ErrorModel(seed_robot(), "geometric,compliance")
    rng = np.random.default_rng(1)
    free = identifiable_parameters(model)
    idx = model.layout.indices(free)
    truth = model.nominal()
    truth[idx] = sample_parameters(model, rng)[idx]  # errors in the identifiable parameters only
    q, y = _data(model, truth, 600, rng)
    rls = RecursiveLeastSquares(model, free=free, sigma=1e-9, forgetting=0.98)
    for k in range(len(q)):
        assert rls.update(q[k], y[k], {"payload": 0.0})
    err = np.abs(rls.params - truth) / prior_scales(model)
    assert err.max() < 1e-4, model.layout.names[int(np.argmax(err))]
    assert rls.n_rejected == 0


def test_rls_with_noise_predicts_held_out_points_at_the_noise_floor():
    model = ErrorModel(seed_robot(), "geometric")
    rng = np.random.default_rng(2)
    truth = sample_parameters(model, rng)  # unidentifiable ones too: predictions still converge
    sigma = 15e-6
    q, y = _data(model, truth, 400, rng, noise=sigma)
    rls = RecursiveLeastSquares(model, sigma=sigma, forgetting=1.0)
    for k in range(len(q)):
        rls.update(q[k], y[k], {"payload": 0.0})
    qt, yt = _data(model, truth, 200, rng)
    err = model.predict(model.inputs(qt, {"payload": np.zeros(200)}), rls.params) - yt
    rms3d = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    assert rms3d < 0.5 * sigma * np.sqrt(3)  # the model error, below one measurement's noise
    nominal_err = model.predict(model.inputs(qt, {"payload": np.zeros(200)}), model.nominal()) - yt
    assert np.sqrt(np.mean(np.sum(nominal_err**2, axis=1))) > 20 * rms3d


def test_outliers_are_gated():
    model = ErrorModel(seed_robot(), "geometric")
    rng = np.random.default_rng(3)
    truth = sample_parameters(model, rng)
    sigma = 15e-6
    q, y = _data(model, truth, 400, rng, noise=sigma)
    bad = rng.uniform(size=len(q)) < 0.05
    y_out = y.copy()
    y_out[bad] += rng.choice((-1, 1), (bad.sum(), 3)) * rng.uniform(0.5e-3, 2e-3, (bad.sum(), 3))
    qt, yt = _data(model, truth, 200, rng)
    inputs_t = model.inputs(qt, {"payload": np.zeros(200)})

    def run(gate):
        rls = RecursiveLeastSquares(model, sigma=sigma, forgetting=0.995, gate=gate)
        for k in range(len(q)):
            rls.update(q[k], y_out[k], {"payload": 0.0})
        e = model.predict(inputs_t, rls.params) - yt
        return np.sqrt(np.mean(np.sum(e**2, axis=1))), rls

    gated, rls = run(gate=25.9)
    ungated, _ = run(gate=np.inf)
    assert rls.n_rejected >= 0.8 * bad.sum()
    assert gated < sigma * np.sqrt(3)
    assert ungated > 3 * gated


def test_what_it_learns_depends_on_the_effects():
    """Data from an elastic arm: with compliance in the model the estimator predicts new poses at
    the noise level; geometric-only is left with the unmodelled sag."""
    truth_model = ErrorModel(seed_robot(), "geometric,compliance")
    rng = np.random.default_rng(4)
    truth = sample_parameters(truth_model, rng)
    sigma = 15e-6
    q, y = _data(truth_model, truth, 500, rng, noise=sigma, payload=0.0)
    qt, yt = _data(truth_model, truth, 200, rng)
    out = {}
    for effects in ("geometric", "geometric,compliance"):
        m = ErrorModel(seed_robot(), effects)
        rls = RecursiveLeastSquares(m, sigma=sigma, forgetting=1.0)
        for k in range(len(q)):
            rls.update(q[k], y[k], {"payload": 0.0})
        e = m.predict(m.inputs(qt, {"payload": np.zeros(200)}), rls.params) - yt
        out[effects] = np.sqrt(np.mean(np.sum(e**2, axis=1)))
    assert out["geometric,compliance"] < sigma * np.sqrt(3)
    assert out["geometric"] > 2 * out["geometric,compliance"]


def test_bad_input_is_ignored_or_refused():
    model = ErrorModel(seed_robot(), "geometric")
    rls = RecursiveLeastSquares(model)
    assert not rls.update(np.zeros(6), np.full(3, np.nan))
    assert rls.n_updates == 0
    with pytest.raises(ValueError, match="forgetting"):
        RecursiveLeastSquares(model, forgetting=1.5)
    with pytest.raises(KeyError, match="nope"):
        RecursiveLeastSquares(model, free=["nope"])
