"""``sixaxis lab ...`` as a user runs it (typer's CliRunner on the real app).

The data are simulated campaigns of the pure-numpy error model (tests/_lab_data.py): a true arm
with geometric errors and, where a test says so, a hidden effect; 15 um of noise per axis. Only
``test_collect_measures_the_simulated_arm`` runs MuJoCo.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from arm.description import load_robot, seed_robot
from arm.effects import load_effect_module
from arm.measurements import MeasurementError, read_measurements, read_poses, write_measurements
from experiments.cli import app
from lab import diagnose, fit
from tests._cli import lab, one_error_line, runner
from tests._lab_data import (
    DIAGNOSE_KEYS,
    FIT_KEYS,
    FLOOR_MM,
    REAL,
    SIGMA,
    campaign,
    real_arm,
    requires_real_data,
)

ROOT = Path(__file__).resolve().parents[1]
SECOND_HARMONIC = ROOT / "examples" / "second_harmonic.py"
NOISE = str(SIGMA * 1e3)  # mm per axis


def lab_json(*args: object) -> dict:
    res = lab(*args, "--json")
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Calibration and held-out files of two arms: geometric errors only ("geo"), and geometric
    errors plus elastic joints at the low end of their range ("comp")."""
    d = tmp_path_factory.mktemp("lab_cli")
    seed = seed_robot()
    out = {"dir": d}
    for name, effects, s in (("geo", "geometric", 21), ("comp", "geometric,compliance", 22)):
        c = campaign(seed, effects, seed=s)
        for part, n in (("", 200), ("_val", 300)):
            path = d / f"{name}{part}.csv"
            write_measurements(c.measure(n), path)
            out[f"{name}{part}"] = path
        out[f"{name}_campaign"] = c
    return out


# -- fit --------------------------------------------------------------------------------------------
def test_fit_json_has_every_spec_key_and_the_python_api_numbers(files):
    path, val = files["geo"], files["geo_val"]
    out = files["dir"] / "fit.json"
    got = lab_json("fit", path, "--validate", val, "--out", out)
    assert FIT_KEYS <= set(got), FIT_KEYS - set(got)
    assert json.loads(out.read_text()) == got  # --out writes the same object

    ref = fit(read_measurements(path), "seed", "geometric", validate=read_measurements(val))
    assert got["effects"] == ["geometric"] and got["n_points"] == 200
    for k in ("rms_mm", "max_mm", "validation_rms_mm", "validation_median_mm"):
        assert got[k] == pytest.approx(getattr(ref, k), rel=1e-9), k
    assert got["rank"] == ref.rank and got["n_parameters"] == ref.n_parameters == 33
    assert got["unidentifiable"] == ref.unidentifiable
    assert got["condition_number"] == pytest.approx(ref.condition_number, rel=1e-9)
    assert got["parameters"].keys() == ref.parameters().keys()
    for name, v in ref.parameters().items():
        assert got["parameters"][name] == pytest.approx(v, rel=1e-9, abs=1e-15), name
    for name, s in ref.standard_errors().items():
        assert (got["std"][name] is None) == (s is None), name
        if s is not None:
            assert got["std"][name] == pytest.approx(s, rel=1e-9), name

    # what a user relies on: SI units, the fit at the noise floor on held-out poses, the
    # structurally unidentifiable parameters named, fixed ones without a standard error
    true = files["geo_campaign"].truth.layout.as_dict(files["geo_campaign"].params)
    for name in ("da2", "dd4", "dalpha2", "dtheta3"):  # errors in m and rad, as the truth's
        assert abs(got["parameters"][name] - true[name]) < 5 * got["std"][name], name
    assert got["validation_rms_mm"] < 1.2 * FLOOR_MM
    assert got["rms_mm"] < FLOOR_MM
    assert "dtheta1 - brz" in got["unidentifiable"] and "dd6 - tz" in got["unidentifiable"]
    assert got["std"]["dtheta1"] is None and got["std"]["da2"] > 0


def test_fit_prints_the_parameter_table_and_summary(files):
    res = lab("fit", files["geo"], "--validate", files["geo_val"])
    assert res.exit_code == 0, res.output
    text = res.stdout
    assert "identified parameters (25 of 33 fitted)" in text
    for word in ("dalpha2", "beta2", "fixed", "mrad", "validation on 300 points"):
        assert word in text, word
    assert "fixed at nominal: " in text and "dd6 - tz" in text


