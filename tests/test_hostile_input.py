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

import copy
import os
import stat
import string
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from arm.description import seed_robot
from arm.effects import load_effect_module
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
from tests._cli import one_error_line, runner
from tests._lab_data import campaign, with_gross_outliers

ROOT = Path(__file__).resolve().parents[1]
SIXAXIS = [sys.executable, "-m", "experiments.cli"]


def sixaxis(*args: object, env: dict[str, str] | None = None):
    return runner.invoke(app, [str(a) for a in args], env=env)


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
        with pytest.raises(OutputError, match=r"not a regular file|is a directory") as exc:
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


_LONG = "a" * 300
_DATA = ROOT / "data" / "ur5" / "calibration.csv"
# every file a `sixaxis lab` command opens, reads, checks or writes, given a name the OS refuses
_LONG_FILE_OPTIONS = {
    "fit DATA": ("fit", f"{_LONG}.csv"),
    "fit --robot FILE.toml": ("fit", _DATA, "--robot", f"{_LONG}.toml"),
    "fit --robot FILE.urdf": ("fit", _DATA, "--robot", f"{_LONG}.urdf"),
    "fit --robot NAME": ("fit", _DATA, "--robot", _LONG),
    "fit --validate": ("fit", _DATA, "--robot", "ur5_robot", "--validate", f"{_LONG}.csv"),
    "fit --effect-module": ("fit", _DATA, "--effect-module", f"{_LONG}.py"),
    "fit --out": ("fit", _DATA, "--out", f"{_LONG}.json"),
    "fit --out in a folder": ("fit", _DATA, "--out", f"{_LONG}/fit.json"),
    "diagnose DATA": ("diagnose", f"{_LONG}.csv"),
    "diagnose --out": ("diagnose", _DATA, "--out", _LONG),
    "discover -o": ("discover", _DATA, "-o", f"{_LONG}.py"),
    "discover --validate": ("discover", _DATA, "--validate", _LONG),
    "bag -o": ("bag", _DATA, "-o", f"{_LONG}.py"),
    "bag --export": ("bag", _DATA, "--export", f"{_LONG}.toml"),
    "report -o": ("report", _DATA, "-o", f"{_LONG}.html"),
    "plan -o": ("plan", "-o", f"{_LONG}.csv"),
    "plan --robot": ("plan", "--robot", _LONG),
    "collect -o": ("collect", "-o", f"{_LONG}.csv"),
    "collect --poses": ("collect", "-o", "{tmp}/m.csv", "--poses", f"{_LONG}.csv"),
    "export -o": ("export", _DATA, "-o", f"{_LONG}.toml"),
    "export --robot": ("export", _DATA, "--robot", f"{_LONG}.urdf"),
    "compensate TARGETS": ("compensate", f"{_LONG}.csv", "--robot", "seed"),
    "compensate --robot": ("compensate", _DATA, "--robot", f"{_LONG}.toml"),
    "compensate --nominal": ("compensate", _DATA, "--robot", "seed", "--nominal", _LONG),
    "compensate -o": ("compensate", _DATA, "--robot", "seed", "-o", f"{_LONG}.csv"),
    "compensate --references": (
        "compensate",
        _DATA,
        "--robot",
        "seed",
        "--references",
        f"{_LONG}.csv",
    ),
    "fit --references": ("fit", _DATA, "--validate", _DATA, "--references", f"{_LONG}.csv"),
    "export --from": ("export", "--from", f"{_LONG}.toml", "-o", "{tmp}/x.toml"),
    "compensate --effect-module": (
        "compensate",
        _DATA,
        "--robot",
        "seed",
        "--effect-module",
        f"{_LONG}.py",
    ),
}


@pytest.mark.parametrize("case", sorted(_LONG_FILE_OPTIONS))
def test_a_file_name_the_os_refuses_is_an_error_line_for_every_file_option(
    case, tmp_path, monkeypatch
):
    """A name over 255 bytes (``OSError: File name too long`` where ``Path.is_file`` looks at
    it) in any file option of any lab command: one line, exit 2, no traceback, nothing written,
    the name shortened in the message."""
    cmd, *args = _LONG_FILE_OPTIONS[case]
    args = [str(a).replace("{tmp}", str(tmp_path)) for a in args]
    monkeypatch.chdir(tmp_path)
    err = one_error_line(sixaxis("lab", cmd, *args))
    assert len(err) < 400
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
    with pytest.raises(InputFileError, match=r"big\.csv: 1\.17 KiB; files are read up to 1000"):
        read_input_text(big)


def test_a_small_input_costs_its_size_not_the_limit(tmp_path):
    """The reader allocates what the file holds: a read of the 1 GiB limit made every CSV read
    cost a 1 GiB buffer (the lab's memory benchmark saw it)."""
    import tracemalloc

    small = tmp_path / "small.csv"
    small.write_text("q1\n" + "0.5\n" * 1000)
    tracemalloc.start()
    try:
        text = read_input_text(small)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert text.count("\n") == 1001
    assert peak < 100_000, peak


