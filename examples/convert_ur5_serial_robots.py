"""Convert the public UR5 laser-tracker data set (Jacobi 2025, MIT) into the lab's measurement files.

The data set ships in this repository, as published, in ``data/ur5/original/``; its converted
files, ``data/ur5/calibration.csv`` and ``data/ur5/test.csv``, are this script's output (a test
checks that they are):

    python examples/convert_ur5_serial_robots.py data/ur5/original -o data/ur5
    sixaxis lab fit data/ur5/calibration.csv --robot ur5 --validate data/ur5/test.csv

Input, the two CSV files of github.com/pauljac7700/serial_robots_datasets (commit 759068d):

* ``3D_UR5_uncalibrated_grid_cleaned.csv``: 1,000 poses on a grid (the calibration set);
* ``3D_UR5_uncalibrated_random_cleaned.csv``: 20 random poses (the test set);

each with the header ``step_order,x_t,y_t,z_t,x_dif,y_dif,z_dif,joint_1,...,joint_6``: the target
position (mm, the robot's base frame, the tool centre registered by the authors), the difference
between the target and the reached position (mm), the commanded joint angles (degrees).

Output, written atomically (``calibration.csv``, ``test.csv``): the lab's measurement CSV, q1..q6
in rad and x y z in m, one row per pose in the source's order. The measured point is the reached
position, ``target - dif`` ("the difference between the target and the reached position"); the
source does not state the sign, and ``--dif-sign plus`` writes ``target + dif`` instead. The two
fit alike once the base and the tool are fitted (UR5 geometric fit: 0.1044 mm against 0.1042 mm
held-out RMS). ``step_order`` is dropped (it is the row number).

Bad input stops with the file, line and column named; nothing is written then.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from arm.errors import SixAxisError
from arm.files import atomic_write_text

HEADER = (
    "step_order",
    "x_t",
    "y_t",
    "z_t",
    "x_dif",
    "y_dif",
    "z_dif",
    *(f"joint_{k}" for k in range(1, 7)),
)
FILES = {
    "calibration.csv": "3D_UR5_uncalibrated_grid_cleaned.csv",
    "test.csv": "3D_UR5_uncalibrated_random_cleaned.csv",
}
SIGNS = {"minus": -1.0, "plus": 1.0}


class ConversionError(SixAxisError, ValueError):
    """An input file of the wrong layout; the message names the file, line and column."""


def read_source(path: Path) -> dict[str, np.ndarray]:
    """The columns of one source CSV, as floats, every cell checked."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise ConversionError(f"{path}: file not found") from None
    except UnicodeDecodeError as exc:
        raise ConversionError(f"{path}: not UTF-8 text ({exc.reason})") from None
    lines = text.splitlines()
    if not lines:
        raise ConversionError(f"{path}: empty")
    header = tuple(h.strip() for h in lines[0].split(","))
    if header != HEADER:
        raise ConversionError(
            f"{path}, line 1: header {','.join(header)} is not {','.join(HEADER)}"
        )
    rows = []
    for i, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != len(HEADER):
            raise ConversionError(f"{path}, line {i}: {len(cells)} fields, expected {len(HEADER)}")
        row = []
        for name, cell in zip(HEADER, cells, strict=True):
            try:
                v = float(cell)
            except ValueError:
                raise ConversionError(
                    f"{path}, line {i}, column '{name}': {cell.strip()!r} is not a number"
                ) from None
            if not math.isfinite(v):
                raise ConversionError(f"{path}, line {i}, column '{name}': {v} is not finite")
            row.append(v)
        rows.append(row)
    if not rows:
        raise ConversionError(f"{path}: no data rows")
    table = np.array(rows)
    return {name: table[:, k] for k, name in enumerate(HEADER)}


def measurements_csv(cols: dict[str, np.ndarray], sign: float) -> str:
    """The lab's CSV: q in rad and x y z in m, every float to its last bit (repr)."""
    q = np.radians(np.column_stack([cols[f"joint_{k}"] for k in range(1, 7)]))
    xyz = np.column_stack([cols[f"{c}_t"] + sign * cols[f"{c}_dif"] for c in ("x", "y", "z")]) / 1e3
    out = ["q1,q2,q3,q4,q5,q6,x,y,z"]
    out += [",".join(repr(float(v)) for v in (*qi, *pi)) for qi, pi in zip(q, xyz, strict=True)]
    return "\n".join(out) + "\n"


def convert(source: Path, out: Path, dif_sign: str = "minus") -> dict[str, int]:
    """Convert the two files in ``source`` into ``out``; returns the poses written per file."""
    if dif_sign not in SIGNS:
        raise ConversionError(f"--dif-sign must be one of {', '.join(SIGNS)}, got {dif_sign!r}")
    texts = {
        name: measurements_csv(read_source(source / src), SIGNS[dif_sign])
        for name, src in FILES.items()
    }  # everything read and checked before anything is written
    out.mkdir(parents=True, exist_ok=True)
    for name, text in texts.items():
        atomic_write_text(out / name, text)
    return {name: text.count("\n") - 1 for name, text in texts.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Convert the UR5 laser-tracker data set for the lab.")
    ap.add_argument("source", type=Path, help="the folder with the two source CSV files")
    ap.add_argument("-o", "--out", type=Path, default=Path("ur5"))
    ap.add_argument(
        "--dif-sign",
        choices=sorted(SIGNS),
        default="minus",
        help="measured point = target minus (default) or plus the difference columns",
    )
    args = ap.parse_args(argv)
    try:
        counts = convert(args.source, args.out, args.dif_sign)
    except (ConversionError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for name, n in counts.items():
        print(f"wrote {n} poses to {args.out / name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