def test_fit_reads_mm_and_degrees_as_the_same_data(files):
    data = read_measurements(files["geo"])
    foreign = files["dir"] / "geo_mm_deg.csv"
    write_measurements(data, foreign, length_unit="mm", angle_unit="deg")
    si = lab_json("fit", files["geo"])
    mm = lab_json("fit", foreign, "--length-unit", "mm", "--angle-unit", "deg")
    assert mm["rms_mm"] == pytest.approx(si["rms_mm"], rel=1e-6)
    for name, v in si["parameters"].items():
        assert mm["parameters"][name] == pytest.approx(v, rel=1e-6, abs=1e-11), name


def test_mm_data_read_as_metres_is_no_traceback(files):
    foreign = files["dir"] / "geo_mm_deg.csv"
    write_measurements(read_measurements(files["geo"]), foreign, "mm", "deg")
    res = lab("fit", foreign)  # no --length-unit mm --angle-unit deg
    assert res.exit_code in (0, 2), res.output
    if res.exit_code == 2:
        assert res.stderr.startswith("error: ") and "geo_mm_deg.csv" in res.stderr
    else:  # a fit that says how bad it is
        assert (
            json.loads(lab("fit", foreign, "--angle-unit", "deg", "--json").stdout)["rms_mm"] > 1e3
        )


@pytest.fixture(scope="module")
def harmonic_files(files):
    """An arm with a second-harmonic transmission error on joint 3 (examples/second_harmonic.py),
    the user's effect the catalogue lacks: 200 poses and 300 held-out ones."""
    from arm import effects

    before = dict(effects.EFFECTS)
    load_effect_module(SECOND_HARMONIC)
    c = campaign(seed_robot(), "geometric,second_harmonic[3]", seed=23, hidden_level="typical")
    true = c.truth.layout.as_dict(c.params)
    d = files["dir"]
    write_measurements(c.measure(200), d / "h2.csv")
    write_measurements(c.measure(300), d / "h2_val.csv")
    effects.EFFECTS.clear()
    effects.EFFECTS.update(before)
    return d / "h2.csv", d / "h2_val.csv", true


def test_a_user_effect_module_brings_the_error_to_the_floor(harmonic_files, user_effects):
    h2, h2_val, true = harmonic_files
    plain = lab_json("fit", h2, "--validate", h2_val)
    assert plain["validation_rms_mm"] > 2 * FLOOR_MM  # the geometric model misses it
    res = lab("fit", h2, "--effects", "geometric,second_harmonic[3]")
    assert res.exit_code == 2 and "unknown effect 'second_harmonic'" in res.stderr
    full = lab_json(
        "fit",
        h2,
        "--validate",
        h2_val,
        "--effect-module",
        SECOND_HARMONIC,
        "--effects",
        "geometric,second_harmonic[3]",
    )
    assert full["effects"] == ["geometric", "second_harmonic[3]"]
    assert full["validation_rms_mm"] < 1.2 * FLOOR_MM
    for name in ("h2s3", "h2c3"):
        assert full["parameters"][name] == pytest.approx(true[name], abs=3e-5), name


def test_diagnose_names_a_user_effect_once_its_module_is_loaded(harmonic_files, user_effects):
    h2 = harmonic_files[0]
    # the catalogue alone: no effect tested whole explains it, the residual depends on q3, and
    # the scan of cyclic errors names its joint and order
    alone = lab_json("diagnose", h2, "--noise-mm", NOISE)
    assert alone["hints"][0]["variable"] == "q3"
    assert alone["verdict"] == "cyclic" and alone["suggestion"] == "geometric,cyclic[3:2]"
    mod = lab_json("diagnose", h2, "--noise-mm", NOISE, "--effect-module", SECOND_HARMONIC)
    assert mod["verdict"] == "second_harmonic"
    assert mod["candidates"][0]["effect"] == "second_harmonic"
    assert mod["candidates"][0]["joints"] == [3]
    assert mod["suggestion"] == "geometric,second_harmonic[3]"


@requires_real_data
def test_real_laser_tracker_data_through_the_cli(tmp_path):
    # the arm's description (not the data) as a robot TOML in mm and degrees, tool unknown
    arm = tmp_path / "rokae.toml"
    real_arm().save(arm, length_unit="mm", angle_unit="deg")
    got = lab_json("fit", REAL / "measurements.csv", "--robot", arm)
    assert got["n_points"] == 30 and got["rms_mm"] < 0.1
    assert got["parameters"]["tz"] == pytest.approx(0.240, abs=2e-3)  # the README's 239.9 mm
    assert math.hypot(got["parameters"]["bx"], got["parameters"]["by"]) == pytest.approx(
        math.hypot(3.6108, 3.2891), abs=0.05
    )


