"""The leaderboard from run records (mean and Student-t CI over seeds, best marked, the command
that made it, the plots), and the ``sixaxis leaderboard`` / ``sixaxis reproduce`` commands on a
real record."""

from __future__ import annotations

import csv
import io
import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from experiments.cli import app
from experiments.config import parse_config
from experiments.leaderboard import build_leaderboard, to_csv, to_markdown, write_leaderboard
from experiments.records import RunStore, load_record
from experiments.sweep import run_sweep
from tests.test_experiments_sweep import fake_run

T975_2DOF = 4.302653  # Student t, 97.5 % quantile, 2 degrees of freedom (tables)


def fake_config(**changes):
    raw = {
        "name": "board",
        "seeds": [0, 1, 2],
        "episode_seconds": 1.0,
        "metrics": ["rms_mm", "max_mm", "solve_time_median_ms"],
        "scenarios": ["nominal", "geometric"],
        "agents": ["hold", "nominal", "calibrated"],
    } | changes
    return parse_config(raw, source="board.toml", check_agents=False)


@pytest.fixture
def runs(tmp_path):
    cfg = fake_config(seeds=[0, 1, 2, 13])  # seed 13 fails in fake_run
    run_sweep(
        cfg, tmp_path / "runs", workers=0, run_fn=fake_run, command="sixaxis sweep board.toml"
    )
    return cfg, tmp_path / "runs"


def rows(text: str) -> list[dict]:
    return list(csv.DictReader(io.StringIO(text)))


def test_csv_has_mean_ci_and_n_per_agent_and_scenario(runs):
    _, path = runs
    board = build_leaderboard(path)
    table = rows(to_csv(board))
    assert len(table) == 6
    assert {"agent", "scenario", "n", "rms_mm_mean", "rms_mm_ci95", "rms_mm_n", "best"} <= set(
        table[0]
    )
    store = RunStore(path)
    for row in table:
        vals = np.array(
            [
                store.load(f"{row['agent']}__{row['scenario']}__seed{s}")["metrics"]["rms_mm"]
                for s in (0, 1, 2)
            ]
        )
        assert row["n"] == "3" and row["failed"] == "1"
        assert float(row["rms_mm_mean"]) == pytest.approx(vals.mean(), rel=1e-12)
        assert float(row["rms_mm_ci95"]) == pytest.approx(
            T975_2DOF * vals.std(ddof=1) / math.sqrt(3), rel=1e-6
        )
        assert float(row["solve_time_median_ms_mean"]) >= 0  # timing metrics are summarised too


def test_best_per_scenario_is_the_lowest_mean_and_marked(runs):
    _, path = runs
    board = build_leaderboard(path)
    table = rows(to_csv(board))
    md = to_markdown(board)
    for scen in ("nominal", "geometric"):
        mine = [r for r in table if r["scenario"] == scen]
        best = min(mine, key=lambda r: float(r["rms_mm_mean"]))
        assert [r["agent"] for r in mine if r["best"] == "1"] == [best["agent"]]
        cell = f"{float(best['rms_mm_mean']):.3g}"[:3]
        assert any(
            f"**{cell}" in line
            for line in md.splitlines()
            if line.startswith(f"| {best['agent']} |")
        )


def test_markdown_states_the_commands_config_and_failures(runs):
    cfg, path = runs
    md = to_markdown(build_leaderboard(path), command="sixaxis leaderboard runs/board")
    assert "sixaxis sweep board.toml\nsixaxis leaderboard runs/board" in md
    assert f"hash `{cfg.hash}`" in md and "config `board`" in md
    assert "24 runs (6 failed), seeds 0-2" in md  # 3 agents x 2 scenarios x 4 seeds; 13 fails
    assert "`hold__nominal__seed13`: RuntimeError: deliberate failure" in md
    assert "| agent | nominal | geometric |" in md


def test_records_of_another_config_are_ignored(runs, tmp_path):
    _, path = runs
    other = fake_config(name="other", episode_seconds=2.0)
    run_sweep(other, tmp_path / "other", workers=0, run_fn=fake_run)
    stray = load_record(tmp_path / "other" / "hold__nominal__seed0.json")
    stray["run_key"] = "hold__nominal__seed7"
    RunStore(path).write(stray)
    board = build_leaderboard(path)
    assert board.ignored == 1
    assert rows(to_csv(board))[0]["n"] == "3"


def test_write_leaderboard_makes_the_files_and_plots(runs, tmp_path):
    _, path = runs
    out = tmp_path / "results"
    paths = write_leaderboard(build_leaderboard(path), out, command="sixaxis leaderboard x")
    assert {p.name for p in out.iterdir()} == {
        "leaderboard.md",
        "leaderboard.csv",
        "leaderboard_error_over_time.png",
        "leaderboard_by_scenario.png",
    }
    for key in ("error_over_time", "by_scenario"):
        data = paths[key].read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    assert (
        "![leaderboard_by_scenario](leaderboard_by_scenario.png)" in paths["markdown"].read_text()
    )


# -- the commands on a real record ----------------------------------------------------------------


@pytest.fixture(scope="module")
def real_record(tmp_path_factory):
    root = tmp_path_factory.mktemp("real")
    cfg = parse_config(
        {
            "name": "real",
            "seeds": [3],
            "episode_seconds": 1.0,
            "settle_seconds": 0.5,
            "metrics": ["rms_mm", "rms_settled_mm", "calib_rms_mm", "calib_params", "effort_rms"],
            "scenarios": ["geometric"],
            "agents": [{"name": "calibrated", "settings": {"calibration_seconds": 0.6}}, "hold"],
            "env": {"trajectory": "lemniscate", "measure_every": 1},
        },
        source="real.toml",
    )
    summary = run_sweep(cfg, root / "runs", workers=0)
    assert not summary.failed
    return root / "runs"


def test_reproduce_reruns_a_record_and_gets_the_same_numbers(real_record):
    rec = load_record(real_record / "calibrated__geometric__seed3.json")
    assert rec["metrics"]["calib_params"] > 0  # it did identify something
    assert rec["metrics"]["calib_rms_mm"] is not None
    res = CliRunner().invoke(
        app, ["reproduce", str(real_record / "calibrated__geometric__seed3.json")]
    )
    assert res.exit_code == 0, res.output
    assert "reproduced" in res.output and "DIFFERS" not in res.output


def test_reproduce_reports_a_difference(real_record, tmp_path):
    rec = json.loads((real_record / "hold__geometric__seed3.json").read_text())
    rec["metrics"]["rms_mm"] *= 1.001
    bad = tmp_path / "tampered.json"
    bad.write_text(json.dumps(rec))
    res = CliRunner().invoke(app, ["reproduce", str(bad)])
    assert res.exit_code == 1
    assert "rms_mm" in res.output and "DIFFERS" in res.output


def test_leaderboard_command_writes_results(real_record, tmp_path):
    res = CliRunner().invoke(app, ["leaderboard", str(real_record), "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "calibrated" in res.output and "hold" in res.output
    md = (tmp_path / "leaderboard.md").read_text()
    assert f"leaderboard {real_record} --out {tmp_path}" in md
    assert rows((tmp_path / "leaderboard.csv").read_text())[0]["agent"] == "calibrated"


def test_leaderboard_of_a_missing_directory_is_a_clear_error(tmp_path):
    res = CliRunner().invoke(app, ["leaderboard", str(tmp_path / "nope")])
    assert res.exit_code == 2
    assert "no such runs directory" in res.output
