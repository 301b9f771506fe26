"""The leaderboard: agents by scenario from a directory of run records, as a markdown table, a CSV
and two PNG plots.

    board = build_leaderboard("runs/full")
    paths = write_leaderboard(board, "results", command="sixaxis leaderboard runs/full")

Each cell is the mean over seeds with the half-width of its 95 % Student-t confidence interval
(``scipy.stats.t``); the best agent of each scenario (lowest mean of the config's ``rank_by``
metric) is marked. The CSV has one row per agent and scenario with ``<metric>_mean``,
``<metric>_ci95`` (half-width) and ``n`` for every metric.
"""

from __future__ import annotations

import csv
import io
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arm.measurements import atomic_write_text
from experiments.metrics import METRICS, Summary, summarize
from experiments.records import RecordError, RunStore

__all__ = ["Leaderboard", "Row", "build_leaderboard", "write_leaderboard"]

log = logging.getLogger(__name__)

MD_NAME = "leaderboard.md"
CSV_NAME = "leaderboard.csv"
PLOT_TIME = "leaderboard_error_over_time.png"
PLOT_SCENARIO = "leaderboard_by_scenario.png"


@dataclass
class Row:
    agent: str
    scenario: str
    n: int
    failed: int
    stats: dict[str, Summary]
    best: bool = False


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

    def row(self, agent: str, scenario: str) -> Row | None:
        return next((r for r in self.rows if r.agent == agent and r.scenario == scenario), None)


def build_leaderboard(runs_dir: str | Path, rank_by: str | None = None) -> Leaderboard:
    """Read every record of a sweep directory and summarise it over seeds.

    With the sweep's manifest (``_sweep.json``) present, only the runs of its config count (records
    left from an older config in the same directory are ignored, with a warning), and agents and
    scenarios keep the config's order."""
    store = RunStore(runs_dir)
    if not store.root.is_dir():
        raise RecordError(f"{store.root}: no such runs directory")
    manifest = store.manifest()
    wanted = manifest.get("runs") if manifest else None
    records, failed, ignored = [], [], 0
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
                key=lambda r: r["spec"]["seed"],
            )
            nfail = sum(
                1
                for r in failed
                if r["spec"]["agent_label"] == agent and r["spec"]["scenario_label"] == scen
            )
            if not mine and not nfail:
                continue
            stats = {m: summarize(_value(r, m) for r in mine) for m in metrics}
            rows.append(Row(agent, scen, len(mine), nfail, stats))
    for scen in scenarios:
        cands = [r for r in rows if r.scenario == scen and math.isfinite(r.stats[rank_by].mean)]
        if cands:
            min(cands, key=lambda r: r.stats[rank_by].mean).best = True
    return Leaderboard(
        runs_dir=Path(runs_dir),
        metrics=metrics,
        rank_by=rank_by,
        agents=[a for a in agents if any(r.agent == a for r in rows)],
        scenarios=[s for s in scenarios if any(r.scenario == s for r in rows)],
        rows=rows,
        records=records,
        failed=failed,
        manifest=manifest,
        ignored=ignored,
        agent_settings=settings,
    )


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


def _cell(s: Summary, metric: str) -> str:
    if METRICS[metric].aggregate == "sum":
        return "–" if s.n == 0 else f"{round(s.total)}/{s.n}"
    if s.n == 0:
        return "–"
    if not math.isfinite(s.ci95):
        return _fmt(s.mean)
    return f"{_fmt(s.mean)} ± {_fmt(s.ci95, 2)}"


def to_csv(board: Leaderboard) -> str:
    """One row per agent and scenario; ``<metric>_mean``, ``<metric>_ci95`` (half-width of the
    95 % Student-t interval), ``<metric>_n``; counts for ``diverged``; ``best`` by ``rank_by``."""
    header = ["agent", "scenario", "n", "failed", "best"]
    for m in board.metrics:
        header += [f"{m}_mean", f"{m}_ci95", f"{m}_n"]
        if METRICS[m].aggregate == "sum":
            header.append(f"{m}_count")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in board.rows:
        line: list[Any] = [r.agent, r.scenario, r.n, r.failed, int(r.best)]
        for m in board.metrics:
            s = r.stats[m]
            line += [_num(s.mean), _num(s.ci95), s.n]
            if METRICS[m].aggregate == "sum":
                line.append("" if s.n == 0 else round(s.total))
        w.writerow(line)
    return buf.getvalue()


def _num(v: float) -> str:
    return "" if v is None or not math.isfinite(v) else repr(float(v))


