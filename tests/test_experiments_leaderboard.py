"""The leaderboard from run records (mean and bootstrap interval over episodes, the best
contender marked, the command that made it, the plots, the JSON), and the ``sixaxis
leaderboard`` / ``sixaxis reproduce`` commands on a real record."""

from __future__ import annotations

import csv
import io
import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from experiments.cli import app
from experiments.config import parse_config
from experiments.leaderboard import (
    build_leaderboard,
    runs_csv,
    to_csv,
    to_markdown,
    write_leaderboard,
)
from experiments.records import RecordError, RunStore, environment_info, load_record
from experiments.sweep import run_sweep
from tests.test_experiments_sweep import fake_run

CLEAN = {"commit": "c0ffee" * 6 + "c0ff", "dirty": False}


def with_git(git: dict):
    """The environment a record states, with the given git state: the records of these tests must
    not depend on whether the checkout running them has local changes."""
    env = dict(environment_info())
    return lambda: env | {"git": dict(git)}


@pytest.fixture(autouse=True)
def clean_tree(monkeypatch):
    monkeypatch.setattr("experiments.sweep.environment_info", with_git(CLEAN))


def fake_config(**changes):
    raw = {
        "name": "board",
        "seeds": [0, 1, 2],
        "episode_seconds": 1.0,
        "settle_seconds": 0.5,
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


def test_csv_has_mean_interval_and_n_per_agent_and_scenario(runs):
    from experiments.statistics import mean_interval

    _, path = runs
    board = build_leaderboard(path)
    table = rows(to_csv(board))
    assert len(table) == 6
    assert {"agent", "scenario", "n", "rms_mm_mean", "rms_mm_lo", "rms_mm_hi", "best"} <= set(
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
        ci = mean_interval(vals)  # the bootstrap interval: inside the values' range, above 0
        assert (float(row["rms_mm_lo"]), float(row["rms_mm_hi"])) == (ci.lo, ci.hi)
        assert 0 < vals.min() <= ci.lo <= vals.mean() <= ci.hi <= vals.max()
        assert float(row["solve_time_median_ms_mean"]) >= 0  # timing metrics are summarised too


def test_the_ranking_is_by_geometric_mean_and_agrees_with_the_paired_orderings(runs):
    _, path = runs
    board = build_leaderboard(path)
    table = rows(to_csv(board))
    md = to_markdown(board)
    store = RunStore(path)
    an = board.analysis
    for scen in ("nominal", "geometric"):
        geo = {
            a: float(
                np.exp(
                    np.mean(
                        [
                            np.log(store.load(f"{a}__{scen}__seed{s}")["metrics"]["rms_mm"])
                            for s in (0, 1, 2)
                        ]
                    )
                )
            )
            for a in ("hold", "nominal", "calibrated")
        }
        best = min(geo, key=geo.__getitem__)
        assert an["ranking"][scen] == sorted(geo, key=geo.__getitem__)
        assert [r["agent"] for r in table if r["scenario"] == scen and r["best"] == "1"] == [best]
        assert any(
            f"**{geo[best]:.3g}"[:5] in line
            for line in md.splitlines()
            if line.startswith(f"| {best} |")
        )
        # the ratio of two cells is their paired ratio: the orderings follow the ranking
        for o in an["orderings"][scen]:
            assert o["value"] == pytest.approx(geo[o["better"]] / geo[o["worse"]], rel=1e-12)
            assert o["value"] <= 1


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
    other = fake_config(name="other", seeds=[7], episode_seconds=2.0)
    run_sweep(other, tmp_path / "other", workers=0, run_fn=fake_run)
    stray = load_record(tmp_path / "other" / "hold__nominal__seed7.json")  # not a run of path's
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
        "leaderboard.json",
        "leaderboard.csv",
        "leaderboard_runs.csv",
        "leaderboard_pairs.csv",
        "leaderboard_error_over_time.png",
        "leaderboard_strips.png",
    }
    for key in ("error_over_time", "strips"):
        data = paths[key].read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    assert "![leaderboard_strips](leaderboard_strips.png)" in paths["markdown"].read_text()
    data = json.loads(paths["json"].read_text())
    assert data["rank_by"] == "rms_mm" and data["scenarios"] == ["nominal", "geometric"]
    assert len(data["pairs"]) == 2 * 3  # every two of three agents, per scenario


# -- the commands on a real record ----------------------------------------------------------------


@pytest.fixture(scope="module")
def real_record(tmp_path_factory):
    root = tmp_path_factory.mktemp("real")
    patch = pytest.MonkeyPatch()
    patch.setattr("experiments.sweep.environment_info", with_git(CLEAN))
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
    try:
        summary = run_sweep(cfg, root / "runs", workers=0)
    finally:
        patch.undo()
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


def test_fewer_than_three_seeds_show_the_range_not_a_t_interval(tmp_path):
    run_sweep(fake_config(seeds=[0, 1]), tmp_path, workers=0, run_fn=fake_run)
    board = build_leaderboard(tmp_path)
    md = to_markdown(board)
    store = RunStore(tmp_path)
    vals = [store.load(f"nominal__geometric__seed{s}")["metrics"]["rms_mm"] for s in (0, 1)]
    lo, hi = sorted(vals)
    assert "±" not in md and "minimum–maximum" in md
    row = next(ln for ln in md.splitlines() if ln.startswith("| nominal | geometric |"))
    assert f"({lo:.3g}–" in row and f"–{hi:.3g})" in row.replace(f"{hi:.3f}", f"{hi:.3g}")
    line = next(
        r for r in rows(to_csv(board)) if r["agent"] == "nominal" and r["scenario"] == "geometric"
    )
    assert line["rms_mm_ci95"] == ""  # no interval from two values
    assert float(line["rms_mm_min"]) == lo and float(line["rms_mm_max"]) == hi


def converging_run(spec):
    """``calibrated`` converges in 1-2 s, ``nominal`` only in seed 0, ``hold`` never; and
    ``calibrated`` says it is an oracle."""
    conv = {"calibrated": 1.0 + 0.5 * spec.seed, "nominal": 2.0 if spec.seed == 0 else None}
    c = conv.get(spec.agent_label)
    return {
        "oracle": spec.agent_label == "calibrated",
        "metrics": {
            "rms_mm": 1.0 + spec.seed,
            "rms_settled_mm": 0.5 + spec.seed,
            "converge_s": c,
            "never_converged": 0.0 if c is not None else 1.0,
        },
    }


def test_convergence_never_reached_is_marked_not_zero_and_oracles_are_marked(tmp_path):
    cfg = fake_config(metrics=["rms_mm", "rms_settled_mm", "converge_s"])
    assert cfg.metrics[-1] == "never_converged"
    run_sweep(cfg, tmp_path, workers=0, run_fn=converging_run)
    board = build_leaderboard(tmp_path)
    md = to_markdown(board)
    long = {
        (ln.split("|")[1].strip(" *"), ln.split("|")[2].strip()): ln
        for ln in md[md.index("## All metrics") :].splitlines()
        if ln.startswith("| ") and ln.count("|") > 5
    }
    # converge_s: no number and no zero where the error never converged, the count instead
    assert "| never (3/3) | 3/3 |" in long["hold", "nominal"]
    assert "| 2.00 (2/3 never) | 2/3 |" in long["nominal", "nominal"]
    assert "| 1.50 (1.00–2.00) | 0/3 |" in long["calibrated (oracle)", "nominal"]
    assert "(oracle): given the plant's truth" in md
    # an oracle is never the best contender, whatever its numbers
    assert not any(r.best for r in board.rows if r.agent == "calibrated")
    table = rows(to_csv(board))
    by = {(r["agent"], r["scenario"]): r for r in table}
    assert by["hold", "geometric"]["converge_s_n"] == "0"
    assert by["hold", "geometric"]["never_converged_count"] == "3"
    assert by["calibrated", "nominal"]["oracle"] == "1" and by["hold", "nominal"]["oracle"] == "0"


def test_records_with_local_changes_are_refused_unless_allowed_and_then_marked(
    tmp_path, monkeypatch
):
    cfg = fake_config()
    run_sweep(cfg, tmp_path, workers=0, run_fn=fake_run)
    # one record made from a tree with local changes
    monkeypatch.setattr("experiments.sweep.environment_info", with_git(CLEAN | {"dirty": True}))
    store = RunStore(tmp_path)
    store.path("nominal__geometric__seed1").unlink()
    run_sweep(cfg, tmp_path, workers=0, run_fn=fake_run)
    with pytest.raises(
        RecordError,
        match=r"1 record\(s\) .*local changes.*nominal__geometric__seed1.*--allow-dirty",
    ):
        build_leaderboard(tmp_path)
    res = CliRunner().invoke(app, ["leaderboard", str(tmp_path), "--out", str(tmp_path / "r")])
    assert res.exit_code == 2 and "--allow-dirty" in res.output
    assert not (tmp_path / "r").exists()  # nothing written
    board = build_leaderboard(tmp_path, allow_dirty=True)
    md = to_markdown(board)
    assert "**1 run(s) made with local changes**" in md
    assert "| nominal (local changes) | geometric |" in md
    assert "| nominal | nominal |" in md  # the clean rows are not marked
    table = {(r["agent"], r["scenario"]): r for r in rows(to_csv(board))}
    assert (
        table["nominal", "geometric"]["dirty"] == "1" and table["hold", "geometric"]["dirty"] == "0"
    )
    # a record from no git checkout is no better
    monkeypatch.setattr(
        "experiments.sweep.environment_info", with_git({"commit": None, "dirty": None})
    )
    store.path("hold__nominal__seed0").unlink()
    run_sweep(cfg, tmp_path, workers=0, run_fn=fake_run)
    with pytest.raises(RecordError, match=r"2 record\(s\)"):
        build_leaderboard(tmp_path)


def test_the_runs_csv_lists_every_run_with_its_commit_and_metrics(runs):
    cfg, path = runs
    board = build_leaderboard(path)
    table = rows(runs_csv(board))
    assert len(table) == 24  # 3 agents x 2 scenarios x 4 seeds, the failed ones too
    store = RunStore(path)
    for row in table:
        rec = store.load(row["run_key"])
        assert row["commit"] == CLEAN["commit"] and row["dirty"] == "0"
        assert row["config_hash"] == cfg.hash and row["run_hash"] == rec["run_hash"]
        assert (row["agent"], row["scenario"], int(row["seed"])) == (
            rec["spec"]["agent_label"],
            rec["spec"]["scenario_label"],
            rec["spec"]["seed"],
        )
        if rec["status"] == "ok":
            assert float(row["rms_mm"]) == rec["metrics"]["rms_mm"]  # exactly: repr round-trips
            assert float(row["solve_time_median_ms"]) == rec["timing"]["solve_time_median_ms"]
        else:
            assert row["status"] == "failed" and row["rms_mm"] == ""
    out = write_leaderboard(board, path.parent / "results", plots=False)
    assert out["runs_csv"].name == "leaderboard_runs.csv"
    assert out["runs_csv"].read_text() == runs_csv(board)


def test_leaderboard_of_a_missing_directory_is_a_clear_error(tmp_path):
    res = CliRunner().invoke(app, ["leaderboard", str(tmp_path / "nope")])
    assert res.exit_code == 2
    assert "no such runs directory" in res.output


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda r: r["spec"].update(seed="abc"), "spec.seed: expected an integer, got 'abc'"),
        (lambda r: r["spec"].update(seed=1.5), "spec.seed: expected an integer, got 1.5"),
        (lambda r: r["spec"].update(seed=-1), "spec.seed: must be >= 0, got -1"),
        (lambda r: r["spec"].update(seed=True), "spec.seed: expected an integer, got True"),
        (lambda r: r["spec"].pop("agent"), "spec.agent: missing"),
        (lambda r: r["spec"].update(settings="x"), "spec.settings: expected an object"),
        (lambda r: r["spec"].update(metrics=5), "spec.metrics: expected an array, got 5"),
        (lambda r: r["spec"].update(metrics=["rms_mm", 3]), "spec.metrics: item 1: expected a str"),
        (lambda r: r["spec"].update(episode_seconds="1"), "spec.episode_seconds: expected a fin"),
        (lambda r: r["spec"].update(episode_seconds=0), "spec.episode_seconds: must be > 0"),
        (lambda r: r["spec"].update(phases=[1]), "spec.phases: item 0: expected an object"),
        (
            lambda r: r["spec"].update(phases=[{"name": "a", "judged": True}]),
            "spec.phases[0].seconds: expected a positive number, got None",
        ),
        (lambda r: r.update(spec=[1]), "spec: expected an object, got [1]"),
        (lambda r: r.update(run_key="other"), "run_key: 'other' is not its spec's run"),
        (lambda r: r.update(status="maybe"), "status: expected 'ok' or 'failed', got 'maybe'"),
        (lambda r: r.update(metrics=[1]), "metrics: expected an object, got [1]"),
        (lambda r: r["metrics"].update(rms_mm="1.2"), "metrics.rms_mm: expected a number"),
    ],
)
def test_a_malformed_record_is_refused_in_one_line_naming_the_field(tmp_path, change, message):
    """``sixaxis reproduce`` used to crash in ``int()`` on a bad seed; the leaderboard and a
    resumed sweep read records the same way."""
    runs = tmp_path / "runs"
    run_sweep(fake_config(seeds=[0, 1, 2]), runs, workers=0, run_fn=fake_run)
    path = runs / "hold__nominal__seed1.json"
    rec = json.loads(path.read_text())
    change(rec)
    path.write_text(json.dumps(rec))
    with pytest.raises(RecordError, match="^" + re.escape(f"{path}: {message}")):
        load_record(path)
    res = CliRunner().invoke(app, ["reproduce", str(path)])
    assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.output
    assert message in " ".join(res.output.split())  # rich may wrap the line
    res = CliRunner().invoke(app, ["leaderboard", str(runs), "--out", str(tmp_path / "r")])
    assert res.exit_code == 2 and message in " ".join(res.output.split()), res.output


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda s: s.update(agent="bogus"), "spec.agent: unknown agent 'bogus'"),
        (
            lambda s: s.update(settings={"gian": 1.0}),
            "spec.settings: agent 'nominal': unknown setting(s) gian",
        ),
        (lambda s: s["env_kwargs"].update(noise_mm=-1.0), "spec.env_kwargs.noise_mm: expected"),
        (lambda s: s["env_kwargs"].update(nosie=1), "spec.env_kwargs.nosie: unknown env option"),
        (lambda s: s.update(scenario="windy"), "spec.env_kwargs.scenario: unknown scenario"),
    ],
)
def test_reproduce_refuses_a_record_that_cannot_rerun_in_one_line(tmp_path, change, message):
    """A well-formed record whose spec the agent or the env would refuse: one line before the
    rerun, not a failed run's traceback."""
    runs = tmp_path / "runs"
    run_sweep(fake_config(seeds=[0, 1, 2]), runs, workers=0, run_fn=fake_run)
    path = runs / "nominal__geometric__seed1.json"
    rec = json.loads(path.read_text())
    change(rec["spec"])
    if "scenario" in rec["spec"]["env_kwargs"]:
        rec["spec"]["env_kwargs"]["scenario"] = rec["spec"]["scenario"]
    path.write_text(json.dumps(rec))
    res = CliRunner().invoke(app, ["reproduce", str(path)])
    assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.output
    text = " ".join(res.output.split())
    assert f"{path}: cannot rerun: {message}" in text, res.output
    assert "rerunning" not in text


