"""The leaderboard's files: leaderboard.md, leaderboard.json (the analysis), leaderboard.csv (per
agent and scenario), leaderboard_runs.csv (every run, for ``sixaxis reproduce``) and
leaderboard_pairs.csv (every two agents), with the plots of :mod:`experiments.leaderboard.plots`;
and the cell formatting they share with the README's section and the command line, so that all of
them show the same numbers."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from arm.files import atomic_write_text
from experiments.comparisons import episode_key
from experiments.config import split_train_seed
from experiments.leaderboard.build import (
    DIRTY_MARK,
    Leaderboard,
    Row,
    episode_order,
    is_clean,
    is_informed,
    is_oracle,
    marks,
    metric_value,
)
from experiments.leaderboard.plots import plot_error_over_time, plot_strips
from experiments.metrics import METRICS, MIN_VALUES_FOR_CI, Summary
from experiments.records import jsonable

__all__ = [
    "CSV_NAME",
    "JSON_NAME",
    "MD_NAME",
    "PAIRS_CSV_NAME",
    "PLOT_STRIPS",
    "PLOT_TIME",
    "RUNS_CSV_NAME",
    "analysis_cell",
    "cell_text",
    "duration_text",
    "interval_text",
    "number_text",
    "ordering_text",
    "pairs_csv",
    "runs_csv",
    "seeds_text",
    "spread_words",
    "to_csv",
    "to_json",
    "to_markdown",
    "write_leaderboard",
]

MD_NAME = "leaderboard.md"
CSV_NAME = "leaderboard.csv"
RUNS_CSV_NAME = "leaderboard_runs.csv"
JSON_NAME = "leaderboard.json"
PAIRS_CSV_NAME = "leaderboard_pairs.csv"
PLOT_STRIPS = "leaderboard_strips.png"
PLOT_TIME = "leaderboard_error_over_time.png"


def number_text(v: float, digits: int = 3) -> str:
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
        text = number_text(s.mean)
    elif s.has_ci:
        text = f"{number_text(s.mean)} [{number_text(s.lo)}, {number_text(s.hi)}]"
    elif s.n >= 2:
        text = f"{number_text(s.mean)} ({number_text(s.min)}–{number_text(s.max)})"
    else:
        text = number_text(s.mean)
    return f"{text} ({k}/{never.n} never)" if k and never is not None else text


def analysis_cell(board: Leaderboard, row: Row, metric: str, spread: bool = True) -> str:
    """A headline cell: the geometric mean over episodes [its 95 % interval] from the analysis
    (``spread=False``: the value alone); the summary's text for other metrics."""
    iv = (board.analysis.get("cells", {}).get(row.agent, {}).get(row.scenario) or {}).get(metric)
    if not iv or "value" not in iv:
        return cell_text(row.stats[metric], metric, row, spread)
    if not spread:
        return number_text(iv["value"]) if iv["value"] is not None else "–"
    return interval_text(iv)


