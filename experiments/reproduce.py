"""Rerun the rows of a committed per-run summary (``results/leaderboard_runs.csv``) from the
config and the commit each row names, and compare the metrics.

    rows = read_runs_csv("results/leaderboard_runs.csv")
    picked = select_rows(rows, run_keys=["mpc__geometric__seed0"])
    for outcome in reproduce_rows(picked):
        outcome.differences()            # [] when every metric is the same

A row's commit is the code that made it. When the repository this package runs from is at that
commit without local changes, the row is rerun in it; otherwise the commit's tracked files are
exported (``git archive``) into a temporary directory and the row is rerun there. Either way the
rerun is a child process of the same Python whose ``PYTHONPATH`` puts that tree first, so the
commit's code, config and shipped policies are what run (checked: the child reports where it
imported the package from). A row made from a tree with local changes, or whose commit this
repository does not have, is refused with a message that says so.

A user's own sweep (its config in their working folder, its agent a class of their package) is
found where the sweep found it: the config by the absolute path the record names, the agent's
package by the folder its module was imported from, put on the child's path. The module's file
must still hold what ran (its sha256, recorded per run): a changed module is named and its rows
are not rerun, since the commit does not hold its code.

Tolerance. ``rtol`` 0 (the default) asks for the same numbers to the last bit, as on the machine
that made the rows. Any ``rtol`` > 0 is a comparison on another CPU: each row is then compared
within the larger of ``rtol`` and its agent's declared cross-CPU tolerance
(:func:`agents.registry.cross_cpu_rtol`, measured by ``benchmarks/perturbation.py``: an MPC
whose online calibration carries a rounding difference further than the policies do keeps a
looser one), and :attr:`Outcome.rtol` says which.

The child runs a small driver that uses only long-standing APIs (``load_config``, ``execute_run``,
``run_in_worker``, ``build_record``), so rows of older commits rerun too.
"""

from __future__ import annotations

import csv
import difflib
import hashlib
import json
import logging
import math
import os
import subprocess
import sys
import tarfile
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from arm.files import is_file
from experiments.errors import ReproduceError
from experiments.metrics import METRICS
from experiments.records import git_state, source_root

__all__ = [
    "Outcome",
    "ReproduceError",
    "read_runs_csv",
    "reproduce_rows",
    "row_rtol",
    "same_value",
    "select_rows",
]

log = logging.getLogger(__name__)

#: the columns a per-run summary must have to be rerun
REQUIRED = (
    "agent",
    "scenario",
    "seed",
    "status",
    "commit",
    "dirty",
    "config_path",
    "run_key",
    "run_hash",
)


@dataclass
class Outcome:
    """One rerun row: the recorded metrics (from the CSV), the reproduced ones, where it ran."""

    row: dict[str, str]
    line: int  # the row's line in the CSV file (the header is line 1)
    recorded: dict[str, float | None]
    reproduced: dict[str, float | None] = field(default_factory=dict)
    where: str = ""
    error: str | None = None
    rtol: float = 0.0

    @property
    def run_key(self) -> str:
        return self.row["run_key"]

    def differences(self) -> list[str]:
        """The metrics that differ (beyond ``rtol``), or ``["error"]`` if the rerun failed."""
        if self.error is not None:
            return ["error"]
        return [
            m
            for m in self.recorded
            if not same_value(self.recorded[m], self.reproduced.get(m, float("nan")), self.rtol)
        ]


def row_rtol(rtol: float, agent: str) -> float:
    """The tolerance a row of ``agent`` is compared within: 0 for 0 (exactly, as on the machine
    that made it); otherwise the larger of ``rtol`` and the agent's cross-CPU tolerance."""
    if rtol == 0:
        return 0.0
    from agents.registry import cross_cpu_rtol

    return max(float(rtol), cross_cpu_rtol(agent))


def same_value(a: float | None, b: float | None, rtol: float) -> bool:
    """Whether two recorded metric values agree: equal (``rtol`` 0) or within ``rtol`` relative;
    a missing value agrees only with a missing value."""
    if a is None or b is None:
        return a is None and b is None
    if rtol == 0:
        return a == b
    return math.isclose(a, b, rel_tol=rtol, abs_tol=0.0)


def _number(text: str, path: Path, line: int, column: str) -> float | None:
    if text == "":
        return None
    try:
        return float(text)
    except ValueError:
        raise ReproduceError(
            f"{path}, line {line}, column {column}: not a number: {text!r}"
        ) from None


