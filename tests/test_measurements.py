"""Measurement files (docs/format.md, the measurement CSV): every malformed case is refused naming
file, line and column; unit options round-trip; extra columns are kept; writes are atomic."""

from __future__ import annotations

import math
import os
import warnings

import numpy as np
import pytest

from arm.description import load_robot
from arm.files import OutputError
from arm.measurements import (
    MeasurementError,
    MeasurementSet,
    atomic_write_text,
    read_measurements,
    write_measurements,
)

HEADER = "q1,q2,q3,q4,q5,q6,x,y,z"
ROW = "0.1,-1.2,0.3,0.4,0.5,0.6,0.7,0.01,0.8"


def _file(tmp_path, text: str, name: str = "data.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


# (file text, min_rows, expected fragments of the message after the file name)
MALFORMED = {
    "missing column": (
        HEADER.replace(",z", "") + "\n" + ROW.rsplit(",", 1)[0] + "\n",
        1,
        ["line 1", "missing required column(s) z"],
    ),
    "two missing columns": ("q1,q2,q3,q4,q5,x,y\n1,2,3,4,5,6,7\n", 1, ["line 1", "q6, z"]),
    "text in a number": (
        f"{HEADER}\n{ROW}\n{ROW.replace('0.4', 'abc')}\n",
        1,
        ["line 3", "column 'q4'", "'abc' is not a number"],
    ),
    "empty cell": (
        f"{HEADER}\n{ROW.replace(',0.7,', ',,')}\n",
        1,
        ["line 2", "column 'x'", "'' is not a number"],
    ),
    "nan": (
        f"{HEADER}\n{ROW.replace('0.01', 'NaN')}\n",
        1,
        ["line 2", "column 'y'", "NaN is not finite"],
    ),
    "inf": (
        f"{HEADER}\n{ROW}\n{ROW}\n{ROW.replace('0.8', '-inf')}\n",
        1,
        ["line 4", "column 'z'", "-inf is not finite"],
    ),
    "too many fields": (f"{HEADER}\n{ROW},5\n", 1, ["line 2", "10 fields, but the header has 9"]),
    "too few fields": (
        f"{HEADER}\n{ROW}\n0.1,0.2\n",
        1,
        ["line 3", "2 fields, but the header has 9"],
    ),
    "bad dir value": (
        f"{HEADER},dir1,dir2\n{ROW},1,-1\n{ROW},1,0\n",
        1,
        ["line 3", "column 'dir2'", "must be -1 or +1"],
    ),
    "non-integer target": (
        f"{HEADER},target\n{ROW},1\n{ROW},1.5\n",
        1,
        ["line 3", "column 'target'", "must be an integer"],
    ),
    "negative payload": (
        f"{HEADER},payload\n{ROW},-2\n",
        1,
        ["line 2", "column 'payload'", ">= 0 kg"],
    ),
    "empty file": ("", 1, ["empty file"]),
    "blank lines only": ("\n\n  \n", 1, ["empty file"]),
    "a blank line among the rows": (
        f"{HEADER}\n{ROW}\n\n{ROW}\n",
        1,
        ["line 3", "a blank line among the rows"],
    ),
    "a line of empty cells among the rows": (
        f"{HEADER}\n{ROW}\n,,,,,,,,\n{ROW}\n",
        1,
        ["line 3", "a blank line among the rows"],
    ),
    "blank lines at the end": (f"{HEADER}\n{ROW}\n\n\n", 30, ["1 measurement rows, at least 30"]),
    "header only": (f"{HEADER}\n", 1, ["0 measurement rows, at least 1 needed"]),
    "too few rows": (f"{HEADER}\n{ROW}\n{ROW}\n", 30, ["2 measurement rows, at least 30 needed"]),
    "duplicate column": (f"{HEADER},x\n{ROW},1\n", 1, ["line 1", "column 'x' appears twice"]),
    "empty column name": (f"{HEADER},\n{ROW},1\n", 1, ["line 1", "column 10 has an empty name"]),
    "a blank cell in an extra column of numbers": (
        f"{HEADER},humidity\n{ROW},41.5\n{ROW},\n",
        1,
        ["line 3", "column 'humidity'", "'' is not a number", "as labels where they hold text"],
    ),
    "text in a column the format knows": (
        f"{HEADER},temperature\n{ROW},warm\n",
        1,
        ["line 2", "column 'temperature'", "'warm' is not a number"],
    ),
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_file_is_refused_naming_where(tmp_path, case):
    text, min_rows, fragments = MALFORMED[case]
    path = _file(tmp_path, text)
    with pytest.raises(MeasurementError) as err:
        read_measurements(path, min_rows=min_rows)
    msg = str(err.value)
    assert msg.startswith(str(path)), msg
    for frag in fragments:
        assert frag in msg, msg


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(MeasurementError, match="file not found"):
        read_measurements(tmp_path / "none.csv")
    with pytest.raises(MeasurementError, match="is a directory, not a regular file"):
        read_measurements(tmp_path)
    binary = tmp_path / "b.csv"
    binary.write_bytes(b"\xff\xfe\x00q1")
    with pytest.raises(MeasurementError, match="not a UTF-8 text file"):
        read_measurements(binary)
    with pytest.raises(MeasurementError, match="length unit"):
        read_measurements(_file(tmp_path, f"{HEADER}\n{ROW}\n"), length_unit="cm")
    with pytest.raises(MeasurementError, match="angle unit"):
        read_measurements(_file(tmp_path, f"{HEADER}\n{ROW}\n"), angle_unit="grad")


def _sample(n: int = 7, seed: int = 0) -> MeasurementSet:
    rng = np.random.default_rng(seed)
    cols = {
        "t": np.arange(n) * 0.5,
        "temperature": rng.uniform(18, 30, n),
        "payload": rng.uniform(0, 5, n),
        **{f"dir{j}": rng.choice((-1.0, 1.0), n) for j in range(1, 7)},
        "target": rng.integers(0, 3, n).astype(float),
        "humidity": rng.uniform(30, 60, n),  # an extra column, for custom effects
    }
    return MeasurementSet(rng.uniform(-3, 3, (n, 6)), rng.uniform(-2, 2, (n, 3)), cols, "sample")


@pytest.mark.parametrize(
    ("length_unit", "angle_unit"), [("m", "rad"), ("mm", "deg"), ("mm", "rad"), ("m", "deg")]
)
def test_units_round_trip(tmp_path, length_unit, angle_unit):
    data = _sample()
    path = tmp_path / "out.csv"
    write_measurements(data, path, length_unit=length_unit, angle_unit=angle_unit)
    back = read_measurements(path, length_unit=length_unit, angle_unit=angle_unit)
    np.testing.assert_allclose(back.q, data.q, rtol=1e-15, atol=0)
    np.testing.assert_allclose(back.xyz, data.xyz, rtol=1e-15, atol=0)
    assert set(back.columns) == set(data.columns)
    for k, v in data.columns.items():
        np.testing.assert_array_equal(back.columns[k], v)
    assert back.source == str(path)


def test_units_are_applied_as_stated(tmp_path):
    """Foreign data: q in degrees and x, y, z in mm, read with explicit options."""
    path = _file(tmp_path, f"{HEADER}\n90,-45,0,0,36,0,900,-250,150\n")
    data = read_measurements(path, length_unit="mm", angle_unit="deg")
    np.testing.assert_allclose(data.q[0], [math.pi / 2, -math.pi / 4, 0, 0, math.pi / 5, 0])
    np.testing.assert_allclose(data.xyz[0], [0.9, -0.25, 0.15])
    si = read_measurements(path)  # never guessed: the same file read as SI
    assert si.q[0, 0] == 90.0 and si.xyz[0, 0] == 900.0


def test_columns_in_any_order_extra_columns_kept_whitespace_and_bom(tmp_path):
    text = "\ufeffz, y ,x,q6,q5,q4,q3,q2,q1,wear\n 0.8 ,0.01,0.7,0.6,0.5,0.4,0.3,-1.2,0.1, 3\n"
    data = read_measurements(_file(tmp_path, text))
    np.testing.assert_allclose(data.q[0], [0.1, -1.2, 0.3, 0.4, 0.5, 0.6])
    np.testing.assert_allclose(data.xyz[0], [0.7, 0.01, 0.8])
    assert list(data.columns) == ["wear"] and data.columns["wear"][0] == 3.0
    assert data.targets == (0,)


def test_targets_subset_and_split():
    data = _sample(20)
    assert data.targets == tuple(int(t) for t in np.unique(data.columns["target"]))
    first, rest = data.split(0.25, np.random.default_rng(1))
    assert len(first) == 5 and len(rest) == 15
    both = np.vstack([first.q, rest.q])
    assert sorted(map(tuple, both)) == sorted(map(tuple, data.q))


def test_writer_refuses_what_the_reader_would(tmp_path):
    data = _sample(3)
    data.xyz[1, 2] = np.nan
    path = tmp_path / "out.csv"
    with pytest.raises(MeasurementError, match=r"row 2, column 'z'"):
        write_measurements(data, path)
    assert not path.exists()
    data = _sample(3)
    data.columns["dir3"][2] = 0.0
    with pytest.raises(MeasurementError, match=r"row 3, column 'dir3'"):
        write_measurements(data, path)


def test_mismatched_lengths_are_refused():
    with pytest.raises(MeasurementError, match="3 joint rows but 2 points"):
        MeasurementSet(np.zeros((3, 6)), np.zeros((2, 3)))
    with pytest.raises(MeasurementError, match="column 't' has 2 rows, not 3"):
        MeasurementSet(np.zeros((3, 6)), np.zeros((3, 3)), {"t": np.zeros(2)})


def test_atomic_write_leaves_old_content_on_failure(tmp_path, monkeypatch):
    """A write that fails midway leaves the previous file whole and no temporary file behind."""
    path = tmp_path / "data.csv"
    write_measurements(_sample(4), path)
    before = path.read_text()

    def fail(fd):
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", fail)
    with pytest.raises(OutputError, match=r"data.csv: cannot write \(disk full\)"):
        write_measurements(_sample(9, seed=5), path)
    assert path.read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]


def test_atomic_write_creates_directories_and_says_so(tmp_path, caplog):
    target = tmp_path / "a" / "b" / "c.txt"
    with caplog.at_level("INFO", logger="arm.files"):
        atomic_write_text(target, "hello\n")
    assert target.read_text() == "hello\n"
    assert [r.getMessage() for r in caplog.records] == [
        f"created the folder {tmp_path / 'a' / 'b'} (it did not exist)"
    ]
    caplog.clear()
    with caplog.at_level("INFO", logger="arm.files"):
        atomic_write_text(target.with_name("d.txt"), "again\n")  # the folder stands: no word
    assert not caplog.records


def test_atomic_write_gives_the_umasks_permissions(tmp_path):
    """Written files are readable as with a plain open(), not left at mkstemp's 0600."""
    old = os.umask(0o022)
    try:
        target = tmp_path / "out.csv"
        write_measurements(_sample(3), target)
    finally:
        os.umask(old)
    assert target.stat().st_mode & 0o777 == 0o644


# -- '#' comment lines: before the header only, alike in every reader ------------------------------
def _readers():
    """Every reader of measurement-like CSVs, each as (name, read(path) -> joint angles)."""
    from arm.measurements import read_poses
    from lab.export import read_targets

    return [
        ("measurements", lambda p: read_measurements(p).q),
        ("measurements in deg", lambda p: read_measurements(p, angle_unit="deg").q),
        ("poses", read_poses),
        ("targets", lambda p: read_targets(p).q),
    ]


def test_a_poses_file_with_the_measured_points_added_is_read_by_every_reader(tmp_path):
    from arm.measurements import poses_csv

    rng = np.random.default_rng(3)
    q = rng.uniform(-1.0, 1.0, (5, 6))
    xyz = rng.uniform(0.2, 0.8, (5, 3))
    # the lab's own poses file (sixaxis lab plan writes it), then x, y, z added by the user
    lines = poses_csv(q).splitlines()
    assert lines[0].startswith("# sixaxis-track poses")
    added = [lines[0], "# measured on Tuesday, tracker AT960", "", lines[1] + ",x,y,z"]
    added += [
        f"{row},{','.join(repr(float(v)) for v in p)}"
        for row, p in zip(lines[2:], xyz, strict=True)
    ]
    path = _file(tmp_path, "\n".join(added) + "\n")
    data = read_measurements(path)
    assert np.allclose(data.q, q, atol=1e-12) and np.allclose(data.xyz, xyz, atol=1e-12)
    assert list(data.lines) == [5, 6, 7, 8, 9]  # the editor's line numbers, past the comments
    for name, read in _readers():
        if name != "measurements in deg":
            assert np.allclose(read(path), q, atol=1e-12), name
    # the declared unit holds for the measurement reader as for the poses reader
    with pytest.raises(MeasurementError, match=r"line 1: the file declares q1\.\.q6 in rad, but"):
        read_measurements(path, angle_unit="deg")
    first, header, *rows = poses_csv(q, "deg").splitlines()
    rows = [f"{r},{','.join(repr(float(v)) for v in p)}" for r, p in zip(rows, xyz, strict=True)]
    deg = _file(tmp_path, "\n".join([first, header + ",x,y,z", *rows]) + "\n", "deg.csv")
    with pytest.raises(
        MeasurementError,
        match=r"deg.csv, line 1: the file declares q1\.\.q6 in deg.*--angle-unit deg",
    ):
        read_measurements(deg, angle_unit="rad")
    assert np.allclose(read_measurements(deg, angle_unit="deg").q, q, atol=1e-12)
    assert np.allclose(read_measurements(deg).q, q, atol=1e-12)  # a unit not given: the declared


def test_a_declared_length_unit_is_read_and_a_contradicting_one_refused(tmp_path):
    """``# x, y, z in mm`` above the header: the reader takes mm where no unit is given (over
    the fallback, the data's unit for a held-out file), refuses another unit given, naming the
    line, and an unknown unit."""
    path = _file(tmp_path, f"# tracker export, x, y, z in mm\n{HEADER}\n{ROW}\n")
    metres = read_measurements(_file(tmp_path, f"{HEADER}\n{ROW}\n", "m.csv"))
    mm = read_measurements(path)
    np.testing.assert_allclose(mm.xyz, metres.xyz * 1e-3)
    np.testing.assert_allclose(read_measurements(path, fallback=("m", "deg")).xyz, mm.xyz)
    np.testing.assert_allclose(read_measurements(path, length_unit="mm").xyz, mm.xyz)
    with pytest.raises(
        MeasurementError, match=r"line 1: the file declares x, y, z in mm.*--length-unit mm"
    ):
        read_measurements(path, length_unit="m")
    bad = _file(tmp_path, f"# x, y, z in inch\n{HEADER}\n{ROW}\n", "inch.csv")
    with pytest.raises(MeasurementError, match=r"line 1: declares x, y, z in 'inch'"):
        read_measurements(bad)
    # no declaration: the fallback's unit (a held-out file read in the data's)
    np.testing.assert_allclose(
        read_measurements(tmp_path / "m.csv", fallback=("mm", "rad")).xyz, mm.xyz
    )


@pytest.mark.parametrize("where", ["between rows", "after the last row"])
def test_a_comment_line_among_the_rows_is_refused_by_every_reader_naming_its_line(tmp_path, where):
    from lab.export import CompensationError

    rows = [ROW, ROW.replace("0.1", "0.2", 1), ROW.replace("0.1", "0.3", 1)]
    at = 1 if where == "between rows" else 3
    body = [*rows[:at], "# second session, 2 degC warmer", *rows[at:]]
    path = _file(tmp_path, "\n".join(["# campaign 4", HEADER, *body]) + "\n")
    line = at + 3
    for name, read in _readers():
        with pytest.raises((MeasurementError, CompensationError)) as exc:
            read(path)
        msg = str(exc.value)
        assert msg.startswith(f"{path}, line {line}: a comment line"), (name, msg)
        assert "before the header" in msg and "\n" not in msg, (name, msg)


def test_a_file_of_comments_alone_is_refused():
    from arm.measurements import parse_measurements

    with pytest.raises(MeasurementError, match=r"^c.csv: only comment lines, expected a header"):
        parse_measurements("# a\n# b\n", "c.csv")


def test_text_columns_are_kept_as_labels_named_once_and_ignored_by_the_fits(tmp_path):
    """A ``set`` column of ``stationing`` rows (and a quoted cell with a comma, a blank one) is
    kept as labels, named in one note; a numeric extra column stays a number for custom effects;
    the fit of the file equals the fit of the file without the text column; the labels are
    written back."""
    from lab import fit
    from tests._lab_data import campaign

    seed = load_robot("seed")
    data = campaign(seed, "geometric", seed=4).measure(40)
    plain = _file(tmp_path, data.to_csv(), "plain.csv")
    lines = plain.read_text().splitlines()
    sets = ["stationing", '"a, b"', ""] * 14
    text = "\n".join(
        [lines[0] + ",set,humidity"]
        + [f"{row},{sets[i]},{40 + i}" for i, row in enumerate(lines[1:])]
    )
    labelled = _file(tmp_path, text + "\n", "labelled.csv")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = read_measurements(labelled)
    notes = [str(w.message) for w in caught if "hold text" in str(w.message)]
    assert len(notes) == 1 and "'set' ('stationing' on line 2)" in notes[0]
    assert list(d.labels) == ["set"] and list(d.labels["set"][:3]) == ["stationing", "a, b", ""]
    assert "set" not in d.columns and d.columns["humidity"][1] == 41.0
    assert sum("hold text" in n for n in d.notes) == 1
    assert list(d.subset([1, 0]).labels["set"]) == ["a, b", "stationing"]
    back = read_measurements(_file(tmp_path, d.to_csv(), "back.csv"))
    assert list(back.labels["set"]) == list(d.labels["set"])
    a, b = fit(plain, seed, "geometric"), fit(d, seed, "geometric")
    np.testing.assert_array_equal(a.params, b.params)
