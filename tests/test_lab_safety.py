"""The lab under hostile input (issue 13): no silent wrong answer, no lost file, no crash.

Every case runs ``sixaxis lab ...`` as a user would (typer's CliRunner) and expects one line
``error: ...`` naming the file, the line, the column, the option or the parameter, exit code 2,
and no file written or replaced."""

from __future__ import annotations

import csv
import io
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from arm.description import seed_robot
from arm.measurements import atomic_path, atomic_write_text, write_measurements
from tests._cli import lab, one_error_line
from tests._lab_data import campaign

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def d(tmp_path_factory):
    """A folder with a calibration file of the seed arm (geometric errors, 60 poses)."""
    d = tmp_path_factory.mktemp("lab_safety")
    c = campaign(seed_robot(), "geometric", seed=31)
    write_measurements(c.measure(60), d / "data.csv")
    return d


def _with_cell(d: Path, name: str, column: str, cell: str, line: int = 3) -> Path:
    rows = list(csv.reader(io.StringIO((d / "data.csv").read_text())))
    rows[line - 1][rows[0].index(column)] = cell
    path = d / name
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")
    return path


# -- huge values ------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", ["fit", "diagnose", "report", "export"])
def test_a_huge_cell_is_refused_at_read_time(d, command):
    path = _with_cell(d, "huge.csv", "x", "1e308", line=5)
    out = d / f"huge_{command}.out"
    args = [command, path] + (["-o", out] if command in ("report", "export") else [])
    res = lab(*args)
    one_error_line(res, "huge.csv", "line 5", "'x'", "1e+308", "physical range")
    assert not out.exists()


def test_ranges_are_stated_in_the_files_units(d):
    path = _with_cell(d, "deg.csv", "q2", "-120.0")  # degrees read as radians
    one_error_line(lab("fit", path), "line 3", "'q2'", "-100 <= q2 <= 100 rad", "--angle-unit deg")
    one_error_line(
        lab("fit", _with_cell(d, "far.csv", "y", "2e6"), "--length-unit", "mm"),
        "'y'",
        "-1e+06 <= y <= 1e+06 mm",
    )


# -- effects and payload ----------------------------------------------------------------------------
@pytest.mark.parametrize("spec", ["compliance[]", "geometric,compliance[ ]"])
def test_an_empty_joint_list_is_refused(d, spec):
    one_error_line(lab("fit", d / "data.csv", "--effects", spec), "--effects", "empty joint list")


def test_a_negative_payload_is_refused_by_every_reader(d, tmp_path):
    toml = tmp_path / "heavy.toml"
    toml.write_text(seed_robot().to_toml().replace("payload = 0.0", "payload = -2"))
    robot_err = one_error_line(lab("fit", d / "data.csv", "--robot", toml), "heavy.toml")
    rows = list(csv.reader(io.StringIO((d / "data.csv").read_text())))
    rows[0].append("payload")
    for r in rows[1:]:
        r.append("-2" if r is rows[2] else "0")
    path = tmp_path / "payload.csv"
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")
    csv_err = one_error_line(lab("fit", path), "payload.csv", "line 3", "'payload'")
    targets = tmp_path / "targets.csv"
    targets.write_text("x,y,z,payload\n0.5,0.1,0.6,-2\n")
    tgt_err = one_error_line(
        lab("compensate", targets, "--robot", "seed", "-o", tmp_path / "j.csv"), "line 2"
    )
    rule = "payload -2 kg must be >= 0 kg"
    assert rule in robot_err and rule in csv_err and rule in tgt_err


