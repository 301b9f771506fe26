"""The leaderboard: agents by scenario from a directory of run records, as markdown, JSON and CSV
tables, a per-run CSV and two PNG plots.

    board = build_leaderboard("runs/full")
    paths = write_leaderboard(board, "results", command="sixaxis leaderboard runs/full")

Ranked by the config's ``rank_by`` (the settled RMS in the shipped configs); the best
*contender* of each scenario (neither given the truth nor told the effects) is marked. Cells are
the mean over episodes with a 95 % bootstrap interval; the paired comparisons, the orderings they
resolve, the aggregates against a reference agent, each hidden effect's cost and the compute
budget come from :mod:`experiments.comparisons` and are what ``leaderboard.json`` holds, from which
:func:`readme_block` writes the README's leaderboard section (docs/benchmark.md says how each is
computed). Oracles (agents given the plant's truth) are marked as such, and so are informed agents
(told the scenario's effects in their config: a model effect set beyond the geometric errors).

Every row must be reproducible: records from a tree with local changes (or from no git checkout)
are refused unless ``allow_dirty=True``, and then marked. ``leaderboard_runs.csv`` beside the
table lists every run (agent, scenario, seed, episode, commit, config, every metric) so that
``sixaxis reproduce results/leaderboard_runs.csv --run KEY`` can rerun any of them.

It is one module, longer than most, because building the board from the records and writing its
files share the cell formatting, so that the markdown, the CSVs, the README and the CLI show the
same numbers.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arm.files import atomic_write_text
from experiments.comparisons import episode_key
from experiments.metrics import METRICS, MIN_VALUES_FOR_CI, Summary, summarize
from experiments.records import RecordError, RunStore, jsonable

__all__ = [
    "Leaderboard",
    "Row",
    "analysis_cell",
    "build_leaderboard",
    "cell_text",
    "interval_text",
    "is_clean",
    "is_informed",
    "is_oracle",
    "ordering_text",
    "pairs_csv",
    "readme_block",
    "runs_csv",
    "spread_words",
    "to_csv",
    "to_json",
    "to_markdown",
    "update_readme",
    "write_leaderboard",
]

log = logging.getLogger(__name__)

MD_NAME = "leaderboard.md"
CSV_NAME = "leaderboard.csv"
RUNS_CSV_NAME = "leaderboard_runs.csv"
#: the metrics shown with intervals: the settled RMS (the ranking), the start-up, the whole episode
HEADLINE = ("rms_settled_mm", "rms_startup_mm", "rms_mm")
JSON_NAME = "leaderboard.json"
PAIRS_CSV_NAME = "leaderboard_pairs.csv"
PLOT_STRIPS = "leaderboard_strips.png"
ORACLE_MARK = " (oracle)"
INFORMED_MARK = " (informed)"
DIRTY_MARK = " (local changes)"
PLOT_TIME = "leaderboard_error_over_time.png"


@dataclass
class Row:
    agent: str
    scenario: str
    n: int
    failed: int
    stats: dict[str, Summary]
    best: bool = False
    oracle: bool = False
    dirty: int = 0  # records from a tree with local changes (allowed with allow_dirty)
    informed: bool = False

    @property
    def display(self) -> str:
        """The agent's label with its marks (oracle, informed, local changes)."""
        return self.agent + marks(self.oracle, self.informed) + (DIRTY_MARK if self.dirty else "")


def marks(oracle: bool, informed: bool) -> str:
    """The marks of a label: (oracle) given the truth, (informed) told the effects."""
    return (ORACLE_MARK if oracle else "") + (INFORMED_MARK if informed and not oracle else "")


@dataclass
class Leaderboard:
    runs_dir: Path
    metrics: list[str]
    rank_by: str
    agents: list[str]
    scenarios: list[str]
    rows: list[Row]
    records: list[dict[str, Any]]
    failed: list[dict[str, Any]]
    manifest: dict[str, Any] | None
    ignored: int = 0
    agent_settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    allow_dirty: bool = False
    #: the paired analysis (:func:`experiments.comparisons.analyse`): what leaderboard.json holds
    analysis: dict[str, Any] = field(default_factory=dict)

    def row(self, agent: str, scenario: str) -> Row | None:
        return next((r for r in self.rows if r.agent == agent and r.scenario == scenario), None)


def is_clean(rec: dict[str, Any]) -> bool:
    """Whether a record was made from a commit without local changes (so that commit reproduces
    it); a record from no git checkout is not."""
    git = rec.get("git") or {}
    return bool(git.get("commit")) and git.get("dirty") is False


def is_oracle(rec: dict[str, Any]) -> bool:
    """Whether the record's agent was given the plant's truth (``needs_truth``)."""
    return bool(rec.get("oracle"))


def is_informed(rec: dict[str, Any]) -> bool:
    """Whether the record's agent was told the scenario's effects in its config: its settings
    for the run (``scenario_settings`` merged in) give a model effect set beyond the geometric
    errors (``effects = "geometric,backlash[1,5]"``). It did not find them; it was told."""
    effects = ((rec.get("spec") or {}).get("settings") or {}).get("effects")
    if effects is None:
        return False
    from arm.effects import parse_effects

    try:
        names = {e.name for e in parse_effects(effects)}
    except Exception:  # a setting the agent refused: the record says what it was told anyway
        names = {str(effects)}
    return bool(names - {"geometric"})