# == the measurement CSV ============================================================================
def _rewrite(data: Path, dest: Path, edit) -> Path:
    lines = data.read_text().splitlines()
    dest.write_text("\n".join(edit(lines)) + "\n")
    return dest


def test_a_negative_target_id_is_refused_naming_the_line(data, tmp_path):
    def negative(lines):
        return [lines[0] + ",target"] + [
            row + ("," + ("-3" if i == 4 else "1")) for i, row in enumerate(lines[1:])
        ]

    path = _rewrite(data, tmp_path / "t.csv", negative)
    one_error_line(
        sixaxis("lab", "fit", path), "t.csv", "line 6", "'target'", "0 <= target <= 1e+06"
    )


@pytest.mark.parametrize("quoted", [False, True])
def test_a_cell_beyond_the_readers_limit_is_refused_naming_the_line(data, tmp_path, quoted):
    def huge(lines):
        cell = '"' + "9" * 200_000 + '"' if quoted else "0" * 200_000
        lines[5] = lines[5] + cell
        return lines

    path = _rewrite(data, tmp_path / "c.csv", huge)
    one_error_line(sixaxis("lab", "fit", path), "c.csv", "line 6", "131072 characters")


def test_a_fifo_or_a_device_as_data_is_refused_without_waiting(tmp_path):
    fifo = tmp_path / "data.csv"
    os.mkfifo(fifo)
    zero = char_device(tmp_path / "zero", 5)
    for command in (["fit"], ["diagnose"], ["compensate", "--robot", "seed"]):
        for path in (fifo, zero):
            one_error_line(sixaxis("lab", command[0], path, *command[1:]), "not a regular file")
    poses = tmp_path / "poses.csv"
    os.mkfifo(poses)
    one_error_line(sixaxis("lab", "collect", "-o", tmp_path / "out.csv", "--poses", poses), "FIFO")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv", "poses.csv", "zero"]


@pytest.mark.parametrize(
    "args, words",
    [
        (["plan", "--seed", -1], ["seed", "non-negative", "-1"]),
        (["plan", "--candidates", 10**12], ["candidates", "1 to 100,000"]),
        (["collect", "--seed", -1], ["--seed", "non-negative"]),
        (["collect", "--arm-seed", -5], ["--arm-seed", "non-negative"]),
        (["collect", "--n", 2 * 10**12], ["n (poses to measure)", "1 to 1,000,000"]),
    ],
)
def test_seeds_and_counts_out_of_bounds_are_refused_before_any_work(tmp_path, args, words):
    out = tmp_path / "out.csv"
    one_error_line(sixaxis("lab", *args, "-o", out), *words)
    assert not out.exists()


# == the robot TOML =================================================================================
def _robot(tmp_path: Path, text: str | bytes, name: str = "robot.toml") -> Path:
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


SEED_TOML = (ROOT / "arm" / "robots" / "seed.toml").read_text()


@pytest.mark.parametrize(
    "extra, words",
    [
        ("[effects.bogus]\nx1 = 1.0\n", ["[effects.bogus]", "unknown effect 'bogus'"]),
        ("[effects.compliance]\nc9 = 1e-6\n", ["[effects.compliance]", "'c9'", "c1, c2"]),
    ],
)
def test_unknown_effects_and_parameters_in_a_robot_toml_are_refused(data, tmp_path, extra, words):
    robot = _robot(tmp_path, SEED_TOML + "\n" + extra)
    one_error_line(sixaxis("lab", "fit", data, "--robot", robot), "robot.toml", *words)
    one_error_line(sixaxis("lab", "plan", "--robot", robot, "-o", tmp_path / "p.csv"), *words)
    assert not (tmp_path / "p.csv").exists()


@pytest.mark.parametrize(
    "limits, unit, words",
    [
        ("[-1000, 1000]", "rad", ["joint 1", "[-1000, 1000]", "two turns", "no arm turns"]),
        ("[-170, 170]", "rad", ["joint 1", "[-170, 170]", 'degrees? say angle_unit = "deg"']),
        ("[-1000, 1000]", "deg", ["joint 1", "two turns either way (720 deg)"]),
    ],
)
def test_joint_limits_beyond_two_turns_are_refused_naming_the_likely_cause(
    tmp_path, limits, unit, words
):
    text = SEED_TOML.replace("[-2.97, 2.97]", limits)
    if unit == "deg":
        text = text.replace('angle_unit = "rad"', 'angle_unit = "deg"').replace(
            "alpha = -1.5707963267948966", "alpha = -90"
        )
        text = text.replace("alpha = 1.5707963267948966", "alpha = 90")
    robot = _robot(tmp_path, text)
    one_error_line(sixaxis("lab", "plan", "--robot", robot, "-o", tmp_path / "p.csv"), *words)
    assert not (tmp_path / "p.csv").exists()


def test_a_wrist_of_plus_minus_400_degrees_is_an_arm(tmp_path):
    wrist = SEED_TOML.replace("[-6.28, 6.28]", "[-6.98, 6.98]")  # +-400 deg
    robot = _robot(tmp_path, wrist)
    res = sixaxis("lab", "plan", "--n", 12, "--candidates", 200, "--robot", robot, "-o", "-")
    assert res.exit_code == 0, res.output