# -- output places ----------------------------------------------------------------------------------
def test_an_output_that_is_an_input_is_refused_and_the_input_kept(d, tmp_path):
    data = d / "data.csv"
    before = data.read_bytes()
    same = d / "sub" / ".." / "data.csv"  # another spelling of the same path
    link = tmp_path / "link.csv"
    link.symlink_to(data)
    for args in (
        ["fit", data, "--out", data],
        ["diagnose", data, "--out", same],
        ["report", data, "-o", same],
        ["export", data, "-o", link],
        ["fit", data, "--validate", link, "--out", tmp_path / "link.csv"],
    ):
        one_error_line(lab(*args), "is the input", "replace")
    assert data.read_bytes() == before
    targets = tmp_path / "targets.csv"
    targets.write_text("x,y,z\n0.5,0.1,0.6\n")
    one_error_line(
        lab("compensate", targets, "--robot", "seed", "-o", targets), "--output", "is the input"
    )
    assert targets.read_text() == "x,y,z\n0.5,0.1,0.6\n"
    module = tmp_path / "mine.py"
    module.write_text("")
    one_error_line(lab("plan", "--n", 5, "--effect-module", module, "-o", module), "is the input")
    one_error_line(
        lab("discover", data, "--effect-module", module, "-o", module), "--output", "is the input"
    )


@pytest.mark.parametrize(
    "command", ["fit", "diagnose", "report", "export", "plan", "collect", "discover"]
)
def test_an_unwritable_output_is_refused_before_any_work(d, command, monkeypatch):
    import lab as lab_api

    def no_work(*a, **k):
        raise AssertionError("computed before checking the output")

    monkeypatch.setattr(lab_api, "fit", no_work)
    monkeypatch.setattr(lab_api, "diagnose", no_work)
    monkeypatch.setattr(lab_api, "plan", no_work)
    monkeypatch.setattr("lab.report.build_report", no_work)
    monkeypatch.setattr("lab.discovery.discover", no_work)
    blocked = d / "data.csv" / "sub" / "out.file"  # a path through a file
    args = {
        "fit": ["fit", d / "data.csv", "--out", blocked],
        "diagnose": ["diagnose", d / "data.csv", "--out", blocked],
        "report": ["report", d / "data.csv", "-o", blocked],
        "export": ["export", d / "data.csv", "-o", blocked],
        "plan": ["plan", "-o", blocked],
        "collect": ["collect", "-o", blocked],
        "discover": ["discover", d / "data.csv", "--out", blocked],
    }[command]
    one_error_line(lab(*args), str(blocked), "not a directory")
    if Path("/proc/self").is_dir():  # a folder where no file can be created, even by root
        one_error_line(lab(*args[:-1], "/proc/self/out.file"), "cannot write in /proc/self")


