"""A fitted model knows its domain (issue 32, item 3): it records the ranges it was identified
over, validation outside them is warned naming the variable and how far, and a term whose form
does not repeat over what the fit covered is not extrapolated: the rows outside are predicted by
the model without it (``extrapolate=True`` keeps it), while a harmonic whose whole period was
covered holds anywhere, and one whose phase was seen a turn away holds there. A tool offset the
fit could not identify is placed with an unseen station's base, not taken as the fit left it."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from arm.description import load_robot
from arm.effects import Compliance, Cyclic, JointAngleEffect, JointScale, Transmission
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from lab import fit
from lab.domain import Domain, OutOfDomainWarning, term_dependence, unseen_phase
from lab.registration import register_points, register_stations
from lab.result import inputs_of

SIGMA = 15e-6


class _TemperatureDrift(JointAngleEffect):
    """theta_2 = q_2 + k (temperature - 20): a line in temperature (a discovered term's form)."""

    name = "temperature_drift_test"
    terms = ("kt",)
    columns = ("temperature",)
    typical = {"kt": (1e-4, 1e-3)}

    def basis(self, inputs, joint, term):
        return inputs.column("temperature") - 20.0


def _poses(n: int, rng: np.random.Generator, q2: tuple[float, float]) -> np.ndarray:
    lo = np.array([-2.5, q2[0], -1.2, -2.5, -1.8, -3.0])
    hi = np.array([2.5, q2[1], 1.2, 2.5, 1.8, 3.0])
    return rng.uniform(lo, hi, size=(n, 6))


def _measured(effects, values: dict, q, temperature, seed: int) -> MeasurementSet:
    """Points of the seed arm with ``values`` of ``effects`` and 15 um of noise per axis."""
    model = ErrorModel(load_robot("seed"), effects)
    p = model.layout.vector(values, default=model.nominal())
    data = MeasurementSet(q, np.zeros((len(q), 3)), {"temperature": temperature})
    xyz = model.predict(inputs_of(model, data), p)
    xyz = xyz + SIGMA * np.random.default_rng(seed).standard_normal(xyz.shape)
    return MeasurementSet(q, xyz, {"temperature": temperature}, source=f"campaign{seed}.csv")


def _without(res, names, data):
    p = res.params.copy()
    for n in names:
        p[res.model.layout.index(n)] = 0.0
    return res.model.predict(inputs_of(res.model, data), p)


def test_a_temperature_term_is_not_extrapolated_beyond_its_fitted_range():
    rng = np.random.default_rng(3)
    drift = _TemperatureDrift(joints=[2])
    truth = {"kt2": 8e-4}
    cal = _measured(
        ["geometric", drift], truth, _poses(150, rng, (-2.0, 0.0)), rng.uniform(22.0, 22.4, 150), 1
    )
    res = fit(cal, "seed", ["geometric", drift], noise_mm=0.015)
    assert res["kt2"] == pytest.approx(8e-4, rel=0.2)  # identified over 0.4 degC
    dom = res.domain
    lo, hi = dom.ranges["temperature"]
    assert 22.0 <= lo < 22.05 and 22.35 < hi <= 22.4
    assert Domain.from_dict(dom.to_dict()) == dom
    assert res.to_dict()["domain"]["ranges"]["temperature"] == [lo, hi]
    # half the validation poses at the fitted temperature, half 2.6 degC above it
    q = cal.q[:40]  # poses within the fitted ranges
    temp = np.where(np.arange(40) < 20, 22.2, 25.0)
    val = _measured(["geometric", drift], truth, q, temp, 2)
    with pytest.warns(OutOfDomainWarning) as rec:
        v = res.validate(val)
    text = str(rec[0].message)
    assert "campaign2.csv" in text and "temperature up to" in text
    assert f"{25.0 - hi:.4g} degC above" in text and "(20 of 40 rows)" in text
    assert "kt2" in text and "--extrapolate" in text
    assert v.validation_dropped == ("kt2",)
    assert [e.variable for e in v.validation_excursions] == ["temperature"]
    # the warm rows: the model without the term; the others: the whole model
    assert v.validation_residuals is not None
    pred = v.validation_residuals + val.xyz
    warm = temp > 24
    # the model without the term: the same rows fitted with it held at zero
    alone = fit(
        cal, "seed", ["geometric", drift], noise_mm=0.015, start={"kt2": 0.0}, fixed=["kt2"]
    )
    assert alone.n_points == res.n_points
    np.testing.assert_allclose(
        pred[warm], alone.predict(val.subset(np.flatnonzero(warm))), atol=1e-9
    )
    assert (
        np.abs(pred[warm] - _without(res, ["kt2"], val.subset(np.flatnonzero(warm)))).max() > 1e-6
    )
    np.testing.assert_allclose(
        pred[~warm], res.predict(val.subset(np.flatnonzero(~warm))), atol=1e-12
    )
    # the option keeps it, and still warns
    with pytest.warns(OutOfDomainWarning, match="extrapolated there"):
        kept = res.validate(val, extrapolate=True)
    assert kept.validation_dropped == ()
    assert kept.validation_residuals is not None
    np.testing.assert_allclose(kept.validation_residuals + val.xyz, res.predict(val), atol=1e-12)
    # within the domain: no warning, nothing left out
    inside = val.subset(np.flatnonzero(~warm))
    with warnings.catch_warnings():
        warnings.simplefilter("error", OutOfDomainWarning)
        assert res.validate(inside).validation_excursions == ()


def test_a_joint_out_of_range_drops_a_harmonic_whose_period_was_not_covered():
    """q2 fitted over 1.2 rad: its first harmonic (period 2 pi) is not extrapolated beyond it,
    its eighth (period 0.79 rad, covered) is; joint 2 read 0.5 rad below the range is named."""
    rng = np.random.default_rng(5)
    effects = ["geometric", Transmission(joints=[2]), Cyclic(orders={2: [8]})]
    truth = {"ts2": 3e-4, "tc2": -2e-4, "cs2_8": 2e-4, "cc2_8": 1e-4}
    q = _poses(200, rng, (-1.6, -0.4))
    cal = _measured(effects, truth, q, np.full(200, 21.0), 3)
    res = fit(cal, "seed", effects, noise_mm=0.015)
    deps = term_dependence(res.model, res.inputs).by_parameter
    assert deps["ts2"] == (("q2", pytest.approx(2 * math.pi)),)
    assert deps["cs2_8"] == (("q2", pytest.approx(2 * math.pi / 8)),)
    assert "c2" not in deps  # nothing of the geometry is ever dropped
    qv = cal.q[:30].copy()
    qv[:10, 1] = -2.1  # ten rows 0.5 rad below the fitted range of q2
    val = _measured(effects, truth, qv, np.full(30, 21.0), 4)
    with pytest.warns(OutOfDomainWarning) as rec:
        v = res.validate(val)
    text = str(rec[0].message)
    lo = res.domain.ranges["q2"][0]
    assert f"q2 up to {lo + 2.1:.4g} rad" in text and "below the fitted" in text
    assert "(10 of 30 rows)" in text
    assert set(v.validation_dropped) == {"ts2", "tc2"}  # the covered harmonic stays
    assert v.validation_residuals is not None
    out = np.flatnonzero(qv[:, 1] < lo)
    alone = fit(
        cal, "seed", effects, noise_mm=0.015, start={"ts2": 0.0, "tc2": 0.0}, fixed=["ts2", "tc2"]
    )
    np.testing.assert_allclose(
        v.validation_residuals[out] + val.xyz[out], alone.predict(val.subset(out)), atol=1e-9
    )
    # an arm that cannot be refitted (built elsewhere) zeroes the terms instead
    bare = replace(res, refit=None)
    np.testing.assert_allclose(
        bare.validate(val).validation_residuals[out] + val.xyz[out],
        _without(res, ["ts2", "tc2"], val.subset(out)),
        atol=1e-12,
    )


def test_a_joint_scale_holds_over_the_fitted_range_of_its_joint_only():
    """A gear-ratio error g q fitted over part of a joint's range is a line in that joint: the
    lab cannot tell it from the local slope of any other error of the joint, so it is left out of
    rows beyond the range (the UR10's series B, its joint scales carried 2-6 rad beyond, missed
    series D by 1.11x the geometric fit's; without them 0.87x). A compliance stays."""
    rng = np.random.default_rng(7)
    effects = ["geometric", JointScale(joints=[2]), Compliance(joints=[2])]
    truth = {"g2": 3e-4, "c2": 5e-6}
    q = _poses(200, rng, (-1.6, -0.4))
    cal = _measured(effects, truth, q, np.full(200, 21.0), 8)
    res = fit(cal, "seed", effects, noise_mm=0.015)
    deps = term_dependence(res.model, res.inputs).by_parameter
    assert deps["g2"] == (("q2", None),)  # a line in q2: no period
    assert "c2" not in deps  # a joint's stiffness is a law of the arm: never dropped
    qv = cal.q[:30].copy()
    qv[:10, 1] = -2.4  # ten rows 0.8 rad below the fitted range of q2
    val = _measured(effects, truth, qv, np.full(30, 21.0), 9)
    with pytest.warns(OutOfDomainWarning, match="g2"):
        v = res.validate(val)
    assert v.validation_dropped == ("g2",)
    assert v.validation_residuals is not None
    out = np.flatnonzero(qv[:, 1] < res.domain.ranges["q2"][0])
    assert out.size == 10
    alone = fit(cal, "seed", effects, noise_mm=0.015, start={"g2": 0.0}, fixed=["g2"])
    np.testing.assert_allclose(
        v.validation_residuals[out] + val.xyz[out], alone.predict(val.subset(out)), atol=1e-9
    )
    with pytest.warns(OutOfDomainWarning, match="extrapolated there"):
        kept = res.validate(val, extrapolate=True)
    assert kept.validation_dropped == ()


def test_the_exported_arm_records_its_domain_and_compensation_is_warned_outside_it(tmp_path):
    """export writes [domain]; compensating targets at a temperature beyond it warns, and the
    thermal term (a line in temperature) is left out there unless --extrapolate keeps it."""
    from arm.description import load_robot as load
    from lab.export import TargetSet, compensate, export_robot

    rng = np.random.default_rng(11)
    q = _poses(150, rng, (-2.0, 0.0))
    temp = rng.uniform(20.0, 24.0, 150)
    cal = _measured(["geometric", "thermal"], {"kappa": 2e-5}, q, temp, 5)
    res = fit(cal, "seed", "geometric,thermal", noise_mm=0.015)
    assert res["kappa"] == pytest.approx(2e-5, rel=0.3)
    path = tmp_path / "calibrated.toml"
    export_robot(res, path)
    arm = load(path)
    assert arm.domain["temperature"] == pytest.approx(res.domain.ranges["temperature"])
    assert arm.domain["n_poses"] == res.n_points
    assert "[domain]" in path.read_text()
    program = cal.subset(np.arange(5))
    targets = TargetSet(res.predict(program), q=program.q)  # the program's points, its joints
    hot = {"temperature": np.full(5, 30.0)}
    with pytest.warns(OutOfDomainWarning, match=r"temperature up to .* degC above") as rec:
        comp = compensate(arm, targets, arm, columns=hot)
    assert "kappa" in str(rec[0].message)
    # the rows outside: solved by the arm without its thermal term
    cold = replace(arm, effects={}, domain={})
    np.testing.assert_allclose(comp.q, compensate(cold, targets, arm, columns=hot).q, atol=1e-7)
    with pytest.warns(OutOfDomainWarning, match="extrapolated there"):
        kept = compensate(arm, targets, arm, columns=hot, extrapolate=True)
    assert np.abs(kept.q - comp.q).max() > 1e-6  # kappa x 10 K moves the solution
    assert kept.error_mm.max() < 1e-6


def _ur10_points(q: np.ndarray, values: dict, station: int, seed: int) -> MeasurementSet:
    """The UR10 with ``values`` (its geometric parameters, SI), 15 um of noise per axis, measured
    from tracker station ``station``."""
    model = ErrorModel(load_robot("ur10_robot"), ["geometric"])
    p = model.layout.vector(values, default=model.nominal())
    xyz = model.predict(inputs_of(model, MeasurementSet(q, np.zeros((len(q), 3)), {})), p)
    turn = station * 0.7  # each station sees the arm from its own place
    c, s = math.cos(turn), math.sin(turn)
    xyz = xyz @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T + [
        2.0 * station,
        1.0,
        -0.5,
    ]
    xyz = xyz + SIGMA * np.random.default_rng(seed).standard_normal(xyz.shape)
    cols = {"station": np.full(len(q), float(station))}
    return MeasurementSet(q, xyz, cols, source=f"station{station}.csv")


def test_a_tool_offset_the_fit_could_not_identify_is_placed_with_a_new_stations_base():
    """ISO cubes with the tool pointing down (UR10: q2 + q3 + q4 = -pi/2, q5 = -pi/2) never turn
    the flange's axis: the tool's offset along it moves every point as the base's height does,
    and the fit cannot tell them apart. Validated from another station on poses that turn the
    flange, that offset is placed with the new base (and said), not taken at whatever value
    the registration left it: the validation measures the arm that was identified."""
    rng = np.random.default_rng(5)
    truth = {"tx": 0.4e-3, "ty": -0.3e-3, "tz": 0.185}  # the nominal arm, a probe on its flange
    n = 120
    q = np.zeros((n, 6))
    q[:, 0] = rng.uniform(-1.0, 1.0, n)
    q[:, 1] = rng.uniform(-2.0, -1.2, n)
    q[:, 2] = rng.uniform(0.6, 1.6, n)
    q[:, 3] = -math.pi / 2 - q[:, 1] - q[:, 2]
    q[:, 4] = -math.pi / 2
    q[:, 5] = rng.uniform(-3.0, 3.0, n)
    cubes = _ur10_points(q, truth, 4, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fit(cubes, "ur10_robot", "geometric", noise_mm=0.015)
    assert res.unidentified_tool() == ["tz"]
    lay = res.model.layout
    tz_fitted = res.params[lay.index("tz")] + res.params[lay.index("dd6")]
    assert abs(tz_fitted - truth["tz"]) > 1e-3  # whatever the registration gave it: not the tool
    # another station, anywhere in the workspace
    q_wide = rng.uniform(
        [-2.5, -2.5, -2.0, -2.5, -2.5, -3.0], [2.5, -0.5, 2.0, 2.5, 2.5, 3.0], (80, 6)
    )
    grid = _ur10_points(q_wide, truth, 1, 2)
    # reference points measured there, which register the station (and place the tool)
    q_ref = rng.uniform(
        [-2.5, -2.5, -2.0, -2.5, -2.5, -3.0], [2.5, -0.5, 2.0, 2.5, 2.5, 3.0], (12, 6)
    )
    refs = _ur10_points(q_ref, truth, 1, 3)
    with pytest.warns(OutOfDomainWarning, match=r"tz not identified by the fit") as rec:
        v = res.validate(grid, references=refs)
    assert any("station(s) 1" in str(w.message) for w in rec)
    assert v.validation_registered == (1,)
    assert set(v.validation_tool_placed) == {"tz"}
    # the placed offset is the true tool's (the fitted dd6 moves along the same axis)
    placed = tz_fitted + v.validation_tool_placed["tz"]
    assert placed == pytest.approx(truth["tz"], abs=0.3e-3)  # the fit had it 0.5 m off

    # and the arm is predicted as well as with the true tool, placed rigidly (the reference);
    # the fit's own tool, placed rigidly, misses by the half metre the registration left
    def rigid_rms_mm(tz: float) -> float:
        p = res.params.copy()
        p[lay.index("tz")] = tz - res.params[lay.index("dd6")]
        pred = res.model.predict(inputs_of(res.model, replace(grid, columns={})), p)
        R, t = register_points(pred, grid.xyz)
        return 1e3 * float(np.sqrt(np.mean(np.sum((pred @ R.T + t - grid.xyz) ** 2, axis=1))))

    # (the station registered on 12 other points, not on the rows it validates: a little above
    # the rigid registration on those rows themselves)
    assert v.validation_rms_mm <= 1.25 * rigid_rms_mm(truth["tz"])
    assert rigid_rms_mm(tz_fitted) > 100 * v.validation_rms_mm
    assert "tz not identified by the fit" in v.summary()
    assert v.to_dict()["validation_tool_placed_mm"]["tz"] == pytest.approx(
        1e3 * v.validation_tool_placed["tz"]
    )
    # a fit that identified its tool places nothing
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = fit(grid, "ur10_robot", "geometric", noise_mm=0.015)
        assert whole.unidentified_tool() == []
        refs = cubes.subset(np.arange(12))
        assert whole.validate(cubes, references=refs).validation_tool_placed == {}


def test_a_harmonic_holds_a_whole_turn_from_where_it_was_fitted():
    """Joint 1 fitted over -1.4..1.4 rad (less than half a turn): its first harmonic is not
    fitted over a whole turn, but a reading a turn away from a fitted one (q1 + 2 pi) is the
    same phase: the term holds there, exactly as fitted; a reading at a phase the fit never saw
    (q1 = pi) still drops it. A joint scale, a line in q1, is dropped at both."""
    rng = np.random.default_rng(8)
    effects = ["geometric", Transmission(joints=[1]), JointScale(joints=[1])]
    truth = {"ts1": 3e-4, "tc1": -2e-4, "g1": 2e-4}
    q = _poses(200, rng, (-2.0, 0.0))
    q[:, 0] *= 1.4 / 2.5
    cal = _measured(effects, truth, q, np.full(200, 21.0), 5)
    res = fit(cal, "seed", effects, noise_mm=0.015)
    qv = cal.q[:20].copy()
    qv[:10, 0] += 2 * math.pi  # the same phases, a turn on
    qv[10:, 0] = math.pi  # a phase the fit did not see (0.64 rad beyond its range)
    val = _measured(effects, truth, qv, np.full(20, 21.0), 6)
    exc, drop = res.out_of_domain(val)
    assert [e.variable for e in exc] == ["q1"]
    assert not drop["ts1"][:10].any() and drop["ts1"][10:].all()
    assert drop["tc1"].tolist() == drop["ts1"].tolist()
    assert drop["g1"].all()
    # against the definition: phase seen iff some fitted reading lies a whole turn away (or
    # within the domain's margin of one)
    lo, hi = res.domain.ranges["q1"]
    v = np.linspace(-10.0, 10.0, 401)
    tol = 0.1 * (hi - lo)
    turns = np.arange(-3, 4)[:, None] * 2 * math.pi
    seen = ((v - turns >= lo - tol) & (v - turns <= hi + tol)).any(axis=0)
    np.testing.assert_array_equal(unseen_phase(v, lo, hi, 2 * math.pi), ~seen)


def test_an_eccentricity_fitted_over_half_a_turn_holds_over_the_whole_turn():
    """A first harmonic alone (the catalogue's transmission: a gear or encoder off its centre)
    errs by that sinusoid over the whole turn: fitted over 3.5 rad of joint 1 it is kept at
    readings the fit never saw (q1 2.2-2.9 rad), where it predicts the true arm to the noise;
    left out there the rows miss by the eccentricity. A joint scale beside it is still left out. Fitted
    over less than half a turn (the test above) it is still left out."""
    rng = np.random.default_rng(11)
    effects = ["geometric", Transmission(joints=[1]), JointScale(joints=[1])]
    truth = {
        "ts1": 4e-4,
        "tc1": -3e-4,
        "g1": 0.0,
    }  # the arm has no gear-ratio error: the fit finds ~0
    q = _poses(300, rng, (-2.0, 0.0))
    q[:, 0] = rng.uniform(-2.5, 1.0, size=300)
    cal = _measured(effects, truth, q, np.full(300, 21.0), 12)
    res = fit(cal, "seed", effects, noise_mm=0.015)
    deps = term_dependence(res.model, res.inputs)
    assert {"ts1", "tc1"} <= deps.once_per_turn and "g1" not in deps.once_per_turn
    qv = _poses(40, rng, (-2.0, 0.0))
    qv[:, 0] = rng.uniform(2.2, 2.9, size=40)  # beyond the fitted -2.5..1.0, a phase not seen
    val = _measured(effects, truth, qv, np.full(40, 21.0), 13)
    exc, drop = res.out_of_domain(val)
    assert [e.variable for e in exc] == ["q1"]
    assert set(drop) == {"g1"}
    with pytest.warns(OutOfDomainWarning, match="g1"):
        v = res.validate(val)
    assert v.validation_dropped == ("g1",)
    assert v.validation_residuals is not None
    kept = np.sqrt(np.mean(np.sum(v.validation_residuals**2, axis=1)))
    alone = fit(
        cal,
        "seed",
        effects,
        noise_mm=0.015,
        start={"ts1": 0.0, "tc1": 0.0, "g1": 0.0},
        fixed=["ts1", "tc1", "g1"],
    )
    dropped = np.sqrt(np.mean(np.sum((alone.predict(val) - val.xyz) ** 2, axis=1)))
    assert kept < 3 * math.sqrt(3) * SIGMA  # the true arm, to the noise
    assert dropped > 5 * kept  # without the eccentricity (0.5 mrad) the rows miss


def test_stations_placed_with_a_shared_offset_are_the_least_squares_solution():
    """register_stations against a general least-squares solve of every station's rotation
    vector and shift and the shared parameters: the same residual, the same offsets."""
    rng = np.random.default_rng(4)
    n, k = 90, 2
    pred = rng.uniform(-1.0, 1.0, (n, 3))
    columns = rng.standard_normal((n, 3, k))
    delta = np.array([0.03, -0.02])
    groups = [np.arange(n) < 40, np.arange(n) >= 40]
    turns = [Rotation.from_rotvec([0.3, -0.1, 0.2]), Rotation.from_rotvec([-0.2, 0.4, 0.1])]
    xyz = np.empty((n, 3))
    for g, R, t in zip(groups, turns, ([1.0, 2.0, 0.5], [-2.0, 0.3, 1.0]), strict=True):
        xyz[g] = R.apply(pred[g] + columns[g] @ delta) + t
    xyz += 1e-3 * rng.standard_normal(xyz.shape)
    placed, found = register_stations(pred, xyz, groups, columns)

    def residual(x):
        pts = pred + columns @ x[12:]
        out = []
        for s, g in enumerate(groups):
            R = Rotation.from_rotvec(x[6 * s : 6 * s + 3])
            out.append(R.apply(pts[g]) + x[6 * s + 3 : 6 * s + 6] - xyz[g])
        return np.concatenate(out).ravel()

    ref = least_squares(residual, np.zeros(12 + k), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    np.testing.assert_allclose(found, ref.x[12:], atol=1e-7)
    pts = pred + columns @ found
    mine = np.concatenate(
        [pts[g] @ R.T + t - xyz[g] for g, (R, t) in zip(groups, placed, strict=True)]
    )
    assert np.sum(mine**2) == pytest.approx(np.sum(ref.fun**2), rel=1e-9)
    # without shared parameters: each station rigidly alone
    alone, none = register_stations(pred, xyz, groups)
    assert none.size == 0
    for g, (R, t) in zip(groups, alone, strict=True):
        R0, t0 = register_points(pred[g], xyz[g])
        np.testing.assert_allclose(R, R0)
        np.testing.assert_allclose(t, t0)