def test_an_arm_of_zero_lengths_does_not_make_plan_search_for_ever(tmp_path):
    zero = SEED_TOML
    for key in ("a = 0.132", "a = 0.620", "a = 0.1634", "d = 0.080", "d = 0.350", "d = 0.2356"):
        zero = zero.replace(key, key.split("=")[0] + "= 0.0")
    zero = zero.replace("point = [0.0, 0.0, 0.050]", "point = [0.0, 0.0, 0.0]")
    robot = _robot(tmp_path, zero)
    one_error_line(
        sixaxis("lab", "plan", "--robot", robot, "--candidates", 200, "-o", tmp_path / "p.csv"),
        "random poses within the limits put the tool point above",
        "every a and d zero",
    )


@pytest.mark.parametrize(
    "text, words",
    [
        (b"# caf\xe9\n" + SEED_TOML.encode(), ["line 1, column 6", "not a UTF-8", "Latin-1"]),
        (
            SEED_TOML.replace("com = [0.0, 0.0, -0.04]", "com = " + "[" * 5000 + "]" * 5000),
            ["nested too deeply"],
        ),
    ],
)
def test_a_robot_toml_that_cannot_be_read_is_one_line(data, tmp_path, text, words):
    robot = _robot(tmp_path, text)
    one_error_line(sixaxis("lab", "fit", data, "--robot", robot), "robot.toml", *words)


def test_a_fifo_as_robot_or_module_is_refused_without_waiting(data, tmp_path):
    robot = tmp_path / "robot.toml"
    os.mkfifo(robot)
    one_error_line(sixaxis("lab", "fit", data, "--robot", robot), "robot.toml", "FIFO")
    module = tmp_path / "mine.py"
    os.mkfifo(module)
    one_error_line(sixaxis("lab", "fit", data, "--effect-module", module), "mine.py", "FIFO")


# == effect modules =================================================================================
MODULE_HEAD = "import numpy as np\nfrom arm.effects import JointAngleEffect\n"


def _module(tmp_path: Path, body: str, name: str = "mine.py") -> Path:
    path = tmp_path / name
    path.write_text(MODULE_HEAD + body)
    return path


def _basis_module(tmp_path: Path, expression: str) -> Path:
    return _module(
        tmp_path,
        "class Mine(JointAngleEffect):\n"
        "    name = 'mine_basis'\n"
        "    terms = ('k',)\n"
        "    def basis(self, inputs, joint, term):\n"
        f"        return {expression}\n",
    )


def test_a_module_may_not_take_a_catalogued_effects_name(data, tmp_path, user_effects):
    from arm.effects import Compliance

    mod = _module(
        tmp_path,
        "class C(JointAngleEffect):\n"
        "    name = 'compliance'\n"
        "    terms = ('k',)\n"
        "    def basis(self, inputs, joint, term):\n"
        "        return np.sin(inputs.q[:, joint - 1])\n",
    )
    args = ("lab", "fit", data, "--effect-module", mod, "--effects", "geometric,compliance")
    one_error_line(sixaxis(*args), "mine.py", "class C", "'compliance'", "arm.effects.Compliance")
    assert user_effects["compliance"] is Compliance


def test_a_module_may_not_name_a_parameter_like_a_catalogued_one(data, tmp_path, user_effects):
    mod = _module(
        tmp_path,
        "class Mine(JointAngleEffect):\n"
        "    name = 'mine_c'\n"
        "    terms = ('c',)\n"
        "    def basis(self, inputs, joint, term):\n"
        "        return np.sin(inputs.q[:, joint - 1])\n",
    )
    args = ("lab", "fit", data, "--effect-module", mod, "--effects", "geometric,mine_c[2]")
    one_error_line(sixaxis(*args), "mine_c", "'c1'", "compliance")
    assert "mine_c" not in user_effects


@pytest.mark.parametrize("code", [0, 3])
def test_a_modules_sys_exit_at_import_is_one_line(data, tmp_path, code, user_effects):
    mod = _module(tmp_path, f"import sys\nsys.exit({code})\n")
    one_error_line(
        sixaxis("lab", "fit", data, "--effect-module", mod), "mine.py", f"sys.exit({code})"
    )


@pytest.mark.parametrize(
    "expression, words",
    [
        ("np.full(inputs.n, np.nan)", ["returned nan at pose 1"]),
        ("np.full(inputs.n, np.inf)", ["returned inf at pose 1"]),
        ("np.ones(3)", ["returned shape (3,)", "one number per pose"]),
        ("np.ones((inputs.n, 2))", ["returned shape (60, 2)"]),
        ("1.0", ["returned a scalar"]),
        ("None", ["returned None"]),
        ("'abc'", ["returned 'abc'"]),
        ("1 / 0", ["raised ZeroDivisionError: division by zero"]),
        ("__import__('sys').exit(0)", ["raised SystemExit"]),
        ("inputs.q[:, joint - 1] * {}['x']", ["raised KeyError"]),
        ("np.full(inputs.n, 1e300)", ["returned 1e+300 at pose 1, beyond 1e+12"]),
        ("np.ones(inputs.n) * 1j", ["returned complex numbers"]),
    ],
)
@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_a_bad_basis_is_one_line_naming_module_effect_and_term(
    data, tmp_path, expression, words, command, user_effects
):
    mod = _basis_module(tmp_path, expression)
    args = ["lab", command, data, "--effect-module", mod, "--effects", "geometric,mine_basis"]
    one_error_line(
        sixaxis(*args), "effect 'mine_basis'", "mine.py", "basis(joint 1, term 'k')", *words
    )


