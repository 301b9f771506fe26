"""benchmarks/mpc_diagnose.py: one episode of its table runs with the agent as it is now (its
settings moved into ``agent.settings`` and the script read them from the agent, so ``make bench``
stopped at its first mpc-diagnose episode while no test ran it)."""

from __future__ import annotations

import pytest

from benchmarks.mpc_diagnose import episode


def test_an_episode_of_the_benchmark_gives_every_column_its_table_reads():
    out = episode("mpc-diagnose", "cyclic", 0, {})
    assert out["lag_s"] == pytest.approx(25 * 0.02) and out["selection_lag_s"] == pytest.approx(0.1)
    assert out["effects"][0] == "geometric" and out["settled"] > 0 and out["whole"] > 0
    assert {"cost_s", "late", "selection_jobs", "solve_median_ms", "solve_p95_ms"} <= set(out)
