"""The agents' CLI commands: ``sixaxis evaluate`` and ``sixaxis train`` (errors, and that a
policy file with a pickled payload runs nothing; a training run is tested in
test_agents_training.py)."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from experiments.cli import app

runner = CliRunner()


def test_evaluate_prints_json_rows():
    res = runner.invoke(app, ["evaluate", "hold", "--seeds", "1", "--json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)
    assert rows[0]["scenario"] == "geometric" and rows[0]["rms_mm"] > 1.0
    assert rows[0]["rms_settled_mm"] > 1.0


def test_evaluate_speaks_the_leaderboards_language(tmp_path):
    """The leaderboard's metric names (settled, start-up, whole), the same numbers as the
    metrics module gives for the same episode, a table whose headers fit 80 columns whole, the
    episode's length from --episode-seconds and the rows written with -o."""
    from agents.registry import make_agent
    from agents.runner import run_episode
    from experiments.leaderboard import HEADLINE
    from experiments.metrics import episode_metrics

    out = tmp_path / "rows.json"
    args = ["evaluate", "nominal", "--seeds", "2", "--episode-seconds", "2.5", "--settle", "1"]
    res = runner.invoke(app, [*args, "-o", str(out)], env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert max(len(line) for line in lines) <= 80
    header = next(line for line in lines if "settled" in line and "scenario" in line)
    for word in ("settled", "start-up", "whole", "max settled", "ms/step"):
        assert word in header, header  # not truncated to "start-…"
    assert "…" not in res.output
    rows = json.loads(out.read_text())
    assert [r["seed"] for r in rows] == [0, 1]
    assert set(HEADLINE) <= set(rows[0]) and "converge_s" not in rows[0]
    r = run_episode(make_agent("nominal"), {"scenario": "geometric"}, seed=1, episode_seconds=2.5)
    m, _ = episode_metrics(r, HEADLINE, settle_seconds=1.0)
    assert len(r.time) == 125
    for k in HEADLINE:
        assert rows[1][k] == m[k]
        assert f"{m[k]:.4f}" in res.output
    csv_out = tmp_path / "rows.csv"
    res = runner.invoke(app, [*args, "--seeds", "1", "-o", str(csv_out)])
    assert res.exit_code == 0, res.output
    assert csv_out.read_text().splitlines()[0].startswith("scenario,seed,rms_settled_mm,")


def test_evaluate_refuses_unknown_agents_and_settings():
    res = runner.invoke(app, ["evaluate", "mpcc"])
    assert res.exit_code == 2 and "unknown agent 'mpcc'" in res.output
    res = runner.invoke(app, ["evaluate", "mpc", "--settings", '{"horizn": 3}'])
    assert res.exit_code == 2 and "horizn" in res.output


def test_train_refuses_a_bad_config(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[train]\nnet_arch = 64\n")
    res = runner.invoke(app, ["train", "ppo", "--config", str(bad)])
    assert res.exit_code == 2 and "net_arch" in res.output
    res = runner.invoke(app, ["train", "sac", "--config", "experiments/configs/ppo-residual.toml"])
    assert res.exit_code == 2 and "sixaxis train ppo" in res.output


def test_a_policy_zip_with_a_pickled_payload_runs_nothing(tmp_path):
    """A shared config, a command line or a run record naming a stable-baselines3 zip whose
    pickle would run code: refused with one line, and the payload never runs."""
    from tests.test_agents_policy import _evil_zip

    marker = tmp_path / "pwned"
    evil = _evil_zip(tmp_path, marker)
    settings = json.dumps({"path": str(evil)})
    res = runner.invoke(app, ["evaluate", "policy", "--settings", settings, "--seeds", "1"])
    assert res.exit_code == 2 and "refusing" in res.output, res.output
    cfg = tmp_path / "shared.toml"
    text = 'name = "shared"\nseeds = [0]\nscenarios = ["geometric"]\nepisode_seconds = 1.0\nsettle_seconds = 0.5\n'
    cfg.write_text(text + f'[[agents]]\nname = "policy"\nsettings = {{ path = "{evil}" }}\n')
    res = runner.invoke(app, ["sweep", str(cfg), "--out", str(tmp_path / "runs"), "-w", "0"])
    assert res.exit_code == 2 and "refusing" in res.output, res.output
    # a run record (made by a harmless run) edited to name the zip
    cfg.write_text(text + '[[agents]]\nname = "hold"\n')
    res = runner.invoke(app, ["sweep", str(cfg), "--out", str(tmp_path / "ok"), "-w", "0"])
    assert res.exit_code == 0, res.output
    (record,) = (tmp_path / "ok").glob("hold__*.json")
    rec = json.loads(record.read_text())
    rec["spec"]["agent"], rec["spec"]["settings"] = "policy", {"path": str(evil)}
    record.write_text(json.dumps(rec))
    res = runner.invoke(app, ["reproduce", str(record)])
    # refused before anything runs: the edited spec is not the run its hash names
    assert res.exit_code == 2 and "the record was edited" in res.output, res.output
    assert not marker.exists()


def test_evaluate_refuses_bad_options_in_one_line_before_any_episode():
    """Each is one line naming the option, exit 2, no traceback (an unknown scenario used to
    print the whole stack around the good message)."""
    cases = [
        (["--scenario", "foo"], "--scenario: unknown scenario 'foo'; known: nominal"),
        (["--scenario", "geometric", "--scenario", "nope"], "unknown scenario 'nope'"),
        (["--settle", "10"], "--settle: 10 s leaves nothing of the 10 s episode"),
        (["--settle", "-1"], "--settle"),
        (["--seeds", "0"], "--seeds"),
        (["--settings", "[1]"], "--settings: expected a JSON object"),
        (["--settings", '{"x"'], "--settings: not JSON"),
        (["--episode-seconds", "0"], "--episode-seconds: expected at least one control step"),
        (["--episode-seconds", "3", "--settle", "3"], "--settle: 3 s leaves nothing of the 3 s"),
        (["-o", "rows.txt"], "--output rows.txt: write the rows as .json or .csv"),
    ]
    for args, message in cases:
        res = runner.invoke(app, ["evaluate", "hold", *args])
        assert res.exit_code == 2, (args, res.output)
        assert message in res.output, (args, res.output)
        assert isinstance(res.exception, SystemExit), (args, res.exception)  # no crash
    res = runner.invoke(app, ["evaluate", "mpc", "--settings", '{"horizon": "x"}'])
    assert res.exit_code == 2 and "agent 'mpc': bad settings {'horizon': 'x'}" in res.output