# == property-based: the readers and the loader take anything =======================================
# Whatever text a reader is given, it reads it or refuses it with its own error (a one-line
# SixAxisError naming the source): never another exception, never a hang.
PROPERTY = settings(
    max_examples=150,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
COLUMNS = ["q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z", "t", "target", "dir1", "payload", "k"]
CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(10**30), max_value=10**30).map(str),
    st.sampled_from(["", " ", "nan", "-inf", "1e309", "0x10", "1_0", "٣", '"1"', '"', "#", "\r"]),
    st.text(max_size=8),
)


@st.composite
def csv_texts(draw) -> str:
    """A CSV close to a measurement file: a header of known and unknown names (some missing,
    some repeated), rows of numbers, words and quotes, ragged now and then."""
    header = draw(st.lists(st.sampled_from(COLUMNS), min_size=0, max_size=16))
    if draw(st.booleans()):
        header = [*COLUMNS[:9], *header]
    rows = draw(
        st.lists(
            st.lists(CELLS, min_size=max(0, len(header) - 1), max_size=len(header) + 1),
            max_size=6,
        )
    )
    sep = draw(st.sampled_from(["\n", "\r\n", "\n\n"]))
    bom = draw(st.sampled_from(["", "\ufeff"]))
    return bom + sep.join([",".join(header), *(",".join(r) for r in rows)]) + sep


@PROPERTY
@given(text=st.one_of(csv_texts(), st.text(max_size=300)))
def test_the_csv_readers_read_or_refuse_any_text(text):
    from arm.measurements import (
        MeasurementError,
        MeasurementSet,
        parse_measurements,
        parse_numeric_csv,
    )

    try:
        data = parse_measurements(text, "any.csv")
    except MeasurementError as exc:
        assert str(exc).startswith("any.csv") and "\n" not in str(exc), exc
    else:
        assert isinstance(data, MeasurementSet) and len(data) >= 1
        assert np.isfinite(data.q).all() and np.isfinite(data.xyz).all()
    try:
        parse_numeric_csv(text, "poses.csv", ("q1",), blank_lines=True, columns=("q1",))
    except MeasurementError as exc:
        assert str(exc).startswith("poses.csv"), exc


def _reads_or_refuses_bytes(path, raw: bytes, read, error: type[Exception]) -> None:
    """``read`` of a file holding ``raw`` returns, or raises ``error`` naming the file first."""
    path.write_bytes(raw)
    try:
        read(path)
    except error as exc:
        assert str(exc).startswith(str(path)), exc


@PROPERTY
@given(raw=st.binary(max_size=300))
def test_the_csv_file_reader_reads_or_refuses_any_bytes(tmp_path, raw):
    from arm.measurements import MeasurementError, read_measurements

    _reads_or_refuses_bytes(tmp_path / "raw.csv", raw, read_measurements, MeasurementError)


TOML_VALUES = st.recursive(
    st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(min_value=-(10**20), max_value=10**20),
        st.booleans(),
        st.text(max_size=6),
    ),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=5), inner, max_size=3)
    ),
    max_leaves=8,
)
SEED_DOC = tomllib.loads(SEED_TOML)
KEYS = [
    ("name",),
    ("convention",),
    ("length_unit",),
    ("angle_unit",),
    ("payload",),
    ("gravity",),
    ("joints", 0, "limits"),
    ("joints", 1, "a"),
    ("joints", 2, "com"),
    ("joints", 3, "mass"),
    ("joints", 5, "alpha"),
    ("tools", 0, "point"),
    ("base",),
    ("effects",),
    ("effects", "compliance"),
    ("bogus",),
]


@st.composite
def robot_docs(draw) -> dict:
    """The seed arm's TOML with a few values replaced by anything TOML can hold."""
    doc = copy.deepcopy(SEED_DOC)
    for key in draw(st.lists(st.sampled_from(KEYS), min_size=1, max_size=3)):
        node = doc
        for k in key[:-1]:
            node = node.setdefault(k, {}) if isinstance(k, str) else node[k]
            if not isinstance(node, dict):
                break
        else:
            node[key[-1]] = draw(TOML_VALUES)
    return doc


@PROPERTY
@given(doc=robot_docs())
def test_the_robot_reader_reads_or_refuses_any_toml_document(doc):
    from arm.description import DescriptionError, RobotDescription
    from arm.effect_api import EffectError
    from arm.effects import check_robot_effects

    try:
        text = tomli_w.dumps(doc)
    except (TypeError, ValueError):  # NaN keys and the like that TOML cannot write
        return
    try:
        robot = RobotDescription.from_toml(text, source="robot.toml")
        check_robot_effects(robot, "robot.toml")
    except (DescriptionError, EffectError) as exc:
        assert str(exc).startswith("robot.toml"), exc