def interval_text(iv: Mapping[str, Any] | None, digits: int = 3) -> str:
    """An interval of the analysis (``value``, ``lo``, ``hi``) as ``value [lo, hi]``."""
    if not iv or iv.get("value") is None:
        return "–"
    if iv.get("lo") is None or iv.get("hi") is None:
        return number_text(iv["value"], digits)
    return f"{number_text(iv['value'], digits)} [{number_text(iv['lo'], digits)}, {number_text(iv['hi'], digits)}]"


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
    """One row per run of the leaderboard (failed ones too): agent label and name, training
    seed (of a label ``<agent>@s<seed>``; empty for one network), scenario,
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
        "train_seed",
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
            order.get(
                (split_train_seed(r["spec"]["agent_label"])[0], r["spec"]["scenario_label"]),
                len(order),
            ),
            r["spec"]["agent_label"],
            episode_order(r),
        ),
    )
    man = board.manifest or {}
    for r in recs:
        spec, git = r["spec"], r.get("git") or {}
        w.writerow(
            [
                spec["agent_label"],
                spec["agent"],
                _blank(split_train_seed(spec["agent_label"])[1]),
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
                *(_num(metric_value(r, m)) for m in plain),
                *(_num(metric_value(r, m)) for m in timing),
            ]
        )
    return buf.getvalue()


def _blank(v: Any) -> Any:
    return "" if v is None else v


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


def to_markdown(board: Leaderboard, command: str | None = None, plots: Sequence[str] = ()) -> str:
    """leaderboard.md: the introduction, then a section for each part of the board, in order."""
    order = [a for a in board.analysis.get("order", board.agents) if a in board.agents]
    lines = _md_intro(board, command)
    lines += _md_grid(
        board,
        order,
        f"## {board.rank_by} ({METRICS[board.rank_by].unit}): the ranking",
        board.rank_by,
        note=(
            f"Agents in the order of their aggregate against `{ref}` (below)."
            if (ref := board.analysis.get("reference"))
            else ""
        ),
        bold=True,
    )
    lines += _md_aggregate(board, order)
    lines += _md_orderings(board)
    for metric, title in (
        ("rms_startup_mm", "## rms_startup_mm (mm): the start-up, the first second"),
        ("rms_mm", "## rms_mm (mm): the whole episode, start-up included (not the ranking)"),
    ):
        if metric in board.metrics and metric != board.rank_by:
            lines += _md_grid(board, order, title, metric)
    lines += _md_cost(board, order)
    lines += _md_compute(board, order)
    lines += _md_all_metrics(board)
    lines += _md_agents(board)
    if plots:
        lines += ["## Plots", ""]
        for p in plots:
            lines.append(f"![{Path(p).stem}]({Path(p).name})")
            lines.append("")
    lines += _md_failed(board)
    return "\n".join(lines)


def seeds_text(compute: Mapping[str, Any] | None) -> str:
    """What a learned agent's row is over, from its analysis's ``compute`` entry: `` (5 seeds)``
    for an agent ranked over its training seeds, `` (1 seed: the best of 3 trained)`` for one
    shipped network (which one, as its policy file says, and of how many); nothing for an agent
    that is not learned, or an analysis written before the leaderboard knew training seeds."""
    if not compute or compute.get("ranked_seeds") is None:
        return ""
    ranked = compute["ranked_seeds"]
    if len(ranked) > 1:
        return f" ({len(ranked)} seeds)"
    trained, picked = compute.get("training_seeds"), compute.get("training_picked")
    if not trained and not ranked:
        return ""
    if trained and trained > 1:
        which = f"the {picked} of" if picked else "one of"
        return f" (1 seed: {which} {trained:.0f} trained)"
    return " (1 seed)"


def _md_label(board: Leaderboard, a: str, seeds: bool = False) -> str:
    """An agent's label with the marks of its rows (oracle, informed, local changes)."""
    mine = [r for r in board.rows if r.agent == a]
    text = a + marks(any(r.oracle for r in mine), any(r.informed for r in mine))
    if seeds:
        text += seeds_text((board.analysis.get("compute") or {}).get(a))
    return text + (DIRTY_MARK if any(r.dirty for r in mine) else "")


def _md_intro(board: Leaderboard, command: str | None) -> list[str]:
    """The title, what the tables say, the commands that made them and the facts of the sweep."""
    m0 = board.rank_by
    man = board.manifest or {}
    cfg = man.get("config", {})
    settle = cfg.get("settle_seconds")
    settle_s = f"{settle:g} s" if isinstance(settle, (int, float)) else "the settling time"
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
        "agents or scenarios are compared; over training seeds and episodes for an agent of "
        "several seeds)."
    )
    lines += ["", "Made by:", "", "```"]
    if man.get("command"):
        lines.append(man["command"])
    lines.append(command or f"sixaxis leaderboard {board.runs_dir}")
    lines += ["```", ""]
    lines += [f"- {f}" for f in _facts(board)]
    lines.append("")
    return lines


def _md_grid(
    board: Leaderboard,
    order: Sequence[str],
    title: str,
    metric: str,
    note: str = "",
    bold: bool = False,
) -> list[str]:
    """A table of agents (rows) by scenarios (columns) of a headline ``metric``'s cells."""
    lines = [title, ""]
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
            c = analysis_cell(board, r, metric)
            if r.failed:
                c += f" ({r.failed} failed)"
            cells.append(f"**{c}**" if r.best and bold else c)
        lines.append(f"| {_md_label(board, a, seeds=True)} | " + " | ".join(cells) + " |")
    lines.append("")
    return lines


