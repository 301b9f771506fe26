"""``sixaxis lab ... A.csv B.csv D.csv``: several files as the sessions they are, and ``sixaxis
lab update``, as a user runs them (typer's CliRunner on the real app)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from arm.measurements import MeasurementSet, read_measurements, write_measurements, write_poses
from tests._cli import lab, one_error_line
from tests._lab_data import drifting_session

UR10 = ("--robot", "ur10_robot", "--noise-mm", "0.015", "--noise-ppm", "6")
TRUTH = {"da2": 3e-4, "dalpha3": -2e-4, "dtheta2": 1e-3, "dtheta4": -2e-3, "c2": 6e-6, "c3": 4e-6}


def _draw(name: str, n: int, seed: int, drop: tuple[str, ...] = ()) -> MeasurementSet:
    data = read_measurements(f"data/ur10/series_{name}.csv")
    rows = np.sort(np.random.default_rng(seed).choice(len(data), n, replace=False))
    d = data.subset(rows)
    cols = {k: v for k, v in d.columns.items() if k not in drop}
    return MeasurementSet(d.q, d.xyz, cols, d.source, std=d.std)


@pytest.fixture(scope="module")
def ur10(tmp_path_factory) -> list[Path]:
    """Draws of the UR10's series A (no std_* columns), B and D (with them)."""
    folder = tmp_path_factory.mktemp("ur10")
    out = []
    for name, n, seed in (("A", 150, 0), ("B", 120, 1), ("D", 100, 2)):
        path = folder / f"series_{name}.csv"
        write_measurements(_draw(name, n, seed), path)
        out.append(path)
    return out