def build_leaderboard(
    runs_dir: str | Path,
    rank_by: str | None = None,
    allow_dirty: bool = False,
    reference: str | None = None,
) -> Leaderboard:
    """Read every record of a sweep directory and summarise it over seeds.

    With the sweep's manifest (``_sweep.json``) present, only the runs of its config count (records
    left from an older config in the same directory are ignored, with a warning), and agents and
    scenarios keep the config's order.

    Records made from a tree with local changes, or outside a git checkout, are refused
    (:class:`RecordError` naming them) unless ``allow_dirty``; then their rows are marked.
    ``reference``: the agent the aggregates are taken against (default ``feedforward`` when it
    ran, else none)."""
    store = RunStore(runs_dir)
    if not store.root.is_dir():
        raise RecordError(f"{store.root}: no such runs directory")
    manifest = store.manifest()
    wanted = manifest.get("runs") if manifest else None
    records: list[dict[str, Any]] = []
    failed: list[dict[str, Any]] = []
    ignored = 0
    for rec in store.records():
        if wanted is not None and wanted.get(rec["run_key"]) != rec.get("run_hash"):
            ignored += 1
            continue
        (records if rec.get("status") == "ok" else failed).append(rec)
    if ignored:
        log.warning(
            "%d record(s) in %s are not runs of the sweep's config; ignored", ignored, runs_dir
        )
    if not records and not failed:
        raise RecordError(f"{store.root}: no run records")
    unclean = sorted(r["run_key"] for r in records + failed if not is_clean(r))
    if unclean and not allow_dirty:
        shown = ", ".join(unclean[:5]) + (
            f" and {len(unclean) - 5} more" if len(unclean) > 5 else ""
        )
        raise RecordError(
            f"{store.root}: {len(unclean)} record(s) were made from a tree with local changes or "
            f"outside a git checkout ({shown}); no commit reproduces them. Commit and rerun the "
            "sweep, or pass --allow-dirty (allow_dirty=True) to mark them in the table"
        )

    cfg = (manifest or {}).get("config", {})
    all_recs = records + failed
    agents = [a["label"] for a in cfg.get("agents", [])] or _ordered(
        r["spec"]["agent_label"] for r in all_recs
    )
    scenarios = [s["label"] for s in cfg.get("scenarios", [])] or _ordered(
        r["spec"]["scenario_label"] for r in all_recs
    )
    metrics = list(cfg.get("metrics") or _ordered(m for r in records for m in r["metrics"]))
    metrics += _ordered(m for r in records for m in r.get("timing", {}) if m in METRICS)
    metrics = [m for m in _ordered(metrics) if m in METRICS]
    rank_by = rank_by or cfg.get("rank_by", "rms_mm")
    if rank_by not in metrics:
        raise RecordError(f"{runs_dir}: no metric {rank_by!r} in the records (have {metrics})")
    settings = {
        a["label"]: {"name": a["name"], "settings": a.get("settings", {}), "env": a.get("env", {})}
        for a in cfg.get("agents", [])
    }

    rows: list[Row] = []
    for agent in agents:
        for scen in scenarios:
            mine = sorted(
                (
                    r
                    for r in records
                    if r["spec"]["agent_label"] == agent and r["spec"]["scenario_label"] == scen
                ),
                key=_episode_order,
            )
            nfail = sum(
                1
                for r in failed
                if r["spec"]["agent_label"] == agent and r["spec"]["scenario_label"] == scen
            )
            if not mine and not nfail:
                continue
            stats = {
                m: summarize((_value(r, m) for r in mine), interval=m in (rank_by, *HEADLINE))
                for m in metrics
            }
            everyone = mine + [
                r
                for r in failed
                if r["spec"]["agent_label"] == agent and r["spec"]["scenario_label"] == scen
            ]
            rows.append(
                Row(
                    agent,
                    scen,
                    len(mine),
                    nfail,
                    stats,
                    oracle=any(is_oracle(r) for r in everyone),
                    dirty=sum(not is_clean(r) for r in everyone),
                    informed=any(is_informed(r) for r in everyone),
                )
            )
    agents = [a for a in agents if any(r.agent == a for r in rows)]
    scenarios = [s for s in scenarios if any(r.scenario == s for r in rows)]
    if reference is None and "feedforward" in agents:
        reference = "feedforward"
    elif reference is not None and reference not in agents:
        raise RecordError(f"{runs_dir}: no agent {reference!r} to compare with (have {agents})")
    from experiments.comparisons import analyse

    analysis = analyse(
        records,
        agents,
        scenarios,
        [m for m in (rank_by, *HEADLINE) if m in metrics and METRICS[m].aggregate == "mean"]
        + [m for m in ("tracker_points",) if m in metrics],
        rank_by,
        reference,
        oracles={r.agent for r in rows if r.oracle},
        informed={r.agent for r in rows if r.informed},
    )
    for r in rows:  # the best contender (neither given the truth nor told the effects)
        r.best = analysis["best"].get(r.scenario) == r.agent
    return Leaderboard(
        runs_dir=Path(runs_dir),
        metrics=metrics,
        rank_by=rank_by,
        agents=agents,
        scenarios=scenarios,
        rows=rows,
        records=records,
        failed=failed,
        manifest=manifest,
        ignored=ignored,
        agent_settings=settings,
        allow_dirty=allow_dirty,
        analysis=analysis,
    )


def _episode_order(rec: dict[str, Any]) -> int:
    """A record's place among its cell's: its episode index (drawn seeds), else its seed."""
    spec = rec["spec"]
    return int(spec["episode"]) if spec.get("episode") is not None else int(spec["seed"])


def _ordered(items) -> list:
    seen: dict = {}
    for x in items:
        seen.setdefault(x, None)
    return list(seen)


def _value(rec: dict[str, Any], metric: str) -> float:
    src = rec.get("timing", {}) if METRICS[metric].timing else rec.get("metrics", {})
    v = src.get(metric)
    return float("nan") if v is None else float(v)


# -- formats ------------------------------------------------------------------------------------