# -- diagnose ---------------------------------------------------------------------------------------
def test_diagnose_names_the_hidden_compliance(files):
    got = lab_json("diagnose", files["comp"], "--noise-mm", NOISE)
    assert DIAGNOSE_KEYS <= set(got), DIAGNOSE_KEYS - set(got)
    assert got["verdict"] == "compliance"
    assert got["noise_floor_mm"] == pytest.approx(FLOOR_MM)
    assert got["rms_mm"] > 2 * FLOOR_MM
    best = got["candidates"][0]
    assert {"effect", "joints", "rms_mm", "p_value", "significant"} <= set(best)
    assert best["effect"] == "compliance" and best["significant"] and 2 in best["joints"]
    assert best["rms_mm"] < 1.1 * FLOOR_MM
    assert {"variable", "score"} <= set(got["hints"][0])
    assert got["hints"][0]["variable"] in ("tau2", "q2", "tau3", "q3")
    ref = diagnose(read_measurements(files["comp"]), "seed", "geometric", noise_mm=SIGMA * 1e3)
    assert got["rms_mm"] == pytest.approx(ref.rms_mm, rel=1e-9)
    assert [c["effect"] for c in got["candidates"]] == [c.effect for c in ref.candidates]

    text = lab("diagnose", files["comp"], "--noise-mm", NOISE).stdout
    assert "verdict: compliance" in text and "compliance[2" in text and "tau2" in text


def test_diagnose_on_clean_data_finds_nothing_missing(files):
    got = lab_json("diagnose", files["geo"], "--noise-mm", NOISE)
    assert got["verdict"] == "none"
    assert not any(c["significant"] for c in got["candidates"])
    assert "verdict: none" in lab("diagnose", files["geo"], "--noise-mm", NOISE).stdout


# -- bad input --------------------------------------------------------------------------------------
def _bad_csv(d: Path, name: str, cell: str) -> Path:
    """A copy of geo.csv whose line 3 (the second pose) has ``cell`` in column q2."""
    rows = list(csv.reader(io.StringIO((d / "geo.csv").read_text())))
    rows[2][rows[0].index("q2")] = cell
    path = d / name
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")
    return path


@pytest.mark.parametrize(
    "case",
    [
        "missing file",
        "text",
        "nan",
        "missing column",
        "unknown effect",
        "bad joints",
        "length unit",
        "angle unit",
        "loss",
        "robot",
        "module",
        "too few poses",
        "noise",
        "thermal without temperature",
    ],
)
def test_bad_input_is_one_error_line_with_exit_code_2(files, case):
    d, geo = files["dir"], files["geo"]
    if case == "missing column":
        text = (d / "geo.csv").read_text().replace("q5,", "qq5,", 1)
        (d / "nocol.csv").write_text(text)
    if case == "too few poses":
        (d / "few.csv").write_text("\n".join((d / "geo.csv").read_text().splitlines()[:6]))
    if case == "thermal without temperature":
        data = read_measurements(geo)
        data.columns.pop("temperature")
        write_measurements(data, d / "notemp.csv")
    args, expect = {
        "missing file": (["fit", d / "nothere.csv"], ["nothere.csv", "not found"]),
        "text": (["fit", _bad_csv(d, "text.csv", "abc")], ["text.csv", "line 3", "'q2'", "abc"]),
        "nan": (["diagnose", _bad_csv(d, "nan.csv", "nan")], ["nan.csv", "line 3", "'q2'"]),
        "missing column": (["fit", d / "nocol.csv"], ["nocol.csv", "line 1", "q5"]),
        "unknown effect": (
            ["fit", geo, "--effects", "geometric,complience"],
            ["--effects", "unknown effect 'complience'", "compliance"],
        ),
        "bad joints": (["diagnose", geo, "--effects", "geometric,compliance[x]"], ["[x]"]),
        "length unit": (["fit", geo, "--length-unit", "in"], ["--length-unit", "'in'"]),
        "angle unit": (["diagnose", geo, "--angle-unit", "grad"], ["--angle-unit", "'grad'"]),
        "loss": (["fit", geo, "--loss", "cauchy"], ["--loss", "'cauchy'"]),
        "robot": (["fit", geo, "--robot", d / "arm.toml"], ["--robot", "arm.toml", "not found"]),
        "module": (["fit", geo, "--effect-module", d / "mine.py"], ["mine.py", "not found"]),
        "too few poses": (["fit", d / "few.csv"], ["few.csv", "5 poses", "33 parameters"]),
        "noise": (["diagnose", geo, "--noise-mm", "0"], ["--noise-mm"]),
        "thermal without temperature": (
            ["fit", d / "notemp.csv", "--effects", "geometric,thermal"],
            ["notemp.csv", "temperature", "thermal"],
        ),
    }[case]
    res = lab(*args)
    assert res.exit_code == 2, res.output
    err = res.stderr
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert "Traceback" not in res.output and res.stdout == ""
    for word in expect:
        assert word in err, (word, err)