def test_agents_told_the_scenarios_effects_are_marked_informed(tmp_path):
    """An agent whose config gives it a model effect set beyond the geometric errors, for a
    scenario, is marked (informed) there, like oracles; told only ``geometric``, it is not."""
    cfg = fake_config(
        scenarios=["nominal", "backlash"],
        agents=[
            "hold",
            {
                "name": "nominal",
                "label": "told",
                "scenario_settings": {"backlash": {"effects": "geometric,backlash[1,5]"}},
            },
            {"name": "calibrated", "settings": {"effects": "geometric"}},
        ],
    )
    run_sweep(cfg, tmp_path, workers=0, run_fn=fake_run)
    board = build_leaderboard(tmp_path)
    assert board.row("told", "backlash").informed and not board.row("told", "nominal").informed
    assert not board.row("calibrated", "backlash").informed
    assert not board.row("hold", "backlash").informed
    md = to_markdown(board)
    assert any(ln.startswith("| told (informed) |") for ln in md.splitlines())
    long = [ln.replace("**", "") for ln in md.splitlines()]
    assert "| told (informed) | backlash |" in "\n".join(long)
    assert "| told | nominal |" in "\n".join(long)
    assert "(informed): told the scenario's effects" in md
    by = {(r["agent"], r["scenario"]): r for r in rows(to_csv(board))}
    assert by["told", "backlash"]["informed"] == "1" and by["told", "nominal"]["informed"] == "0"
    runs_table = rows(runs_csv(board))
    told = [r for r in runs_table if r["agent"] == "told"]
    assert {(r["scenario"], r["informed"]) for r in told} == {("backlash", "1"), ("nominal", "0")}


