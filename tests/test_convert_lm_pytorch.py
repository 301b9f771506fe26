"""examples/convert_lm_pytorch.py on small synthetic files in the public repository's layout: the
controller's jointtarget lines, the tracker's lines of nominal and measured values, the DH table
and the limits; the lab reads what it writes, and bad files are refused by file and line."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from arm.description import load_robot
from arm.errormodel import ErrorModel
from arm.measurements import read_measurements

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "convert_lm_pytorch.py"
DH = "alpha, a, d, theta\n0, 0, 487, 0\n-90, 85, 0, -90\n0, 640, 0, 0\n-90, 205, 720, 0\n90, 0, 0, 0\n-90, 0, 75, 180\n"
LIMITS = "UpperLimit,LowerLimit\n100,-100\n100,-90\n60,-100\n100,-100\n90,-90\n120,-120\n"


@pytest.fixture(scope="module")
def conv():
    spec = importlib.util.spec_from_file_location("convert_lm_pytorch", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _repo(tmp_path, q_deg, xyz_mm, laser_extra=""):
    data = tmp_path / "repo" / "data"
    data.mkdir(parents=True)
    (data / "dh.csv").write_text(DH)
    (data / "joint_limits.csv").write_text(LIMITS)
    lines = [
        f"LOCAL VAR jointtarget j{k + 1} = j:{{\t {','.join(repr(float(v)) for v in q)}      ,"
        "\t0\t}\t\t{EJ 0,0,0,0,0,0}"
        for k, q in enumerate(q_deg)
    ]
    (data / "joint_angle.csv").write_text("\n".join(lines) + "\n")
    laser = [
        "名称 名义X 名义Y 名义Z 名义Rx 名义Ry 名义Rz 测量X 测量Y 测量Z 测量Rx 测量Ry 测量Rz 余量位置 余量方向"
    ]
    for k, p in enumerate(xyz_mm):
        nominal = " ".join(f"{v + 0.1:.4f}" for v in p) + " 45.5 -70.9 -166.4"
        laser.append(
            f"Motion{k + 1} {nominal} {' '.join(f'{v:.4f}' for v in p)} 1.2 -3.4 5.6 0.1 0.03"
        )
    (data / "laser_pos.csv").write_text("\n".join(laser) + laser_extra + "\n")
    return tmp_path / "repo"


def test_conversion_is_read_back_by_the_lab(conv, tmp_path):
    rng = np.random.default_rng(0)
    q_deg = rng.uniform(-40, 40, (5, 6))
    xyz_mm = rng.uniform(500, 3500, (5, 3)).round(4)
    repo = _repo(tmp_path, q_deg, xyz_mm)
    out = tmp_path / "out"
    assert conv.main([str(repo), "-o", str(out)]) == 0
    data = read_measurements(out / "measurements.csv")
    np.testing.assert_allclose(data.q, np.radians(q_deg), atol=5e-10)
    np.testing.assert_allclose(data.xyz, xyz_mm / 1e3, atol=5e-11)  # the measured, not nominal
    robot = load_robot(out / "robot.toml")
    rows = [[float(x) for x in r.split(",")] for r in DH.splitlines()[1:]]
    for j, (al, a, d, th) in zip(robot.joints, rows, strict=True):
        assert j.alpha == pytest.approx(math.radians(al))
        assert j.a == pytest.approx(a / 1e3) and j.d == pytest.approx(d / 1e3)
        assert j.theta_offset == pytest.approx(math.radians(th))
    assert robot.joints[1].lower == pytest.approx(math.radians(-90))
    assert robot.joints[2].upper == pytest.approx(math.radians(60))
    assert (out / "dh_mdh_deg_mm.csv").read_text() == DH
    # the lab can model these poses with that arm
    m = ErrorModel(robot)
    assert m.predict(m.inputs(data.q), m.nominal()).shape == (5, 3)


def test_the_tables_give_the_arm_of_the_real_data_tests(conv):
    """The converter's arm equals the one the real-data tests build from the same table."""
    from tests.conftest import rokae_arm

    rows = [[float(x) for x in r.split(",")] for r in DH.splitlines()[1:]]
    lim = [[float(x) for x in r.split(",")] for r in LIMITS.splitlines()[1:]]
    ours = conv.robot_of(rows, lim)
    ref = rokae_arm()
    for a, b in zip(ours.joints, ref.joints, strict=True):
        assert (a.alpha, a.a, a.d, a.theta_offset) == pytest.approx(
            (b.alpha, b.a, b.d, b.theta_offset)
        )


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("laser_short", "laser_pos.csv, line 3: 9 numbers"),
        ("count", "has 3 poses but"),
        ("dh_header", "dh.csv, line 1: header"),
        ("angle_text", "joint_angle.csv, line 2: 'x1' is not a number"),
    ],
)
def test_bad_files_are_refused_by_file_and_line(conv, tmp_path, damage, message, capsys):
    q = np.zeros((3, 6))
    xyz = np.ones((3, 3)) * 1000
    repo = _repo(tmp_path, q, xyz)
    data = repo / "data"
    if damage == "laser_short":
        lines = (data / "laser_pos.csv").read_text().splitlines()
        lines[2] = "Motion2 1 2 3 4 5 6 7 8 9"
        (data / "laser_pos.csv").write_text("\n".join(lines) + "\n")
    elif damage == "count":
        (data / "laser_pos.csv").write_text(
            (data / "laser_pos.csv").read_text() + "Motion4 " + " ".join(["1"] * 14) + "\n"
        )
    elif damage == "dh_header":
        (data / "dh.csv").write_text(DH.replace("alpha", "twist"))
    else:
        lines = (data / "joint_angle.csv").read_text().splitlines()
        lines[1] = lines[1].replace("0.0", "x1", 1)
        (data / "joint_angle.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert conv.main([str(repo), "-o", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not (out / "measurements.csv").exists()  # nothing half-written


def _rpy_deg_matrix(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rz(rz) Ry(ry) Rx(rx), degrees, multiplied out: the repository's from_euler("xyz")."""
    a, b, c = np.radians([rx, ry, rz])
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def test_the_probes_orientation_is_kept_in_both_layouts(conv, tmp_path):
    """The tracker's raw export and the header CSVs of the repository's later commits give the
    same file; Rx Ry Rz (deg) become roll, pitch, yaw of the same rotation."""
    from arm.so3 import rotation_matrix

    rng = np.random.default_rng(1)
    q_deg = rng.uniform(-40, 40, (4, 6))
    xyz_mm = rng.uniform(500, 3500, (4, 3)).round(4)
    repo = _repo(tmp_path, q_deg, xyz_mm)  # measured Rx Ry Rz: 1.2 -3.4 5.6 on every line
    assert conv.main([str(repo), "-o", str(tmp_path / "raw")]) == 0
    data = read_measurements(tmp_path / "raw" / "measurements.csv")
    assert data.orientation_form == "rpy" and data.measured.all()
    want = _rpy_deg_matrix(1.2, -3.4, 5.6)
    np.testing.assert_allclose(rotation_matrix(data.orientation), [want] * 4, atol=1e-9)
    # the same poses as header CSVs (q1..q6 deg; x,y,z,rx,ry,rz)
    csv_repo = tmp_path / "csv" / "data"
    csv_repo.mkdir(parents=True)
    for name in ("dh.csv", "joint_limits.csv"):
        (csv_repo / name).write_text((repo / "data" / name).read_text())
    (csv_repo / "joint_angle.csv").write_text(
        "q1,q2,q3,q4,q5,q6\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in q_deg)
    )
    (csv_repo / "laser_pos.csv").write_text(
        "x,y,z,rx,ry,rz\n"
        + "".join(",".join(f"{v:.4f}" for v in p) + ",1.2,-3.4,5.6\n" for p in xyz_mm)
    )
    assert conv.main([str(tmp_path / "csv"), "-o", str(tmp_path / "hdr")]) == 0
    assert (tmp_path / "hdr" / "measurements.csv").read_text() == (
        tmp_path / "raw" / "measurements.csv"
    ).read_text()
    assert conv.main([str(repo), "-o", str(tmp_path / "pos"), "--positions-only"]) == 0
    plain = read_measurements(tmp_path / "pos" / "measurements.csv")
    assert plain.orientation is None
    np.testing.assert_array_equal(plain.xyz, data.xyz)
