"""The outputs a refactor must leave byte-identical: the lab's commands, a small sweep's
leaderboard and the reproduction of committed rows.

    python benchmarks/outputs_snapshot.py OUT            # run every command, write OUT/
    python benchmarks/outputs_snapshot.py --compare A B  # name every output that differs

Each command's stdout (and the files it writes) land in ``OUT``; paths (the output folder, the
checkout) and times (``in 1.2 s``, ISO timestamps, durations in the JSON records) are replaced by
placeholders, and so are the current commit and the columns and keys that hold times, so that two
checkouts compare byte for byte. ``OUT/files/`` holds every file the commands wrote (normalised;
plots as written) and ``OUT/manifest.txt`` their sha256. Issue 31 ("no number changes") is shown
by comparing a snapshot made before a refactor with one made after it, each from a clean checkout
(the leaderboard refuses records of a tree with local changes).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
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
    ("collect-all", "sixaxis lab collect -o all.csv --scenario all --n 150 --seed 5"),
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
        "discover-json",
        "sixaxis lab discover hidden.csv --noise-mm 0.015 --order 8 --name second --json",
    ),
    (
        "fit-discovered",
        "sixaxis lab fit hidden.csv --effect-module found.py --effects geometric,discovered "
        "--validate hidden_val.csv --noise-mm 0.015",
    ),
    ("discover-compliance", "sixaxis lab discover data.csv --noise-mm 0.015 -o found_tau.py"),
    ("discover-all", "sixaxis lab discover all.csv --noise-mm 0.015 --order 4 -o found_all.py"),
    (
        "ur10-discover",
        "sixaxis lab discover {data}/ur10/series_D.csv --robot ur10_robot --noise-mm 0.015 "
        "--noise-ppm 6 --order 8 -o ur10_found.py",
    ),
    (
        "report",
        "sixaxis lab report data.csv --validate validation.csv --noise-mm 0.015 -o report.html",
    ),
    (
        "export",
        "sixaxis lab export data.csv --effects geometric,compliance[2,3] -o calibrated.toml",
    ),
    ("export-urdf", "sixaxis lab export {data}/ur5/calibration.csv --robot ur5_robot -o ur5.urdf"),
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
        "sixaxis reproduce lb/leaderboard_runs.csv --run feedforward__geometric__seed0 --rtol 0",
    ),
    (
        "reproduce-committed",
        "sixaxis reproduce {root}/results/leaderboard_runs.csv --run mpc__geometric__ep0 --rtol 0",
    ),
    ("evaluate", "sixaxis evaluate feedforward --scenario geometric --seeds 1"),
    # the command line's help (its options are declared once; the text must stay the same)
    *(
        (f"help-{c.replace(' ', '-')}", f"sixaxis {c} --help")
        for c in (
            "lab",
            "lab fit",
            "lab diagnose",
            "lab discover",
            "lab report",
            "lab export",
            "lab compensate",
            "lab plan",
            "lab collect",
            "sweep",
            "leaderboard",
            "reproduce",
        )
    ),
    # bad input: every problem named at once, in the same words
    ("lab-fit-bad-options", "sixaxis lab fit data.csv --noise-mm -1 --loss l2 --outliers maybe"),
    ("sweep-bad-keys", "sixaxis sweep bad_keys.toml --out bad"),
    ("sweep-bad-values", "sixaxis sweep bad_values.toml --out bad"),
    ("sweep-bad-entries", "sixaxis sweep bad_entries.toml --out bad"),
    ("env-bad-options", "python env_options.py"),
]

SWEEP = textwrap.dedent(
    """\
    name = "snapshot"
    seeds = [0, 1]
    scenarios = ["geometric", "compliance"]
    agents = ["nominal", "feedforward", "calibrated"]
    """
)

# bad configs and options whose error messages are part of the outputs
INPUTS = {
    "bad_keys.toml": textwrap.dedent(
        """\
        nmae = "typo"
        seeds = "three"
        agents = "nominal"
        time_limit_s = "long"
        """
    ),
    "bad_values.toml": textwrap.dedent(
        """\
        name = "bad name/with slash"
        seeds = [0, -1, 0, 1.5]
        scenarios = ["geometric"]
        agents = ["nominal"]
        time_limit_s = 0
        memory_limit_mb = 12
        isolate = "none"
        episode_seconds = 0.001
        settle_seconds = -1.0
        converge_mm = 0.0
        metrics = ["rms_mm", "rms_mm", "nonsense", 3]
        rank_by = "speed"
        env = { scenario = "thermal", noise_mm = -1.0, measure_every = 0, colour = "red" }
        """
    ),
    "bad_entries.toml": textwrap.dedent(
        """\
        seeds = 100000
        scenarios = ["geometric", "no_such", { name = "compliance", extra = 1 }, 7, "geometric"]
        agents = ["nominal", "no_such_agent", { name = "feedforward", colour = 1 }, 3]
        campaign = { stations = 2 }

        [[phases]]
        name = "warm"
        seconds = 0.0001
        judged = false
        """
    ),
    "env_options.py": textwrap.dedent(
        """\
        from envs.sixaxis_track_v0 import SixAxisTrackEnv

        cases = [
            dict(noise_mm=-1, measure_every=0, trajectory="zig", x=1),
            dict(scenario="nope", dropout=1.0, latency_steps=-1, measurements=1),
            dict(temperature_noise=-1, temperature_lag="x", preview_steps=1.5, jerk_weight=-1),
            dict(episode_seconds=0.0, render_mode="human", width=0, height=10**6),
            dict(robot="no_such_robot", posture=[0.0]),
            dict(scenario=3, robot=3, overrides={"nope": {}}),
            dict(overrides={"compliance": {"nope": 1}}, scenario="compliance"),
            dict(posture=[0.0] * 7),
            dict(noise_mm=float("nan"), measure_every=True),
            dict(),
        ]
        for kwargs in cases:
            print(sorted(kwargs), SixAxisTrackEnv.check_options(**kwargs))
        try:
            SixAxisTrackEnv(noise_mm=-1, width=0)
        except ValueError as exc:
            print(type(exc).__name__, exc)
        """
    ),
}

TIMES = [
    # rich's log time column, or its blank when the record's second is the one before's
    (
        re.compile(
            r"^(\[\d{2}/\d{2}/\d{2} \d{1,2}:\d{2}:\d{2}\]| {19}) "
            r"(?=(DEBUG|INFO|WARNING|ERROR|CRITICAL) )",
            re.MULTILINE,
        ),
        "[<LOGTIME>] ",
    ),
    (
        re.compile(r"\b\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}:\d{2}(\.\d+)?([+-]\d{2}:?\d{2}|Z)?"),
        "<TIME>",
    ),
    (re.compile(r"\b\d{4}-\d{2}-\d{2}\b"), "<DATE>"),
    (re.compile(r"\[\d{2}/\d{2}/\d{2} "), "[<DATE> "),
    (re.compile(r"\b(in|took) \d+(\.\d+)? ?(s|ms|min)\b"), r"\1 <T>"),
    (re.compile(r"\(\d+(\.\d+)? ?(s|ms|min)\)"), "(<T>)"),
    (re.compile(r'"(wall_s|seconds|time_s|elapsed_s|duration_s)": [0-9.e+-]+'), r'"\1": <T>'),
    (re.compile(r"\b\d+(\.\d+)? ?s/(it|step)\b"), "<RATE>"),
    (re.compile(r"\b\d+:\d{2}:\d{2}\b"), "<CLOCK>"),
]


# what a run's records, tables and JSON say about time, process and machine rather than results
VOLATILE = ("solve_time", "wall_time", "wall_s", "timing", "started", "finished", "pid", "host")


def _volatile(name: str) -> bool:
    name = name.lower().replace(" ", "_")
    return any(v in name for v in VOLATILE)


@functools.cache
def _head() -> str:
    """The checkout's commit (asked once: every output is normalised with it)."""
    from experiments.records import git_state

    return git_state(ROOT)["commit"] or ""