# -- temporaries ------------------------------------------------------------------------------------
def test_a_killed_writer_leaves_a_temporary_that_the_next_write_removes(tmp_path):
    target = tmp_path / "report.html"
    code = (
        "import os, signal, sys\n"
        "from arm.measurements import atomic_path\n"
        f"with atomic_path({str(target)!r}) as tmp:\n"
        "    tmp.write_text('half')\n"
        "    os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=False)
    assert res.returncode == -signal.SIGKILL
    left = list(tmp_path.glob(".report.html.*.tmp"))
    assert len(left) == 1 and not target.exists()
    # a live writer's temporary (this process's own) is never touched
    with atomic_path(target) as mine:
        mine.write_text("x")
        other = tmp_path / f".report.html.{os.getpid()}.zzzz.tmp"
        other.write_text("mine")
    atomic_write_text(target, "whole")
    assert target.read_text() == "whole"
    assert sorted(p.name for p in tmp_path.glob(".report.html.*.tmp")) == [other.name]


def test_report_removes_what_a_killed_report_left(d, tmp_path):
    out = tmp_path / "report.html"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f".report.html.{dead.pid}.abcd1234.tmp"
    stale.write_text("x" * 1000)
    res = lab("report", d / "data.csv", "-o", out, "--rounds", 0)
    assert res.exit_code == 0, res.output
    assert out.is_file() and not stale.exists()
    assert not list(tmp_path.glob(".*.tmp"))


def test_sigterm_stops_a_lab_command_like_ctrl_c(d, tmp_path):
    """SIGTERM while ``report`` writes its HTML: exit code 143, no temporary, no half file."""
    out = tmp_path / "report.html"
    code = (
        "import os, signal, sys\n"
        "from experiments.cli import app\n"
        "def fsync(fd):\n"  # the signal arrives while the temporary is open
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "os.fsync = fsync\n"
        f"sys.argv = ['sixaxis', 'lab', 'report', {str(d / 'data.csv')!r}, '-o', {str(out)!r},"
        " '--rounds', '0']\n"
        "app()\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=False
    )
    assert res.returncode == 128 + signal.SIGTERM, res.stderr
    assert "Traceback" not in res.stderr
    assert not out.exists() and not list(tmp_path.glob(".*.tmp"))


def test_json_out_is_written_only_after_the_checks(d, tmp_path):
    out = tmp_path / "deep" / "fit.json"  # a folder still to create is fine
    res = lab("fit", d / "data.csv", "--out", out)
    assert res.exit_code == 0, res.output
    assert json.loads(out.read_text())["n_points"] == 60


# -- outliers, duplicates -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def dirty(d):
    """200 poses with a hidden compliance and 2 % gross outliers (lines 4, 51, 121, 178)."""
    import numpy as np

    from arm.measurements import MeasurementSet

    c = campaign(seed_robot(), "geometric,compliance[2,3]", seed=404)
    m = c.measure(200)
    xyz = m.xyz.copy()
    rows = np.array([2, 49, 119, 176])
    xyz[rows] += [1e-3, -0.6e-3, 0.8e-3]
    write_measurements(MeasurementSet(m.q, xyz, m.columns), d / "dirty.csv")
    return d / "dirty.csv", [int(r) + 2 for r in rows]


def test_outliers_are_named_by_line_left_out_and_kept_on_request(dirty):
    path, lines = dirty
    got = json.loads(lab("diagnose", path, "--noise-mm", "0.015", "--json").stdout)
    assert got["verdict"] == "compliance" and got["outliers_mode"] == "auto"
    assert [o["line"] for o in got["outliers"]] == lines
    assert "robust sigmas" in got["outlier_rule"]
    text = lab("diagnose", path, "--noise-mm", "0.015").stdout
    assert "4 outlier(s) left out of the fit and the tests: line 4 (" in text
    assert "--outliers keep fits them" in text
    keep = json.loads(
        lab("diagnose", path, "--noise-mm", "0.015", "--outliers", "keep", "--json").stdout
    )
    assert keep["verdict"] == "unexplained" and keep["outliers"] == []
    fitted = json.loads(lab("fit", path, "--json").stdout)
    assert fitted["n_points"] == 196 and fitted["n_rows"] == 200
    assert [o["line"] for o in fitted["outliers"]] == lines
    assert "4 outlier(s) left out of the fit" in lab("fit", path).stdout
    one_error_line(lab("fit", path, "--outliers", "drop"), "--outliers", "auto, keep")


def test_the_report_names_what_every_model_left_out(dirty, tmp_path):
    path, lines = dirty
    out = tmp_path / "r.html"
    res = lab("report", path, "--noise-mm", "0.015", "-o", out, "--rounds", 1)
    assert res.exit_code == 0, res.output
    html = out.read_text()
    assert "4 gross outlier(s) left out of every model" in html
    assert all(f"line {k}:" in html for k in lines)
    assert "verdict compliance" in res.stdout and "4 outlier(s) left out" in res.stdout


def test_duplicates_are_counted_once_at_the_cli(d, tmp_path):
    import numpy as np

    from arm.measurements import read_measurements

    data = read_measurements(d / "data.csv")
    write_measurements(data.subset(np.zeros(200, dtype=int)), tmp_path / "same.csv")
    for command in ("fit", "diagnose"):
        one_error_line(lab(command, tmp_path / "same.csv"), "199 duplicate row(s)")
    write_measurements(data.subset(np.repeat(np.arange(60), 10)), tmp_path / "ten.csv")
    ten = json.loads(lab("fit", tmp_path / "ten.csv", "--json").stdout)
    once = json.loads(lab("fit", d / "data.csv", "--json").stdout)
    assert ten["parameters"] == once["parameters"] and ten["std"] == once["std"]
    assert ten["condition_number"] == once["condition_number"]
    assert len(ten["duplicates"]) == 540 and ten["duplicates"][0]["first_line"] == 2
    assert (
        "540 duplicate row(s) counted once: line 2 (copied on lines 3-11)"
        in lab("fit", tmp_path / "ten.csv").stdout
    )


# -- plausibility of the identified model ---------------------------------------------------------
PUMA560 = """
name = "puma560"
convention = "standard"
length_unit = "m"
angle_unit = "deg"

[[joints]]
alpha = 90.0
a = 0.0
d = 0.0
limits = [-160, 160]
[[joints]]
alpha = 0.0
a = 0.4318
d = 0.0
limits = [-225, 45]
[[joints]]
alpha = -90.0
a = 0.0203
d = 0.15005
limits = [-45, 225]
[[joints]]
alpha = 90.0
a = 0.0
d = 0.4318
limits = [-110, 170]
[[joints]]
alpha = -90.0
a = 0.0
d = 0.0
limits = [-100, 100]
[[joints]]
alpha = 0.0
a = 0.0
d = 0.0
limits = [-266, 266]

[[tools]]
point = [0.0, 0.0, 0.0]
"""


def test_data_in_metres_read_as_millimetres_is_refused(d, tmp_path):
    out = tmp_path / "cal.toml"
    for args in (
        ["fit", d / "data.csv", "--length-unit", "mm"],
        ["diagnose", d / "data.csv", "--length-unit", "mm", "--noise-mm", "0.015"],
        ["export", d / "data.csv", "--length-unit", "mm", "-o", out],
    ):
        one_error_line(
            lab(*args),
            "not a plausible model of 'seed'",
            "da3 = -6",
            "(bound 10 mm)",
            "1000 times smaller",
            "--length-unit m",
            "--accept-large",
        )
    assert not out.exists()  # nothing a compensation could use


def test_joint_angles_in_degrees_below_100_are_named_as_degrees(d, tmp_path):
    """Degrees under 100 pass the read's physical range but not the arm's limits: the refusal
    says degrees read as radians when every reading would be within the limits in degrees."""
    import numpy as np

    rows = list(csv.reader(io.StringIO((d / "data.csv").read_text())))
    cols = [rows[0].index(f"q{j}") for j in range(1, 7)]
    small = [r for r in rows[1:] if all(abs(np.degrees(float(r[c]))) < 100 for c in cols)]
    for r in small:
        for c in cols:
            r[c] = repr(float(np.degrees(float(r[c]))))
    assert len(small) >= 2  # the read's range (100 rad) passes them all
    path = tmp_path / "deg_small.csv"
    path.write_text("\n".join(",".join(r) for r in [rows[0], *small]) + "\n")
    one_error_line(
        lab("fit", path),
        "deg_small.csv",
        "beyond joint",
        "degrees read as radians",
        "--angle-unit deg",
    )
    radians = _with_cell(d, "one_far.csv", "q2", "3.5", line=4)  # one typo, not a unit
    assert "degrees" not in one_error_line(
        lab("fit", radians), "one_far.csv", "a typo in the file?"
    )


def test_another_robots_standard_dh_file_is_refused(d, tmp_path):
    arm = tmp_path / "puma560.toml"
    arm.write_text(PUMA560)
    err = one_error_line(lab("fit", d / "data.csv", "--robot", arm), "data.csv")
    assert (
        "not a plausible model of 'puma560'" in err
        or "cannot follow" in err
        or ("beyond joint" in err and "another arm's data, or the wrong --robot?" in err)
    ), err
    assert "robot" in err


def test_accept_large_lets_an_expert_through(d):
    got = json.loads(
        lab("fit", d / "data.csv", "--length-unit", "mm", "--accept-large", "--json").stdout
    )
    big = {b["name"]: b for b in got["implausible"]}
    assert big["da3"]["bound"] == 0.01 and big["da3"]["value"] < -0.6
    assert "bx" not in big and "tz" not in big  # base and tool are never bounded


@pytest.mark.parametrize("effect", ["compliance", "load_backlash"])
def test_an_effect_without_the_data_it_needs_is_refused(d, tmp_path, effect):
    import re

    arm = tmp_path / "massless.toml"
    arm.write_text(re.sub(r"mass = [0-9.]+", "mass = 0.0", seed_robot().to_toml()))
    one_error_line(
        lab("fit", d / "data.csv", "--robot", arm, "--effects", f"geometric,{effect}"),
        f"{effect} cannot be fitted without the arm's mass model",
        "no link masses",
    )
    text = lab("diagnose", d / "data.csv", "--robot", arm).stdout
    assert "not tested, for lack of data: compliance, load_backlash (needs the arm's mass" in text
    got = json.loads(lab("diagnose", d / "data.csv", "--robot", arm, "--json").stdout)
    assert "mass model" in got["skipped"][effect]


def test_an_effect_that_no_data_can_identify_is_refused(d, tmp_path):
    """compliance on joint 1 of the seed arm: gravity has no torque about a vertical axis."""
    one_error_line(
        lab("fit", d / "data.csv", "--effects", "geometric,compliance[1]"),
        "compliance[1] cannot be fitted from these data",
        "c1",
        "move no measured point",
    )


# -- load_backlash near zero torque ---------------------------------------------------------------
def test_one_pose_on_the_far_side_of_the_gap_at_the_cli(tmp_path):
    """The issue's case at the CLI: a pose at -0.05 N·m about joint 2 rests on the other side of
    the gap; the diagnosis names load_backlash, and says why that pose was left out."""
    from tests.test_lab_outliers import gravity_loaded_campaign

    data, _ = gravity_loaded_campaign(seed_robot(), 900, 200, odd_tau=-0.05)
    write_measurements(data, tmp_path / "lb.csv")
    got = json.loads(lab("diagnose", tmp_path / "lb.csv", "--noise-mm", "0.015", "--json").stdout)
    assert got["verdict"] == "load_backlash"
    odd = next(o for o in got["outliers"] if o["line"] == 2)  # the first pose
    assert "ambiguous for load_backlash: tau2 = -0.05 N·m" in odd["note"]
    text = lab("diagnose", tmp_path / "lb.csv", "--noise-mm", "0.015").stdout
    assert "verdict: load_backlash" in text and "line 2 (" in text and "ambiguous" in text


# -- memory ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_memory_grows_by_at_most_a_few_kb_per_pose_at_the_cli(tmp_path):
    """``sixaxis lab fit`` of geometric + compliance and ``diagnose`` of the whole catalogue, in a
    fresh interpreter each, on 8,000 and 32,000 poses: the peak resident memory grows by at most
    2 KB and 4 KB per added pose (issue 13; was 6 and 22 KB). benchmarks/lab.py measures the
    sizes up to 200,000."""
    import numpy as np

    c = campaign(seed_robot(), "geometric,compliance[2,3]", seed=77)
    files = {}
    for n in (8_000, 32_000):
        files[n] = tmp_path / f"d{n}.csv"
        write_measurements(c.measure(n), files[n])
    code = (
        "import resource, sys\n"
        "from experiments.cli import app\n"
        "try:\n"
        "    app(sys.argv[2:], standalone_mode=False)\n"
        "finally:\n"
        "    with open(sys.argv[1], 'w') as fh:\n"
        "        fh.write(str(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss))\n"
    )

    def peak(*args: object) -> float:
        out = tmp_path / "rss.txt"
        res = subprocess.run(
            [sys.executable, "-c", code, str(out), "lab", *map(str, args), "--json"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=False,
        )
        assert res.returncode == 0, res.stderr[-2000:]
        return 1024.0 * float(out.read_text())  # bytes

    for command, effects, per_pose in (
        ("fit", "geometric,compliance", 2048),
        ("diagnose", "geometric", 4096),
    ):
        small = peak(command, files[8_000], "--effects", effects)
        large = peak(command, files[32_000], "--effects", effects)
        slope = (large - small) / 24_000
        assert slope <= per_pose, (command, slope)
        assert np.isfinite(slope)


def test_a_missing_validation_file_names_the_option(d, tmp_path):
    missing = tmp_path / "nosuch.csv"
    one_error_line(lab("fit", d / "data.csv", "--validate", missing), f"--validate {missing}")
    bad = _with_cell(d, "bad_val.csv", "x", "1e308", line=5)
    one_error_line(lab("fit", d / "data.csv", "--validate", bad), "--validate", "line 5", "'x'")