# -- plan -------------------------------------------------------------------------------------------
def test_plan_writes_n_poses_that_read_back(files):
    out = files["dir"] / "poses.csv"
    got = lab_json("plan", "--n", 15, "--candidates", 400, "--seed", 3, "-o", out)
    q = read_poses(out)
    assert q.shape == (15, 6)
    assert np.allclose(q, got["q"], rtol=0, atol=1e-15)
    assert seed_robot().within_limits(q).all()
    assert got["o1"] > got["random_o1"]
    # the header line carries the schema version; degrees on request, same poses
    assert out.read_text().startswith("# sixaxis-track poses to measure, schema_version 1")
    deg = files["dir"] / "poses_deg.csv"
    res = lab("plan", "--n", 15, "--candidates", 400, "--seed", 3, "-o", deg, "--angle-unit", "deg")
    assert res.exit_code == 0, res.output
    assert "O1" in res.stdout and "wrote" in res.stdout
    assert np.allclose(read_poses(deg, "deg"), q, atol=1e-12)
    # the file says its unit: read without one it is the same poses, against it it is refused
    assert np.allclose(read_poses(deg), q, atol=1e-12)
    with pytest.raises(MeasurementError, match=r"line 1: the file declares q1..q6 in deg"):
        read_poses(deg, "rad")
    res = lab("collect", "--poses", deg, "--angle-unit", "rad", "-o", files["dir"] / "m.csv")
    assert res.exit_code == 2 and "say --angle-unit deg" in res.output, res.output
    assert not (files["dir"] / "m.csv").exists()
    # O4: the weakest direction planned for
    o4 = lab_json("plan", "--n", 15, "--candidates", 400, "--criterion", "O4", "-o", out)
    assert o4["criterion"] == "o4" and o4["o4"] > o4["random_o4"]
    res = lab("plan", "--criterion", "O2", "-o", out)
    assert res.exit_code == 2 and "--criterion" in res.stderr
    res = lab("plan", "--n", 15, "--candidates", 400, "-o", files["dir"])  # a directory
    assert res.exit_code == 2 and "is a directory" in res.stderr


def test_plan_near_a_program_chooses_poses_in_its_region(files):
    # a program that runs in a corner of the joint space: the poses are chosen there (its box,
    # 0.1 rad wider), not anywhere within the limits
    rng = np.random.default_rng(4)
    lo = np.array([0.5, -1.4, 0.2, -0.5, 0.3, -1.0])
    program = lo + 0.4 * rng.random((25, 6))
    prog = files["dir"] / "program.csv"
    prog.write_text("q1,q2,q3,q4,q5,q6\n" + "".join(",".join(map(str, r)) + "\n" for r in program))
    out = files["dir"] / "near.csv"
    got = lab_json("plan", "--n", 12, "--candidates", 300, "--near", prog, "-o", out)
    q = read_poses(out)
    assert q.shape == (12, 6) and np.allclose(q, got["q"], atol=1e-15)
    assert np.all(q >= program.min(axis=0) - 0.1 - 1e-9)
    assert np.all(q <= program.max(axis=0) + 0.1 + 1e-9)
    # without it the poses spread over the limits
    anywhere = np.array(lab_json("plan", "--n", 12, "--candidates", 300, "-o", out)["q"])
    assert np.ptp(anywhere[:, 0]) > 2 * np.ptp(q[:, 0])
    # a program outside the limits, or a file without joints, is refused by name
    bad = files["dir"] / "bad.csv"
    bad.write_text("q1,q2,q3,q4,q5,q6\n" + ",".join(["9"] * 6) + "\n")
    one_error_line(lab("plan", "--near", bad, "-o", out), "--near", "q1")
    none = files["dir"] / "none.csv"
    none.write_text("x,y,z\n1,2,3\n")
    one_error_line(lab("plan", "--near", none, "-o", out), "--near", "q1")


