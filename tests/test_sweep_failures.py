"""A sweep survives its runs: an agent that raises, returns NaN, exhausts its memory or never
returns is recorded as a failed run with its reason, and the sweep goes on (``-w 1`` and
``-w 0``). Bad sweep and reproduce requests are refused in one line, with nothing written."""

from __future__ import annotations

import csv
import json
import signal
import socket

import pytest
from typer.testing import CliRunner

from experiments.cli import app
from experiments.config import parse_config
from experiments.records import RunStore
from experiments.sweep import run_sweep

runner = CliRunner()


def failing_config(isolate: str = "class-path", time_limit_s: float = 4.0, **extra):
    agents = [
        "hold",
        {"name": "tests._user_agent:Raises", "label": "raises"},
        {"name": "tests._user_agent:NaNAction", "label": "nan"},
        {"name": "tests._user_agent:MemoryHog", "label": "hog"},
    ]
    raw = {
        "name": "failing",
        "seeds": [0],
        "episode_seconds": 1.0,
        "settle_seconds": 0.5,
        "metrics": ["rms_mm", "rms_settled_mm"],
        "scenarios": ["geometric"],
        "agents": agents,
        "env": {"trajectory": "circle"},
        "time_limit_s": time_limit_s,
        "memory_limit_mb": 2048,
        "isolate": isolate,
    } | extra
    return parse_config(raw, source="failing.toml")


def config_refusal(res, path, *problems: str) -> str:
    """The CLI refused a config: exit code 2, no traceback, ``error: FILE: bad experiment
    config:`` and one line per problem (the config loader's format)."""
    out = res.output.strip()
    assert res.exit_code == 2 and "Traceback" not in out, out
    lines = out.splitlines()
    assert lines[0] == f"error: {path}: bad experiment config:", out
    assert len(lines) == 1 + len(problems), out
    for line, p in zip(lines[1:], problems, strict=True):
        assert line.startswith("  - ") and p in line, out
    return out


def one_line_refusal(res, *needles: str) -> str:
    """The CLI refused: exit code 2, one line ``error: ...`` naming ``needles``, no traceback."""
    out = res.output.strip()
    assert res.exit_code == 2, out
    assert "Traceback" not in out
    assert res.exception is None or isinstance(res.exception, SystemExit)
    lines = out.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:"), out
    for n in needles:
        assert n in out, out
    return out


@pytest.mark.parametrize("workers", [1, pytest.param(0, marks=pytest.mark.slow)])
def test_agents_that_raise_return_nan_or_exhaust_memory_fail_and_the_sweep_goes_on(
    tmp_path, workers
):
    summary = run_sweep(failing_config(time_limit_s=120.0), tmp_path, workers=workers)
    assert sorted(summary.failed) == sorted(
        f"{a}__geometric__seed0" for a in ("raises", "nan", "hog")
    )
    store = RunStore(tmp_path)
    assert store.load("hold__geometric__seed0")["status"] == "ok"
    err = {a: store.load(f"{a}__geometric__seed0")["error"] for a in ("raises", "nan", "hog")}
    assert err["raises"]["type"] == "AgentFailure"
    assert (
        "act raised RuntimeError: deliberate failure at step 3 (step 2)" in err["raises"]["message"]
    )
    assert "deliberate failure" in err["raises"]["traceback"]  # the agent's own, from its process
    assert err["nan"]["type"] == "AgentFailure"
    assert "non-finite action (joint(s) [2]" in err["nan"]["message"]
    assert err["hog"]["type"] == "AgentFailure" and "MemoryError" in err["hog"]["message"]


