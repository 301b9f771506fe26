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
from typer.testing import CliRunner

from arm.description import seed_robot
from arm.measurements import atomic_path, atomic_write_text, write_measurements
from experiments.cli import app
from tests._lab_data import campaign

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]


def lab(*args: object):
    return runner.invoke(app, ["lab", *map(str, args)])


def one_error_line(res, *words: str) -> str:
    assert res.exit_code == 2, res.output
    err = res.stderr
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert "Traceback" not in res.output
    for w in words:
        assert w in err, (w, err)
    return err


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


@pytest.mark.parametrize("command", ["fit", "diagnose", "report", "export", "plan", "collect"])
def test_an_unwritable_output_is_refused_before_any_work(d, command, monkeypatch):
    import lab as lab_api

    def no_work(*a, **k):
        raise AssertionError("computed before checking the output")

    monkeypatch.setattr(lab_api, "fit", no_work)
    monkeypatch.setattr(lab_api, "diagnose", no_work)
    monkeypatch.setattr(lab_api, "plan", no_work)
    monkeypatch.setattr("lab.report.build_report", no_work)
    blocked = d / "data.csv" / "sub" / "out.file"  # a path through a file
    args = {
        "fit": ["fit", d / "data.csv", "--out", blocked],
        "diagnose": ["diagnose", d / "data.csv", "--out", blocked],
        "report": ["report", d / "data.csv", "-o", blocked],
        "export": ["export", d / "data.csv", "-o", blocked],
        "plan": ["plan", "-o", blocked],
        "collect": ["collect", "-o", blocked],
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