def test_every_interval_the_leaderboard_prints_is_the_loop_written_bootstrap(runs):
    """Cells, pairs (and the orderings among them), the cost of an effect, the aggregate and the
    CSV's intervals of the mean: each against the bootstrap written as a loop over resamples
    from the same draws (tests/_bootstrap_loops.py)."""
    from tests import _bootstrap_loops as loops

    _, path = runs
    board = build_leaderboard(path, reference="nominal")
    an, store = board.analysis, RunStore(path)

    def values(agent: str, scen: str, metric: str = "rms_mm") -> list[float]:
        return [store.load(f"{agent}__{scen}__seed{s}")["metrics"][metric] for s in (0, 1, 2)]

    def ratio_interval(a: list[float], b: list[float]) -> tuple[float, float]:
        lo, hi = loops.bca([list(np.log(a)), list(np.log(b))], loops.mean_difference)
        return float(np.exp(lo)), float(np.exp(hi))

    checked = 0
    for a in board.agents:
        for s in board.scenarios:
            iv = an["cells"][a][s]["rms_mm"]
            lo, hi = loops.bca([list(np.log(values(a, s)))], loops.mean)
            assert (iv["lo"], iv["hi"]) == pytest.approx((np.exp(lo), np.exp(hi)), rel=1e-12)
            checked += 1
    for p in an["pairs"] + [o for s in board.scenarios for o in an["orderings"][s]]:
        expect = ratio_interval(
            values(p["better"], p["scenario"]), values(p["worse"], p["scenario"])
        )
        assert (p["lo"], p["hi"]) == pytest.approx(expect, rel=1e-12)
        checked += 1
    for a, by_scen in an["cost_of_effect"].items():
        for s, iv in by_scen.items():
            expect = ratio_interval(values(a, s), values(a, "nominal"))
            assert (iv["lo"], iv["hi"]) == pytest.approx(expect, rel=1e-12)
            checked += 1
    for a, agg in an["aggregate"].items():
        ratios = [
            [
                [x / r for x, r in zip(values(a, s), values("nominal", s), strict=True)]
                for s in sorted(board.scenarios)
            ]
        ]
        assert (agg["iqm"]["lo"], agg["iqm"]["hi"]) == pytest.approx(
            loops.stratified(ratios, loops.iqm), rel=1e-12
        )
        checked += 1
    for row in rows(to_csv(board)):
        lo, hi = loops.bca([values(row["agent"], row["scenario"])], loops.mean)
        assert (float(row["rms_mm_lo"]), float(row["rms_mm_hi"])) == pytest.approx(
            (lo, hi), rel=1e-12
        )
        checked += 1
    assert checked >= 6 + 6 + 4 + 3 + 6