def _fmt(v: float, digits: int = 3) -> str:
    if v is None or not math.isfinite(v):
        return "–"
    if v == 0:
        return "0"
    mag = math.floor(math.log10(abs(v)))
    decimals = max(0, digits - 1 - mag)
    return f"{v:.{decimals}f}"


def cell_text(s: Summary, metric: str, row: Row | None = None, spread: bool = True) -> str:
    """A summary as text: ``mean [lo, hi]`` (the 95 % bootstrap interval, from three values),
    ``mean (min–max)`` (two), ``mean`` (one), ``k/n`` for counts. A metric with a companion count
    of runs where it is missing (``converge_s``/``never_converged``) says so: ``never (3/3)``,
    ``1.2 [0.9, 1.6] (1/4 never)``, the mean being over the runs that converged.
    ``spread=False``: the mean alone."""
    if METRICS[metric].aggregate == "sum":
        return "–" if s.n == 0 else f"{round(s.total)}/{s.n}"
    companion = METRICS[metric].companion
    never = row.stats.get(companion) if row is not None and companion else None
    k = round(never.total) if never is not None and never.n else 0
    if s.n == 0:
        return ("never" if not spread or never is None else f"never ({k}/{never.n})") if k else "–"
    if not spread:
        text = _fmt(s.mean)
    elif s.has_ci:
        text = f"{_fmt(s.mean)} [{_fmt(s.lo)}, {_fmt(s.hi)}]"
    elif s.n >= 2:
        text = f"{_fmt(s.mean)} ({_fmt(s.min)}–{_fmt(s.max)})"
    else:
        text = _fmt(s.mean)
    return f"{text} ({k}/{never.n} never)" if k and never is not None else text


def analysis_cell(board: Leaderboard, row: Row, metric: str, spread: bool = True) -> str:
    """A headline cell: the geometric mean over episodes [its 95 % interval] from the analysis
    (``spread=False``: the value alone); the summary's text for other metrics."""
    iv = (board.analysis.get("cells", {}).get(row.agent, {}).get(row.scenario) or {}).get(metric)
    if not iv or "value" not in iv:
        return cell_text(row.stats[metric], metric, row, spread)
    if not spread:
        return _fmt(iv["value"]) if iv["value"] is not None else "–"
    return interval_text(iv)


def interval_text(iv: Mapping[str, Any] | None, digits: int = 3) -> str:
    """An interval of the analysis (``value``, ``lo``, ``hi``) as ``value [lo, hi]``."""
    if not iv or iv.get("value") is None:
        return "–"
    if iv.get("lo") is None or iv.get("hi") is None:
        return _fmt(iv["value"], digits)
    return f"{_fmt(iv['value'], digits)} [{_fmt(iv['lo'], digits)}, {_fmt(iv['hi'], digits)}]"


def to_csv(board: Leaderboard) -> str:
    """One row per agent and scenario; ``<metric>_mean``, ``<metric>_lo`` and ``<metric>_hi``
    (the 95 % bootstrap interval of the mean, for the metrics the tables show with one; empty
    with fewer than three values), ``<metric>_ci95`` (its half-width), ``<metric>_min``,
    ``<metric>_max``, ``<metric>_n``; counts for sums (``diverged``, ``never_converged``);
    ``best`` (the best contender by ``rank_by``); ``oracle`` (given the truth); ``dirty``
    (records with local changes); ``informed`` (told the scenario's effects)."""
    header = ["agent", "scenario", "n", "failed", "best", "oracle", "dirty", "informed"]
    for m in board.metrics:
        header += [f"{m}_mean", f"{m}_lo", f"{m}_hi", f"{m}_ci95", f"{m}_min", f"{m}_max"]
        header.append(f"{m}_n")
        if METRICS[m].aggregate == "sum":
            header.append(f"{m}_count")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in board.rows:
        line: list[Any] = [
            r.agent,
            r.scenario,
            r.n,
            r.failed,
            int(r.best),
            int(r.oracle),
            r.dirty,
            int(r.informed),
        ]
        for m in board.metrics:
            s = r.stats[m]
            ok = s.has_ci
            line += [
                _num(s.mean),
                _num(s.lo if ok else math.nan),
                _num(s.hi if ok else math.nan),
                _num(s.ci95 if ok else math.nan),
                _num(s.min),
                _num(s.max),
                s.n,
            ]
            if METRICS[m].aggregate == "sum":
                line.append("" if s.n == 0 else round(s.total))
        w.writerow(line)
    return buf.getvalue()