# -- report -----------------------------------------------------------------------------------------
def test_report_writes_html(files):
    out = files["dir"] / "report.html"
    res = lab(
        "report",
        files["comp"],
        "--validate",
        files["comp_val"],
        "--noise-mm",
        NOISE,
        "-o",
        out,
    )
    assert res.exit_code == 0, res.output
    html = out.read_text()
    assert html.lstrip().lower().startswith("<!doctype html")
    assert "compliance" in html and "<img" in html
    assert "verdict compliance" in res.stdout and f"wrote {out}" in res.stdout
    # the last model of the loop reaches the floor on held-out poses
    last = res.stdout.strip().splitlines()[-2]
    held = float(last.split("held-out ")[1].split(" mm")[0])
    assert held < 1.2 * FLOOR_MM, last


# -- export and compensate --------------------------------------------------------------------------
def test_export_then_compensate_reaches_the_true_arm(files):
    d, c = files["dir"], files["comp_campaign"]
    toml = d / "calibrated.toml"
    res = lab("export", files["comp"], "--effects", "geometric,compliance", "-o", toml)
    assert res.exit_code == 0, res.output
    assert load_robot(toml).name == "seed-calibrated"

    # targets: where the true arm puts its tool point at 40 reachable poses
    rng = np.random.default_rng(5)
    from arm.sampling import sample_poses

    q_true = sample_poses(seed_robot(), 40, rng)
    xyz = c.truth.predict(c.truth.inputs(q_true, {}), c.params)
    targets = d / "targets.csv"
    targets.write_text("x,y,z\n" + "".join(",".join(map(repr, map(float, p))) + "\n" for p in xyz))
    joints = d / "joints.csv"
    refused = lab("compensate", targets, "--robot", toml, "-o", joints)
    assert refused.exit_code == 2 and "--free-orientation" in refused.stderr
    summary = lab_json("compensate", targets, "--robot", toml, "-o", joints, "--free-orientation")
    assert summary["n_targets"] == 40 and summary["converged"] == 40
    assert summary["start"] == "nominal_ik" and summary["nominal_robot"] == "seed"
    q = read_poses(joints)
    # the true arm, commanded the compensated joint angles, lands on the targets (the fit's
    # error only), where the nominal inverse kinematics misses by millimetres
    miss = np.linalg.norm(c.truth.predict(c.truth.inputs(q, {}), c.params) - xyz, axis=1)
    assert 1e3 * math.sqrt(np.mean(miss**2)) < 0.02
    assert summary["start_rms_mm"] > 1.0

    res = lab("compensate", targets, "--robot", toml, "-o", joints, "--free-orientation")
    assert res.exit_code == 0, res.output
    assert "nominal inverse kinematics" in res.stdout and "orientation free" in res.stdout

    bad = d / "bad_targets.csv"
    bad.write_text("x,y,z\n0.5,0.1,0.6\n0.5,oops,0.6\n")
    res = lab("compensate", bad, "--robot", toml, "-o", joints)
    assert res.exit_code == 2 and "bad_targets.csv, line 3, column 'y'" in res.stderr
    res = lab("compensate", targets, "--robot", d / "none.toml")
    assert res.exit_code == 2 and "none.toml" in res.stderr


def test_the_effects_are_parsed_once_and_a_bad_spec_refused_before_the_data_are_read(
    files, monkeypatch
):
    """The command parses --effects once, refusing a bad specification before it reads any data,
    and hands the parsed effects to the lab, which does not parse the text again."""
    import arm.effects
    from lab import screening

    texts: list[str] = []
    original = arm.effects.parse_effects

    def counted(spec):
        if isinstance(spec, str):
            texts.append(spec)
        return original(spec)

    monkeypatch.setattr(arm.effects, "parse_effects", counted)
    monkeypatch.setattr(screening, "parse_effects", counted)
    spec = "geometric,compliance[2,3]"
    got = lab_json("fit", files["comp"], "--effects", spec, "--validate", files["comp_val"])
    assert texts == [spec]
    ref = fit(read_measurements(files["comp"]), "seed", spec)
    assert got["effects"] == ["geometric", "compliance[2,3]"] and got["rms_mm"] == ref.rms_mm
    texts.clear()
    res = lab(
        "plan", "--n", 25, "--effects", spec, "--candidates", 200, "-o", files["dir"] / "p.csv"
    )
    assert res.exit_code == 0, res.output
    assert texts == [spec]
    # refused at once: the data file, which does not exist, is not reached
    res = lab("fit", files["dir"] / "absent.csv", "--effects", "geometric,complience")
    one_error_line(res, "--effects", "unknown effect 'complience'")
    assert "absent.csv" not in res.stderr


