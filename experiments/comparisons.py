"""The paired analysis behind the leaderboard: every agent on every scenario episode by episode,
as plain data (``results/leaderboard.json``) from which the tables, the plots and the README's
leaderboard section are all written.

    analysis = analyse(records, agents, scenarios, rank_by="rms_settled_mm", reference="feedforward")

What it holds (:mod:`experiments.statistics` computes every interval):

- ``cells``: per agent, scenario and metric, the geometric mean over episodes (``value``) with its
  bootstrap interval, and the arithmetic mean (``mean``).
- ``ranking``: per scenario, the agents by their geometric mean ``rank_by`` (lowest first; the
  ratio of two is their paired ratio, so the ranking and the orderings agree), and ``best``,
  the best *contender*: an agent neither given the truth (oracle) nor told the scenario's effects
  (informed).
- ``orderings``: per scenario, each agent against the next one in that ranking: the paired ratio
  (the geometric mean of the per-episode ratios) with its interval, and whether it is resolved.
  ``pairs`` holds the same for every two agents.
- ``aggregate``: per agent, against the reference agent across every scenario: the IQM and the
  geometric mean of the per-episode ratios, with intervals; the agents are listed by the IQM.
- ``cost_of_effect``: per agent and scenario, its ``rank_by`` there against its own on the
  ``nominal`` scenario, episode by episode (the same seeds): what the hidden effect costs it.
- ``compute``: per agent, the training budget of a learned policy (steps and wall time of the
  shipped run, seeds trained, which seed was shipped: ``best``/``median`` as its file says), the
  training seeds it is ranked over (``ranked_seeds``: empty for one network), the tracker points
  it used per episode, its solve time.

An agent labelled ``<agent>@s<seed>`` in a sweep (``ppo@s3``) is that agent's network of one
training seed: its runs are ranked as ``<agent>``, over all its seeds (the stratified bootstrap of
:mod:`experiments.statistics`), and stay one row each in the runs CSV.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from experiments.config import split_train_seed
from experiments.metrics import METRICS
from experiments.statistics import (
    Interval,
    aggregate_over_seeds,
    paired_ratio,
    seeded_geometric_mean_interval,
    seeded_paired_ratio,
)

__all__ = ["NOMINAL", "analyse", "episode_key", "ranked_agent"]

#: the training seed key of an agent of one network (not learned, or one seed unnamed)
ONE = -1

#: {training seed: {episode: value}}: an agent's metric on one scenario
BySeed = dict[int, dict[int, float]]

#: the scenario without hidden effects, against which an effect's cost is measured
NOMINAL = "nominal"


def episode_key(rec: Mapping[str, Any]) -> int:
    """The episode a record is (its index among drawn seeds, else its seed): what pairs runs."""
    spec = rec["spec"]
    return int(spec["episode"]) if spec.get("episode") is not None else int(spec["seed"])


def ranked_agent(rec: Mapping[str, Any]) -> tuple[str, int | None]:
    """The agent a record ranks as and its training seed (``ppo@s3``: ``ppo``, 3)."""
    return split_train_seed(str(rec["spec"]["agent_label"]))


def _value(rec: Mapping[str, Any], metric: str) -> float:
    src = rec.get("timing", {}) if METRICS[metric].timing else rec.get("metrics", {})
    v = src.get(metric)
    return math.nan if v is None else float(v)


def _interval(iv: Interval) -> dict[str, float | int | None]:
    def num(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {"value": num(iv.value), "lo": num(iv.lo), "hi": num(iv.hi), "n": iv.n}


class _Runs:
    """The successful runs by agent (over its training seeds) and scenario, each cell's runs by
    training seed and episode."""

    def __init__(self, records: Iterable[Mapping[str, Any]]) -> None:
        self.by_cell: dict[tuple[str, str], dict[int, dict[int, Mapping[str, Any]]]] = {}
        for rec in records:
            agent, seed = ranked_agent(rec)
            cell = self.by_cell.setdefault((agent, rec["spec"]["scenario_label"]), {})
            cell.setdefault(ONE if seed is None else seed, {})[episode_key(rec)] = rec

    def series(self, agent: str, scenario: str, metric: str) -> BySeed:
        """A metric of a cell, by training seed and episode."""
        cell = self.by_cell.get((agent, scenario), {})
        return {sd: {k: _value(r, metric) for k, r in eps.items()} for sd, eps in cell.items()}

    def seeds(self, agent: str) -> list[int]:
        """The training seeds an agent ran with (``[ONE]``: one network)."""
        return sorted({sd for (a, _), cell in self.by_cell.items() if a == agent for sd in cell})

    def records(self, agent: str, scenario: str) -> list[Mapping[str, Any]]:
        cell = self.by_cell.get((agent, scenario), {})
        return [r for eps in cell.values() for r in eps.values()]


def analyse(
    records: Iterable[Mapping[str, Any]],
    agents: Sequence[str],
    scenarios: Sequence[str],
    metrics: Sequence[str],
    rank_by: str,
    reference: str | None,
    oracles: Iterable[str] = (),
    informed: Iterable[str] = (),
) -> dict[str, Any]:
    """The analysis (see the module docstring) of the successful runs ``records``: the comparisons
    of the module docstring, in order."""
    oracles, informed = set(oracles), set(informed)
    runs = _Runs(records)
    cells = _cells(runs, agents, scenarios, metrics)
    ranking, best, orderings, pairs = _orderings(
        runs, cells, agents, scenarios, rank_by, oracles | informed
    )
    aggregate = _aggregate(runs, cells, agents, scenarios, rank_by, reference)
    order = sorted(aggregate, key=lambda a: aggregate[a]["iqm"]["value"] or math.inf) + [
        a for a in agents if a in cells and a not in aggregate
    ]
    return {
        "rank_by": rank_by,
        "reference": reference if reference in aggregate else None,
        "agents": list(agents),
        "scenarios": list(scenarios),
        "oracles": sorted(oracles),
        "informed": sorted(informed),
        "order": order,
        "cells": cells,
        "ranking": ranking,
        "best": best,
        "orderings": orderings,
        "pairs": pairs,
        "aggregate": aggregate,
        "cost_of_effect": _cost_of_effect(runs, cells, agents, scenarios, rank_by),
        "compute": _compute(runs, agents, scenarios),
    }


def _cells(
    runs: _Runs, agents: Sequence[str], scenarios: Sequence[str], metrics: Sequence[str]
) -> dict[str, dict[str, dict[str, Any]]]:
    """Each cell's metrics: the geometric mean over episodes with its interval (see
    experiments.statistics) and the plain mean; a count's total."""
    cells: dict[str, dict[str, dict[str, Any]]] = {}
    for a in agents:
        for s in scenarios:
            if (a, s) not in runs.by_cell:
                continue
            row = cells.setdefault(a, {}).setdefault(s, {})
            for m in metrics:
                by_seed = runs.series(a, s, m)
                values = [v for eps in by_seed.values() for v in eps.values()]
                finite = [v for v in values if math.isfinite(v)]
                if METRICS[m].aggregate == "sum":
                    row[m] = {"total": float(sum(finite)), "n": len(finite)}
                else:
                    row[m] = _interval(seeded_geometric_mean_interval(by_seed)) | {
                        "mean": float(np.mean(finite)) if finite else None
                    }
    return cells