def read_runs_csv(path: str | Path) -> list[tuple[int, dict[str, str]]]:
    """The rows of a per-run summary as ``(line, row)``; a clear error for a file that is not
    one (missing, not CSV, a required column absent)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ReproduceError(f"{p}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ReproduceError(f"{p}: cannot read: {exc}") from None
    reader = csv.DictReader(text.splitlines())
    header = reader.fieldnames or []
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise ReproduceError(
            f"{p}: not a per-run summary (leaderboard_runs.csv): no column(s) {', '.join(missing)}"
        )
    rows = []
    for i, row in enumerate(reader, start=2):
        if None in row or any(v is None for v in row.values()):
            raise ReproduceError(f"{p}, line {i}: {len(header)} columns expected")
        rows.append((i, dict(row)))
    if not rows:
        raise ReproduceError(f"{p}: a header and no rows: nothing to reproduce")
    return rows


def _no_run(key: str, keys: Sequence[str], source: str) -> str:
    """Why ``key`` names no row, and the keys the user may have meant: an agent ranked over its
    training seeds has a row per seed (``ppo@s2__thermal__ep4``), not one under its name."""
    agent, _, rest = key.partition("__")
    seeds = [k for k in keys if k.partition("__")[2] == rest and k.split("@")[0] == agent]
    if "@" not in agent and seeds:
        return (
            f"{source}: no run {key!r}: {agent!r} is ranked over its training seeds, and each "
            f"seed's run is a row of its own: {', '.join(seeds)}"
        )
    near = difflib.get_close_matches(key, keys, n=5, cutoff=0.5) or list(keys)[:5]
    return f"{source}: no run {key!r} (runs are named like {', '.join(near)}, ...)"


def select_rows(
    rows: Sequence[tuple[int, dict[str, str]]],
    run_keys: Iterable[str] = (),
    lines: Iterable[int] = (),
    every: bool = False,
    source: str = "the summary",
) -> list[tuple[int, dict[str, str]]]:
    """The rows named by run key or by line number (or all of them)."""
    if every:
        return list(rows)
    by_key = {r["run_key"]: (i, r) for i, r in rows}
    by_line = {i: (i, r) for i, r in rows}
    out = []
    for k in run_keys:
        if k not in by_key:
            raise ReproduceError(_no_run(k, list(by_key), source))
        out.append(by_key[k])
    for n in lines:
        if n not in by_line:
            raise ReproduceError(
                f"{source}: no line {n} (rows are on lines 2-{max(by_line, default=1)})"
            )
        out.append(by_line[n])
    if not out:
        raise ReproduceError(f"{source}: name the rows to rerun (--run KEY, --line N or --all)")
    return list({i: (i, r) for i, r in out}.values())


def recorded_metrics(row: Mapping[str, str], path: Path, line: int) -> dict[str, float | None]:
    """The row's reproducible metrics (timing metrics vary from run to run: not compared)."""
    return {
        c: _number(v, path, line, c)
        for c, v in row.items()
        if c in METRICS and not METRICS[c].timing
    }


# -- running ------------------------------------------------------------------------------------

#: what the child process runs, in the exported tree of a commit: the specs named by the JSON on
#: stdin, one result per line of stdout (the last line: a JSON list)
_DRIVER = r"""
import json, logging, sys
logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
import experiments
from experiments.config import load_config
from experiments.sweep import build_record, execute_run, run_in_worker

out = []
for item in json.loads(sys.stdin.read()):
    try:
        cfg = load_config(item["config_path"])
        if hasattr(cfg, "spec_for"):  # the seed comes from the row (drawn at sweep time)
            spec = cfg.spec_for(item["agent"], item["scenario"], item["seed"], item["episode"])
        else:  # a commit from before drawn seeds: its runs are its config's
            spec = next((s for s in cfg.runs() if s.run_key == item["run_key"]), None)
        if spec is None or spec.run_key != item["run_key"] or spec.seed != item["seed"]:
            raise LookupError(
                f"the config {item['config_path']} has no run {item['run_key']} with seed "
                f"{item['seed']}"
            )
        if spec.run_hash != item["run_hash"]:
            raise LookupError(
                f"the config's run {item['run_key']} with seed {item['seed']} has hash "
                f"{spec.run_hash}, the row {item['run_hash']}: the row is not what was run"
            )
        rec = build_record(spec, run_in_worker(execute_run, spec.to_dict()))
        err = rec.get("error") or {}
        out.append({"metrics": rec.get("metrics") or {}, "status": rec.get("status"),
                    "error": (err.get("type", "") + ": " + str(err.get("message", ""))) if err else None})
    except Exception as exc:
        out.append({"metrics": {}, "status": "failed", "error": f"{type(exc).__name__}: {exc}"})
print(json.dumps({"module": experiments.__file__, "results": out}))
"""