def _md_aggregate(board: Leaderboard, order: Sequence[str]) -> list[str]:
    """Each agent against the reference, over every scenario (nothing without a reference)."""
    an, m0 = board.analysis, board.rank_by
    ref = an.get("reference")
    if not an.get("aggregate"):
        return []
    lines = [
        f"## Across scenarios, against `{ref}`",
        "",
        f"Each agent's `{m0}` over `{ref}`'s on the same episode, over every scenario and "
        "episode: the interquartile mean (IQM) of the ratios, as rliable recommends, and their "
        "geometric mean; 95 % percentile intervals of the stratified bootstrap (rliable's: "
        "each resample draws the episodes anew within each scenario, and for an agent of "
        "several training seeds first the seeds). Below 1: better than the reference.",
        "",
        "| agent | IQM of the ratios | geometric mean |",
        "|---|---:|---:|",
    ]
    for a in order:
        agg = an["aggregate"].get(a)
        if agg:
            lines.append(
                f"| {_md_label(board, a, seeds=True)} | {interval_text(agg['iqm'])} | "
                f"{interval_text(agg['geomean'])} |"
            )
    lines.append("")
    return lines


def _md_orderings(board: Leaderboard) -> list[str]:
    """Each scenario's ranking and every step of it with its paired interval."""
    an, m0 = board.analysis, board.rank_by
    lines = [
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
    return lines


def _md_cost(board: Leaderboard, order: Sequence[str]) -> list[str]:
    """What each scenario's hidden effect costs each agent (nothing without that analysis)."""
    cost = board.analysis.get("cost_of_effect") or {}
    if not cost:
        return []
    scen = [s for s in board.scenarios if s != "nominal"]
    lines = [
        f"## What the hidden effect costs each agent: `{board.rank_by}` against its own on "
        "`nominal`",
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
                f"| {_md_label(board, a)} | "
                + " | ".join(interval_text(cost[a].get(s)) for s in scen)
                + " |"
            )
    lines.append("")
    return lines


def _md_compute(board: Leaderboard, order: Sequence[str]) -> list[str]:
    """The compute budget of each agent (nothing without that analysis)."""
    comp = board.analysis.get("compute") or {}
    if not comp:
        return []
    lines = [
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
        wall = duration_text(c.get("training_wall_s"))
        seeds = (
            f"{c['training_seeds']:.0f} ({duration_text(c.get('training_wall_s_all_seeds'))})"
            if c.get("training_seeds")
            else "–"
        )
        points = f"{c['tracker_points']:.0f}" if c.get("tracker_points") is not None else "–"
        solve = number_text(c["solve_time_median_ms"]) if c.get("solve_time_median_ms") else "–"
        lines.append(f"| {_md_label(board, a)} | {steps} | {wall} | {seeds} | {points} | {solve} |")
    lines.append("")
    return lines


def _md_all_metrics(board: Leaderboard) -> list[str]:
    """Every metric of every row, long format, and what each metric is."""
    lines = ["## All metrics", ""]
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
    return lines


def _md_agents(board: Leaderboard) -> list[str]:
    """Each agent's name, settings and env overrides (nothing without the sweep's config)."""
    if not board.agent_settings:
        return []
    lines = [
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
    return lines


def _md_failed(board: Leaderboard) -> list[str]:
    """The failed runs and their errors (nothing when none failed)."""
    if not board.failed:
        return []
    lines = ["## Failed runs", ""]
    for rec in sorted(board.failed, key=lambda f: f["run_key"]):
        err = rec.get("error") or {}
        msg = str(err.get("message", "")).splitlines()[0][:200] if err.get("message") else ""
        lines.append(f"- `{rec['run_key']}`: {err.get('type', '?')}: {msg}")
    lines.append("")
    return lines


def duration_text(seconds: float | None) -> str:
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