@pytest.mark.parametrize(
    ("isolate", "workers"),
    [
        ("class-path", 1),
        pytest.param("class-path", 0, marks=pytest.mark.slow),
        ("none", 0),
        pytest.param("none", 1, marks=pytest.mark.slow),
    ],
)
def test_an_agent_that_never_returns_is_stopped_by_the_time_limit(tmp_path, isolate, workers):
    """In its own process the agent is killed when the run's time is up; in the worker (or, with
    -w 0, in the sweep's own process) an alarm stops its Python code. Either way the run is
    recorded as failed and the sweep goes on."""
    raw = failing_config(isolate=isolate, time_limit_s=8.0).to_dict()
    raw["agents"] = [{"name": "tests._user_agent:Hang", "label": "hang"}, {"name": "hold"}]
    raw["scenarios"] = ["geometric"]
    summary = run_sweep(parse_config(raw, source="hang.toml"), tmp_path, workers=workers)
    assert summary.failed == ["hang__geometric__seed0"]
    rec = RunStore(tmp_path).load("hang__geometric__seed0")
    assert rec["error"]["type"] == "TimeLimitExceeded" and "time limit" in rec["error"]["message"]
    assert rec["isolated"] is (isolate == "class-path")
    assert RunStore(tmp_path).load("hold__geometric__seed0")["status"] == "ok"


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="no SIGALRM")
def test_a_hang_no_signal_stops_ends_its_worker_and_the_sweep_goes_on(tmp_path, monkeypatch):
    """A hang inside C code (here: SIGALRM ignored) does not see the time limit; the sweep ends
    its worker after a grace (shortened here) and records the run as failed."""
    monkeypatch.setattr("experiments.sweep.OVERDUE_GRACE_S", 2.0)
    raw = failing_config(isolate="none", time_limit_s=10.0).to_dict()
    raw["agents"] = [
        {"name": "tests._user_agent:Hang", "label": "stuck", "settings": {"block_alarm": True}},
        {"name": "hold"},
    ]
    raw["scenarios"] = ["geometric"]
    raw["seeds"] = [0, 1]
    cfg = parse_config(raw, source="stuck.toml")
    summary = run_sweep(cfg, tmp_path, workers=2)
    assert sorted(summary.failed) == ["stuck__geometric__seed0", "stuck__geometric__seed1"]
    rec = RunStore(tmp_path).load("stuck__geometric__seed0")
    assert (
        rec["error"]["type"] == "TimeLimitExceeded"
        and "worker was ended" in rec["error"]["message"]
    )
    assert all(
        RunStore(tmp_path).load(f"hold__geometric__seed{s}")["status"] == "ok" for s in (0, 1)
    )