def _orderings(
    runs: _Runs,
    cells: Mapping[str, Mapping[str, Mapping[str, Any]]],
    agents: Sequence[str],
    scenarios: Sequence[str],
    rank_by: str,
    not_contending: set[str],
) -> tuple[dict[str, list[str]], dict[str, str | None], dict[str, list[Any]], list[Any]]:
    """Each scenario's ranking, its best contender, every pair's paired ratio and the steps of
    the ranking among them."""

    def mean_of(a: str, s: str) -> float:
        v = (cells.get(a, {}).get(s, {}).get(rank_by) or {}).get("value")
        return math.inf if v is None else float(v)

    ranking: dict[str, list[str]] = {}
    best: dict[str, str | None] = {}
    orderings: dict[str, list[Any]] = {}
    pairs: list[Any] = []
    for s in scenarios:
        ranked = sorted((a for a in agents if s in cells.get(a, {})), key=lambda a: mean_of(a, s))
        ranked = [a for a in ranked if math.isfinite(mean_of(a, s))]
        ranking[s] = ranked
        contenders = [a for a in ranked if a not in not_contending]
        best[s] = contenders[0] if contenders else None
        for i, better in enumerate(ranked):
            for worse in ranked[i + 1 :]:
                r = seeded_paired_ratio(
                    runs.series(better, s, rank_by), runs.series(worse, s, rank_by)
                )
                pairs.append(
                    {"scenario": s, "better": better, "worse": worse}
                    | _interval(r)
                    | {"resolved": r.below_one}
                )
        orderings[s] = [
            next(p for p in pairs if p["scenario"] == s and p["better"] == b and p["worse"] == w)
            for b, w in itertools.pairwise(ranked)
        ]
    return ranking, best, orderings, pairs


