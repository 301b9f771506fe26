"""The lab beyond one 3-D point (issue 19's must-show): on a simulated campaign with 6-DoF poses,
per-point stds and two tracker stations, the weighted, station-aware fit predicts held-out poses
better than the naive one (each station's positions fitted alone, unweighted: what the lab could
do before), each step of the way; orientation rows raise the rank and lower the condition
number, in the fit and in the plan; a validation set from a station the fit has not seen has only
its base registered, and says so; the diagnosis tests the weighted rows; and the plain case keeps
its numbers."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import lab
from arm.description import seed_robot
from arm.measurements import MeasurementSet
from lab import report_html
from tests._beyond_points import pose_campaign


def _held_out_error_um(pred: np.ndarray, truth: np.ndarray) -> float:
    """3-D RMS of the model's points against the true (noise-free) ones, um."""
    return 1e6 * float(np.sqrt(np.mean(np.sum((pred - truth) ** 2, axis=1))))


@pytest.fixture(scope="module")
def campaign():
    c = pose_campaign(seed_robot(), seed=1)
    data, _ = c.measure(60)  # stations 1 and 2, 6-DoF, each row's stds
    held, truth = c.measure(200)  # the same stations, other poses
    return c, data, held, truth


def _quiet_fit(*args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return lab.fit(*args, **kw)


def test_the_weighted_station_aware_fit_predicts_held_out_poses_better(campaign):
    """Naive: each station's positions fitted alone, unweighted (before stations, a file held
    one base). Then one fit of both stations (the arm shared), then weighted by the rows' stds,
    then with the orientation rows too: each lowers the held-out error of the arm's model."""
    _, data, held, truth = campaign
    station, held_station = data.columns["station"], held.columns["station"]
    sq = []
    for s in (1, 2):
        on, off = station == s, held_station == s
        alone = _quiet_fit(MeasurementSet(data.q[on], data.xyz[on], {}, "station alone"))
        pred = alone.predict(MeasurementSet(held.q[off], held.xyz[off], {}, "held out"))
        sq.append(np.sum((pred - truth[off]) ** 2, axis=1))
    naive = 1e6 * float(np.sqrt(np.mean(np.concatenate(sq))))
    stations = _quiet_fit(MeasurementSet(data.q, data.xyz, data.columns, "no stds"))
    weighted = _quiet_fit(data, measured=("x", "y", "z"))
    poses = _quiet_fit(data)
    errors = [_held_out_error_um(r.predict(held), truth) for r in (stations, weighted, poses)]
    assert weighted.weighted and poses.weighted and not stations.weighted
    assert poses.orientation_rms_mrad is not None and weighted.orientation_rms_mrad is None
    # naive 61 um, one fit of both stations 49, weighted 37, with orientations 22 (measured)
    assert errors[-1] < 0.6 * naive, (naive, errors)
    assert naive > errors[0] > errors[1] > errors[2], (naive, errors)


def test_orientation_rows_raise_the_rank_and_lower_the_condition_number(campaign):
    _, data, _, _ = campaign
    positions = _quiet_fit(data, measured=("x", "y", "z"))
    poses = _quiet_fit(data)
    # dalpha6, da6 (and more) come out of the orientation; the tool frame's rotation is new
    assert poses.rank - 3 > positions.rank, (positions.rank, poses.rank)
    assert poses.condition_number < positions.condition_number
    assert {"trx", "try", "trz"} <= set(poses.names) - set(positions.names)
    # planning for a 6-DoF instrument: the same
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        p3 = lab.plan(30, "seed", "geometric", candidates=400)
        p6 = lab.plan(30, "seed", "geometric", candidates=400, noise_mrad=0.05)
    assert p6.identifiability.rank > p3.identifiability.rank
    assert p6.identifiability.condition_number < p3.identifiability.condition_number


def test_a_station_the_fit_has_not_seen_has_only_its_base_registered(campaign):
    """Held-out rows of a new station are predicted through its frame registered on reference
    points measured there (the arm as fitted, nothing refitted); without them it is refused."""
    c, data, _, _ = campaign
    other, _ = c.measure(30, stations=(3,))
    refs, _ = c.measure(4, stations=(3,), orientation_fraction=0.0)
    with pytest.raises(lab.RegistrationError, match=r"station\(s\) 3 not among.*--references"):
        _quiet_fit(data, validate=other)
    res = _quiet_fit(data, validate=other, references=refs)
    assert res.validation_registered == (3,)
    assert "station 3 registered on 4 reference points" in res.summary()
    assert res.to_dict()["validation_registered"] == [3]
    (reg,) = res.to_dict()["validation_registrations"]
    assert reg["station"] == 3 and reg["n_points"] == 4 and 0 < reg["rms_mm"] < 0.1
    # the arm as fitted: its held-out error is the model's and the registration's (4 points)
    sigma = float(np.median(other.std[:, 0]))
    assert res.validation_rms_mm < 1e3 * 4 * sigma * np.sqrt(3)
    assert res.validation_orientation_rms_mrad is not None
    assert res.validation_orientation_rms_mrad < 0.5
    np.testing.assert_array_equal(res.params, _quiet_fit(data).params)  # nothing refitted
    # a fit of one station validated from another: the same
    one = data.subset(np.flatnonzero(data.columns["station"] == 1))
    single = _quiet_fit(one, validate=other, references=refs)
    assert single.validation_registered == (3,)
    # reference rows given as held-out too are left out of the figure
    first = other.subset(np.arange(4))
    both = _quiet_fit(data, validate=other, references=first)
    rest = _quiet_fit(data, validate=other.subset(np.arange(4, 30)), references=first)
    assert len(both.validation_residuals) == 26
    assert both.validation_rms_mm == pytest.approx(rest.validation_rms_mm, rel=1e-12)


def test_the_diagnosis_tests_the_weighted_rows():
    c = pose_campaign(seed_robot(), seed=1, effects="geometric,compliance")
    data, _ = c.measure(150, orientation_fraction=0.7)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = lab.diagnose(data, "seed", "geometric")
    assert d.fit.weighted and d.fit.orientation_rms_mrad is not None
    assert d.verdict == "compliance" and d.suggestion == "geometric,compliance[2,3]"
    assert d.chi2_p_value_after is not None and d.chi2_p_value_after > 0.01


def test_orientations_without_a_stated_uncertainty_leave_the_positions_alone(campaign):
    """No std_rx.. and no --noise-mrad: the orientations cannot be weighed against positions;
    the positions are fitted, with a warning; asking for the orientation then is refused."""
    _, data, _, _ = campaign
    bare = MeasurementSet(
        data.q, data.xyz, data.columns, "no stds", orientation=data.orientation, mask=data.mask
    )
    with pytest.warns(lab.OrientationNotFittedWarning):
        res = lab.fit(bare, "seed", "geometric")
    assert res.orientation_rms_mrad is None and "trx" not in res.names
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stated = lab.fit(bare, "seed", "geometric", noise_mm=0.03, noise_mrad=0.05)
    assert stated.orientation_rms_mrad is not None and "trx" in stated.names
    with pytest.raises(lab.FitError, match="--noise-mrad"):
        lab.fit(bare, "seed", "geometric", measured=("x", "y", "z", "rx", "ry", "rz"))


def test_a_6dof_fit_of_two_stations_exports_and_reads_back(campaign, tmp_path):
    """The calibrated arm carries the first station's base and the tool frame's rotation
    ([effects.geometric] trx try trz); read back, it predicts that station's fitted poses."""
    from arm.description import load_robot
    from arm.errormodel import ErrorModel
    from lab.export import export_robot

    _, data, _, _ = campaign
    res = _quiet_fit(data)
    back = export_robot(res, tmp_path / "cal.toml")
    assert load_robot(tmp_path / "cal.toml").effects["geometric"] == pytest.approx(
        {n: res[n] for n in ("trx", "try", "trz")}
    )
    first = data.subset(np.flatnonzero(data.columns["station"] == 1))
    model = ErrorModel(back, orientation=True)
    inputs = model.inputs(first.q)
    xyz, R = model.predict_pose(inputs, model.nominal())
    fitted = res.predict(first)
    np.testing.assert_allclose(xyz, fitted, atol=1e-9)
    _, R_fit = res.model.predict_pose(res.model.inputs(first.q, first.columns), res.params)
    np.testing.assert_allclose(R, R_fit, atol=1e-9)


def test_the_report_says_what_was_fitted_beyond_points(campaign, tmp_path):
    from lab.report import build_report

    c, data, _, _ = campaign
    other, _ = c.measure(20, stations=(3,))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        refs, _ = c.measure(4, stations=(3,), orientation_fraction=0.0)
        report = build_report(data, "seed", "geometric", validate=other, references=refs, rounds=0)
    html = report_html.render(report)
    assert "tracker stations 1, 2, one base each" in html
    assert "orientations fitted too" in html and "weighted by its stated uncertainty" in html
    assert "validation station(s) 3 not in the fit" in html


def test_identifiability_of_the_poses_is_the_fits_own(campaign):
    """lab.identifiability_of, asked before any fit, sees the rows a fit would: one base per
    station and the orientation rows where their uncertainty is stated. Its rank is the rank of
    the fit's identification at the nominal arm, and the orientation rows raise it there too."""
    _, data, _, _ = campaign
    positions = lab.identifiability_of(data, "seed", measured=("x", "y", "z"))
    poses = lab.identifiability_of(data, "seed")
    assert {"bx2", "trx"} <= set(poses.names)
    assert "trx" not in positions.names
    assert poses.rank - 3 > positions.rank
    assert poses.condition_number < positions.condition_number
    fitted = _quiet_fit(data)
    assert set(poses.names) == set(fitted.names)
    assert poses.rank == fitted.rank