def test_huge_seed_counts_short_episodes_and_bad_limits_are_refused_in_one_line(tmp_path):
    cfg = tmp_path / "big.toml"
    base = 'scenarios = ["geometric"]\nagents = ["hold"]\nepisode_seconds = 1.0\nsettle_seconds = 0.5\n'
    cfg.write_text("seeds = 100000000\n" + base)
    res = runner.invoke(app, ["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "r")])
    config_refusal(res, cfg, "seeds: 100000000 episodes per agent and scenario; at most 10000")
    cfg.write_text(
        "seeds = 3\n" + base.replace("= 1.0\nsettle_seconds = 0.5", "= 0.01\nsettle_seconds = 0.0")
    )
    res = runner.invoke(app, ["sweep", str(cfg), "--out", str(tmp_path / "r")])
    config_refusal(res, cfg, "episode_seconds: 0.01 s is shorter than one control step (0.02 s)")
    cfg.write_text("seeds = 3\ntime_limit_s = 0\n" + base)
    res = runner.invoke(app, ["sweep", str(cfg), "--out", str(tmp_path / "r")])
    config_refusal(res, cfg, "time_limit_s: must lie in (0, 1e+07) (seconds), got 0")
    assert not (tmp_path / "r").exists()


def test_a_dry_run_of_drawn_seeds_lists_episodes_and_draws_nothing_to_disk(tmp_path):
    cfg = tmp_path / "d.toml"
    cfg.write_text(
        'seeds = 25\nscenarios = ["geometric"]\nagents = ["hold"]\nepisode_seconds = 1.0\n'
        "settle_seconds = 0.5\n"
    )
    res = runner.invoke(app, ["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "r")])
    assert res.exit_code == 0, res.output
    assert "25 runs (episode seeds drawn" in res.output and "hold__geometric__ep24" in res.output
    assert not (tmp_path / "r").exists()


def test_a_dask_address_where_nothing_listens_is_one_line(tmp_path):
    with socket.socket() as s:  # a port that was free a moment ago
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = tmp_path / "d.toml"
    cfg.write_text(
        'seeds = [0]\nscenarios = ["geometric"]\nagents = ["hold"]\nepisode_seconds = 1.0\n'
        "settle_seconds = 0.5\n"
    )
    args = ["sweep", str(cfg), "--out", str(tmp_path / "r"), "--backend", "dask"]
    res = runner.invoke(app, [*args, "--address", f"tcp://127.0.0.1:{port}"])
    one_line_refusal(res, f"--address tcp://127.0.0.1:{port}: no Dask scheduler answers there")
    res = runner.invoke(app, [*args, "--address", "tcp://nohost"])
    one_line_refusal(res, "not a scheduler address")
    assert not any((tmp_path / "r").glob("*.json"))


@pytest.mark.parametrize(
    ("agent", "needle"),
    [
        ("tests._user_agent:Raises", "act raised RuntimeError: deliberate failure at step 3"),
        ("tests._user_agent:NaNAction", "act returned a non-finite action (joint(s) [2]"),
    ],
)
def test_evaluate_with_an_agent_that_raises_or_returns_nan_is_one_line(agent, needle):
    res = runner.invoke(app, ["evaluate", agent, "--seeds", "1"])
    one_line_refusal(res, "on geometric, seed 0", needle)


# -- reproduce ----------------------------------------------------------------------------------


def _summary(tmp_path, rows):
    path = tmp_path / "runs.csv"
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["agent"])
        w.writeheader()
        w.writerows(rows)
    return path


def _row(**changes):
    row = {
        "agent": "hold",
        "agent_name": "hold",
        "scenario": "geometric",
        "scenario_name": "geometric",
        "seed": "0",
        "episode": "",
        "oracle": "0",
        "status": "ok",
        "commit": "0" * 40,
        "dirty": "0",
        "config_name": "x",
        "config_path": "experiments/configs/quick.toml",
        "config_hash": "",
        "run_key": "hold__geometric__seed0",
        "run_hash": "abc",
        "informed": "0",
        "rms_mm": "1.0",
    }
    return row | changes


def test_reproduce_refuses_an_empty_summary_a_negative_tolerance_and_an_edited_seed(tmp_path):
    header_only = tmp_path / "empty.csv"
    header_only.write_text(",".join(_row()) + "\n")
    res = runner.invoke(app, ["reproduce", str(header_only), "--all"])
    one_line_refusal(res, "empty.csv: a header and no rows: nothing to reproduce")
    summary = _summary(tmp_path, [_row()])
    res = runner.invoke(app, ["reproduce", str(summary), "--all", "--rtol", "-1"])
    one_line_refusal(res, "--rtol: a relative tolerance must be >= 0, got -1")
    # a fixed seed edited (0 -> 1) with its metrics kept: the row no longer names its run
    edited = _summary(tmp_path, [_row(seed="1")])
    res = runner.invoke(app, ["reproduce", str(edited), "--all"])
    one_line_refusal(res, "line 2 (hold__geometric__seed0)", "the row was edited")


def test_a_record_whose_spec_was_edited_is_refused(tmp_path):
    cfg = parse_config(
        {
            "name": "one",
            "seeds": 1,
            "episode_seconds": 0.5,
            "settle_seconds": 0.2,
            "scenarios": ["geometric"],
            "agents": ["hold"],
            "metrics": ["rms_mm"],
        },
        source="one.toml",
    )
    run_sweep(cfg, tmp_path, workers=0)
    path = tmp_path / "hold__geometric__ep0.json"
    rec = json.loads(path.read_text())
    rec["spec"]["seed"] += 1
    path.write_text(json.dumps(rec))
    res = runner.invoke(app, ["reproduce", str(path)])
    one_line_refusal(res, "the record was edited, it is not the run it names")


def cautious_run(spec):
    """A run whose code issues a Python warning (as the lab's cautions are) and logs one."""
    import logging
    import warnings

    from arm.errors import SixAxisWarning

    warnings.warn("poor pose set: deliberate", SixAxisWarning, stacklevel=1)
    logging.getLogger("agents.test").warning("a logged caution")
    return {"metrics": {"rms_mm": 1.0}}


@pytest.mark.parametrize("workers", [0, 1])
def test_a_runs_warnings_go_to_its_record_not_the_terminal(tmp_path, capfd, workers):
    raw = {
        "name": "w",
        "seeds": [0],
        "episode_seconds": 1.0,
        "settle_seconds": 0.5,
        "metrics": ["rms_mm"],
        "scenarios": ["geometric"],
        "agents": ["hold"],
    }
    run_sweep(parse_config(raw, source="w.toml"), tmp_path, workers=workers, run_fn=cautious_run)
    rec = RunStore(tmp_path).load("hold__geometric__seed0")
    assert "SixAxisWarning: poor pose set: deliberate" in rec["warnings"]
    assert "agents.test: a logged caution" in rec["warnings"]
    assert "poor pose set" not in capfd.readouterr().err
