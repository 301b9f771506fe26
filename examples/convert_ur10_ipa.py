"""Convert the public UR10 laser-tracker series (Landgraf et al. 2021, MIT) into the lab's files.

Three series of one UR10, months apart, each from its own tracker station, at its own temperature,
in its own region of the joint space (``data/ur10/README.md``). Their converted files,
``data/ur10/series_A.csv``, ``series_B.csv`` and ``series_D.csv``, are this script's output:

    python examples/convert_ur10_ipa.py SOURCE_DIR -o data/ur10
    sixaxis lab fit data/ur10/series_B.csv --robot ur10_robot --noise-mm 0.015 --noise-ppm 6 \\
        --validate data/ur10/series_D.csv --references tour/D_references.csv

Input, a folder holding one CSV per series whose name starts ``series_A``, ``series_B`` and
``series_D`` (github.com/christianlandgraf/ipa-robot-accuracy, commit 507fba6), in either layout:

* the source's own: semicolon-separated, decimal commas, joint columns ``shoulder_pan_joint`` ..
  ``wrist_3_joint`` (rad), ``measurement_x/y/z`` (mm), ``measurement_temperature`` (degC) and, in
  B and D, ``measurement_std_x/y/z`` (mm); other columns (the probe's orientation) are dropped;
* or those columns already renamed: comma-separated ``q1..q6, x, y, z, temperature`` and
  ``std_x, std_y, std_z``, lengths still in mm.

Output, written atomically: the lab's measurement CSV, q1..q6 in rad, x y z and std_x..std_z in
m, temperature in degC, and a ``station`` column: each series was measured from its own tracker
station, numbered by the series' letter (A 1, B 2, D 4; the source's series C is not published
with the others). One row per measurement in the source's order, every number written with ten
significant digits (the source gives at most eight in mm; 1e-10 m is far below its 0.01 mm).

Bad input stops with the file, line and column named; nothing is written then.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from arm.errors import SixAxisError
from arm.files import atomic_write_text

SERIES = {"A": 1, "B": 2, "D": 4}
JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
# the lab's column <- the source's, and the factor to SI
SOURCE = {
    **{f"q{k + 1}": (j, 1.0) for k, j in enumerate(JOINTS)},
    **{c: (f"measurement_{c}", 1e-3) for c in ("x", "y", "z")},
    "temperature": ("measurement_temperature", 1.0),
    **{f"std_{c}": (f"measurement_std_{c}", 1e-3) for c in ("x", "y", "z")},
}
REQUIRED = ("q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z", "temperature")
STDS = ("std_x", "std_y", "std_z")


class ConversionError(SixAxisError, ValueError):
    """An input file of the wrong layout; the message names the file, line and column."""


def read_series(path: Path) -> dict[str, list[float]]:
    """The lab's columns of one series (SI units), every cell checked."""
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except FileNotFoundError:
        raise ConversionError(f"{path}: file not found") from None
    except UnicodeDecodeError as exc:
        raise ConversionError(f"{path}: not UTF-8 text ({exc.reason})") from None
    if not lines:
        raise ConversionError(f"{path}: empty")
    source = ";" in lines[0]
    sep = ";" if source else ","
    header = [h.strip() for h in lines[0].split(sep)]
    where = {}
    for col, (name, _) in SOURCE.items():
        key = name if source else col
        if key in header:
            where[col] = header.index(key)
    missing = [SOURCE[c][0] if source else c for c in REQUIRED if c not in where]
    stds = [c for c in STDS if c in where]
    if stds and len(stds) < 3:
        missing += [SOURCE[c][0] if source else c for c in STDS if c not in where]
    if missing:
        raise ConversionError(f"{path}, line 1: column {missing[0]!r} is missing")
    out: dict[str, list[float]] = {c: [] for c in where}
    for i, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(sep)
        if len(cells) != len(header):
            raise ConversionError(
                f"{path}, line {i}: {len(cells)} cells, the header has {len(header)}"
            )
        for col, k in where.items():
            text = cells[k].strip().replace(",", ".") if source else cells[k].strip()
            try:
                v = float(text)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                name = header[k]
                raise ConversionError(
                    f"{path}, line {i}, column {name!r}: {cells[k]!r} is not a number"
                )
            factor = SOURCE[col][1] if source or col not in ("x", "y", "z", *STDS) else 1e-3
            out[col].append(v * factor)
    if not out["q1"]:
        raise ConversionError(f"{path}: no rows")
    return out


def measurements_csv(columns: dict[str, list[float]], station: int) -> str:
    """The lab's measurement CSV of one series."""
    names = [c for c in (*REQUIRED, *STDS) if c in columns]
    lines = [",".join([*names, "station"])]
    for r in range(len(columns["q1"])):
        lines.append(",".join([*(f"{columns[c][r]:.10g}" for c in names), str(station)]))
    return "\n".join(lines) + "\n"


def find_series(folder: Path, letter: str) -> Path:
    found = sorted(p for p in folder.glob(f"series_{letter}*.csv") if p.is_file())
    if not found:
        raise ConversionError(f"{folder}: no file series_{letter}*.csv")
    if len(found) > 1:
        names = ", ".join(p.name for p in found)
        raise ConversionError(f"{folder}: several files for series {letter}: {names}")
    return found[0]


def convert(folder: Path, out: Path) -> dict[str, int]:
    """Every series of ``folder`` into ``out``/series_X.csv; returns the rows per file. Every
    input is read and checked before anything is written."""
    texts = {}
    for letter, station in SERIES.items():
        cols = read_series(find_series(folder, letter))
        texts[f"series_{letter}.csv"] = (measurements_csv(cols, station), len(cols["q1"]))
    out.mkdir(parents=True, exist_ok=True)
    for name, (text, _) in texts.items():
        atomic_write_text(out / name, text)
    return {name: n for name, (_, n) in texts.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", type=Path, help="the folder of the series' CSV files")
    ap.add_argument("-o", "--out", type=Path, default=Path("data/ur10"), help="output folder")
    args = ap.parse_args(argv)
    try:
        counts = convert(args.source, args.out)
    except ConversionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for name, n in counts.items():
        print(f"{args.out / name}: {n} rows")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