def _aggregate(
    runs: _Runs,
    cells: Mapping[str, Mapping[str, Any]],
    agents: Sequence[str],
    scenarios: Sequence[str],
    rank_by: str,
    reference: str | None,
) -> dict[str, dict[str, Any]]:
    """Each agent against the reference over every scenario (an agent missing a scenario is not
    aggregated)."""
    aggregate: dict[str, dict[str, Any]] = {}
    if reference is None or reference not in cells:
        return aggregate
    ref = {
        s: _over_seeds(runs.series(reference, s, rank_by))
        for s in scenarios
        if s in cells[reference]
    }
    for a in agents:
        if a not in cells:
            continue
        mine = {s: runs.series(a, s, rank_by) for s in ref if s in cells[a]}
        if set(mine) != set(ref):
            continue
        by_seed = {sd: {s: mine[s].get(sd, {}) for s in mine} for sd in runs.seeds(a)}
        agg = aggregate_over_seeds(by_seed, ref)
        aggregate[a] = {k: _interval(v) for k, v in agg.items()}
    return aggregate


def _over_seeds(by_seed: BySeed) -> dict[int, float]:
    """A reference's value per episode: its one network's, or the geometric mean over its
    training seeds (a reference is not resampled over seeds)."""
    if len(by_seed) == 1:
        return next(iter(by_seed.values()))
    keys = set.intersection(*(set(eps) for eps in by_seed.values()))
    return {k: float(np.exp(np.mean([np.log(eps[k]) for eps in by_seed.values()]))) for k in keys}


def _cost(a: BySeed, base: BySeed) -> Interval:
    """An agent on a scenario against itself on ``nominal``, seed by seed and episode by
    episode: one network's paired ratio, or over several seeds the stratified bootstrap of the
    per-seed, per-episode ratios."""
    if len(a) == 1 and len(base) == 1:
        return paired_ratio(next(iter(a.values())), next(iter(base.values())))
    ratios = {
        sd: {k: v / base[sd][k] for k, v in eps.items() if k in base.get(sd, {})}
        for sd, eps in a.items()
        if sd in base
    }
    return seeded_geometric_mean_interval(ratios)


def _cost_of_effect(
    runs: _Runs,
    cells: Mapping[str, Mapping[str, Any]],
    agents: Sequence[str],
    scenarios: Sequence[str],
    rank_by: str,
) -> dict[str, dict[str, Any]]:
    """Each agent on each scenario against itself on ``nominal``, episode by episode."""
    cost: dict[str, dict[str, Any]] = {}
    if NOMINAL not in scenarios:
        return cost
    for a in agents:
        if NOMINAL not in cells.get(a, {}):
            continue
        base = runs.series(a, NOMINAL, rank_by)
        cost[a] = {
            s: _interval(_cost(runs.series(a, s, rank_by), base))
            for s in scenarios
            if s != NOMINAL and s in cells[a]
        }
    return cost


def _compute(
    runs: _Runs, agents: Sequence[str], scenarios: Sequence[str]
) -> dict[str, dict[str, Any]]:
    """Each agent's compute budget: its training (from its report: steps, wall time, seeds
    trained, which of them was shipped), the training seeds it is ranked over, and its runs'
    tracker points and solve times."""
    compute: dict[str, dict[str, Any]] = {}
    for a in agents:
        recs = [r for s in scenarios for r in runs.records(a, s)]
        if not recs:
            continue
        report = recs[0].get("report") or {}
        points = [_value(r, "tracker_points") for r in recs if "tracker_points" in METRICS]
        solve = [_value(r, "solve_time_median_ms") for r in recs]
        compute[a] = {
            "training_steps": _num(report.get("training_steps")),
            "training_wall_s": _num(report.get("training_wall_s")),
            "training_seeds": _num(report.get("training_seeds")),
            "training_wall_s_all_seeds": _num(report.get("training_wall_s_all_seeds")),
            "training_picked": report.get("training_picked")
            if isinstance(report.get("training_picked"), str)
            else None,
            "ranked_seeds": [sd for sd in runs.seeds(a) if sd != ONE],
            "tracker_points": _mean(points),
            "solve_time_median_ms": _median(solve),
        }
    return compute


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def _mean(values: Sequence[float]) -> float | None:
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.mean(x)) if x.size else None


def _median(values: Sequence[float]) -> float | None:
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else None