def test_fit_takes_several_files_and_names_the_sessions(ur10):
    res = lab("fit", *ur10, *UR10, "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["stations"] == [1, 2, 4]
    assert [(Path(s["source"]).name, s["rows"], s["stations"]) for s in out["sessions"]] == [
        ("series_A.csv", 150, [1]),
        ("series_B.csv", 120, [2]),
        ("series_D.csv", 100, [4]),
    ]
    # and the text names them too
    res = lab("fit", *ur10, *UR10)
    assert res.exit_code == 0, res.output
    assert "sessions: " in res.stdout and "series_D.csv (100 rows, station 4)" in res.stdout


def test_every_command_still_parses_its_options_after_the_files(ur10, tmp_path):
    # the list of files comes first; options after it (and between) still parse
    res = lab("diagnose", *ur10, *UR10, "--alpha", "0.01", "--json")
    assert res.exit_code == 0, res.output
    assert len(json.loads(res.stdout)["sessions"]) == 3
    res = lab("discover", *ur10[1:], "-o", tmp_path / "found.py", *UR10, "--order", "8", "--json")
    assert res.exit_code == 0, res.output
    assert [s["stations"] for s in json.loads(res.stdout)["sessions"]] == [[2], [4]]
    res = lab("bag", *ur10, "--bags", "1", "--poses", "60", *UR10, "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["bag"]["bags"] == 1
    res = lab("report", ur10[0], "--rounds", "1", "-o", tmp_path / "r.html", ur10[1], *UR10)
    assert res.exit_code == 0, res.output
    assert "series_B.csv (120 rows, station 2)" in (tmp_path / "r.html").read_text()


def test_a_file_without_a_station_is_its_own(ur10, tmp_path):
    plain = tmp_path / "plain.csv"
    write_measurements(_draw("B", 60, 5, drop=("station",)), plain)
    res = lab("fit", ur10[1], plain, *UR10, "--json")
    assert res.exit_code == 0, res.output
    assert [s["stations"] for s in json.loads(res.stdout)["sessions"]] == [[2], [3]]


def test_a_missing_file_among_several_is_one_error_line(ur10, tmp_path):
    one_error_line(lab("fit", ur10[0], tmp_path / "nope.csv", *UR10), "nope.csv")


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> tuple[list[Path], Path, Path]:
    """Three sessions of one drifting arm to calibrate on, 30 poses of a fourth and 200 more of
    it held out."""
    folder = tmp_path_factory.mktemp("drift")
    rng = np.random.default_rng(7)
    lo, hi = (
        np.array([-2.0, -1.8, -0.8, -2.0, -1.4, -2.5]),
        np.array([2.0, -0.7, 0.8, 2.0, 1.4, 2.5]),
    )
    files = []
    for s in (1, 2, 3):
        path = folder / f"s{s}.csv"
        write_measurements(
            drifting_session(TRUTH, 250, s, s, region=(rng.uniform(lo, hi), 0.9)), path
        )
        files.append(path)
    new = drifting_session(TRUTH, 230, 9, 9, region=(rng.uniform(lo, hi), 0.9))
    write_measurements(new.subset(np.arange(30)), folder / "new.csv")
    write_measurements(new.subset(np.arange(30, 230)), folder / "held.csv")
    return files, folder / "new.csv", folder / "held.csv"


def test_update_a_calibration_with_a_few_poses_of_a_new_session(sessions, tmp_path):
    files, new, held = sessions
    cal = tmp_path / "cal.toml"
    res = lab("export", *files, "--effects", "geometric,compliance", "-o", cal)
    assert res.exit_code == 0, res.output
    assert "[uncertainty]" in cal.read_text()
    out = tmp_path / "updated.toml"
    res = lab("update", cal, new, "--validate", held, "--predict", held, "-o", out, "--json")
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)
    # the prediction on the target beside the figure measured there
    if got["predicted"]["chosen"] == "model":  # the update itself (else its geometric fallback)
        assert got["predicted"]["measured_rms_mm"] == got["validation_rms_mm"]
    assert 0.67 <= got["validation_rms_mm"] / got["predicted"]["rms_mm"] <= 1.5
    assert got["update"]["poses"] == 30 and got["update"]["free"][:3] == ["bx", "by", "bz"]
    assert got["validation_rms_mm"] < 0.5 * got["update"]["prior_validation_rms_mm"]
    # the updated calibration is one like any other: fit on it, update it again
    res = lab("update", out, held, "--json")
    assert res.exit_code == 0, res.output


def test_update_refuses_another_robot_and_a_file_without_uncertainty(sessions, tmp_path):
    files, new, _ = sessions
    cal = tmp_path / "cal.toml"
    assert lab("export", *files, "-o", cal).exit_code == 0
    one_error_line(lab("update", cal, new, "--robot", "ur5"), "'ur5'", "'seed'")
    one_error_line(lab("update", "seed", new), "no [nominal]")
    one_error_line(lab("update", cal, new, "-o", tmp_path / "x.urdf"), "robot TOML")


def test_fit_predicts_the_accuracy_on_a_target_before_it_is_measured(sessions, tmp_path):
    files, new, held = sessions
    # a program's joints alone: a prediction, nothing measured
    program = tmp_path / "program.csv"
    write_poses(read_measurements(held).q, program)
    res = lab("fit", *files, "--effects", "geometric,compliance", "--predict", program, "--json")
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)["predicted"]
    assert got["chosen"] in ("model", "geometric") and got["blocks"] == "sessions"
    assert got["unseen"] and got["poses"] == 200 and got["measured_rms_mm"] is None
    assert got["low_mm"] <= got["rms_mm"] <= got["high_mm"]
    # with --validate the measured figure beside it (the text says both); the new station is
    # registered on separate reference poses
    res = lab(
        "fit",
        *files,
        "--effects",
        "geometric,compliance",
        "--predict",
        held,
        "--validate",
        held,
        "--references",
        new,
    )
    assert res.exit_code == 0, res.output
    assert "--predict: predicted" in res.stdout and "measured" in res.stdout
    one_error_line(lab("fit", *files, "--predict", tmp_path / "missing.csv"), "--predict")


def test_bag_predicts_on_a_program_too(sessions, tmp_path):
    files, _, held = sessions
    program = tmp_path / "program.csv"
    write_poses(read_measurements(held).q[:50], program)
    res = lab("bag", *files, "--bags", "1", "--poses", "200", "--predict", program, "--json")
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)["predicted"]
    assert got["poses"] == 50 and got["rms_mm"] > 0 and got["chosen"] in ("model", "geometric")
