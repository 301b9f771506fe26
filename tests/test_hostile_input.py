"""Hostile input, second round (issue 22): no crash, no hang, no silent answer.

Every case runs the ``sixaxis`` command as a user would (typer's CliRunner, or a subprocess where
the process itself is the point) and asserts a clean refusal: exit code 2, one line ``error: ...``
naming the input and what is wrong, no traceback, nothing written and the inputs untouched; or,
for a legitimate input, a result that says what it is. Property-based tests (hypothesis) feed the
CSV and TOML readers and the effect-module loader arbitrary text: they either read it or refuse it
with their own error, never anything else.

Devices are replicas made in ``tmp_path`` (``os.mknod`` of the character devices 1:3 and 1:7,
what ``/dev/null`` and ``/dev/full`` are): a test never touches the real ``/dev/null``, which a
broken writer running as root would replace with a regular file.
"""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from arm.description import seed_robot
from arm.files import (
    MAX_INPUT_BYTES,
    InputFileError,
    OutputError,
    atomic_path,
    atomic_write_text,
    read_input_text,
)
from arm.measurements import write_measurements
from experiments.cli import app
from tests._lab_data import campaign

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
SIXAXIS = [sys.executable, "-m", "experiments.cli"]


def sixaxis(*args: object, env: dict[str, str] | None = None):
    return runner.invoke(app, [str(a) for a in args], env=env)


def one_error_line(res, *words: str) -> str:
    """The result is a clean refusal: exit code 2, one line ``error: ...`` on stderr naming
    ``words``, no traceback."""
    assert res.exit_code == 2, (res.exit_code, res.output, res.exception)
    err = res.stderr
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert "Traceback" not in res.output
    for w in words:
        assert w in err, (w, err)
    return err


def snapshot(folder: Path) -> dict[str, tuple[int, bytes | None]]:
    """What stands in ``folder``: each entry's type and, for a regular file, its bytes."""
    out = {}
    for p in sorted(folder.iterdir()):
        st = os.lstat(p)
        out[p.name] = (
            stat.S_IFMT(st.st_mode),
            p.read_bytes() if stat.S_ISREG(st.st_mode) else None,
        )
    return out


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """A calibration file of the seed arm (geometric errors, 60 poses)."""
    d = tmp_path_factory.mktemp("hostile")
    c = campaign(seed_robot(), "geometric", seed=22)
    write_measurements(c.measure(60), d / "data.csv")
    return d / "data.csv"


def char_device(path: Path, minor: int) -> Path:
    """A replica of /dev/null (minor 3) or /dev/full (minor 7) at ``path``; skips where this
    user may not make device nodes."""
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, minor))
    except PermissionError:
        pytest.skip("making a device node needs root (CAP_MKNOD)")
    return path


# == outputs ========================================================================================
def _specials(tmp_path: Path) -> dict[str, Path]:
    """Everything that is not a regular file and may stand where an output goes."""
    null = char_device(tmp_path / "null", 3)
    full = char_device(tmp_path / "full", 7)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    folder = tmp_path / "folder"
    folder.mkdir()
    link_null = tmp_path / "link-to-null"
    link_null.symlink_to(null)
    link_fifo = tmp_path / "stdout"  # what /dev/stdout is: a link to /proc/self/fd/1
    link_fifo.symlink_to(fifo)
    return {
        "null": null,
        "full": full,
        "fifo": fifo,
        "folder": folder,
        "link-to-null": link_null,
        "stdout": link_fifo,
    }


def test_atomic_writes_refuse_what_is_not_a_regular_file(tmp_path):
    specials = _specials(tmp_path)
    before = snapshot(tmp_path)
    for name, path in specials.items():
        with pytest.raises(OutputError, match="not a regular file|is a directory") as exc:
            atomic_write_text(path, "x\n")
        assert name in str(exc.value)
        with pytest.raises(OutputError), atomic_path(path):
            pytest.fail("atomic_path gave a temporary for a special file")
    assert snapshot(tmp_path) == before  # nothing replaced, no temporary left


def test_a_link_to_a_regular_file_is_written_through_and_kept(tmp_path):
    real = tmp_path / "real.csv"
    real.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(real)
    atomic_write_text(link, "new\n")
    assert link.is_symlink() and real.read_text() == "new\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.csv", "real.csv"]