@PROPERTY
@given(raw=st.binary(max_size=400))
def test_the_robot_file_reader_reads_or_refuses_any_bytes(tmp_path, raw):
    from arm.description import DescriptionError, load_robot

    _reads_or_refuses_bytes(tmp_path / "raw.toml", raw, load_robot, DescriptionError)


HOSTILE_RETURNS = [
    "np.sin(inputs.q[:, joint - 1])",
    "np.full(inputs.n, np.nan)",
    "np.full(inputs.n, -np.inf)",
    "np.ones(inputs.n + 1)",
    "np.ones((inputs.n, 1))",
    "np.zeros(())",
    "[1.0] * inputs.n",
    "None",
    "'x'",
    "{}",
    "inputs.column('nope')",
    "1 // 0",
    "__import__('sys').exit(1)",
    "np.linalg.inv(np.zeros((2, 2)))",
]


@st.composite
def effect_modules(draw) -> str:
    """An effect module as a user might write it, right or wrong: its name, terms, basis and what
    it does at import drawn from hostile choices."""
    name = draw(st.sampled_from(["mine", "compliance", "geometric", "Bad", "x y", "k2", ""]))
    terms = draw(st.lists(st.sampled_from(["k", "c", "ts", "kappa", "tx", "q", "s"]), max_size=3))
    body = draw(st.sampled_from(HOSTILE_RETURNS))
    head = draw(st.sampled_from(["", "raise ValueError('no')\n", "import sys\nsys.exit(2)\n"]))
    base = draw(st.sampled_from(["JointAngleEffect", "object"]))
    return (
        MODULE_HEAD
        + head
        + f"class E({base}):\n    name = {name!r}\n    terms = {tuple(terms)!r}\n"
        + "    def basis(self, inputs, joint, term):\n"
        + f"        return {body}\n"
    )


@pytest.fixture(scope="module")
def small_data(data):
    from arm.measurements import read_measurements

    return read_measurements(data).subset(np.arange(40))


@settings(
    max_examples=60,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(source=st.one_of(effect_modules(), st.text(alphabet=string.printable, max_size=120)))
def test_the_effect_loader_loads_or_refuses_any_module(tmp_path, source, small_data, user_effects):
    from arm.effect_api import EffectError
    from arm.errors import SixAxisError
    from lab import fit

    path = tmp_path / "anything.py"
    path.write_text(source)
    try:
        names = load_effect_module(path)
    except EffectError as exc:
        assert "anything.py" in str(exc) and "\n" not in str(exc), exc
        return
    for name in names:
        try:
            fit(small_data, seed_robot(), f"geometric,{name}")
        except SixAxisError as exc:
            assert "\n" not in str(exc).strip(), exc


# == policy files ===================================================================================
@pytest.fixture
def policy(tmp_path) -> Path:
    """A copy of the shipped ppo-residual policy (its .npz and .json) to spoil."""
    from agents.policy import POLICY_DIR

    for ext in (".npz", ".json"):
        (tmp_path / f"p{ext}").write_bytes((POLICY_DIR / f"ppo-residual{ext}").read_bytes())
    return tmp_path / "p.npz"


def _edit_json(path: Path, edit) -> None:
    import json

    meta_path = path.with_suffix(".json")
    meta = json.loads(meta_path.read_text())
    edit(meta)
    meta_path.write_text(json.dumps(meta))


def _edit_arrays(path: Path, edit) -> None:
    with np.load(path) as data:
        arrays = {k: data[k].copy() for k in data.files}
    edit(arrays)
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda m: m["policy_kwargs"].update(bogus=1), ["policy_kwargs 'bogus' unknown for ppo"]),
        (lambda m: m.update(obs_size=1e9), ["obs_size must be a whole number", "1000000000.0"]),
        (lambda m: m.update(obs_size=10**9), ["obs_size must be a whole number"]),
        (
            lambda m: m["policy_kwargs"].update(net_arch={"pi": [200_000], "vf": [64]}),
            ["net_arch (pi)", "1 to 4096 units", "200000"],
        ),
        (
            lambda m: m["policy_kwargs"].update(net_arch=[4096] * 8),
            ["parameters, more than the 5,000,000"],
        ),
        (lambda m: m.update(variant="bogus"), ["variant 'bogus'", "residual, plain"]),
        (lambda m: m["policy_kwargs"].update(activation_fn="os.system"), ["activation_fn"]),
        (lambda m: m.update(act_size=6), ["act_size of a residual policy is 3"]),
        (lambda m: m.update(observe=["torque"]), ["observe: unknown part 'torque'"]),
        (lambda m: m.update(observe="joints"), ["observe must be a list of names"]),
        (lambda m: m.update(observe=["joints"]), ["observe is for the tool variant"]),
    ],
)
def test_a_policy_description_is_checked_before_its_network_is_built(
    policy, monkeypatch, edit, words
):
    from agents import policy as policy_module

    def no_build(*a, **k):
        raise AssertionError("the network was built before its description was checked")

    monkeypatch.setattr(policy_module, "build_network", no_build)
    _edit_json(policy, edit)
    with pytest.raises(policy_module.PolicyFileError) as exc:
        policy_module.load_policy_file(policy)
    for w in ("p.json", *words):
        assert w in str(exc.value), (w, str(exc.value))