def test_an_agent_over_training_seeds_is_ranked_as_one_agent(tmp_path):
    """``hold@s1``..``hold@s3``: one agent ``hold`` over three training seeds; its cells, pairs
    and aggregate are the stratified bootstrap over seeds and episodes (written as loops), its
    runs stay one row each in the runs CSV with their training seed, and the tables say how many
    seeds a row is over."""
    from tests import _bootstrap_loops as loops

    seeded = [{"name": "hold", "label": f"hold@s{k}"} for k in (1, 2, 3)]
    cfg = fake_config(seeds=[0, 1, 2, 3], agents=["nominal", *seeded])
    path = tmp_path / "runs"
    run_sweep(cfg, path, workers=0, run_fn=fake_run)
    board = build_leaderboard(path, reference="nominal")
    assert board.agents == ["nominal", "hold"]
    row = board.row("hold", "geometric")
    assert row is not None and row.n == 12 and row.seeds == 3
    store, an = RunStore(path), board.analysis

    def values(label: str, scen: str) -> list[float]:
        return [store.load(f"{label}__{scen}__seed{e}")["metrics"]["rms_mm"] for e in range(4)]

    labels = [f"hold@s{k}" for k in (1, 2, 3)]
    cell = an["cells"]["hold"]["geometric"]["rms_mm"]
    lo, hi = loops.stratified(
        [[list(np.log(values(lb, "geometric")))] for lb in labels], loops.mean
    )
    assert (cell["lo"], cell["hi"]) == pytest.approx((np.exp(lo), np.exp(hi)), rel=1e-12)
    assert cell["value"] == pytest.approx(
        np.exp(np.mean(np.log([values(lb, "geometric") for lb in labels])))
    )
    pair = next(p for p in an["pairs"] if p["scenario"] == "nominal")
    a, b = (
        [values(lb, "nominal") for lb in labels] if p == "hold" else [values("nominal", "nominal")]
        for p in (pair["better"], pair["worse"])
    )
    assert (pair["lo"], pair["hi"]) == pytest.approx(loops.seeded_pair(a, b), rel=1e-12)
    ratios = [
        [
            [x / r for x, r in zip(values(lb, s), values("nominal", s), strict=True)]
            for s in sorted(board.scenarios)
        ]
        for lb in labels
    ]
    agg = an["aggregate"]["hold"]["iqm"]
    assert (agg["lo"], agg["hi"]) == pytest.approx(loops.stratified(ratios, loops.iqm), rel=1e-12)
    assert an["compute"]["hold"]["ranked_seeds"] == [1, 2, 3]
    cost = an["cost_of_effect"]["hold"]["geometric"]
    per_seed = [
        [
            [
                float(np.log(x / y))
                for x, y in zip(values(lb, "geometric"), values(lb, "nominal"), strict=True)
            ]
        ]
        for lb in labels
    ]
    lo, hi = loops.stratified(per_seed, loops.mean)
    assert (cost["lo"], cost["hi"]) == pytest.approx((np.exp(lo), np.exp(hi)), rel=1e-12)
    csv_row = next(
        r for r in rows(to_csv(board)) if r["agent"] == "hold" and r["scenario"] == "geometric"
    )
    expect = loops.stratified([[values(lb, "geometric")] for lb in labels], loops.mean)
    assert (float(csv_row["rms_mm_lo"]), float(csv_row["rms_mm_hi"])) == pytest.approx(
        expect, rel=1e-12
    )

    table = rows(runs_csv(board))
    assert sorted({(r["agent"], r["train_seed"]) for r in table if r["agent_name"] == "hold"}) == [
        ("hold@s1", "1"),
        ("hold@s2", "2"),
        ("hold@s3", "3"),
    ]
    assert {r["train_seed"] for r in table if r["agent"] == "nominal"} == {""}
    md = to_markdown(board)
    assert "| hold (3 seeds) |" in md and "| nominal |" in md