@pytest.mark.parametrize("command", ["plan", "fit", "compensate", "export"])
def test_an_output_that_is_not_a_regular_file_is_refused_not_replaced(
    data, tmp_path, command, monkeypatch
):
    import lab as lab_api

    def no_work(*a, **k):
        raise AssertionError("computed before checking the output")

    monkeypatch.setattr(lab_api, "fit", no_work)
    monkeypatch.setattr(lab_api, "plan", no_work)
    specials = _specials(tmp_path)
    targets = tmp_path / "targets.csv"
    targets.write_text("x,y,z\n0.7,0.0,0.8\n")
    before = snapshot(tmp_path)
    for name, path in specials.items():
        args = {
            "plan": ["lab", "plan", "-o", path],
            "fit": ["lab", "fit", data, "--out", path],
            "compensate": ["lab", "compensate", targets, "--robot", "seed", "-o", path],
            "export": ["lab", "export", data, "-o", path],
        }[command]
        why = "is a directory" if name == "folder" else "not a regular file"
        one_error_line(sixaxis(*args), name, why)
    assert snapshot(tmp_path) == before


def test_dash_writes_to_standard_output_and_the_tables_to_stderr(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = sixaxis("lab", "plan", "--n", 12, "--candidates", 200, "-o", "-")
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    assert lines[0].startswith("# sixaxis-track poses") and lines[1] == "q1,q2,q3,q4,q5,q6"
    assert len(lines) == 2 + 12  # the poses file and nothing else
    assert "O1" in res.stderr  # the table went to stderr
    assert list(tmp_path.iterdir()) == []  # no file named "-"
    one_error_line(sixaxis("lab", "plan", "-o", "-", "--json"), "--json", "standard output")


def test_over_long_output_names_and_paths_are_refused(tmp_path):
    long_name = tmp_path / ("a" * 300 + ".csv")
    one_error_line(sixaxis("lab", "plan", "-o", long_name), "name of 304 bytes", "at most")
    deep = tmp_path.joinpath(*["d" * 200] * 25, "p.csv")
    err = one_error_line(sixaxis("lab", "plan", "-o", deep), "a path of", "at most")
    assert len(err) < 400  # the path is shortened in the message
    assert list(tmp_path.iterdir()) == []


def test_render_refuses_a_directory_a_device_a_foreign_extension_and_a_huge_frame(tmp_path):
    folder = tmp_path / "video.mp4"
    folder.mkdir()
    null = char_device(tmp_path / "null.mp4", 3)
    before = snapshot(tmp_path)
    one_error_line(sixaxis("render", "hold", "-o", folder), "video.mp4", "is a directory")
    one_error_line(sixaxis("render", "hold", "-o", null), "null.mp4", "not a regular file")
    one_error_line(sixaxis("render", "hold", "-o", tmp_path / "v.xyz"), "v.xyz", ".mp4")
    one_error_line(
        sixaxis("render", "hold", "-o", tmp_path / "v.mp4", "--width", 20000),
        "20000",
        "4096",
    )
    assert snapshot(tmp_path) == before


def test_an_unknown_gl_backend_is_one_line(tmp_path):
    env = dict(os.environ, MUJOCO_GL="bogus", PYOPENGL_PLATFORM="bogus")
    res = subprocess.run(
        [*SIXAXIS, "render", "hold", "-o", tmp_path / "v.mp4", "--seconds", "0.1"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    err = [line for line in res.stderr.splitlines() if line.startswith("error: ")]
    assert len(err) == 1 and "MUJOCO_GL='bogus'" in err[0] and "egl" in err[0], res.stderr
    assert list(tmp_path.iterdir()) == []


# == inputs =========================================================================================
def test_inputs_that_are_not_regular_files_are_refused_before_reading(tmp_path):
    null = char_device(tmp_path / "zero", 5)  # what /dev/zero is: it never ends
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)  # reading it would wait for a writer for ever
    for path in (null, fifo, tmp_path):
        with pytest.raises(InputFileError, match="not a regular file"):
            read_input_text(path)


def test_an_input_beyond_its_size_limit_is_refused_unread(tmp_path, monkeypatch):
    big = tmp_path / "big.csv"
    big.write_text("q1\n" + "0\n" * 600)
    monkeypatch.setitem(MAX_INPUT_BYTES, "csv", 1000)
    with pytest.raises(InputFileError, match="big.csv: 1.17 KiB; files are read up to 1000"):
        read_input_text(big)
