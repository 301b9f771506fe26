"""What the lab's commands write and say where the user typed something unexpected: the export's
format follows the output's suffix, --json is the JSON object alone on stdout, and a slip (another
arm's held-out data, a CSV with another separator or a comment line among its rows) is named in
one line with the file and the likely cause (a noise in the wrong unit: tests/test_lab_noise.py)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from arm.description import load_robot
from arm.measurements import MeasurementError, read_measurements, write_measurements
from lab import ValidationMismatchError, ValidationMismatchWarning, fit
from tests._cli import lab, one_error_line
from tests._lab_data import campaign

DATA = Path(__file__).resolve().parents[1] / "data" / "ur5"


def _with_column(src: Path, dst: Path, name: str, value: str) -> Path:
    rows = list(csv.reader(src.open()))
    rows[0].append(name)
    for r in rows[1:]:
        r.append(value)
    with dst.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return dst


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """300 poses of the UR5 grid: fits in a second."""
    d = tmp_path_factory.mktemp("ur5")
    data = read_measurements(DATA / "calibration.csv")
    write_measurements(data.subset(np.arange(0, 1000, 3)[:300]), d / "cal.csv")
    return d / "cal.csv"


# -- the export's format ------------------------------------------------------------------------
def test_the_export_format_follows_the_output_suffix(small, tmp_path):
    urdf = tmp_path / "cal.urdf"
    res = lab("export", small, "--robot", "ur5_robot", "-o", urdf)
    assert res.exit_code == 0, res.output
    assert "<robot" in urdf.read_text() and (tmp_path / "cal.metrology.toml").is_file()
    # ... and is read back as the calibrated arm: compensation keeps the measured joints
    joints = tmp_path / "joints.csv"
    res = lab("compensate", DATA / "test.csv", "--robot", urdf, "-o", joints, "--json")
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["converged"] == 20 and summary["max_joint_change_mrad"] < 2.0
    assert summary["nominal_robot"] == load_robot("ur5_robot").name  # recorded by the export
    toml = tmp_path / "cal.toml"
    assert lab("export", small, "--robot", "ur5_robot", "-o", toml).exit_code == 0
    recorded, nominal = load_robot(toml).nominal, load_robot("ur5_robot")
    assert recorded is not None and recorded.name == nominal.name
    for key in ("alpha", "a", "d", "theta_offset", "lower", "upper"):  # through degrees
        np.testing.assert_allclose(recorded.column(key), nominal.column(key), atol=1e-12)


def test_a_format_that_the_suffix_contradicts_is_refused(small, tmp_path):
    for out, form in (("x.urdf", "toml"), ("x.toml", "urdf")):
        one_error_line(
            lab("export", small, "--robot", "ur5_robot", "-o", tmp_path / out, "--format", form),
            f"--format {form}",
            out,
        )
    assert not list(tmp_path.iterdir())


# -- --json ---------------------------------------------------------------------------------------
def test_json_is_alone_on_stdout_when_the_csv_carries_extra_columns(small, tmp_path):
    data = _with_column(small, tmp_path / "extra.csv", "extra", "1.5")
    targets = _with_column(DATA / "test.csv", tmp_path / "targets.csv", "extra", "2")
    cal = tmp_path / "cal.toml"
    assert lab("export", small, "--robot", "ur5_robot", "-o", cal).exit_code == 0
    for args in (
        ("fit", data, "--robot", "ur5_robot"),
        ("diagnose", data, "--robot", "ur5_robot", "--noise-mm", "0.015"),
        ("compensate", targets, "--robot", cal, "-o", tmp_path / "j.csv"),
    ):
        res = lab(*args, "--json")
        assert res.exit_code == 0, res.output
        assert json.loads(res.stdout)["schema_version"] == 1, args  # nothing else on stdout
        if args[0] != "compensate":
            assert "'extra'" in res.stderr and "warning" in res.stderr


# -- named slips ------------------------------------------------------------------------------------
def test_validation_far_beyond_the_fit_is_named(small, tmp_path):
    """Held-out data in another frame (the tracker moved by 0.5 m) or of another arm."""
    moved = read_measurements(DATA / "test.csv")
    moved = type(moved)(moved.q, moved.xyz + np.array([0.5, 0.0, 0.0]), moved.columns, "moved.csv")
    # 0.5 m is thousands of times the fit's RMS: no region explains it, refused
    with pytest.raises(ValidationMismatchError, match=r"moved.csv: validation RMS .* another arm"):
        fit(small, "ur5_robot", validate=moved)
    with pytest.warns(ValidationMismatchWarning, match=r"moved.csv: validation RMS .* another arm"):
        fit(small, "ur5_robot", validate=moved, accept_other_frame=True)
    # 2 mm is tens of times the fit's: a warning (poses far outside those fitted?)
    near = type(moved)(moved.q, moved.xyz - np.array([0.498, 0.0, 0.0]), moved.columns, "near.csv")
    with pytest.warns(ValidationMismatchWarning, match=r"near.csv: .* or poses far outside"):
        fit(small, "ur5_robot", validate=near)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ValidationMismatchWarning)
        res = fit(small, "ur5_robot", validate=DATA / "test.csv")  # the same arm: no word
    assert res.validation_rms_mm < 0.2
    seed_data = tmp_path / "seed.csv"
    write_measurements(campaign(load_robot("seed"), "geometric", seed=2).measure(60), seed_data)
    # the command line says it on stderr (a process of its own: its log goes there), the JSON
    # alone on stdout
    command = ["fit", str(seed_data), "--validate", str(DATA / "test.csv"), "--json"]
    res = subprocess.run(
        [sys.executable, "-m", "experiments.cli", "lab", *command],
        capture_output=True,
        text=True,
        env=os.environ | {"COLUMNS": "300"},
    )
    assert res.returncode == 2 and res.stdout == "", res.stderr
    assert "error: " in res.stderr and "test.csv: validation RMS" in res.stderr
    assert "another arm" in res.stderr and "--accept-other-frame" in res.stderr


@pytest.mark.parametrize(
    ("make", "cause"),
    [
        (lambda t: t.replace(",", ";"), "separated by semicolons, not commas"),
        (lambda t: t.replace(",", "\t"), "separated by tabs, not commas"),
    ],
)
def test_a_csv_with_another_separator_is_named(tmp_path, make, cause):
    path = tmp_path / "odd.csv"
    path.write_text(make((DATA / "test.csv").read_text()))
    with pytest.raises(MeasurementError, match=r"odd.csv, line 1: missing required") as exc:
        read_measurements(path)
    assert cause in str(exc.value)
    one_error_line(lab("fit", path, "--robot", "ur5_robot"), "odd.csv", cause)


def test_comment_lines_before_the_header_are_taken_and_one_inside_the_data_is_named(tmp_path):
    text = (DATA / "test.csv").read_text()
    noted = tmp_path / "noted.csv"
    noted.write_text("# UR5, test poses\n# tracker at the door\n" + text)
    res = lab("fit", noted, "--robot", "ur5_robot", "--validate", noted, "--json")
    assert res.exit_code == 0, res.output
    plain = lab("fit", DATA / "test.csv", "--robot", "ur5_robot", "--json")
    out, ref = json.loads(res.stdout), json.loads(plain.stdout)
    assert out["n_points"] == ref["n_points"] == 20 and out["rms_mm"] == ref["rms_mm"]
    lines = text.splitlines()
    odd = tmp_path / "odd.csv"
    odd.write_text("\n".join([*lines[:3], "# second session, 2 deg warmer", *lines[3:]]) + "\n")
    with pytest.raises(MeasurementError, match=r"odd.csv, line 4: a comment line \('#'\) among"):
        read_measurements(odd)
    res = lab("fit", noted, "--robot", "ur5_robot", "--validate", odd)
    one_error_line(res, "--validate", "odd.csv, line 4: a comment line", "before the header")


def test_a_column_that_begins_a_known_name_gets_a_suggestion(tmp_path):
    path = _with_column(DATA / "test.csv", tmp_path / "t.csv", "temp", "20")
    with pytest.warns(UserWarning, match=r"'temp' \(did you mean 'temperature'\?\)"):
        read_measurements(path)


def _codes(res) -> list[tuple[str, str]]:
    assert res.exit_code == 0, res.output
    return [(w["code"], w["message"]) for w in json.loads(res.stdout)["warnings"]]


def test_the_json_carries_every_warning_once_with_its_class(small, tmp_path):
    """fit, diagnose, discover, bag and compensate: ``warnings`` lists what the command said on
    stderr, ``{code, message}`` with the warning's class name: a column the format does not know
    (the reader's note), held-out data of other units accepted as they are; the poor pose set
    of UR10 data fitted as a UR5 (said at two fits) once, in the JSON and on stderr."""
    data = _with_column(small, tmp_path / "extra.csv", "extra", "1.5")
    targets = _with_column(DATA / "test.csv", tmp_path / "targets.csv", "extra", "2")
    # a calibration of the grid's first 100 poses: the targets' q1 reaches beyond them
    first = tmp_path / "first.csv"
    write_measurements(read_measurements(DATA / "calibration.csv").subset(np.arange(100)), first)
    cal = tmp_path / "cal.toml"
    assert lab("export", first, "--robot", "ur5_robot", "-o", cal).exit_code == 0
    for args in (
        ("fit", data, "--robot", "ur5_robot"),
        ("diagnose", data, "--robot", "ur5_robot", "--noise-mm", "0.015"),
        ("discover", data, "--robot", "ur5_robot", "--noise-mm", "0.015"),
        ("bag", data, "--robot", "ur5_robot", "--noise-mm", "0.015", "--bags", 1),
        ("compensate", targets, "--robot", cal, "-o", tmp_path / "j.csv"),
    ):
        codes = _codes(lab(*args, "--json"))
        if args[0] == "compensate":  # targets outside the poses the calibration saw
            assert [c for c, _ in codes] == ["OutOfDomainWarning"], codes
            assert "outside the fitted domain" in codes[0][1]
            continue
        notes = [m for c, m in codes if c == "MeasurementWarning"]
        assert len(notes) == 1 and "'extra'" in notes[0], (args[0], codes)
    mm = tmp_path / "test_mm.csv"
    write_measurements(read_measurements(DATA / "test.csv"), mm, length_unit="mm")
    codes = _codes(
        lab(
            "fit", small, "--robot", "ur5_robot", "--validate", mm, "--accept-other-frame", "--json"
        )
    )
    assert [c for c, _ in codes].count("ValidationMismatchWarning") == 1
    b = DATA.parent / "ur10" / "series_B.csv"
    command = ["fit", str(b), "--robot", "ur5_robot", "--noise-mm", "0.015", "--accept-large"]
    command.append("--json")
    res = subprocess.run(  # a process of its own: its log goes to its stderr
        [sys.executable, "-m", "experiments.cli", "lab", *command],
        capture_output=True,
        text=True,
        env=os.environ | {"COLUMNS": "300"},
    )
    assert res.returncode == 0, res.stderr
    codes = [w["code"] for w in json.loads(res.stdout)["warnings"]]
    assert codes.count("PoorPoseSetWarning") == 1
    assert res.stderr.count("poor pose set") == 1


def test_held_out_units_are_the_files_own(small, tmp_path):
    """A UR5 validation file in mm (607,195 mm RMS read as m): refused in one line naming the
    way out; read in mm by --validate-length-unit mm or by its '# x, y, z in mm' line (the data
    stay in m), or validated on as it is with --accept-other-frame."""
    mm = tmp_path / "test_mm.csv"
    write_measurements(read_measurements(DATA / "test.csv"), mm, length_unit="mm")
    declared = tmp_path / "declared.csv"
    declared.write_text("# tracker export, x, y, z in mm\n" + mm.read_text())
    args = ("fit", small, "--robot", "ur5_robot", "--validate")
    one_error_line(
        lab(*args, mm),
        "test_mm.csv: validation RMS 6.072e+05 mm",
        "--validate-length-unit",
        "--accept-other-frame",
    )
    good = json.loads(lab(*args, DATA / "test.csv", "--json").stdout)["validation_rms_mm"]
    assert good < 0.2
    for how in ((mm, "--validate-length-unit", "mm"), (declared,)):
        res = lab(*args, *how, "--json")
        assert res.exit_code == 0, res.output
        assert json.loads(res.stdout)["validation_rms_mm"] == pytest.approx(good, rel=1e-9)
    one_error_line(
        lab(*args, declared, "--validate-length-unit", "m"),
        "declared.csv, line 1: the file declares x, y, z in mm",
    )
    res = lab(*args, mm, "--accept-other-frame", "--json")
    assert json.loads(res.stdout)["validation_rms_mm"] > 6e5
    one_error_line(lab(*args, mm, "--validate-length-unit", "inch"), "--validate-length-unit")