def _strip_json(obj: object) -> object:
    if isinstance(obj, dict):
        return {k: ("<T>" if _volatile(k) else _strip_json(v)) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_strip_json(v) for v in obj]
    return obj


def _strip_table(text: str, sep: str) -> str:
    """Blank the columns of ``sep``-separated tables whose header names a time."""
    out, blank = [], set[int]()
    for line in text.split("\n"):
        cells = line.split(sep)
        if len(cells) < 3:
            blank = set()
            out.append(line)
            continue
        if not blank and not all(set(c.strip()) <= set("-:| ") for c in cells):
            found = {i for i, c in enumerate(cells) if _volatile(c)}
            if found:
                blank = found
                out.append(line)
                continue
        out.append(sep.join("<T>" if i in blank else c for i, c in enumerate(cells)))
    return "\n".join(out)


def _strip_last_column(text: str) -> str:
    """Blank the last column of space-aligned tables (rich's, without rules) whose header's last
    cell names a time (``ms/step``)."""
    out, blank = [], False
    for line in text.split("\n"):
        cells = line.split()
        if not cells:
            blank = False
        elif cells[-1] in ("ms/step", "s/step", "ms/episode"):
            blank = True
        elif blank and re.fullmatch(r"[0-9.e+-]+", cells[-1]):
            line = line[: line.rstrip().rfind(cells[-1])] + "<T>" + line[len(line.rstrip()) :]
        out.append(line)
    return "\n".join(out)


