"""Online calibration: identifiability, convergence on noise-free data, noise, outliers, and what
the chosen effects let it learn."""

from __future__ import annotations

import numpy as np
import pytest

from agents.online_calibration import (
    MeasurementBuffer,
    RecursiveLeastSquares,
    identifiable_parameters,
    merge_effects,
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
    assert not rls.update(np.array([0.1, np.nan, 0, 0, 0, 0]), np.array([0.5, 0.0, 0.5]))
    assert not rls.update(np.full(6, np.inf), np.array([0.5, 0.0, 0.5]))
    assert rls.n_updates == 0 and np.all(np.isfinite(rls.params))
    with pytest.raises(ValueError, match="forgetting"):
        RecursiveLeastSquares(model, forgetting=1.5)
    with pytest.raises(KeyError, match="nope"):
        RecursiveLeastSquares(model, free=["nope"])


def test_update_is_the_regularised_forgetting_filter():
    """The compiled update against the filter of the module docstring written out in numpy,
    with a forgetting and a noise at which the prior's (1 - lam) I term matters."""
    model = ErrorModel(seed_robot(), "geometric")
    rng = np.random.default_rng(5)
    truth = sample_parameters(model, rng)
    sigma, lam = 3e-3, 0.9
    q, y = _data(model, truth, 40, rng, noise=1e-5)
    rls = RecursiveLeastSquares(model, sigma=sigma, forgetting=lam)
    n = len(rls.free)
    info, z = np.eye(n), np.zeros(n)
    for k in range(len(q)):
        p = model.nominal()
        p[rls.idx] += rls.scale * z
        x, J = model.predict(model.inputs(q[k : k + 1], {"payload": np.zeros(1)}), p, jacobian=True)
        H = J[0][:, rls.idx] * rls.scale
        e = y[k] - x[0]
        assert rls.update(q[k], y[k], {"payload": 0.0})
        info = lam * info + (1 - lam) * np.eye(n) + H.T @ H / sigma**2
        z = z + np.linalg.solve(info, H.T @ e / sigma**2 - (1 - lam) * z)
        np.testing.assert_allclose(rls.info, info, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(rls.z, z, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(rls.params[rls.idx], model.nominal()[rls.idx] + rls.scale * z)


def test_widen_keeps_what_was_learned_and_starts_the_new_from_the_prior():
    narrow = ErrorModel(seed_robot(), "geometric")
    wide = ErrorModel(seed_robot(), merge_effects(narrow, "backlash[1,5]"))
    assert wide.effect_names == ["geometric", "backlash[1,5]"]
    rng = np.random.default_rng(6)
    truth = sample_parameters(wide, rng)
    cols = {"payload": 0.0, **{f"dir{j}": float(rng.choice((-1, 1))) for j in range(1, 7)}}
    q = sample_poses(wide.robot, 60, rng)
    rls = RecursiveLeastSquares(narrow, sigma=15e-6)
    for k in range(30):
        c = {k_: np.array([v]) for k_, v in cols.items()}
        rls.update(q[k], wide.predict(wide.inputs(q[k : k + 1], c), truth)[0], cols)
    before_p, before_info, before_free = rls.params, rls.info, list(rls.free)
    added = rls.widen(wide)
    assert added == ["bl1", "bl5"]
    assert rls.free == [*before_free, "bl1", "bl5"]
    names = list(wide.layout.names)
    np.testing.assert_array_equal(
        rls.params[wide.layout.indices(list(narrow.layout.names))], before_p
    )
    np.testing.assert_array_equal(rls.params[wide.layout.indices(["bl1", "bl5"])], 0.0)
    n = len(before_free)
    np.testing.assert_array_equal(rls.info[:n, :n], before_info)
    np.testing.assert_array_equal(rls.info[n:, n:], np.eye(2))  # the prior, in scaled units
    np.testing.assert_array_equal(rls.info[:n, n:], 0.0)
    assert names.index("bl1") > names.index("tz")
    with pytest.raises(ValueError, match="lacks parameter"):
        rls.widen(narrow)


def test_a_widened_estimator_learns_the_new_effect():
    """Data with backlash: geometric only, the estimator is left with the direction-dependent
    error; widened half-way to backlash, it predicts new poses at the noise level."""
    narrow = ErrorModel(seed_robot(), "geometric")
    wide = ErrorModel(seed_robot(), "geometric,backlash")
    rng = np.random.default_rng(7)
    truth = sample_parameters(wide, rng)
    sigma = 15e-6
    n = 600
    q = sample_poses(wide.robot, n, rng)
    dirs = rng.choice((-1.0, 1.0), (n, 6))
    cols = {"payload": np.zeros(n), **{f"dir{j + 1}": dirs[:, j] for j in range(6)}}
    y = wide.predict(wide.inputs(q, cols), truth) + rng.normal(0.0, sigma, (n, 3))

    def row(k):
        return {c: float(v[k]) for c, v in cols.items()}

    kept, widened = (
        RecursiveLeastSquares(narrow, sigma=sigma),
        RecursiveLeastSquares(narrow, sigma=sigma),
    )
    for k in range(n):
        if k == n // 2:
            widened.widen(wide)
        kept.update(q[k], y[k], row(k))
        widened.update(q[k], y[k], row(k))
    qt = sample_poses(wide.robot, 200, rng)
    dt = rng.choice((-1.0, 1.0), (200, 6))
    ct = {"payload": np.zeros(200), **{f"dir{j + 1}": dt[:, j] for j in range(6)}}
    yt = wide.predict(wide.inputs(qt, ct), truth)

    def rms(model, p):
        e = model.predict(model.inputs(qt, ct), p) - yt
        return np.sqrt(np.mean(np.sum(e**2, axis=1)))

    assert rms(wide, widened.params) < sigma * np.sqrt(3)
    assert rms(narrow, kept.params) > 5 * rms(wide, widened.params)


def test_merge_effects_unions_joints():
    m = ErrorModel(seed_robot(), "geometric,backlash[1]")
    assert merge_effects(m, "backlash[5],compliance[2]") == [
        "geometric",
        "backlash[1,5]",
        "compliance[2]",
    ]
    assert merge_effects(m, "geometric,backlash[1]") == ["geometric", "backlash[1]"]
    assert merge_effects(ErrorModel(seed_robot(), "geometric,backlash"), "backlash[2]") == [
        "geometric",
        "backlash",
    ]
    # a cyclic error: the orders of each joint merge
    c = ErrorModel(seed_robot(), "geometric,cyclic[2:17],compliance[2]")
    assert merge_effects(c, "geometric,cyclic[2:5;3:9],compliance[3]") == [
        "geometric",
        "cyclic[2:5,17;3:9]",
        "compliance[2,3]",
    ]


def test_buffer_keeps_points_with_the_lab_columns_and_drops_the_oldest():
    buf = MeasurementBuffer(capacity=4)
    robot = seed_robot()
    rng = np.random.default_rng(8)
    q = sample_poses(robot, 6, rng)
    for k in range(6):
        cols = {"t": 0.1 * k, "temperature": 20.0, "payload": 1.5, "dir2": -1.0}
        cols |= {f"dir{j}": 1.0 for j in (1, 3, 4, 5, 6)}
        buf.append(q[k], np.full(3, float(k)), cols, accepted=k != 4)
    assert (len(buf), buf.total, buf.first) == (4, 6, 2)
    d = buf.to_measurements(since=0)
    np.testing.assert_array_equal(d.xyz[:, 0], [2.0, 3.0, 5.0])  # 4 was rejected
    assert set(d.columns) == set(MeasurementBuffer.COLUMNS)
    np.testing.assert_array_equal(d.columns["dir2"], -1.0)
    assert len(buf.to_measurements(since=3, accepted_only=False)) == 3
    tau = buf.gravity_torques(robot, since=2)
    model = ErrorModel(robot, "geometric")
    ref = model.inputs(q[2:], {"payload": np.full(4, 1.5)}).tau  # the lab's own computation
    np.testing.assert_allclose(tau, ref)
    # a column missing at some point is left out of the set, not filled in
    buf.append(q[0], np.zeros(3), {"t": 1.0}, accepted=True)
    assert set(buf.to_measurements(since=5).columns) == {"t"}


def test_update_in_place_equals_the_packed_call():
    """The update writes the point into the compiled function's argument in place; the same
    update through ToolModel.pack (columns by name, missing ones at their defaults) gives the
    same bits."""
    model = ErrorModel(seed_robot(), "geometric,backlash,thermal")
    rng = np.random.default_rng(11)
    q = sample_poses(model.robot, 30, rng)
    fast = RecursiveLeastSquares(model)
    packed = RecursiveLeastSquares(model)
    packed._fast = False
    for k in range(len(q)):
        cols = {f"dir{i}": float(rng.choice((-1.0, 1.0))) for i in range(1, 7)}
        if k % 3:
            cols["temperature"] = float(rng.uniform(15.0, 45.0))  # else the default, 20 degC
        y = np.array([0.6, 0.1, 0.7]) + 1e-3 * rng.standard_normal(3)
        assert fast.update(q[k], y, cols) == packed.update(q[k], y, cols)
        np.testing.assert_array_equal(fast.params, packed.params)
        np.testing.assert_array_equal(fast.info, packed.info)
