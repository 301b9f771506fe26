"""The leaderboard: agents by scenario from a directory of run records, as a markdown table, a CSV,
a per-run CSV and two PNG plots.

    board = build_leaderboard("runs/full")
    paths = write_leaderboard(board, "results", command="sixaxis leaderboard runs/full")

Each cell is the mean over seeds with the half-width of its 95 % Student-t confidence interval
(``scipy.stats.t``), or with the minimum and maximum over seeds when there are fewer than three;
the best agent of each scenario (lowest mean of the config's ``rank_by`` metric) is marked. The
whole-episode RMS, the settled RMS and the convergence time stand side by side in the first table.
Oracles (agents given the plant's truth) are marked as such, and so are informed agents (told the
scenario's effects in their config: a model effect set beyond the geometric errors).

Every row must be reproducible: records from a tree with local changes (or from no git checkout)
are refused unless ``allow_dirty=True``, and then marked. ``leaderboard_runs.csv`` beside the
table lists every run (agent, scenario, seed, commit, config, every metric) so that
``sixaxis reproduce results/leaderboard_runs.csv --run KEY`` can rerun any of them.

The CSV has one row per agent and scenario with ``<metric>_mean``, ``<metric>_ci95`` (half-width;
empty with fewer than three values), ``<metric>_min``, ``<metric>_max`` and ``<metric>_n``.

It is one module, longer than most, because building the board from the records and writing its
files share the cell formatting, so that the markdown, the CSVs and the CLI show the same numbers.
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

from arm.files import atomic_write_text
from experiments.metrics import METRICS, MIN_VALUES_FOR_CI, Summary, summarize
from experiments.records import RecordError, RunStore

__all__ = [
    "Leaderboard",
    "Row",
    "build_leaderboard",
    "cell_text",
    "is_clean",
    "is_informed",
    "is_oracle",
    "runs_csv",
    "spread_words",
    "to_csv",
    "to_markdown",
    "write_leaderboard",
]

log = logging.getLogger(__name__)

MD_NAME = "leaderboard.md"
CSV_NAME = "leaderboard.csv"
RUNS_CSV_NAME = "leaderboard_runs.csv"
#: the first table: the whole episode, the settled part and the convergence, side by side
HEADLINE = ("rms_mm", "rms_settled_mm", "converge_s")
ORACLE_MARK = " (oracle)"
INFORMED_MARK = " (informed)"
DIRTY_MARK = " (local changes)"
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
    runs_dir: str | Path, rank_by: str | None = None, allow_dirty: bool = False
) -> Leaderboard:
    """Read every record of a sweep directory and summarise it over seeds.

    With the sweep's manifest (``_sweep.json``) present, only the runs of its config count (records
    left from an older config in the same directory are ignored, with a warning), and agents and
    scenarios keep the config's order.

    Records made from a tree with local changes, or outside a git checkout, are refused
    (:class:`RecordError` naming them) unless ``allow_dirty``; then their rows are marked."""
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
            stats = {m: summarize(_value(r, m) for r in mine) for m in metrics}
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
        allow_dirty=allow_dirty,
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
    """A summary as text: ``mean ± ci95`` (three values or more), ``mean (min–max)`` (two),
    ``mean`` (one), ``k/n`` for counts. A metric with a companion count of runs where it is
    missing (``converge_s``/``never_converged``) says so: ``never (3/3)``, ``1.2 ± 0.4 (1/4
    never)``, the mean being over the runs that converged. ``spread=False``: the mean alone (and
    ``never`` without the count when no run converged)."""
    if METRICS[metric].aggregate == "sum":
        return "–" if s.n == 0 else f"{round(s.total)}/{s.n}"
    companion = METRICS[metric].companion
    never = row.stats.get(companion) if row is not None and companion else None
    k = round(never.total) if never is not None and never.n else 0
    if s.n == 0:
        return ("never" if not spread else f"never ({k}/{never.n})") if k else "–"
    if not spread:
        text = _fmt(s.mean)
    elif s.has_ci:
        text = f"{_fmt(s.mean)} ± {_fmt(s.ci95, 2)}"
    elif s.n >= 2:
        text = f"{_fmt(s.mean)} ({_fmt(s.min)}–{_fmt(s.max)})"
    else:
        text = _fmt(s.mean)
    return f"{text} ({k}/{never.n} never)" if k else text


def to_csv(board: Leaderboard) -> str:
    """One row per agent and scenario; ``<metric>_mean``, ``<metric>_ci95`` (half-width of the
    95 % Student-t interval; empty with fewer than three values), ``<metric>_min``,
    ``<metric>_max``, ``<metric>_n``; counts for sums (``diverged``, ``never_converged``);
    ``best`` by ``rank_by``; ``oracle`` (given the truth); ``dirty`` (records with local
    changes); ``informed`` (told the scenario's effects)."""
    header = ["agent", "scenario", "n", "failed", "best", "oracle", "dirty", "informed"]
    for m in board.metrics:
        header += [f"{m}_mean", f"{m}_ci95", f"{m}_min", f"{m}_max", f"{m}_n"]
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
            ci = s.ci95 if s.has_ci else float("nan")
            line += [_num(s.mean), _num(ci), _num(s.min), _num(s.max), s.n]
            if METRICS[m].aggregate == "sum":
                line.append("" if s.n == 0 else round(s.total))
        w.writerow(line)
    return buf.getvalue()


def runs_csv(board: Leaderboard) -> str:
    """One row per run of the leaderboard (failed ones too): agent label and name, scenario,
    seed, whether it is an oracle, status, the commit and whether the tree was dirty, the config
    (name, path, hash), the run key and hash, whether it was informed, and every metric (timing
    metrics last; they vary from run to run). ``sixaxis reproduce`` reruns any row."""
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
        return "mean ± half-width of the 95 % Student-t confidence interval over seeds"
    if ns and max(ns) < MIN_VALUES_FOR_CI:
        return (
            f"mean (minimum–maximum) over seeds: fewer than {MIN_VALUES_FOR_CI} seeds, too few "
            "for a confidence interval"
        )
    return (
        "mean ± half-width of the 95 % Student-t confidence interval over seeds, or (minimum–"
        f"maximum) where fewer than {MIN_VALUES_FOR_CI} seeds finished"
    )


def headline_metrics(board: Leaderboard) -> list[str]:
    """The metrics of the side-by-side table: whole-episode RMS, settled RMS, convergence time
    (those of them the records have)."""
    return [m for m in HEADLINE if m in board.metrics]


def headline_cell(board: Leaderboard, row: Row) -> str:
    """``whole · settled · convergence`` means of one row (the first table)."""
    return " · ".join(
        cell_text(row.stats[m], m, row, spread=False) for m in headline_metrics(board)
    )


def to_markdown(board: Leaderboard, command: str | None = None, plots: Sequence[str] = ()) -> str:
    m0 = board.rank_by
    meta = METRICS[m0]
    man = board.manifest or {}
    seeds = sorted({r["spec"]["seed"] for r in board.records})
    cfg = man.get("config", {})
    lines = ["# Leaderboard", ""]
    head = headline_metrics(board)
    if head:
        what = {
            "rms_mm": "the tracking RMS over the whole judged episode",
            "rms_settled_mm": (
                f"the RMS after the settling time ({cfg.get('settle_seconds', '?'):g} s)"
                if isinstance(cfg.get("settle_seconds"), (int, float))
                else "the RMS after the settling time"
            ),
            "converge_s": (
                f"the time after which the true error stays below "
                f"{cfg.get('converge_mm', 0.25):g} mm (`never`: it did not, in that many seeds)"
            ),
        }
        lines.append(
            "Each agent on each scenario, judged on the plant's *true* tool point: "
            + "; ".join(f"`{m}` ({METRICS[m].unit}), {what[m]}" for m in head)
            + f". Ranked by `{m0}`; **bold**: the best agent of each scenario. Agents marked "
            "(oracle) are given the plant's truth: they show what knowing the arm is worth, not "
            "what a controller can do."
            + (
                " Agents marked (informed) are told the scenario's effects in their config (the "
                "model's effect set): they show what knowing which effects are there is worth, "
                "not what a controller finds."
                if any(r.informed for r in board.rows)
                else ""
            )
        )
        lines.append("")
    lines.append(
        f"Cells of the other tables: {spread_words(board)} ({len(seeds)} seed(s)); lower is better."
    )
    lines += ["", "Made by:", "", "```"]
    if man.get("command"):
        lines.append(man["command"])
    lines.append(command or f"sixaxis leaderboard {board.runs_dir}")
    lines += ["```", ""]
    commits = sorted({(r.get("git") or {}).get("commit") or "?" for r in board.records})
    ndirty = sum(not is_clean(r) for r in board.records + board.failed)
    versions = (board.records[0].get("versions") if board.records else {}) or {}
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
        conv = cfg.get("converge_mm")
        facts.append(
            f"{episode}, settling time {cfg.get('settle_seconds'):g} s"
            + (f", convergence threshold {conv:g} mm" if conv is not None else "")
            + f", env options `{cfg.get('env') or {}}`"
        )
    facts.append(
        f"{len(board.records) + len(board.failed)} runs ({len(board.failed)} failed), seeds "
        f"{_ranges(seeds)}"
    )
    if ndirty:
        facts.append(
            f"commit {', '.join(c[:10] for c in commits)}: **{ndirty} run(s) made with local "
            "changes** (`--allow-dirty`; rows marked (local changes)): no commit reproduces them"
        )
    else:
        facts.append(
            f"commit {', '.join(c[:10] for c in commits)}, clean: every run is reproducible "
            f"from it (`sixaxis reproduce {RUNS_CSV_NAME} --run RUN_KEY`)"
        )
    if versions:
        facts.append(", ".join(f"{k} {v}" for k, v in versions.items() if v))
    lines += [f"- {f}" for f in facts]
    if board.ignored:
        lines.append(f"- {board.ignored} record(s) of another config in the directory ignored")
    lines.append("")

    def grid(title: str, cell) -> None:
        lines.append(title)
        lines.append("")
        lines.append("| agent | " + " | ".join(board.scenarios) + " |")
        lines.append("|---|" + "---:|" * len(board.scenarios))
        for a in board.agents:
            mine = [board.row(a, s) for s in board.scenarios]
            shown = next(r for r in mine if r is not None)
            cells = []
            for r in mine:
                if r is None:
                    cells.append("")
                    continue
                c = cell(r)
                if r.failed:
                    c += f" ({r.failed} failed)"
                cells.append(f"**{c}**" if r.best else c)
            name = a + marks(shown.oracle, any(r is not None and r.informed for r in mine))
            name += DIRTY_MARK if any(r is not None and r.dirty for r in mine) else ""
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines.append("")

    if head:
        grid(
            "## " + " · ".join(f"{m} ({METRICS[m].unit})" for m in head) + " (means)",
            lambda r: headline_cell(board, r),
        )
    grid(f"## {m0} ({meta.unit})", lambda r: cell_text(r.stats[m0], m0, r))

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
        for label, s in board.agent_settings.items():
            oracle = any(r.oracle for r in board.rows if r.agent == label)
            informed = any(r.informed for r in board.rows if r.agent == label)
            lines.append(
                f"| {label}{marks(oracle, informed)} | `{s['name']}` | "
                f"`{s['settings'] or {}}` | `{s['env'] or {}}` |"
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
        means, lo, hi = [], [], []
        for s in scen:
            r = board.row(a, s)
            st = r.stats[m] if r else None
            means.append(st.mean if st and st.n else np.nan)
            if st and st.has_ci:
                lo.append(st.ci95)
                hi.append(st.ci95)
            elif st and st.n >= 2:  # too few seeds for an interval: their range
                lo.append(st.mean - st.min)
                hi.append(st.max - st.mean)
            else:
                lo.append(0.0)
                hi.append(0.0)
        ax.bar(
            x + (i - (len(agents) - 1) / 2) * width,
            means,
            width,
            yerr=[lo, hi],
            capsize=2,
            color=colors[a],
            label=a,
        )
    ax.set_xticks(x, scen)
    ax.set_yscale("log")
    ax.set_ylabel(f"{m} ({METRICS[m].unit})")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(ncol=min(4, len(agents)), fontsize=8, frameon=False)
    ax.set_title(f"{METRICS[m].description} by scenario (mean, 95 % CI or range over seeds)")
    return _save(fig, path)


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
    """Write leaderboard.md, leaderboard.csv, leaderboard_runs.csv (every run) and (``plots``)
    the two PNGs into ``out_dir``."""
    out = Path(out_dir)
    paths: dict[str, Path] = {}
    paths["runs_csv"] = out / RUNS_CSV_NAME
    atomic_write_text(paths["runs_csv"], runs_csv(board))
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