def pairs_csv(board: Leaderboard) -> str:
    """Every two agents on every scenario: the better (lower mean of ``rank_by``), the worse,
    the paired ratio better / worse (the geometric mean of the per-episode ratios), its 95 %
    bootstrap interval, the episodes it is over, and whether the interval lies below 1."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["scenario", "better", "worse", "ratio", "lo", "hi", "n", "resolved"])
    for p in board.analysis.get("pairs", []):
        w.writerow(
            [
                p["scenario"],
                p["better"],
                p["worse"],
                _num(p["value"]),
                _num(p["lo"]),
                _num(p["hi"]),
                p["n"],
                int(p["resolved"]),
            ]
        )
    return buf.getvalue()


def runs_csv(board: Leaderboard) -> str:
    """One row per run of the leaderboard (failed ones too): agent label and name, scenario,
    seed, whether it is an oracle, status, the commit and whether the tree was dirty, the config
    (name, path, hash), the run key and hash, whether it was informed, a class-path agent's
    module file and its sha256 (empty for registered agents: the commit holds their code), and
    every metric (timing metrics last; they vary from run to run). ``sixaxis reproduce`` reruns
    any row."""
    timing = [m for m in board.metrics if METRICS[m].timing]
    plain = [m for m in board.metrics if not METRICS[m].timing]
    header = [
        "agent",
        "agent_name",
        "scenario",
        "scenario_name",
        "seed",
        "episode",
        "oracle",
        "status",
        "commit",
        "dirty",
        "config_name",
        "config_path",
        "config_hash",
        "run_key",
        "run_hash",
        "informed",
        "agent_module",
        "agent_module_sha256",
        *plain,
        *timing,
    ]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    order = {(a, s): i for i, (a, s) in enumerate((r.agent, r.scenario) for r in board.rows)}
    recs = sorted(
        board.records + board.failed,
        key=lambda r: (
            order.get((r["spec"]["agent_label"], r["spec"]["scenario_label"]), len(order)),
            _episode_order(r),
        ),
    )
    man = board.manifest or {}
    for r in recs:
        spec, git = r["spec"], r.get("git") or {}
        w.writerow(
            [
                spec["agent_label"],
                spec["agent"],
                spec["scenario_label"],
                spec["scenario"],
                spec["seed"],
                "" if spec.get("episode") is None else spec["episode"],
                int(is_oracle(r)),
                r.get("status"),
                git.get("commit") or "",
                "" if git.get("dirty") is None else int(bool(git.get("dirty"))),
                r.get("config_name") or man.get("config_name") or "",
                r.get("config_path") or man.get("config_path") or "",
                r.get("config_hash") or man.get("config_hash") or "",
                r["run_key"],
                r.get("run_hash", ""),
                int(is_informed(r)),
                (r.get("agent_module") or {}).get("file", ""),
                (r.get("agent_module") or {}).get("sha256", ""),
                *(_num(_value(r, m)) for m in plain),
                *(_num(_value(r, m)) for m in timing),
            ]
        )
    return buf.getvalue()


def _num(v: float) -> str:
    return "" if v is None or not math.isfinite(v) else repr(float(v))


def spread_words(board: Leaderboard) -> str:
    ns = {r.stats[board.rank_by].n for r in board.rows if r.stats[board.rank_by].n}
    if ns and min(ns) >= MIN_VALUES_FOR_CI:
        return "mean [95 % bootstrap interval] over episodes"
    if ns and max(ns) < MIN_VALUES_FOR_CI:
        return (
            f"mean (minimum–maximum) over episodes: fewer than {MIN_VALUES_FOR_CI}, too few for "
            "an interval"
        )
    return (
        "mean [95 % bootstrap interval] over episodes, or (minimum–maximum) where fewer than "
        f"{MIN_VALUES_FOR_CI} finished"
    )


def _facts(board: Leaderboard) -> list[str]:
    man = board.manifest or {}
    cfg = man.get("config", {})
    facts = []
    if man:
        facts.append(
            f"config `{man.get('config_name')}` (`{man.get('config_path')}`, hash "
            f"`{man.get('config_hash')}`)"
        )
    if cfg:
        ph = cfg.get("phases") or []
        if ph:
            episode = " then ".join(
                f"{p['name']} {p['seconds']:g} s{' (judged)' if p['judged'] else ''}" for p in ph
            )
        else:
            episode = f"{cfg.get('episode_seconds'):g} s episodes"
        facts.append(
            f"{episode}, settling time {cfg.get('settle_seconds'):g} s, env options "
            f"`{cfg.get('env') or {}}`"
        )
    drawn = [r["spec"] for r in board.records if r["spec"].get("episode") is not None]
    seeds = sorted({r["spec"]["seed"] for r in board.records})
    if drawn:
        n = len({sp["episode"] for sp in drawn})
        facts.append(
            f"{len(board.records) + len(board.failed)} runs ({len(board.failed)} failed): "
            f"{n} episodes per agent and scenario, their seeds drawn from [2^32, 2^63) when the "
            f"sweep started, the same for every agent and scenario (each run's seed is in "
            f"`{RUNS_CSV_NAME}`)"
        )
    else:
        facts.append(
            f"{len(board.records) + len(board.failed)} runs ({len(board.failed)} failed), seeds "
            f"{_ranges(seeds)} (fixed, public: not for a published table)"
        )
    commits = sorted({(r.get("git") or {}).get("commit") or "?" for r in board.records})
    ndirty = sum(not is_clean(r) for r in board.records + board.failed)
    if ndirty:
        facts.append(
            f"commit {', '.join(c[:10] for c in commits)}: **{ndirty} run(s) made with local "
            "changes** (`--allow-dirty`; rows marked (local changes)): no commit reproduces them"
        )
    else:
        facts.append(
            f"commit {', '.join(c[:10] for c in commits)}, clean: every run is reproducible "
            f"from it (`sixaxis reproduce {RUNS_CSV_NAME} --run RUN_KEY`: exactly on the machine "
            "that made it, within `--rtol 1e-6` elsewhere)"
        )
    versions = (board.records[0].get("versions") if board.records else {}) or {}
    if versions:
        facts.append(", ".join(f"{k} {v}" for k, v in versions.items() if v))
    if board.ignored:
        facts.append(f"{board.ignored} record(s) of another config in the directory ignored")
    return facts


def ordering_text(analysis: Mapping[str, Any], scenario: str) -> str:
    """A scenario's ranking as one line: ``a < b ≈ c``: ``<`` where the paired interval resolves
    the step, ``≈`` where it does not."""
    ranked = analysis["ranking"].get(scenario) or []
    if not ranked:
        return ""
    parts = [f"`{ranked[0]}`"]
    for o in analysis["orderings"].get(scenario, []):
        parts.append("<" if o["resolved"] else "≈")
        parts.append(f"`{o['worse']}`")
    return " ".join(parts)


def to_markdown(board: Leaderboard, command: str | None = None, plots: Sequence[str] = ()) -> str:  # noqa: C901  (one document: a branch per section of leaderboard.md)
    m0 = board.rank_by
    an = board.analysis
    man = board.manifest or {}
    cfg = man.get("config", {})
    settle = cfg.get("settle_seconds")
    settle_s = f"{settle:g} s" if isinstance(settle, (int, float)) else "the settling time"
    ref = an.get("reference")
    lines = ["# Leaderboard", ""]
    lines.append(
        f"Each agent on each scenario, judged on the plant's *true* tool point, episode by "
        f"episode. Ranked by `{m0}` ({METRICS[m0].unit}): "
        + (
            f"the tracking RMS after {settle_s}, what calibration and control decide. "
            if m0 == "rms_settled_mm"
            else f"{METRICS[m0].description}. "
        )
        + "The start-up (the first second) and the whole episode are tables of their own. Cells "
        "of those three tables: the geometric mean over episodes [95 % bootstrap interval] "
        "(every agent runs the same episodes, whose difficulty spreads tenfold: the ratio of "
        "two cells is then their paired ratio, and the order of a table agrees with its "
        "orderings); the long table and `leaderboard.csv` also have the arithmetic means "
        f"({spread_words(board)}). Lower is better. **Bold**: the best contender of each "
        "scenario. (oracle): given the plant's truth, what knowing the arm is worth, not what a "
        "controller can do; (informed): told the scenario's effects in its config. Orderings are "
        "claimed only where the paired interval resolves them (`<`); `≈` is not resolved. "
        "Intervals are 95 % bootstrap intervals (BCa, episodes resampled; paired where two "
        "agents or scenarios are compared)."
    )
    lines += ["", "Made by:", "", "```"]
    if man.get("command"):
        lines.append(man["command"])
    lines.append(command or f"sixaxis leaderboard {board.runs_dir}")
    lines += ["```", ""]
    lines += [f"- {f}" for f in _facts(board)]
    lines.append("")
    order = [a for a in an.get("order", board.agents) if a in board.agents]

    def label(a: str) -> str:
        mine = [r for r in board.rows if r.agent == a]
        text = a + marks(any(r.oracle for r in mine), any(r.informed for r in mine))
        return text + (DIRTY_MARK if any(r.dirty for r in mine) else "")

    def grid(title: str, cell, note: str = "", bold: bool = False) -> None:
        lines.append(title)
        lines.append("")
        if note:
            lines.extend([note, ""])
        lines.append("| agent | " + " | ".join(board.scenarios) + " |")
        lines.append("|---|" + "---:|" * len(board.scenarios))
        for a in order:
            cells = []
            for s in board.scenarios:
                r = board.row(a, s)
                if r is None:
                    cells.append("")
                    continue
                c = cell(r)
                if r.failed:
                    c += f" ({r.failed} failed)"
                cells.append(f"**{c}**" if r.best and bold else c)
            lines.append(f"| {label(a)} | " + " | ".join(cells) + " |")
        lines.append("")

    grid(
        f"## {m0} ({METRICS[m0].unit}): the ranking",
        lambda r: analysis_cell(board, r, m0),
        note=f"Agents in the order of their aggregate against `{ref}` (below)." if ref else "",
        bold=True,
    )
    if an.get("aggregate"):
        lines += [
            f"## Across scenarios, against `{ref}`",
            "",
            f"Each agent's `{m0}` over `{ref}`'s on the same episode, over every scenario and "
            "episode: the interquartile mean (IQM) of the ratios, as rliable recommends, and their "
            "geometric mean; 95 % bootstrap intervals that resample episodes in every scenario "
            "at once. Below 1: better than the reference.",
            "",
            "| agent | IQM of the ratios | geometric mean |",
            "|---|---:|---:|",
        ]
        for a in order:
            agg = an["aggregate"].get(a)
            if agg:
                lines.append(
                    f"| {label(a)} | {interval_text(agg['iqm'])} | "
                    f"{interval_text(agg['geomean'])} |"
                )
        lines.append("")
    lines += [
        "## Which orderings are resolved",
        "",
        f"Each scenario's agents by their geometric mean `{m0}`, each against the next: `<` "
        "where the paired interval of their per-episode ratio lies below 1, `≈` where it does "
        "not. Every "
        f"pair of agents is in `{PAIRS_CSV_NAME}`.",
        "",
        "| scenario | ranking |",
        "|---|---|",
    ]
    for s in board.scenarios:
        lines.append(f"| {s} | {ordering_text(an, s)} |")
    lines += [
        "",
        "| scenario | better | worse | ratio [95 % interval] | resolved |",
        "|---|---|---|---:|---|",
    ]
    for s in board.scenarios:
        for o in an["orderings"].get(s, []):
            lines.append(
                f"| {s} | {o['better']} | {o['worse']} | {interval_text(o, 4)} | "
                f"{'yes' if o['resolved'] else 'no'} |"
            )
    lines.append("")
    for metric, title in (
        ("rms_startup_mm", "## rms_startup_mm (mm): the start-up, the first second"),
        ("rms_mm", "## rms_mm (mm): the whole episode, start-up included (not the ranking)"),
    ):
        if metric in board.metrics and metric != m0:
            grid(title, lambda r, m=metric: analysis_cell(board, r, m))
    cost = an.get("cost_of_effect") or {}
    if cost:
        scen = [s for s in board.scenarios if s != "nominal"]
        lines += [
            f"## What the hidden effect costs each agent: `{m0}` against its own on `nominal`",
            "",
            "The same agent on the same episode seeds, with and without the scenario's hidden "
            "effect: the geometric mean of the per-episode ratios [95 % interval].",
            "",
            "| agent | " + " | ".join(scen) + " |",
            "|---|" + "---:|" * len(scen),
        ]
        for a in order:
            if a in cost:
                lines.append(
                    f"| {label(a)} | "
                    + " | ".join(interval_text(cost[a].get(s)) for s in scen)
                    + " |"
                )
        lines.append("")
    comp = an.get("compute") or {}
    if comp:
        lines += [
            "## Compute budget",
            "",
            "Learned agents: the training steps and wall time of the shipped run (and how many "
            "training seeds were run to choose it, and their wall time in all: "
            "`results/learning/`); every agent: the tracker points it used per episode (every "
            "phase) and its median computation per control step on this machine.",
            "",
            "| agent | training steps | training wall time | seeds trained (wall time in all) "
            "| tracker points per episode | solve time, median (ms) |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for a in order:
            c = comp.get(a)
            if not c:
                continue
            steps = f"{c['training_steps']:,.0f}" if c.get("training_steps") else "–"
            wall = _duration(c.get("training_wall_s"))
            seeds = (
                f"{c['training_seeds']:.0f} ({_duration(c.get('training_wall_s_all_seeds'))})"
                if c.get("training_seeds")
                else "–"
            )
            points = f"{c['tracker_points']:.0f}" if c.get("tracker_points") is not None else "–"
            solve = _fmt(c["solve_time_median_ms"]) if c.get("solve_time_median_ms") else "–"
            lines.append(f"| {label(a)} | {steps} | {wall} | {seeds} | {points} | {solve} |")
        lines.append("")

    # every metric, long format
    lines.append("## All metrics")
    lines.append("")
    lines.append(
        "| agent | scenario | n | "
        + " | ".join(f"{m} ({METRICS[m].unit})" for m in board.metrics)
        + " |"
    )
    lines.append("|---|---|---:|" + "---:|" * len(board.metrics))
    for r in board.rows:
        cells = [cell_text(r.stats[m], m, r) for m in board.metrics]
        name = f"**{r.display}**" if r.best else r.display
        lines.append(f"| {name} | {r.scenario} | {r.n} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append(
        "Metrics: "
        + "; ".join(f"`{m}`: {METRICS[m].description}" for m in board.metrics)
        + ". Timing metrics are of this machine."
    )
    lines.append("")

    if board.agent_settings:
        lines += [
            "## Agents",
            "",
            "| label | agent | settings | env overrides |",
            "|---|---|---|---|",
        ]
        for lab, st in board.agent_settings.items():
            oracle = any(r.oracle for r in board.rows if r.agent == lab)
            informed = any(r.informed for r in board.rows if r.agent == lab)
            lines.append(
                f"| {lab}{marks(oracle, informed)} | `{st['name']}` | "
                f"`{st['settings'] or {}}` | `{st['env'] or {}}` |"
            )
        lines.append("")

    if plots:
        lines += ["## Plots", ""]
        for p in plots:
            lines.append(f"![{Path(p).stem}]({Path(p).name})")
            lines.append("")

    if board.failed:
        lines += ["## Failed runs", ""]
        for rec in sorted(board.failed, key=lambda f: f["run_key"]):
            err = rec.get("error") or {}
            msg = str(err.get("message", "")).splitlines()[0][:200] if err.get("message") else ""
            lines.append(f"- `{rec['run_key']}`: {err.get('type', '?')}: {msg}")
        lines.append("")
    return "\n".join(lines)


def _duration(seconds: float | None) -> str:
    if not seconds:
        return "–"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _ranges(seeds: Sequence[int]) -> str:
    if not seeds:
        return "none"
    if list(seeds) == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 2:
        return f"{seeds[0]}-{seeds[-1]}"
    return ", ".join(map(str, seeds))


# -- plots --------------------------------------------------------------------------------------


def _colors(agents: Sequence[str]) -> dict[str, Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return {a: cmap(i % 10) for i, a in enumerate(agents)}


def plot_error_over_time(board: Leaderboard, path: str | Path) -> Path:
    """True tool-point error over the episode, one panel per scenario, one line per agent (the
    mean over seeds; log scale)."""
    from matplotlib.figure import Figure

    scen = board.scenarios
    ncol = min(4, len(scen))
    nrow = math.ceil(len(scen) / ncol)
    fig = Figure(figsize=(4.2 * ncol, 3.2 * nrow + 0.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrow, ncol, sharex=True, sharey=True, squeeze=False)).ravel()
    colors = _colors(board.agents)
    for ax, s in zip(axes, scen, strict=False):
        for a in board.agents:
            recs = [
                r
                for r in board.records
                if r["spec"]["agent_label"] == a and r["spec"]["scenario_label"] == s
            ]
            series = [r.get("series") or {} for r in recs]
            series = [x for x in series if x.get("time") and x.get("true_error_mm")]
            if not series:
                continue
            n = min(len(x["time"]) for x in series)
            t = np.asarray(series[0]["time"][:n], dtype=float)
            e = np.array(
                [[np.nan if v is None else v for v in x["true_error_mm"][:n]] for x in series],
                dtype=float,
            )
            with np.errstate(all="ignore"):
                mean = np.nanmean(e, axis=0)
            mean = np.where(mean > 0, mean, np.nan)
            ax.plot(t, mean, color=colors[a], lw=1.2, label=a)
        ax.set_title(s)
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[len(scen) :]:
        ax.set_visible(False)
    for ax in axes[(nrow - 1) * ncol : nrow * ncol]:
        ax.set_xlabel("time (s)")
    for ax in axes[::ncol]:
        ax.set_ylabel("true error (mm)")
    handles, labels = axes[0].get_legend_handles_labels()
    for ax in axes[1 : len(scen)]:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 8), frameon=False)
    fig.suptitle("Tracking error over the episode (mean over seeds)")
    return _save(fig, path)


def plot_strips(board: Leaderboard, path: str | Path) -> Path:
    """Per-episode ``rank_by`` of every agent, one panel per scenario: a dot per episode, the
    mean as a bar with its 95 % bootstrap interval (log scale)."""
    from matplotlib.figure import Figure

    m = board.rank_by
    an = board.analysis
    order = [a for a in an.get("order", board.agents) if a in board.agents]
    scen = board.scenarios
    ncol = min(3, len(scen))
    nrow = math.ceil(len(scen) / ncol)
    fig = Figure(figsize=(5.2 * ncol, 0.32 * len(order) * nrow + 1.2 * nrow + 0.8))
    axes = np.atleast_1d(fig.subplots(nrow, ncol, sharey=True, squeeze=False)).ravel()
    colors = _colors(board.agents)
    rng = np.random.default_rng(0)  # the jitter only
    for ax, s in zip(axes, scen, strict=False):
        for y, a in enumerate(order):
            vals = np.array(
                [
                    _value(r, m)
                    for r in board.records
                    if r["spec"]["agent_label"] == a and r["spec"]["scenario_label"] == s
                ],
                dtype=float,
            )
            vals = vals[np.isfinite(vals) & (vals > 0)]
            if not vals.size:
                continue
            jitter = rng.uniform(-0.18, 0.18, vals.size)
            ax.scatter(vals, y + jitter, s=9, color=colors[a], alpha=0.6, lw=0)
            row = board.row(a, s)
            st = row.stats[m] if row is not None else None
            if st is not None and st.n:
                ax.plot([st.mean, st.mean], [y - 0.3, y + 0.3], color="k", lw=1.5)
                if st.has_ci:
                    ax.plot([st.lo, st.hi], [y, y], color="k", lw=1.0)
        ax.set_xscale("log")
        ax.set_title(s)
        ax.grid(True, axis="x", which="both", alpha=0.3)
        ax.set_xlabel(f"{m} ({METRICS[m].unit})")
    for ax in axes[len(scen) :]:
        ax.set_visible(False)
    axes[0].set_yticks(range(len(order)), order)
    axes[0].invert_yaxis()
    for ax in axes[::ncol]:
        ax.set_yticks(range(len(order)), order)
    fig.suptitle(f"{m} per episode (dots), mean and 95 % bootstrap interval (black), log scale")
    fig.set_layout_engine("constrained")
    return _save(fig, path)


def to_json(board: Leaderboard, command: str | None = None) -> dict[str, Any]:
    """What ``leaderboard.json`` holds: where the records came from (config, commit, episodes,
    the commands) and the analysis (:mod:`experiments.comparisons`)."""
    man = board.manifest or {}
    commits = sorted({(r.get("git") or {}).get("commit") or "" for r in board.records})
    episodes = sorted({episode_key(r) for r in board.records})
    everyone = board.records + board.failed
    stamps = [
        (t.get("started"), t.get("finished"))
        for t in (r.get("timing") or {} for r in everyone)
        if t.get("started") and t.get("finished")
    ]
    wall = None
    if stamps:
        from datetime import datetime

        first = min(datetime.fromisoformat(str(a)) for a, _ in stamps)
        last = max(datetime.fromisoformat(str(b)) for _, b in stamps)
        wall = (last - first).total_seconds()
    run_s = sum(float((r.get("timing") or {}).get("wall_time_s") or 0.0) for r in everyone)
    hosts = sorted({(r.get("timing") or {}).get("host") or "" for r in everyone} - {""})
    return jsonable(
        {
            "config_name": man.get("config_name"),
            "config_path": man.get("config_path"),
            "config_hash": man.get("config_hash"),
            "commands": [c for c in (man.get("command"), command) if c],
            "commits": commits,
            "clean": not any(not is_clean(r) for r in board.records + board.failed),
            "runs": len(board.records) + len(board.failed),
            "failed": len(board.failed),
            "episodes": len(episodes),
            "drawn_seeds": any(r["spec"].get("episode") is not None for r in board.records),
            "settle_seconds": (man.get("config") or {}).get("settle_seconds"),
            # from the first run's start to the last one's end (a resumed sweep's pauses count)
            "sweep_wall_s": wall,
            "runs_wall_s": run_s,
            "hosts": hosts,
            **board.analysis,
        }
    )


def _save(fig, path: str | Path) -> Path:
    """Write a PNG atomically (temp file + rename)."""
    from arm.files import atomic_path

    p = Path(path)
    with atomic_path(p) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    return p


def write_leaderboard(
    board: Leaderboard,
    out_dir: str | Path = "results",
    command: str | None = None,
    plots: bool = True,
) -> dict[str, Path]:
    """Write leaderboard.md, leaderboard.json (the analysis), leaderboard.csv (per agent and
    scenario), leaderboard_runs.csv (every run), leaderboard_pairs.csv (every two agents) and
    (``plots``) the two PNGs into ``out_dir``."""
    out = Path(out_dir)
    paths: dict[str, Path] = {}
    paths["runs_csv"] = out / RUNS_CSV_NAME
    atomic_write_text(paths["runs_csv"], runs_csv(board))
    paths["pairs_csv"] = out / PAIRS_CSV_NAME
    atomic_write_text(paths["pairs_csv"], pairs_csv(board))
    paths["json"] = out / JSON_NAME
    atomic_write_text(
        paths["json"], json.dumps(to_json(board, command), indent=1, allow_nan=False) + "\n"
    )
    if plots:
        paths["strips"] = plot_strips(board, out / PLOT_STRIPS)
        paths["error_over_time"] = plot_error_over_time(board, out / PLOT_TIME)
    paths["csv"] = out / CSV_NAME
    atomic_write_text(paths["csv"], to_csv(board))
    paths["markdown"] = out / MD_NAME
    atomic_write_text(
        paths["markdown"],
        to_markdown(
            board,
            command,
            [paths[k].name for k in ("strips", "error_over_time") if k in paths],
        ),
    )
    return paths


# -- the README's leaderboard section ---------------------------------------------------------------

README_BEGIN = "<!-- leaderboard:begin -->"
README_END = "<!-- leaderboard:end -->"


def readme_block(data: Mapping[str, Any]) -> str:
    """The README's leaderboard section, written from ``leaderboard.json`` alone (what
    :func:`to_json` wrote): the ranking table with each agent's aggregate, the orderings the
    paired intervals resolve, and sentences that claim no ordering they do not resolve.
    ``tests/test_readme_leaderboard.py`` checks that the README holds exactly this."""
    m0 = data["rank_by"]
    ref = data.get("reference")
    scen = list(data["scenarios"])
    cells, agg = data["cells"], data.get("aggregate") or {}
    oracles, informed = set(data.get("oracles", [])), set(data.get("informed", []))
    order = [a for a in data["order"] if a in cells]
    commit = ", ".join(c[:10] for c in data.get("commits", []))

    def mark(a: str) -> str:
        return a + marks(a in oracles, a in informed)

    def mean(a: str, s: str, m: str = m0) -> float | None:
        return ((cells.get(a, {}).get(s) or {}).get(m) or {}).get("value")

    settle = data.get("settle_seconds")
    lines = [
        README_BEGIN,
        "<!-- written by `sixaxis leaderboard --readme` from results/leaderboard.json; "
        "tests/test_readme_leaderboard.py keeps the two equal -->",
        "",
        f"From {'clean ' if data.get('clean') else ''}commit {commit} "
        f"(`results/leaderboard.md`, with every interval): {data['episodes']} episodes per agent "
        "and scenario"
        + (", their seeds drawn when the sweep started" if data.get("drawn_seeds") else "")
        + f", {data['runs']} runs ({data['failed']} failed"
        + (
            f"; the sweep took {_duration(data['sweep_wall_s'])} on "
            f"{len(data.get('hosts') or [])} host(s), {_duration(data.get('runs_wall_s'))} of "
            "run time"
            if data.get("sweep_wall_s")
            else ""
        )
        + f"). Each cell is the geometric mean over the episodes of `{m0}` "
        + (f"(the tracking RMS after {settle:g} s, mm)" if isinstance(settle, (int, float)) else "")
        + "; **bold**: the best contender of the scenario; (oracle): given the plant's truth; "
        "(informed): told the scenario's effects."
        + (
            f" The last column is each agent's `{m0}` against `{ref}`'s on the same episodes, "
            "over every scenario: the IQM of the per-episode ratios [95 % interval]."
            if ref
            else ""
        ),
        "",
        "| agent | " + " | ".join(scen) + (f" | vs `{ref}` |" if ref else " |"),
        "|---|" + "---:|" * (len(scen) + (1 if ref else 0)),
    ]
    for a in order:
        row = []
        for s in scen:
            v = mean(a, s)
            text = _fmt(v) if v is not None else ""
            row.append(f"**{text}**" if data["best"].get(s) == a and text else text)
        if ref:
            row.append(interval_text((agg.get(a) or {}).get("iqm")))
        lines.append(f"| {mark(a)} | " + " | ".join(row) + " |")
    lines += [
        "",
        "Each scenario's agents in that order, each against the next: `<` where the paired 95 % "
        "interval of their per-episode ratio resolves the step, `≈` where it does not:",
        "",
    ]
    lines += [f"- `{s}`: {ordering_text(data, s)}" for s in scen]
    lines += ["", *_readme_sentences(data), README_END]
    return "\n".join(lines) + "\n"


def _readme_sentences(data: Mapping[str, Any]) -> list[str]:
    """What the table says, claiming only resolved orderings."""
    oracles, informed = set(data.get("oracles", [])), set(data.get("informed", []))
    pairs = data.get("pairs", [])

    def pair(a: str, b: str, s: str) -> Mapping[str, Any] | None:
        return next(
            (p for p in pairs if p["scenario"] == s and {p["better"], p["worse"]} == {a, b}),
            None,
        )

    out = []
    for s in data["scenarios"]:
        best = data["best"].get(s)
        if best is None:
            continue
        rivals = [
            a for a in data["ranking"][s] if a != best and a not in oracles and a not in informed
        ]
        unresolved = [a for a in rivals if not (pair(best, a, s) or {}).get("resolved")]
        if not unresolved:
            out.append(
                f"- On `{s}`, `{best}` is the best contender, resolved against every other one."
            )
        else:
            names = ", ".join(f"`{a}`" for a in unresolved)
            out.append(
                f"- On `{s}`, `{best}` comes first among the contenders; not resolved from it: "
                f"{names}."
            )
    below: dict[tuple[str, str], list[str]] = {}
    for p in pairs:
        if p["resolved"] and p["worse"] in oracles and p["better"] not in oracles | informed:
            below.setdefault((p["better"], p["worse"]), []).append(p["scenario"])
    for (a, o), where in sorted(below.items()):
        out.append(
            f"- `{a}` tracks below `{o}` (oracle) on {', '.join(f'`{s}`' for s in where)} "
            "(resolved): the oracle's model knowledge is not a ceiling on the settled metric."
        )
    return out


def update_readme(path: str | Path, block: str) -> Path:
    """Replace the README's leaderboard section (between :data:`README_BEGIN` and
    :data:`README_END`, markers included) with ``block``; a README without both markers is
    refused, and nothing is written."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordError(f"{p}: cannot read: {exc}") from None
    i, j = text.find(README_BEGIN), text.find(README_END)
    if i < 0 or j < i:
        raise RecordError(
            f"{p}: no leaderboard section to rewrite (the lines {README_BEGIN} and {README_END})"
        )
    atomic_write_text(p, text[:i] + block.rstrip("\n") + text[j + len(README_END) :])
    return p
