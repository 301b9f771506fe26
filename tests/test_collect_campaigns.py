"""Simulated campaigns beyond one 3-D point (envs.collect): poses measured from several tracker
stations, each in its own frame; a 6-DoF probe whose orientation, in the rows where it is seen,
is the truth's last frame turned by the probe's mounting; noise that grows with the distance from
the tracker, as each row's stated uncertainty says; and the file that reads back."""

from __future__ import annotations

import numpy as np
import pytest

from arm import read_measurements, seed_robot
from arm.noise import InstrumentNoise
from arm.so3 import rotation_matrix
from envs.collect import CollectError, collect_measurements
from envs.instrument import TrackerStation
from envs.scenarios import draw_truth

ROBOT = seed_robot()
STATIONS = [
    TrackerStation((3.0, -1.0, 0.5), (0.002, -0.001, 2.5)),
    TrackerStation((-2.0, 4.0, 1.0), (0.0, 0.003, -1.0)),
]
TURN = (0.4, -1.1, 0.7)


@pytest.fixture(scope="module")
def truth():
    return draw_truth("geometric", ROBOT, np.random.default_rng(11))


def test_each_station_measures_in_its_own_frame_and_the_probe_turns_with_the_tool(truth):
    n = 10
    plain = collect_measurements(truth, n=n, seed=4, noise_mm=0.0)
    data = collect_measurements(
        truth,
        n=n,
        seed=4,
        noise_mm=0.0,
        stations=STATIONS,
        orientation=True,
        noise_mrad=0.0,
        tool_rotation=TURN,
    )
    np.testing.assert_array_equal(data.q, plain.q)
    np.testing.assert_array_equal(data.columns["station"], [1] * 5 + [2] * 5)
    # the truth's kinematic model, not the plant's MuJoCo frames, says where the tool frame is
    _, R6 = truth.model.predict_pose(truth.model.inputs(plain.q), truth.params)
    for k, st in enumerate(STATIONS):
        rows = data.columns["station"] == k + 1
        Rs = rotation_matrix(np.array(st.rotation))
        want = (plain.xyz[rows] - st.position) @ Rs
        np.testing.assert_allclose(data.xyz[rows], want, atol=1e-12)
        turned = np.einsum("ji,njk->nik", Rs, R6[rows] @ rotation_matrix(np.array(TURN)))
        np.testing.assert_allclose(rotation_matrix(data.orientation[rows]), turned, atol=1e-9)
    assert data.measured.all()


def test_noise_grows_with_distance_as_the_stated_uncertainties_say(truth, tmp_path):
    n = 16
    kw = dict(n=n, seed=8, stations=2, orientation=True, orientation_fraction=0.5)
    clean = collect_measurements(truth, noise_mm=0.0, noise_mrad=0.0, **kw)
    path = tmp_path / "campaign.csv"
    data = collect_measurements(
        truth, noise_mm=0.015, noise_ppm=6.0, noise_mrad=0.2, stds=True, path=path, **kw
    )
    law = InstrumentNoise(mm=0.015, ppm=6.0, mrad=0.2)
    distance = np.linalg.norm(clean.xyz, axis=1)  # the tracker at its station's origin
    np.testing.assert_allclose(data.std[:, 0], law.point_sigma(distance), rtol=1e-9)
    assert np.ptp(distance) > 0.5 and np.ptp(data.std[:, 0]) > 3e-6  # stations metres apart
    # each row's noise is drawn with its own sigma: whitened, it is standard normal
    z = (data.xyz - clean.xyz) / data.std[:, :3]
    assert 0.6 < z.std() < 1.4 and abs(z.mean()) < 0.5
    # the probe is seen in some rows; the others leave the orientation blank
    seen = data.measured[:, 3]
    assert 0 < seen.sum() < n
    assert np.all(np.isnan(data.std[~seen, 3:])) and np.allclose(data.std[seen, 3:], 2e-4)
    back = read_measurements(path)
    np.testing.assert_array_equal(back.measured, data.measured)
    np.testing.assert_allclose(back.std[:, :3], data.std[:, :3], rtol=1e-15)
    # the instrument model gives the stated uncertainties back from the file alone
    np.testing.assert_allclose(law.sigmas(back)[:, 0], data.std[:, 0], rtol=1e-4)
    assert back.stations == (1, 2)
    with pytest.raises(CollectError, match="orientation_fraction"):
        collect_measurements(truth, n=2, orientation=True, orientation_fraction=1.5)


def test_the_command_line_collects_fits_and_validates_a_campaign_from_stations(tmp_path):
    """lab collect from two stations with a 6-DoF probe; lab fit of it weighs each row by its
    stated uncertainty, fits one base per station and the orientation; a validation campaign of
    the same arm from a third station has its base registered on reference points measured
    there, and the output says so."""
    import json

    from typer.testing import CliRunner

    from experiments.cli import app

    runner = CliRunner()
    common = ["--scenario", "geometric", "--orientation", "--noise-ppm", "6", "--stds"]
    fit_csv, val_csv = tmp_path / "fit.csv", tmp_path / "val.csv"
    args = ["-n", "40", "--seed", "1", "--stations", "2", "--orientation-fraction", "0.8"]
    r = runner.invoke(app, ["lab", "collect", "-o", str(fit_csv), *args, *common])
    assert r.exit_code == 0, r.output
    args = ["-n", "12", "--seed", "2", "--arm-seed", "1", "--stations", "1", "--first-station", "3"]
    r = runner.invoke(app, ["lab", "collect", "-o", str(val_csv), *args, *common])
    assert r.exit_code == 0, r.output
    # 4 of its rows as reference points of the third station: they register it, and are left
    # out of the validation figure
    refs_csv = tmp_path / "refs.csv"
    lines = val_csv.read_text().splitlines()
    head = [t for t in lines if t.startswith("#")]
    rows = [t for t in lines if not t.startswith("#")]
    refs_csv.write_text("\n".join([*head, *rows[:5]]) + "\n")
    given = ["lab", "fit", str(fit_csv), "--validate", str(val_csv), "--json"]
    r = runner.invoke(app, [*given, "--references", str(refs_csv)])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["stations"] == [1, 2] and out["weighted"] is True
    assert out["validation_registered"] == [3]
    assert out["validation_registrations"][0]["n_points"] == 4
    assert {"trx", "try", "trz", "bx1", "bx2"} <= set(out["parameters"])
    assert out["orientation_rms_mrad"] < 0.5 and out["validation_rms_mm"] < 0.2
    assert out["validation_orientation_rms_mrad"] < 0.5  # the same probe on the same arm
    # the positions alone, from the same file
    r = runner.invoke(app, ["lab", "fit", str(fit_csv), "--measured", "x,y,z", "--json"])
    assert r.exit_code == 0, r.output
    pos = json.loads(r.stdout)
    assert pos["orientation_rms_mrad"] is None and "trx" not in pos["parameters"]
    assert pos["rank"] < out["rank"]
    # an unknown column is named, not dropped
    text = fit_csv.read_text().splitlines()
    extra = tmp_path / "extra.csv"
    extra.write_text("\n".join([text[0] + ",humidity"] + [t + ",40" for t in text[1:]]) + "\n")
    r = runner.invoke(app, ["lab", "fit", str(extra)])
    assert r.exit_code == 0, r.output
    assert "warning:" in r.output and "'humidity'" in r.output