@pytest.mark.parametrize(
    "edit, words",
    [
        (
            lambda a: a[next(k for k in a if k.startswith("weights/"))].flat.__setitem__(3, np.nan),
            ["NaN or infinite", "flat index 3"],
        ),
        (lambda a: a["obs_var"].__setitem__(0, -1.0), ["obs_var[0] = -1 is negative"]),
        (lambda a: a["obs_mean"].__setitem__(2, np.inf), ["obs_mean holds NaN or infinity"]),
        (lambda a: a.update(obs_clip=np.asarray(0.0)), ["obs_clip = 0 must be > 0"]),
    ],
)
def test_policy_weights_that_would_act_nan_are_refused(policy, edit, words):
    from agents.policy import PolicyFileError, load_policy_file

    _edit_arrays(policy, edit)
    with pytest.raises(PolicyFileError) as exc:
        load_policy_file(policy)
    for w in ("p.npz", *words):
        assert w in str(exc.value), (w, str(exc.value))


def test_a_fifo_as_a_policy_file_is_refused_without_waiting(policy, tmp_path):
    from agents.policy import PolicyAgent, PolicyFileError, load_policy_file

    fifo = tmp_path / "fifo.npz"
    os.mkfifo(fifo)
    (tmp_path / "fifo.json").write_bytes(policy.with_suffix(".json").read_bytes())
    with pytest.raises(PolicyFileError, match="FIFO"):
        PolicyAgent(path=str(fifo), name="mine")
    with pytest.raises(PolicyFileError, match="FIFO"):
        load_policy_file(fifo)
    policy.with_suffix(".json").unlink()
    os.mkfifo(policy.with_suffix(".json"))  # the description a FIFO
    with pytest.raises(PolicyFileError, match=r"p\.json: is a FIFO"):
        load_policy_file(policy)
    res = sixaxis("evaluate", "policy", "--settings", f'{{"path": "{fifo}"}}')
    one_error_line(res, "fifo.npz", "FIFO")


# == the env =========================================================================================
def test_a_nan_posture_is_refused_and_none_leaves_a_joint_free():
    import gymnasium as gym

    import envs  # noqa: F401
    from envs.sixaxis_track_v0 import EnvOptionError

    with pytest.raises(EnvOptionError, match="posture of joint 2 is NaN; give None"):
        gym.make("SixAxisTrack-v0", posture=[None, float("nan"), None, None, None, None])
    env = gym.make("SixAxisTrack-v0", posture=[None, -1.6, 0.6, None, None, None])
    env.reset(seed=0, options={"posture": [None, -1.6, None, None, None, None]})
    with pytest.raises(ValueError, match="NaN"):
        env.reset(seed=0, options={"posture": [np.nan] * 6})


@pytest.mark.parametrize(
    "seconds, limit, steps", [(20.0, None, 1000), (3.0, None, 150), (20.0, 700, 700)]
)
def test_the_episode_lasts_its_episode_seconds_not_a_registered_500_steps(seconds, limit, steps):
    import gymnasium as gym

    import envs  # noqa: F401

    kw = {} if limit is None else {"max_episode_steps": limit}
    env = gym.make("SixAxisTrack-v0", episode_seconds=seconds, **kw)
    assert env.spec.max_episode_steps == steps
    env.reset(seed=0)
    n, done = 0, False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.zeros(6))
        n += 1
        done = terminated or truncated
    assert n == steps and truncated


def test_a_phase_longer_than_the_envs_episode_is_refused_not_cut_short():
    from agents.registry import make_agent
    from agents.runner import EpisodeError, Phase, run_episode

    with pytest.raises(
        EpisodeError, match=r"0\.5 s asked, but the env's episode ends after 0\.2 s"
    ):
        run_episode(
            make_agent("hold"), {"episode_seconds": 0.2}, seed=0, phases=[Phase("a", 0.5, {})]
        )


def test_a_closed_env_is_not_stepped_until_it_is_reset():
    import gymnasium as gym

    import envs  # noqa: F401
    from envs.sixaxis_track_v0 import EnvStateError

    env = gym.make("SixAxisTrack-v0")
    env.reset(seed=0)
    env.step(np.zeros(6))
    env.close()
    env.close()  # twice is fine
    base = env.unwrapped
    with pytest.raises(EnvStateError, match=r"step\(\) after close\(\); reset\(\) it first"):
        base.step(np.zeros(6))
    base.reset(seed=0)  # opens it again, as stable-baselines3's checker expects
    base.step(np.zeros(6))


