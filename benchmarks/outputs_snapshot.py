"""The outputs a refactor must leave byte-identical: the lab's commands, a small sweep's
leaderboard and the reproduction of committed rows.

    python benchmarks/outputs_snapshot.py OUT            # run every command, write OUT/
    python benchmarks/outputs_snapshot.py --compare A B  # name every output that differs

Each command's stdout (and the files it writes) land in ``OUT``; paths (the output folder, the
checkout) and times (``in 1.2 s``, ISO timestamps, durations in the JSON records) are replaced by
placeholders so that two checkouts compare byte for byte. ``OUT/manifest.txt`` lists every file's
sha256. Issue 31 ("no number changes") is shown by comparing a snapshot made before a refactor with
one made after it.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# commands run in OUT (a fresh folder), in order; {data} is the repository's data folder
COMMANDS: list[tuple[str, str]] = [
    ("collect", "sixaxis lab collect -o data.csv --scenario compliance --n 120 --seed 1"),
    (
        "collect-validation",
        "sixaxis lab collect -o validation.csv --scenario compliance --n 60 --seed 2 --arm-seed 1",
    ),
    ("collect-hidden", "sixaxis lab collect -o hidden.csv --scenario cyclic --n 200 --seed 3"),
    (
        "collect-hidden-validation",
        "sixaxis lab collect -o hidden_val.csv --scenario cyclic --n 80 --seed 4 --arm-seed 3",
    ),
    ("fit", "sixaxis lab fit data.csv --validate validation.csv --noise-mm 0.015"),
    (
        "fit-json",
        "sixaxis lab fit data.csv --effects geometric,compliance[2,3] --validate validation.csv "
        "--noise-mm 0.015 --json",
    ),
    ("fit-robust", "sixaxis lab fit data.csv --loss huber --outliers keep --noise-mm 0.015"),
    ("diagnose", "sixaxis lab diagnose data.csv --noise-mm 0.015"),
    ("diagnose-json", "sixaxis lab diagnose data.csv --noise-mm 0.015 --json"),
    (
        "discover",
        "sixaxis lab discover hidden.csv --noise-mm 0.015 --validate hidden_val.csv -o found.py",
    ),
    (
        "report",
        "sixaxis lab report data.csv --validate validation.csv --noise-mm 0.015 -o report.html",
    ),
    (
        "export",
        "sixaxis lab export data.csv --effects geometric,compliance[2,3] -o calibrated.toml",
    ),
    ("export-urdf", "sixaxis lab export {data}/ur5/calibration.csv --robot ur5 -o ur5.urdf"),
    (
        "compensate",
        "sixaxis lab compensate validation.csv --robot calibrated.toml -o joints.csv",
    ),
    ("plan", "sixaxis lab plan --n 20 --seed 1 -o poses.csv"),
    (
        "ur5-fit",
        "sixaxis lab fit {data}/ur5/calibration.csv --robot ur5 --validate {data}/ur5/test.csv",
    ),
    (
        "ur5-diagnose",
        "sixaxis lab diagnose {data}/ur5/calibration.csv --robot ur5 --json",
    ),
    (
        "ur10-fit",
        "sixaxis lab fit {data}/ur10/series_D.csv --robot ur10_robot --noise-mm 0.015 "
        "--noise-ppm 6 --validate {data}/ur10/series_B.csv",
    ),
    ("sweep", "sixaxis sweep sweep.toml --out runs"),
    ("leaderboard", "sixaxis leaderboard runs --out lb"),
    (
        "reproduce-local",
        "sixaxis reproduce lb/leaderboard_runs.csv --run feedforward__geometric__ep0 --rtol 0",
    ),
    (
        "reproduce-committed",
        "sixaxis reproduce {root}/results/leaderboard_runs.csv --run mpc__geometric__ep0 --rtol 0",
    ),
    ("evaluate", "sixaxis evaluate feedforward --scenario geometric --seeds 1"),
]

SWEEP = textwrap.dedent(
    """\
    name = "snapshot"
    seeds = 2
    scenarios = ["geometric", "compliance"]
    agents = ["nominal", "feedforward", "calibrated"]
    """
)

TIMES = [
    (
        re.compile(r"\b\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}:\d{2}(\.\d+)?([+-]\d{2}:?\d{2}|Z)?"),
        "<TIME>",
    ),
    (re.compile(r"\b\d{4}-\d{2}-\d{2}\b"), "<DATE>"),
    (re.compile(r"\[\d{2}/\d{2}/\d{2} "), "[<DATE> "),
    (re.compile(r"\b(in|took) \d+(\.\d+)? ?(s|ms|min)\b"), r"\1 <T>"),
    (re.compile(r'"(wall_s|seconds|time_s|elapsed_s|duration_s)": [0-9.e+-]+'), r'"\1": <T>'),
    (re.compile(r"\b\d+(\.\d+)? ?s/(it|step)\b"), "<RATE>"),
    (re.compile(r"\b\d+:\d{2}:\d{2}\b"), "<CLOCK>"),
]


def normalise(text: str, out: Path) -> str:
    text = text.replace(str(out), "<OUT>").replace(str(ROOT), "<REPO>")
    for pattern, repl in TIMES:
        text = pattern.sub(repl, text)
    return text


def run(out: Path, only: list[str] | None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    work = out / "work"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    (work / "sweep.toml").write_text(SWEEP)
    env = dict(os.environ, COLUMNS="100", NO_COLOR="1", TERM="dumb")
    sixaxis = str(Path(sys.executable).parent / "sixaxis")
    for name, command in COMMANDS:
        if only and name not in only:
            continue
        cmd = command.format(data=ROOT / "data", root=ROOT).replace("sixaxis", sixaxis, 1)
        proc = subprocess.run(
            cmd, shell=True, cwd=work, env=env, capture_output=True, text=True, check=False
        )
        record = f"$ {command}\nexit {proc.returncode}\n--- stdout\n{proc.stdout}--- stderr\n"
        record += proc.stderr
        (out / f"{name}.txt").write_text(normalise(record, work))
        print(f"{name}: exit {proc.returncode}", flush=True)
    files = sorted(p for p in work.rglob("*") if p.is_file())
    lines = []
    for p in files:
        data = p.read_bytes()
        if p.suffix in {".csv", ".json", ".md", ".toml", ".urdf", ".py", ".html", ".txt"}:
            data = normalise(data.decode(), work).encode()
        lines.append(f"{hashlib.sha256(data).hexdigest()}  {p.relative_to(work)}")
    (out / "manifest.txt").write_text("\n".join(lines) + "\n")


def compare(a: Path, b: Path) -> int:
    names = sorted({p.name for p in a.glob("*.txt")} | {p.name for p in b.glob("*.txt")})
    differ = 0
    for name in names:
        pa, pb = a / name, b / name
        if not pa.exists() or not pb.exists():
            print(f"only in one: {name}")
            differ += 1
        elif pa.read_bytes() != pb.read_bytes():
            print(f"differs: {name}")
            differ += 1
    if not differ:
        print(f"identical: {len(names)} outputs and the manifest of every file written")
    return 1 if differ else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="?", type=Path)
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    parser.add_argument("--only", nargs="*", help="run only these commands (by name)")
    args = parser.parse_args()
    if args.compare:
        sys.exit(compare(*args.compare))
    if args.out is None:
        parser.error("give OUT, or --compare BEFORE AFTER")
    run(args.out.resolve(), args.only)


if __name__ == "__main__":
    main()