# -- collect (MuJoCo) -------------------------------------------------------------------------------
def test_collect_measures_the_simulated_arm(files):
    d = files["dir"]
    out = d / "sim.csv"
    res = lab("collect", "-o", out, "--n", 3, "--seed", 4, "--scenario", "compliance")
    assert res.exit_code == 0, res.output
    data = read_measurements(out)
    assert len(data) == 3
    assert {"t", "temperature", "payload", *(f"dir{i}" for i in range(1, 7))} <= set(data.columns)
    # given poses (e.g. a plan's): measured there
    poses = d / "two_poses.csv"
    poses.write_text("# two poses\nq1,q2,q3,q4,q5,q6\n0,-1.2,0.3,0,0.8,0\n0.5,-1.0,0.2,0.4,0.6,1\n")
    out2 = d / "sim2.csv"
    res = lab("collect", "-o", out2, "--poses", poses, "--scenario", "geometric")
    assert res.exit_code == 0, res.output
    assert np.allclose(read_measurements(out2).q, read_poses(poses), atol=1e-4)
    res = lab("collect", "-o", out2, "--scenario", "bogus")
    assert res.exit_code == 2 and "unknown scenario 'bogus'" in res.stderr


def test_an_output_in_a_missing_folder_is_written_and_the_folder_named(tmp_path):
    """collect, as every writer, makes the folders its output needs, and says so in one line on
    stderr (without --verbose), once: a mistyped folder is seen at once."""

    def collect(out: Path) -> subprocess.CompletedProcess:
        command = ["lab", "collect", "-o", str(out), "--n", "2", "--scenario", "geometric"]
        return subprocess.run(
            [sys.executable, "-m", "experiments.cli", *command],
            capture_output=True,
            text=True,
            cwd=tmp_path,
            env=os.environ | {"COLUMNS": "300"},
        )

    res = collect(Path("some", "new", "folder", "data.csv"))
    assert res.returncode == 0, res.stderr
    assert len(read_measurements(tmp_path / "some/new/folder/data.csv")) == 2
    said = [line for line in res.stderr.splitlines() if "created the folder" in line]
    assert len(said) == 1 and "created the folder some/new/folder (it did not exist)" in said[0]
    res = collect(Path("some", "new", "folder", "again.csv"))
    assert res.returncode == 0 and "created the folder" not in res.stderr, res.stderr


def test_the_lab_commands_but_collect_do_not_load_mujoco(files):
    code = (
        "import sys\n"
        "from typer.testing import CliRunner\n"
        "from experiments.cli import app\n"
        f"r = CliRunner().invoke(app, ['lab', 'diagnose', {str(files['geo'])!r}, '--json'])\n"
        "assert r.exit_code == 0, r.output\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('mujoco', 'torch')))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]", out.stdout


def test_the_options_choices_and_ranges_are_the_librarys(files):
    """The CLI shows the vocabulary's choices and ranges and refuses a bad value in the library's
    words, naming the flag, on one line (it has no checks of its own)."""
    from lab.options import LOSSES, LabOptions

    res = runner.invoke(app, ["lab", "fit", "--help"], env={"COLUMNS": "200"})
    assert "[" + "|".join(LOSSES) + "]" in res.stdout and "[auto|keep]" in res.stdout
    for args, line in (
        (["--noise-mm", "-1"], "error: --noise-mm must be >= 0 (mm), got -1.0"),
        (["--loss", "l2"], "error: --loss must be one of linear, huber, soft_l1, got 'l2'"),
        (["--length-unit", "inch"], "error: --length-unit must be one of m, mm, got 'inch'"),
    ):
        res = lab("fit", files["geo"], *args)
        assert res.exit_code == 2 and res.stderr.strip() == line, res.stderr
    with pytest.raises(Exception, match=r"noise_mm must be >= 0 \(mm\), got -1\.0"):
        LabOptions(noise_mm=-1.0)  # the same check, in the library's own name
