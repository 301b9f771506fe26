"""The agents' CLI commands: ``sixaxis evaluate`` and ``sixaxis train ppo`` (errors only; a
training run is tested in test_agents_ppo.py)."""

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
    # hold never converges: no number, and said so
    assert rows[0]["converge_s"] is None and rows[0]["never_converged"] == 1.0
    assert rows[0]["rms_settled_mm"] > 1.0


def test_evaluate_refuses_unknown_agents_and_settings():
    res = runner.invoke(app, ["evaluate", "mpcc"])
    assert res.exit_code == 2 and "unknown agent 'mpcc'" in res.output
    res = runner.invoke(app, ["evaluate", "mpc", "--settings", '{"horizn": 3}'])
    assert res.exit_code == 2 and "horizn" in res.output


def test_train_refuses_a_bad_config(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[ppo]\nnet_arch = 64\n")
    res = runner.invoke(app, ["train", "ppo", "--config", str(bad)])
    assert res.exit_code == 2 and "net_arch" in res.output
