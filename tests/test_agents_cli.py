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
    res = runner.invoke(app, ["evaluate", "ppo-residual", "--settings", settings, "--seeds", "1"])
    assert res.exit_code == 2 and "refusing" in res.output, res.output
    cfg = tmp_path / "shared.toml"
    text = 'name = "shared"\nseeds = [0]\nscenarios = ["geometric"]\nepisode_seconds = 1.0\nsettle_seconds = 0.5\n'
    cfg.write_text(text + f'[[agents]]\nname = "ppo-residual"\nsettings = {{ path = "{evil}" }}\n')
    res = runner.invoke(app, ["sweep", str(cfg), "--out", str(tmp_path / "runs"), "-w", "0"])
    assert res.exit_code == 2 and "refusing" in res.output, res.output
    # a run record (made by a harmless run) edited to name the zip
    cfg.write_text(text + '[[agents]]\nname = "hold"\n')
    res = runner.invoke(app, ["sweep", str(cfg), "--out", str(tmp_path / "ok"), "-w", "0"])
    assert res.exit_code == 0, res.output
    (record,) = (tmp_path / "ok").glob("hold__*.json")
    rec = json.loads(record.read_text())
    rec["spec"]["agent"], rec["spec"]["settings"] = "ppo-residual", {"path": str(evil)}
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
        (["--converge-mm", "0"], "--converge-mm: must be > 0"),
    ]
    for args, message in cases:
        res = runner.invoke(app, ["evaluate", "hold", *args])
        assert res.exit_code == 2, (args, res.output)
        assert message in res.output, (args, res.output)
        assert isinstance(res.exception, SystemExit), (args, res.exception)  # no crash
    res = runner.invoke(app, ["evaluate", "mpc", "--settings", '{"horizon": "x"}'])
    assert res.exit_code == 2 and "agent 'mpc': bad settings {'horizon': 'x'}" in res.output