def to_markdown(board: Leaderboard, command: str | None = None, plots: Sequence[str] = ()) -> str:
    m0 = board.rank_by
    meta = METRICS[m0]
    man = board.manifest or {}
    seeds = sorted({r["spec"]["seed"] for r in board.records})
    lines = ["# Leaderboard", ""]
    lines.append(
        f"{meta.description[:1].upper()}{meta.description[1:]} ({meta.unit}): mean ± half-width of the 95 % Student-t "
        f"confidence interval over {len(seeds)} seed(s); lower is better; **bold**: the best agent "
        "of each scenario."
    )
    lines += ["", "Made by:", "", "```"]
    if man.get("command"):
        lines.append(man["command"])
    lines.append(command or f"sixaxis leaderboard {board.runs_dir}")
    lines += ["```", ""]
    commits = sorted({(r.get("git") or {}).get("commit") or "?" for r in board.records})
    dirty = any((r.get("git") or {}).get("dirty") for r in board.records)
    versions = (board.records[0].get("versions") if board.records else {}) or {}
    facts = []
    if man:
        facts.append(
            f"config `{man.get('config_name')}` (`{man.get('config_path')}`, hash "
            f"`{man.get('config_hash')}`)"
        )
    cfg = man.get("config", {})
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
    facts.append(
        f"{len(board.records) + len(board.failed)} runs ({len(board.failed)} failed), seeds "
        f"{_ranges(seeds)}"
    )
    facts.append(
        f"commit {', '.join(c[:10] for c in commits)}{' with local changes' if dirty else ''}"
    )
    if versions:
        facts.append(", ".join(f"{k} {v}" for k, v in versions.items() if v))
    lines += [f"- {f}" for f in facts]
    if board.ignored:
        lines.append(f"- {board.ignored} record(s) of another config in the directory ignored")
    lines.append("")

    # the headline table: agents by scenario
    lines.append(f"## {m0} ({meta.unit})")
    lines.append("")
    lines.append("| agent | " + " | ".join(board.scenarios) + " |")
    lines.append("|---|" + "---:|" * len(board.scenarios))
    for a in board.agents:
        cells = []
        for s in board.scenarios:
            r = board.row(a, s)
            if r is None:
                cells.append("")
                continue
            c = _cell(r.stats[m0], m0)
            if r.failed:
                c += f" ({r.failed} failed)"
            cells.append(f"**{c}**" if r.best else c)
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
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
        cells = [_cell(r.stats[m], m) for m in board.metrics]
        name = f"**{r.agent}**" if r.best else r.agent
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
        for label, s in board.agent_settings.items():
            lines.append(
                f"| {label} | `{s['name']}` | `{s['settings'] or {}}` | `{s['env'] or {}}` |"
            )
        lines.append("")

    if plots:
        lines += ["## Plots", ""]
        for p in plots:
            lines.append(f"![{Path(p).stem}]({Path(p).name})")
            lines.append("")

    if board.failed:
        lines += ["## Failed runs", ""]
        for r in sorted(board.failed, key=lambda r: r["run_key"]):
            err = r.get("error") or {}
            msg = str(err.get("message", "")).splitlines()[0][:200] if err.get("message") else ""
            lines.append(f"- `{r['run_key']}`: {err.get('type', '?')}: {msg}")
        lines.append("")
    return "\n".join(lines)


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


def plot_by_scenario(board: Leaderboard, path: str | Path) -> Path:
    """The ranking metric by scenario: one bar per agent with its 95 % confidence interval."""
    from matplotlib.figure import Figure

    m = board.rank_by
    scen, agents = board.scenarios, board.agents
    fig = Figure(
        figsize=(max(6.0, 1.3 * len(scen) * max(1, len(agents)) / 4 + 3), 4.2), layout="constrained"
    )
    ax = fig.subplots()
    colors = _colors(agents)
    width = 0.8 / max(1, len(agents))
    x = np.arange(len(scen))
    for i, a in enumerate(agents):
        means, errs = [], []
        for s in scen:
            r = board.row(a, s)
            st = r.stats[m] if r else None
            means.append(st.mean if st and st.n else np.nan)
            errs.append(st.ci95 if st and math.isfinite(st.ci95) else 0.0)
        ax.bar(
            x + (i - (len(agents) - 1) / 2) * width,
            means,
            width,
            yerr=errs,
            capsize=2,
            color=colors[a],
            label=a,
        )
    ax.set_xticks(x, scen)
    ax.set_yscale("log")
    ax.set_ylabel(f"{m} ({METRICS[m].unit})")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(ncol=min(4, len(agents)), fontsize=8, frameon=False)
    ax.set_title(f"{METRICS[m].description} by scenario (mean, 95 % CI over seeds)")
    return _save(fig, path)


def _save(fig, path: str | Path) -> Path:
    """Write a PNG atomically (temp file + rename)."""
    from arm.measurements import atomic_path

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
    """Write leaderboard.md, leaderboard.csv and (``plots``) the two PNGs into ``out_dir``."""
    out = Path(out_dir)
    paths: dict[str, Path] = {}
    if plots:
        paths["error_over_time"] = plot_error_over_time(board, out / PLOT_TIME)
        paths["by_scenario"] = plot_by_scenario(board, out / PLOT_SCENARIO)
    paths["csv"] = out / CSV_NAME
    atomic_write_text(paths["csv"], to_csv(board))
    paths["markdown"] = out / MD_NAME
    atomic_write_text(
        paths["markdown"],
        to_markdown(
            board,
            command,
            [paths[k].name for k in ("error_over_time", "by_scenario") if k in paths],
        ),
    )
    return paths
