"""The leaderboard's build: the run records of a sweep directory summarised per agent and
scenario, with the paired analysis (:mod:`experiments.comparisons`). Its files are written by
:mod:`experiments.leaderboard.writers`, :mod:`~experiments.leaderboard.plots` and
:mod:`~experiments.leaderboard.readme`."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from arm.files import is_dir
from experiments.config import split_train_seed
from experiments.metrics import METRICS, Summary, summarize
from experiments.records import RecordError, RunStore

__all__ = [
    "DIRTY_MARK",
    "HEADLINE",
    "INFORMED_MARK",
    "ORACLE_MARK",
    "Leaderboard",
    "Row",
    "build_leaderboard",
    "episode_order",
    "is_clean",
    "is_informed",
    "is_oracle",
    "marks",
    "metric_value",
]

log = logging.getLogger(__name__)

#: the metrics shown with intervals: the settled RMS (the ranking), the start-up, the whole episode
HEADLINE = ("rms_settled_mm", "rms_startup_mm", "rms_mm")
ORACLE_MARK = " (oracle)"
INFORMED_MARK = " (informed)"
DIRTY_MARK = " (local changes)"


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
    #: the training seeds it is over (1: one network, or an agent that is not learned)
    seeds: int = 1

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
    """Read every record of a sweep directory and summarise it over seeds. Runs labelled
    ``<agent>@s<training seed>`` are one agent's networks: its rows are over all of them.

    With the sweep's manifest (``_sweep.json``) present, only the runs of its config count (records
    left from an older config in the same directory are ignored, with a warning), and agents and
    scenarios keep the config's order.

    Records made from a tree with local changes, or outside a git checkout, are refused
    (:class:`RecordError` naming them) unless ``allow_dirty``; then their rows are marked.
    ``reference``: the agent the aggregates are taken against (default ``feedforward`` when it
    ran, else none)."""
    store = RunStore(runs_dir)
    if not is_dir(store.root):
        raise RecordError(f"{store.root}: no such runs directory")
    manifest = store.manifest()
    records, failed, ignored = _read_records(store, manifest, runs_dir)
    if not allow_dirty:
        _refuse_unclean(store, records + failed)

    cfg = (manifest or {}).get("config", {})
    all_recs = records + failed
    labels = [a["label"] for a in cfg.get("agents", [])] or _ordered(
        r["spec"]["agent_label"] for r in all_recs
    )
    _refuse_one_network_beside_seeds(store, labels)
    agents = _ordered(split_train_seed(a)[0] for a in labels)
    scenarios = [s["label"] for s in cfg.get("scenarios", [])] or _ordered(
        r["spec"]["scenario_label"] for r in all_recs
    )
    metrics = list(cfg.get("metrics") or _ordered(m for r in records for m in r["metrics"]))
    metrics += _ordered(m for r in records for m in r.get("timing", {}) if m in METRICS)
    metrics = [m for m in _ordered(metrics) if m in METRICS]
    rank_by = rank_by or cfg.get("rank_by", "rms_mm")
    if rank_by not in metrics:
        raise RecordError(f"{runs_dir}: no metric {rank_by!r} in the records (have {metrics})")
    settings: dict[str, dict[str, Any]] = {}
    for a in cfg.get("agents", []):
        settings.setdefault(
            split_train_seed(a["label"])[0],
            {"name": a["name"], "settings": a.get("settings", {}), "env": a.get("env", {})},
        )
    rows = _rows(records, failed, agents, scenarios, metrics, rank_by)
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


def _read_records(
    store: RunStore, manifest: dict[str, Any] | None, runs_dir: str | Path
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], int]:
    """The finished and the failed records of the sweep's config, and how many others were
    ignored (left from an older config in the same directory)."""
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
    return records, failed, ignored


def _refuse_unclean(store: RunStore, records: list[dict[str, Any]]) -> None:
    """Refuse records made from a tree with local changes or outside a git checkout."""
    unclean = sorted(r["run_key"] for r in records if not is_clean(r))
    if unclean:
        shown = ", ".join(unclean[:5]) + (
            f" and {len(unclean) - 5} more" if len(unclean) > 5 else ""
        )
        raise RecordError(
            f"{store.root}: {len(unclean)} record(s) were made from a tree with local changes or "
            f"outside a git checkout ({shown}); no commit reproduces them. Commit and rerun the "
            "sweep, or pass --allow-dirty (allow_dirty=True) to mark them in the table"
        )


def _refuse_one_network_beside_seeds(store: RunStore, labels: list[str]) -> None:
    """Refuse an agent that is both one network (``ppo``) and trained seeds (``ppo@s1``): the
    leaderboard could not tell which of them its row ranks."""
    seeded = {split_train_seed(a)[0] for a in labels if split_train_seed(a)[1] is not None}
    both = sorted(seeded & set(labels))
    if both:
        raise RecordError(
            f"{store.root}: agent {both[0]!r} ran both as one network (label {both[0]!r}) and "
            f"over training seeds ({both[0]}@s<seed>); the leaderboard ranks an agent over its "
            f"seeds: label the one network otherwise (e.g. {both[0]}-shipped) or drop it"
        )


def _rows(
    records: list[dict[str, Any]],
    failed: list[dict[str, Any]],
    agents: list[str],
    scenarios: list[str],
    metrics: list[str],
    rank_by: str,
) -> list[Row]:
    """One row per agent and scenario that ran: its metrics summarised over its episodes."""

    def cell(recs: list[dict[str, Any]], agent: str, scen: str) -> list[dict[str, Any]]:
        return [
            r
            for r in recs
            if split_train_seed(r["spec"]["agent_label"])[0] == agent
            and r["spec"]["scenario_label"] == scen
        ]

    rows: list[Row] = []
    for agent in agents:
        for scen in scenarios:
            mine = sorted(cell(records, agent, scen), key=episode_order)
            theirs = cell(failed, agent, scen)
            if not mine and not theirs:
                continue
            stats = {m: _summary(mine, m, interval=m in (rank_by, *HEADLINE)) for m in metrics}
            everyone = mine + theirs
            rows.append(
                Row(
                    agent,
                    scen,
                    len(mine),
                    len(theirs),
                    stats,
                    oracle=any(is_oracle(r) for r in everyone),
                    dirty=sum(not is_clean(r) for r in everyone),
                    informed=any(is_informed(r) for r in everyone),
                    seeds=max(
                        1, len({split_train_seed(r["spec"]["agent_label"])[1] for r in mine})
                    ),
                )
            )
    return rows


def _summary(mine: list[dict[str, Any]], metric: str, interval: bool) -> Summary:
    """A metric of a cell's runs: over its episodes, and for an agent of several training seeds
    with the interval of the stratified bootstrap over seeds and episodes."""
    s = summarize((metric_value(r, metric) for r in mine), interval=interval)
    by_seed: dict[int | None, dict[int, float]] = {}
    for r in mine:
        seed = split_train_seed(r["spec"]["agent_label"])[1]
        by_seed.setdefault(seed, {})[episode_order(r)] = metric_value(r, metric)
    if not interval or len(by_seed) < 2 or not s.has_ci:
        return s
    from experiments.statistics import seeded_mean_interval

    ci = seeded_mean_interval(by_seed)
    return dataclasses.replace(s, ci95=(ci.hi - ci.lo) / 2, lo=ci.lo, hi=ci.hi)


def episode_order(rec: dict[str, Any]) -> int:
    """A record's place among its cell's: its episode index (drawn seeds), else its seed."""
    spec = rec["spec"]
    return int(spec["episode"]) if spec.get("episode") is not None else int(spec["seed"])


def _ordered(items: Iterable[Any]) -> list[Any]:
    seen: dict = {}
    for x in items:
        seen.setdefault(x, None)
    return list(seen)


def metric_value(rec: dict[str, Any], metric: str) -> float:
    src = rec.get("timing", {}) if METRICS[metric].timing else rec.get("metrics", {})
    v = src.get(metric)
    return float("nan") if v is None else float(v)