def test_one_network_beside_its_agents_seeds_is_refused(tmp_path):
    cfg = fake_config(seeds=[0, 1], agents=["hold", {"name": "hold", "label": "hold@s2"}])
    run_sweep(cfg, tmp_path / "runs", workers=0, run_fn=fake_run)
    with pytest.raises(RecordError, match=r"agent 'hold' ran both as one network"):
        build_leaderboard(tmp_path / "runs")


def test_a_learned_row_says_which_seed_it_is_from_its_policy_file():
    from experiments.leaderboard.writers import seeds_text

    assert seeds_text({"ranked_seeds": [], "training_seeds": 3.0, "training_picked": "best"}) == (
        " (1 seed: the best of 3 trained)"
    )
    assert seeds_text({"ranked_seeds": [], "training_seeds": 3.0, "training_picked": None}) == (
        " (1 seed: one of 3 trained)"
    )
    assert seeds_text({"ranked_seeds": [], "training_seeds": 1.0}) == " (1 seed)"
    assert seeds_text({"ranked_seeds": [1, 2, 3, 4, 5], "training_seeds": 1.0}) == " (5 seeds)"
    assert seeds_text({"ranked_seeds": [], "training_seeds": None}) == ""  # not learned
    assert seeds_text({"training_seeds": 3.0}) == ""  # an analysis from before seeds


def test_an_agent_label_may_name_a_training_seed_and_nothing_else():
    from experiments.config import ConfigError, split_train_seed

    assert split_train_seed("ppo@s3") == ("ppo", 3)
    assert split_train_seed("ppo-residual") == ("ppo-residual", None)
    with pytest.raises(ConfigError, match=r"label: 'hold@x'"):
        fake_config(agents=[{"name": "hold", "label": "hold@x"}])


def test_a_shipped_policys_row_says_which_seed_it_is():
    """The shipped policies' files say how many seeds were trained and which was shipped; a run's
    report carries both, and the leaderboard's label reads them (results/learning/README.md:
    every agent ships its median seed of five)."""
    from agents.policy import PolicyAgent
    from agents.runner import run_episode
    from experiments.leaderboard.writers import seeds_text

    agent = PolicyAgent("ppo")
    report = run_episode(agent, {"scenario": "nominal"}, seed=5, episode_seconds=0.2).report
    assert report["training_seeds"] == 5.0 and report["training_picked"] == "median"
    compute = {
        "ranked_seeds": [],
        "training_seeds": report["training_seeds"],
        "training_picked": report["training_picked"],
    }
    assert seeds_text(compute) == " (1 seed: the median of 5 trained)"