def test_the_observation_stays_in_its_space_whatever_the_temperature_override():
    import gymnasium as gym

    import envs  # noqa: F401
    from envs.sixaxis_track_v0 import EnvOptionError, SixAxisTrackEnv

    with pytest.raises(EnvOptionError, match=r"temperature0 = 300 .*\(-50 to 200 degC\).*kelvin"):
        gym.make(
            "SixAxisTrack-v0", scenario="thermal", overrides={"thermal": {"temperature0": 300}}
        )
    problems = SixAxisTrackEnv.check_options(
        scenario="payload", overrides={"payload": {"payload1": 500.0}}
    )
    assert "payload.payload1 = 500.0" in problems["overrides"]
    # the hottest start the probe reads, heating far beyond any arm: the probe saturates
    env = gym.make(
        "SixAxisTrack-v0",
        scenario="thermal",
        overrides={"thermal": {"temperature0": 195.0, "heating": 5.0}},
        episode_seconds=2.0,
    )
    obs, _ = env.reset(seed=0)
    space = env.observation_space
    temp = env.unwrapped.task.obs_slices["temperature"]
    while True:
        assert space.contains(obs), obs[temp]
        obs, _, terminated, truncated, _ = env.step(np.full(6, 0.5, dtype=np.float32))
        if terminated or truncated:
            break
    assert obs[temp][0] == 200.0  # saturated, not beyond the space


# == the lab on hard data ============================================================================
def _gross(d, share: float, seed: int):
    """``d`` with ``share`` of its points moved 2-8 mm in random directions; the rows moved."""
    return with_gross_outliers(d, np.random.default_rng(seed), share, size_m=(2e-3, 8e-3))


@pytest.mark.parametrize("effects", ["geometric", "geometric,compliance"])
@pytest.mark.parametrize("loss", ["linear", "huber"])
def test_forty_percent_gross_outliers_are_not_called_a_calibration(tmp_path, effects, loss):
    """The issue's case: 40 % of 60 poses 2-8 mm off gave a plain exit-0 "3.2 mm fit"
    (2.8 mm with huber). Least squares hides them; the trimmed fit finds them, and beyond the
    stated 10 % the lab refuses, naming the fraction and the rows; --outliers keep still fits."""
    d = campaign(seed_robot(), effects, seed=40).measure(60)
    bad, idx = _gross(d, 0.4, 1)
    path = tmp_path / "gross.csv"
    write_measurements(bad, path)
    out = tmp_path / "fit.json"
    err = one_error_line(
        sixaxis("lab", "fit", path, "--loss", loss, "--out", out),
        "gross.csv",
        f"{len(idx)} of 60 poses (40 %) are gross outliers",
        "more than the 10 %",
        "not a calibration",
        f"line {idx[0] + 2}",
        "--outliers keep",
    )
    assert "2." in err and not out.exists()
    res = sixaxis("lab", "fit", path, "--loss", loss, "--outliers", "keep", "--json")
    assert res.exit_code == 0, res.output


def test_a_few_gross_outliers_are_still_left_out_by_line():
    from lab import fit

    d = campaign(seed_robot(), "geometric", seed=41).measure(100)
    bad, idx = _gross(d, 0.05, 2)
    res = fit(bad, seed_robot(), "geometric")
    assert list(res.outliers) == list(idx)


@pytest.mark.parametrize("seed", [0, 1, 2, 5])
def test_a_small_campaign_with_a_missing_effect_is_not_called_gross_outliers(seed):
    """29 poses of an arm whose compliance (at the high end of its range) the geometric model
    misses. A fit of some 21 of them with 25 parameters explains those so well that the others
    looked apart, and these seeds (55 of 120 such campaigns) were refused as "28 % gross
    outliers, not a calibration"; so was a leave-one-out fold of the real Rokae set. They fit,
    with every pose."""
    from lab import screen

    d = campaign(seed_robot(), "geometric,compliance", seed=seed, hidden_level="high").measure(29)
    s = screen(d, seed_robot(), "geometric", noise_mm=0.015)
    assert s.fit.n_points == 29
    # every pose fitted (no catalogued candidate can be ruled out from 29 poses, issue 29)
    assert len(s.fit.outliers) == 0


def test_a_calibration_the_lab_calls_contaminated_is_fitted_robustly_by_the_calibrated_agent():
    """The lab refuses 20 % of poses 2-8 mm off as not a calibration (lab.ContaminatedError);
    the `calibrated` agent then follows the refusal's advice (every pose, its robust loss)
    instead of staying nominal, as it did on 14 of the leaderboard's episodes: the clean poses
    are fitted to a tenth of a millimetre (the outliers still pull the soft-L1 fit a little)."""
    from agents.reference import fit_measurements
    from arm.errormodel import ErrorModel
    from lab import ContaminatedError, fit

    c = campaign(seed_robot(), "geometric", seed=42)
    d, idx = with_gross_outliers(c.measure(60), np.random.default_rng(3), 0.2, (2e-3, 8e-3))
    with pytest.raises(ContaminatedError, match="gross outliers"):
        fit(d, seed_robot(), "geometric", loss="soft_l1", noise_mm=0.015)
    model = ErrorModel(seed_robot(), "geometric")
    p, fitted = fit_measurements(model, d.q, d.xyz, d.columns, noise=15e-6)
    assert len(fitted) > 20
    clean = d.subset(np.setdiff1d(np.arange(len(d)), idx))

    def rms_mm(params):
        r = model.predict(model.inputs(clean.q, clean.columns), params) - clean.xyz
        return 1e3 * np.sqrt(np.mean(np.sum(r**2, axis=1)))

    assert rms_mm(p) < 0.1 and rms_mm(model.nominal()) > 1.0


