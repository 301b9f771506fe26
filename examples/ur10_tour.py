"""The files of docs/lab.md's multi-station tour, cut from the shipped UR10 series (data/ur10/):

    python examples/ur10_tour.py -o tour

* ``tour/BD.csv``: ``--poses`` rows of series B (station 2) and of series D (station 4), drawn at
  random, joined in one measurement CSV (the two files share their columns): a calibration of
  two tracker stations;
* ``tour/A_program.csv``: ``--program`` poses of series A (station 1, a station the calibration
  has not seen) as a program to compensate: its joints (q1..q6) and the points the arm reached
  there, measured from A's station (x, y, z): the targets, in that station's frame;
* ``tour/A_references.csv``: ``--references`` other measured poses of A: the reference points
  that register A's station;
* ``tour/D_references.csv``: ``--references`` poses of D, which register D's station where a
  calibration of B alone is validated on D (they are left out of the validation figure).

The program's poses keep away from the wrist's and the elbow's singularities (|q5| and |q3| at
least ``--clear`` rad), where the compensation of a program is a question of its own. Rows are
copied as the series write them; the same seed gives the same files. Any other series in the
lab's format (``--series-a``, ``--series-b``, ``--series-d``) is cut the same way.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from arm.files import atomic_write_text  # noqa: E402


def _rows(path: Path) -> tuple[str, list[str]]:
    lines = [t for t in path.read_text(encoding="utf-8").splitlines() if t.strip()]
    return lines[0], lines[1:]


def _column(header: str, rows: list[str], name: str) -> np.ndarray:
    k = header.split(",").index(name)
    return np.array([float(r.split(",")[k]) for r in rows])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", type=Path, default=Path("tour"), help="folder to write")
    ap.add_argument("--poses", type=int, default=200, help="rows of B and of D each")
    ap.add_argument("--program", type=int, default=40, help="program poses of A")
    ap.add_argument("--references", type=int, default=4, help="reference points of A")
    ap.add_argument("--clear", type=float, default=0.3, help="|q5|, |q3| of a program pose, rad")
    ap.add_argument("--seed", type=int, default=0)
    data = ROOT / "data" / "ur10"
    for k in "abd":
        ap.add_argument(f"--series-{k}", type=Path, default=data / f"series_{k.upper()}.csv")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    header_b, b = _rows(args.series_b)
    header_d, d = _rows(args.series_d)
    if header_b != header_d:
        ap.error(f"{args.series_b} and {args.series_d} have other columns: cannot be joined")
    joined = [*(b[i] for i in sorted(rng.choice(len(b), min(args.poses, len(b)), False)))]
    joined += [d[i] for i in sorted(rng.choice(len(d), min(args.poses, len(d)), False))]
    header_a, a = _rows(args.series_a)
    clear = (np.abs(_column(header_a, a, "q5")) >= args.clear) & (
        np.abs(_column(header_a, a, "q3")) >= args.clear
    )
    chosen = rng.permutation(np.flatnonzero(clear))
    program = sorted(chosen[: args.program])
    refs = sorted(chosen[args.program : args.program + args.references])
    out = args.output
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "BD.csv", "\n".join([header_b, *joined]) + "\n")
    atomic_write_text(out / "A_program.csv", "\n".join([header_a, *(a[i] for i in program)]) + "\n")
    atomic_write_text(out / "A_references.csv", "\n".join([header_a, *(a[i] for i in refs)]) + "\n")
    d_refs = sorted(rng.choice(len(d), min(args.references, len(d)), False))
    atomic_write_text(
        out / "D_references.csv", "\n".join([header_d, *(d[i] for i in d_refs)]) + "\n"
    )
    print(
        f"wrote {out / 'BD.csv'} ({len(joined)} poses of B and D), {out / 'A_program.csv'} "
        f"({len(program)} poses of A), {out / 'A_references.csv'} ({len(refs)} of A) and "
        f"{out / 'D_references.csv'} ({len(d_refs)} of D)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