def normalise(text: str, out: Path, suffix: str = ".txt") -> str:
    text = text.replace(str(out), "<OUT>").replace(str(ROOT), "<REPO>")
    head = _head()
    if head:
        text = text.replace(head, "<HEAD>").replace(head[:10], "<HEAD>").replace(head[:7], "<HEAD>")
    if suffix == ".json":
        try:
            text = json.dumps(_strip_json(json.loads(text)), indent=1, sort_keys=True)
        except ValueError:
            pass
    elif suffix == ".csv":
        text = _strip_table(text, ",")
    else:
        text = _strip_table(text, "|")
        text = _strip_table(text, "│")
        text = _strip_last_column(text)
    for pattern, repl in TIMES:
        text = pattern.sub(repl, text)
    return text


def run(out: Path, only: list[str] | None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    work = out / "work"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    (work / "sweep.toml").write_text(SWEEP)
    for name, text in INPUTS.items():
        (work / name).write_text(text)
    env = dict(os.environ, COLUMNS="100", NO_COLOR="1", TERM="dumb")
    sixaxis = str(Path(sys.executable).parent / "sixaxis")
    for name, command in COMMANDS:
        if only and name not in only:
            continue
        cmd = command.format(data=ROOT / "data", root=ROOT)
        if cmd.startswith("python "):
            cmd = cmd.replace("python", sys.executable, 1)
        else:
            cmd = cmd.replace("sixaxis", sixaxis, 1)
        proc = subprocess.run(
            cmd, shell=True, cwd=work, env=env, capture_output=True, text=True, check=False
        )
        record = f"$ {command}\nexit {proc.returncode}\n--- stdout\n{proc.stdout}--- stderr\n"
        record += proc.stderr
        (out / f"{name}.txt").write_text(normalise(record, work))
        print(f"{name}: exit {proc.returncode}", flush=True)
    snapshot_files(out, work)


def snapshot_files(out: Path, work: Path) -> None:
    """``out/files/``: every file the commands wrote in ``work``, normalised (a sweep's lock file
    holds the process id of the sweep that held it: blanked), and ``out/manifest.txt``."""
    files = sorted(p for p in work.rglob("*") if p.is_file())
    lines = []
    shutil.rmtree(out / "files", ignore_errors=True)
    for p in files:
        data = p.read_bytes()
        if p.suffix == ".lock":  # a lock names the process that held it
            data = b"<LOCK>"
        elif p.suffix in {".csv", ".json", ".md", ".toml", ".urdf", ".py", ".html", ".txt"}:
            data = normalise(data.decode(), work, p.suffix).encode()
        elif p.suffix == ".lock":
            data = re.sub(rb"\d+", b"<PID>", data)
        rel = p.relative_to(work)
        (out / "files" / rel).parent.mkdir(parents=True, exist_ok=True)
        (out / "files" / rel).write_bytes(data)
        lines.append(f"{hashlib.sha256(data).hexdigest()}  {rel}")
    (out / "manifest.txt").write_text("\n".join(lines) + "\n")


def compare(a: Path, b: Path) -> int:
    """Name every output (a command's text, or a file it wrote) that differs."""

    def listing(root: Path) -> set[str]:
        files = (p.relative_to(root) for p in root.rglob("*") if p.is_file())
        return {str(p) for p in files if p.parts[0] != "work"}

    names = sorted(listing(a) | listing(b))
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
        print(f"identical: {len(names)} outputs (command texts and every file written)")
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
