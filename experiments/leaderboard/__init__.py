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

One job per module: :mod:`~experiments.leaderboard.build` reads the records and summarises them
(:class:`Leaderboard`); :mod:`~experiments.leaderboard.writers` writes its tables and JSON, with
the cell formatting that the README's section and the command line share;
:mod:`~experiments.leaderboard.plots` draws the PNGs; :mod:`~experiments.leaderboard.readme`
writes the README's section from the JSON. This package gathers their public names.
"""

from __future__ import annotations

from experiments.leaderboard.build import (
    DIRTY_MARK,
    HEADLINE,
    INFORMED_MARK,
    ORACLE_MARK,
    Leaderboard,
    Row,
    build_leaderboard,
    is_clean,
    is_informed,
    is_oracle,
    marks,
)
from experiments.leaderboard.plots import plot_error_over_time, plot_strips
from experiments.leaderboard.readme import README_BEGIN, README_END, readme_block, update_readme
from experiments.leaderboard.writers import (
    CSV_NAME,
    JSON_NAME,
    MD_NAME,
    PAIRS_CSV_NAME,
    PLOT_STRIPS,
    PLOT_TIME,
    RUNS_CSV_NAME,
    analysis_cell,
    cell_text,
    interval_text,
    ordering_text,
    pairs_csv,
    runs_csv,
    spread_words,
    to_csv,
    to_json,
    to_markdown,
    write_leaderboard,
)

__all__ = [
    "CSV_NAME",
    "DIRTY_MARK",
    "HEADLINE",
    "INFORMED_MARK",
    "JSON_NAME",
    "MD_NAME",
    "ORACLE_MARK",
    "PAIRS_CSV_NAME",
    "PLOT_STRIPS",
    "PLOT_TIME",
    "README_BEGIN",
    "README_END",
    "RUNS_CSV_NAME",
    "Leaderboard",
    "Row",
    "analysis_cell",
    "build_leaderboard",
    "cell_text",
    "interval_text",
    "is_clean",
    "is_informed",
    "is_oracle",
    "marks",
    "ordering_text",
    "pairs_csv",
    "plot_error_over_time",
    "plot_strips",
    "readme_block",
    "runs_csv",
    "spread_words",
    "to_csv",
    "to_json",
    "to_markdown",
    "update_readme",
    "write_leaderboard",
]
