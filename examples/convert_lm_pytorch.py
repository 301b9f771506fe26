"""Convert the public laser-tracker data of ``dongjy-s/LM_PyTorch`` into the lab's files.

That repository (a Rokae-style six-axis arm measured by a laser tracker) states no licence, so
this project does not redistribute its data: clone it and convert it on your machine.

    git clone https://github.com/dongjy-s/LM_PyTorch && git -C LM_PyTorch checkout e87ba15
    python examples/convert_lm_pytorch.py LM_PyTorch -o rokae-laser-tracker
    sixaxis lab fit rokae-laser-tracker/measurements.csv --robot rokae-laser-tracker/robot.toml

Input, from the repository's ``data/`` folder, in either of the two layouts its history holds
(the raw exports at commit e87ba15; header CSVs at c65e54ba and c7f708a6):

* ``dh.csv``: the nominal modified DH table, a header ``alpha, a, d, theta`` and six rows
  (alpha and theta offset in degrees, a and d in mm);
* ``joint_limits.csv``: a header ``UpperLimit,LowerLimit`` and six rows in degrees;
* ``joint_angle.csv``: the controller's ``jointtarget`` lines, one per pose, e.g.
  ``LOCAL VAR jointtarget j1 = j:{ 2.636,29.518,6.100,34.748,-47.376,35.792 , 0 } {EJ 0,...}``
  (the first six numbers in ``j:{...}`` are q1..q6 in degrees), or a header ``q1,...,q6`` and
  one row of six numbers in degrees per pose;
* ``laser_pos.csv``: the tracker's export, a header line, then one line per pose: a name, six
  nominal numbers, then the six measured ones, then residuals; or a header ``x,y,z,rx,ry,rz``
  and one row of the six measured numbers per pose. The six are X Y Z in mm in the tracker's
  frame and the orientation of the tracker's 6-DoF probe, Rx Ry Rz in degrees, meaning
  R = Rz(Rz) Ry(Ry) Rx(Rx): the repository reads them with
  ``scipy.spatial.transform.Rotation.from_euler("xyz", [rx, ry, rz], degrees=True)``, rotations
  about the fixed x, then y, then z axis (``tools/calibrate.py``, ``jacobian_torch.py``).

Output, in the output folder (written atomically):

* ``measurements.csv``: the lab's measurement file (q1..q6 in rad, x y z in m, the orientation as
  ``roll, pitch, yaw`` in rad: the same convention; ``--positions-only`` leaves it out);
* ``robot.toml``: the nominal arm (tool at the flange, base at the tracker's origin: the lab
  registers both in closed form before it fits);
* ``dh_mdh_deg_mm.csv`` and ``joint_limits_deg.csv``: the two tables as they were.

Bad input stops with the file and line named; nothing is written then.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from arm.description import Joint, RobotDescription
from arm.errors import SixAxisError
from arm.files import atomic_write_text

NAME = "rokae"
_JOINTTARGET = re.compile(r"j:\s*\{([^}]*)\}")
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


class ConversionError(SixAxisError, ValueError):
    """An input file of the wrong layout; the message names the file and the line."""


def _read(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8-sig").splitlines()
    except FileNotFoundError:
        raise ConversionError(f"{path}: file not found") from None
    except UnicodeDecodeError as exc:
        raise ConversionError(f"{path}: not UTF-8 text ({exc.reason})") from None


def _numbers(fields: list[str], path: Path, line: int) -> list[float]:
    out = []
    for f in fields:
        f = f.strip()
        if not _NUMBER.match(f):
            raise ConversionError(f"{path}, line {line}: {f!r} is not a number")
        out.append(float(f))
    return out


def _table(path: Path, header: tuple[str, ...], width: int) -> list[list[float]]:
    """Six rows of ``width`` numbers under a header naming ``header``."""
    lines = [(i, s) for i, s in enumerate(_read(path), start=1) if s.strip()]
    if not lines:
        raise ConversionError(f"{path}: empty")
    got = tuple(h.strip() for h in lines[0][1].split(","))
    if got != header:
        raise ConversionError(f"{path}, line {lines[0][0]}: header {got} is not {header}")
    rows = []
    for i, s in lines[1:]:
        values = _numbers(s.split(","), path, i)
        if len(values) != width:
            raise ConversionError(f"{path}, line {i}: {len(values)} numbers, expected {width}")
        rows.append(values)
    if len(rows) != 6:
        raise ConversionError(f"{path}: {len(rows)} rows, expected 6 (one per joint)")
    return rows


def read_joint_angles(path: Path) -> np.ndarray:
    """(N, 6) joint angles in degrees from the controller's ``jointtarget`` lines, or from a
    ``q1,...,q6`` CSV in degrees."""
    lines = _read(path)
    if not any("jointtarget" in s or _JOINTTARGET.search(s) for s in lines):
        return _header_rows(path, lines, ("q1", "q2", "q3", "q4", "q5", "q6"))
    out = []
    for i, s in enumerate(lines, start=1):
        m = _JOINTTARGET.search(s)
        if m is None:
            if s.strip() and "jointtarget" in s:
                raise ConversionError(f"{path}, line {i}: a jointtarget without j:{{...}}")
            continue  # blank lines, headers, comments
        fields = [f for f in m.group(1).replace("\t", " ").split(",") if f.strip()]
        if len(fields) < 6:
            raise ConversionError(f"{path}, line {i}: {len(fields)} values in j:{{...}}, need 6")
        out.append(_numbers(fields[:6], path, i))
    if not out:
        raise ConversionError(f"{path}: no jointtarget line (j:{{q1,...,q6, ...}})")
    return np.array(out)


def _header_rows(path: Path, lines: list[str], header: tuple[str, ...]) -> np.ndarray:
    """The rows of a CSV whose first line is ``header`` (case and spaces aside)."""
    rows = [(i, s) for i, s in enumerate(lines, start=1) if s.strip()]
    if not rows:
        raise ConversionError(f"{path}: empty")
    got = tuple(h.strip().lower() for h in rows[0][1].split(","))
    if got != header:
        raise ConversionError(f"{path}, line {rows[0][0]}: header {got} is not {header}")
    out = []
    for i, s in rows[1:]:
        values = _numbers(s.split(","), path, i)
        if len(values) != len(header):
            raise ConversionError(
                f"{path}, line {i}: {len(values)} numbers, expected {len(header)}"
            )
        out.append(values)
    if not out:
        raise ConversionError(f"{path}: no row after the header")
    return np.array(out)


LASER_HEADER = ("x", "y", "z", "rx", "ry", "rz")


def read_laser_poses(path: Path) -> np.ndarray:
    """(N, 6) measured X Y Z in mm and Rx Ry Rz in degrees: the second group of six numbers on
    each line of the tracker's export after its header, or the rows of an ``x,y,z,rx,ry,rz``
    CSV."""
    lines = _read(path)
    rows = [(i, s) for i, s in enumerate(lines, start=1) if s.strip()]
    if rows and tuple(h.strip().lower() for h in rows[0][1].split(",")) == LASER_HEADER:
        return _header_rows(path, lines, LASER_HEADER)
    out = []
    for i, s in rows[1:]:  # the first line is the header
        tokens = [t for t in re.split(r"[\s,;]+", s.strip()) if t]
        numbers = [float(t) for t in tokens if _NUMBER.match(t)]
        if len(numbers) < 12:
            raise ConversionError(
                f"{path}, line {i}: {len(numbers)} numbers; expected six nominal and six "
                "measured (X Y Z mm, then Rx Ry Rz deg)"
            )
        out.append(numbers[6:12])
    if not out:
        raise ConversionError(f"{path}: no measurement line after the header")
    return np.array(out)


def read_laser_positions(path: Path) -> np.ndarray:
    """(N, 3) measured X Y Z in mm (:func:`read_laser_poses` without the orientation)."""
    return read_laser_poses(path)[:, :3]


def robot_of(dh: list[list[float]], limits: list[list[float]]) -> RobotDescription:
    joints = tuple(
        Joint(
            alpha=math.radians(al),
            a=a / 1e3,
            d=d / 1e3,
            theta_offset=math.radians(th),
            lower=math.radians(lo),
            upper=math.radians(hi),
        )
        for (al, a, d, th), (hi, lo) in zip(dh, limits, strict=True)
    )
    return RobotDescription(NAME, joints)


def measurements_csv(
    q_deg: np.ndarray, xyz_mm: np.ndarray, rpy_deg: np.ndarray | None = None
) -> str:
    """The lab's CSV: q in rad (9 decimals: the controller's 1e-13 deg and more), x y z in m
    (7 decimals: the tracker's 1e-4 mm), roll pitch yaw in rad (10 decimals: its 1e-4 deg)."""
    header = "q1,q2,q3,q4,q5,q6,x,y,z" + ("" if rpy_deg is None else ",roll,pitch,yaw")
    rows = [header]
    angles = np.zeros((len(q_deg), 0)) if rpy_deg is None else np.radians(rpy_deg)
    for q, p, r in zip(np.radians(q_deg), xyz_mm / 1e3, angles, strict=True):
        cells = [*(f"{v:.9f}" for v in q), *(f"{v:.7f}" for v in p), *(f"{v:.10f}" for v in r)]
        rows.append(",".join(cells))
    return "\n".join(rows) + "\n"


def convert(repo: Path, out: Path, orientation: bool = True) -> dict:
    """Convert the repository checked out at ``repo`` into ``out``; returns a summary.
    ``orientation``: keep the probe's orientation (roll, pitch, yaw), else positions only."""
    data = repo / "data"
    if not data.is_dir():
        raise ConversionError(f"{repo}: no data/ folder (a clone of dongjy-s/LM_PyTorch?)")
    dh_path, lim_path = data / "dh.csv", data / "joint_limits.csv"
    dh = _table(dh_path, ("alpha", "a", "d", "theta"), 4)
    limits = _table(lim_path, ("UpperLimit", "LowerLimit"), 2)
    for k, (hi, lo) in enumerate(limits, start=1):
        if not lo < hi:
            raise ConversionError(f"{lim_path}: joint {k} limits {lo}..{hi} are empty")
    q = read_joint_angles(data / "joint_angle.csv")
    poses = read_laser_poses(data / "laser_pos.csv")
    if len(q) != len(poses):
        raise ConversionError(
            f"{data / 'joint_angle.csv'} has {len(q)} poses but {data / 'laser_pos.csv'} "
            f"{len(poses)} measurements"
        )
    robot = robot_of(dh, limits)
    out.mkdir(parents=True, exist_ok=True)
    rpy = poses[:, 3:] if orientation else None
    atomic_write_text(out / "measurements.csv", measurements_csv(q, poses[:, :3], rpy))
    robot.save(out / "robot.toml", length_unit="mm", angle_unit="deg")
    for src, name in ((dh_path, "dh_mdh_deg_mm.csv"), (lim_path, "joint_limits_deg.csv")):
        atomic_write_text(out / name, src.read_text(encoding="utf-8-sig"))  # as they were
    return {"poses": len(q), "out": str(out), "robot": robot.name, "orientation": orientation}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Convert dongjy-s/LM_PyTorch's data for the lab.")
    ap.add_argument("repo", type=Path, help="the repository checked out at commit e87ba15")
    ap.add_argument("-o", "--out", type=Path, default=Path("rokae-laser-tracker"))
    ap.add_argument(
        "--positions-only",
        action="store_true",
        help="leave the probe's orientation out (x, y, z only)",
    )
    args = ap.parse_args(argv)
    try:
        s = convert(args.repo, args.out, orientation=not args.positions_only)
    except (ConversionError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    what = "poses (with orientation)" if s["orientation"] else "positions"
    print(f"wrote {s['poses']} {what} to {s['out']}/measurements.csv and the arm to robot.toml")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