def _git(root: Path, *args: str) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(
            ["git", *args], cwd=root, capture_output=True, timeout=300, check=False
        )
    except (OSError, subprocess.SubprocessError) as exc:
        raise ReproduceError(f"cannot run git in {root}: {exc}") from None


def export_commit(commit: str, dest: Path, root: Path | None = None) -> Path:
    """The tracked files of ``commit`` (of the repository at ``root``) written under ``dest``."""
    root = root or source_root()
    if _git(root, "cat-file", "-e", f"{commit}^{{commit}}").returncode != 0:
        raise ReproduceError(
            f"commit {commit} is not in the repository at {root}: fetch it (git fetch) first"
        )
    arch = _git(root, "archive", "--format=tar", commit)
    if arch.returncode != 0:
        raise ReproduceError(f"git archive {commit} failed: {arch.stderr.decode(errors='replace')}")
    tar_path = dest / "tree.tar"
    tar_path.write_bytes(arch.stdout)
    tree = dest / "tree"
    tree.mkdir()
    with tarfile.open(tar_path) as tar:
        tar.extractall(tree, filter="data")
    tar_path.unlink()
    return tree


def _run_child(
    tree: Path, items: list[dict[str, str]], extra_path: Sequence[str] = ()
) -> list[dict[str, Any]]:
    env = dict(os.environ)
    paths = [str(tree), *dict.fromkeys(extra_path)]
    if env.get("PYTHONPATH"):
        paths.append(env["PYTHONPATH"])
    env["PYTHONPATH"] = os.pathsep.join(paths)
    proc = subprocess.run(
        [sys.executable, "-c", _DRIVER],
        input=json.dumps(items),
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    last = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    try:
        answer = json.loads(last)
    except json.JSONDecodeError:
        raise ReproduceError(
            f"the rerun in {tree} failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}"
        ) from None
    module = Path(answer["module"]).resolve()
    if tree.resolve() not in module.parents:
        raise ReproduceError(
            f"the rerun imported {module}, not the commit's code in {tree}: an installed copy of "
            "sixaxis-track shadows it"
        )
    return answer["results"]


def row_identity(row: Mapping[str, str], path: Path, line: int) -> dict[str, Any]:
    """The run a row names: agent and scenario labels, seed, episode index (drawn seeds) and
    its run key and hash, checked against each other (a row whose seed was edited names another
    run than its key: refused here, or, for a drawn seed, by its hash when it is rerun)."""
    where = f"{path}, line {line} ({row['run_key']})"
    try:
        seed = int(row["seed"])
    except ValueError:
        raise ReproduceError(f"{where}, column seed: not an integer: {row['seed']!r}") from None
    if seed < 0:
        raise ReproduceError(f"{where}, column seed: negative: {seed}")
    prefix = f"{row['agent']}__{row['scenario']}__"
    key = row["run_key"]
    episode: int | None = None
    if key == f"{prefix}seed{seed}":
        pass
    elif key.startswith(f"{prefix}ep") and key[len(prefix) + 2 :].isdigit():
        episode = int(key[len(prefix) + 2 :])
        if row.get("episode", str(episode)) not in ("", str(episode)):
            raise ReproduceError(
                f"{where}, column episode: {row['episode']!r} is not its run key's ({episode})"
            )
    else:
        raise ReproduceError(
            f"{where}: the run key is not the run of agent {row['agent']!r}, scenario "
            f"{row['scenario']!r} and seed {seed}: the row was edited"
        )
    if not row.get("run_hash"):
        raise ReproduceError(f"{where}: names no run hash (column run_hash is empty)")
    return {
        "agent": row["agent"],
        "scenario": row["scenario"],
        "seed": seed,
        "episode": episode,
        "run_key": key,
        "run_hash": row["run_hash"],
    }


def check_row(row: Mapping[str, str], path: Path, line: int) -> None:
    """Refuse a row no commit reproduces: made with local changes, naming no commit, or whose
    columns do not name one run (:func:`row_identity`)."""
    where = f"{path}, line {line} ({row['run_key']})"
    if row.get("dirty") not in ("0", "False", "false"):
        raise ReproduceError(
            f"{where}: made from a tree with local changes (dirty = {row.get('dirty')!r}); no "
            "commit reproduces it"
        )
    if not row.get("commit"):
        raise ReproduceError(f"{where}: names no commit")
    if not row.get("config_path"):
        raise ReproduceError(f"{where}: names no config (column config_path is empty)")
    if Path(row["config_path"]).is_absolute() and not is_file(row["config_path"]):
        raise ReproduceError(
            f"{where}: the config {row['config_path']} (outside the repository, where the sweep "
            "found it) is not there any more"
        )
    row_identity(row, path, line)


def agent_module_check(row: Mapping[str, str]) -> str | None:
    """Why a row of a class-path agent cannot be rerun (its recorded module file, column
    ``agent_module``, is gone or holds other code than its ``agent_module_sha256``), or None."""
    file, recorded = row.get("agent_module") or "", row.get("agent_module_sha256") or ""
    if not file:
        return None
    module = row["agent_name"].partition(":")[0]
    try:
        now = hashlib.sha256(Path(file).read_bytes()).hexdigest()
    except OSError as exc:
        return f"the agent module {module} ({file}) cannot be read: {exc}"
    if recorded and now != recorded:
        return (
            f"the agent module {module} ({file}) changed since the run: sha256 "
            f"{recorded[:12]}... recorded, {now[:12]}... now; the row's commit does not hold it"
        )
    return None


def module_import_root(row: Mapping[str, str]) -> str:
    """The folder a row's agent module was imported from (its file less the module's dotted
    path: ``/w/mypkg/myagent.py`` of ``mypkg.myagent`` is ``/w``)."""
    p = Path(row["agent_module"])
    root = p.parent
    module = row["agent_name"].partition(":")[0]
    for _ in range(len(module.split(".")) - (0 if p.stem == "__init__" else 1)):
        root = root.parent
    return str(root)


def reproduce_rows(
    rows: Sequence[tuple[int, dict[str, str]]],
    source: str | Path = "leaderboard_runs.csv",
    rtol: float = 0.0,
    isolated: bool = False,
    root: Path | None = None,
) -> list[Outcome]:
    """Rerun each row from its commit and config; see the module docstring. ``isolated``: rerun
    in an exported tree even when this checkout is at the row's commit."""
    path = Path(source)
    if not (isinstance(rtol, (int, float)) and math.isfinite(rtol) and rtol >= 0):
        raise ReproduceError(f"rtol: a relative tolerance must be a number >= 0, got {rtol!r}")
    if not rows:
        raise ReproduceError(f"{path}: no rows to rerun")
    root = root or source_root()
    outcomes: list[Outcome] = []
    groups: dict[str, list[Outcome]] = {}
    roots: dict[str, list[str]] = {}
    for line, row in rows:
        check_row(row, path, line)
        o = Outcome(
            row, line, recorded_metrics(row, path, line), rtol=row_rtol(rtol, row["agent_name"])
        )
        outcomes.append(o)
        # a user's config and package: the sweep's config folder, and each module's import root
        # (a config with a user's agent needs it importable for any of its rows)
        if Path(row["config_path"]).is_absolute():
            roots.setdefault(row["commit"], []).append(str(Path(row["config_path"]).parent))
        if row.get("agent_module"):
            roots.setdefault(row["commit"], []).append(module_import_root(row))
        if row.get("status") != "ok":
            o.where = "not rerun"
            o.error = f"the row is a {row.get('status') or 'unknown'} run: nothing to compare"
            continue
        why = agent_module_check(row)
        if why is not None:
            o.where = "not rerun"
            o.error = why
            continue
        groups.setdefault(row["commit"], []).append(o)
    here = git_state(root)
    for commit, group in groups.items():
        items = [
            {"config_path": o.row["config_path"]} | row_identity(o.row, path, o.line) for o in group
        ]
        if not isolated and here.get("commit") == commit and here.get("dirty") is False:
            where = f"this checkout (at {commit[:10]})"
            log.info("rerunning %d row(s) in this checkout, at %s", len(items), commit[:10])
            results = _run_child(root, items, roots.get(commit, []))
        else:
            where = f"commit {commit[:10]} (exported)"
            with tempfile.TemporaryDirectory(prefix="sixaxis-reproduce-") as tmp:
                tree = export_commit(commit, Path(tmp), root)
                missing = [
                    it["config_path"] for it in items if not is_file(tree / it["config_path"])
                ]
                if missing:
                    raise ReproduceError(
                        f"{path}: commit {commit[:10]} has no config {', '.join(sorted(set(missing)))}"
                    )
                log.info("rerunning %d row(s) at commit %s in %s", len(items), commit[:10], tree)
                results = _run_child(tree, items, roots.get(commit, []))
        for o, res in zip(group, results, strict=True):
            o.where = where
            if res.get("status") != "ok":
                o.error = res.get("error") or "failed"
            o.reproduced = {
                m: (None if v is None else float(v)) for m, v in (res.get("metrics") or {}).items()
            }
    return outcomes