def test_repeated_poses_fit_as_their_distinct_poses_do():
    """The same 60 poses measured 200 times with fresh noise (the issue's 480,000 rows, scaled
    down). Judged by rows, the noise let nearly dependent parameters in, the missing compliance
    drove them past a centimetre and the fit was refused as "another robot's file"; judged by
    distinct poses, it fits as the 60 do."""
    from arm.measurements import MeasurementSet
    from lab import fit

    c = campaign(seed_robot(), "geometric,compliance", seed=5)
    once = c.measure(60)
    exact = c.truth.predict(c.truth.inputs(once.q, once.columns), c.params)
    rng = np.random.default_rng(3)
    reps, sigma = 200, 15e-6
    q = np.tile(once.q, (reps, 1))
    cols = {k: np.tile(v, reps) for k, v in once.columns.items()}
    xyz = np.tile(exact, (reps, 1)) + rng.normal(0, sigma, (60 * reps, 3))
    many = MeasurementSet(q, xyz, cols, "repeated")
    mean = MeasurementSet(once.q, xyz.reshape(reps, 60, 3).mean(axis=0), once.columns)
    res = fit(many, seed_robot(), "geometric", noise_mm=1e3 * sigma)
    ref = fit(mean, seed_robot(), "geometric", noise_mm=1e3 * sigma)
    assert res.n_points == 60 * reps and not res.implausible
    assert res.rank == ref.rank and res.unidentifiable == ref.unidentifiable
    np.testing.assert_allclose(res.params, ref.params, atol=1e-9)


def test_one_row_beyond_a_joint_limit_is_named(data, tmp_path):
    def beyond(lines):
        cells = lines[8].split(",")
        cells[2] = "2.5"  # q3 of the seed arm lies within [-1.6, 1.6] rad
        lines[8] = ",".join(cells)
        return lines

    path = _rewrite(data, tmp_path / "q3.csv", beyond)
    one_error_line(
        sixaxis("lab", "fit", path),
        "q3.csv, line 9, column 'q3'",
        "2.5 rad is beyond joint 3's limits [-1.6, 1.6]",
        "typo",
    )


def test_a_target_out_of_reach_is_refused_or_marked_failed(tmp_path):
    targets = tmp_path / "targets.csv"
    targets.write_text("x,y,z\n0.8,0.0,0.8\n10,0,0\n")
    out = tmp_path / "joints.csv"
    one_error_line(
        sixaxis("lab", "compensate", targets, "--robot", "seed", "-o", out, "--free-orientation"),
        "targets.csv: 1 of 2 targets not reached",
        "line 3: (10, 0, 0) m missed by",
        "nothing written",
        "--keep-unreached",
    )
    assert not out.exists()
    res = sixaxis(
        "lab",
        "compensate",
        targets,
        "--robot",
        "seed",
        "-o",
        out,
        "--keep-unreached",
        "--free-orientation",
    )
    assert res.exit_code == 0, res.output
    rows = [line.split(",") for line in out.read_text().splitlines()[1:]]
    assert rows[0][-1] == "converged" and [r[-1] for r in rows[1:]] == ["1", "0"]


def test_over_long_output_folders_of_sweep_leaderboard_and_train_are_one_line(tmp_path):
    long = tmp_path / ("r" * 300)
    config = ROOT / "experiments" / "configs" / "quick.toml"
    one_error_line(sixaxis("sweep", config, "-o", long, "--dry-run"), "name of 300 bytes")
    one_error_line(sixaxis("leaderboard", tmp_path, "-o", long), "rrrr")
    train = ROOT / "experiments" / "configs" / "ppo-residual.toml"
    one_error_line(
        sixaxis("train", "ppo", "--config", train, "--output", long), "name of 300 bytes"
    )
    assert list(tmp_path.iterdir()) == []


def test_no_module_asks_pathlib_whether_a_users_path_exists():
    """``Path.is_file``, ``exists`` and ``is_dir`` raise ``OSError`` for a name the OS refuses
    (the traceback found three times): every module asks :func:`arm.files.is_file` /
    :func:`arm.files.is_dir` or ``os.path``, which answer False."""
    import re

    found = [
        f"{p.relative_to(ROOT)}:{i}"
        for pkg in ("arm", "lab", "envs", "agents", "experiments")
        for p in sorted((ROOT / pkg).rglob("*.py"))
        if p != ROOT / "arm" / "files.py"
        for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if re.search(r"\.(is_file|exists|is_dir)\(\)", line)
    ]
    assert found == []
