"""The leaderboard's two plots: each agent's tracking error over the episode, and its
``rank_by`` per episode with the mean and its interval. PNGs written atomically, without a
timestamp in their metadata, so that the same board draws the same bytes."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.leaderboard.build import Leaderboard, metric_value
from experiments.metrics import METRICS

__all__ = ["plot_error_over_time", "plot_strips"]


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
                    metric_value(r, m)
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


def _save(fig, path: str | Path) -> Path:
    """Write a PNG atomically (temp file + rename)."""
    from arm.files import atomic_path

    p = Path(path)
    with atomic_path(p) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    return p
