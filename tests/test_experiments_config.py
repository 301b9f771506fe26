"""Experiment configs: the shipped ones parse, a config expands into the right runs, and a bad
config is refused before any run starts, naming the file and the key at fault."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from experiments.config import ConfigError, load_config, parse_config

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "experiments" / "configs"

GOOD = {
    "name": "t",
    "seeds": [0, 1],
    "episode_seconds": 2.0,
    "settle_seconds": 1.0,
    "scenarios": ["nominal", "geometric"],
    "agents": ["hold", {"name": "nominal", "settings": {"gain": 0.4}}],
}


def parse(**changes):
    raw = {k: v for k, v in (GOOD | changes).items() if v is not None}
    return parse_config(raw, source="cfg.toml", check_agents=False)


def refused(**changes) -> str:
    with pytest.raises(ConfigError) as err:
        parse(**changes)
    msg = str(err.value)
    assert msg.startswith("cfg.toml: bad experiment config")
    return msg


@pytest.mark.parametrize("name", ["quick", "full", "compliance_story"])
def test_shipped_configs_parse(name):
    cfg = load_config(CONFIGS / f"{name}.toml")
    assert cfg.name == name
    seeds = list(range(2**40, 2**40 + cfg.draw_seeds)) if cfg.draw_seeds else None
    runs = cfg.runs(seeds)
    assert len(runs) == len(cfg.agents) * len(cfg.scenarios) * cfg.n_seeds
    assert len({r.run_key for r in runs}) == len(runs)
    if name == "full":  # published: at least 20 episode seeds, drawn when the sweep starts
        assert cfg.draw_seeds >= 20 and cfg.rank_by == "rms_settled_mm"
        assert {s.scenario for s in cfg.scenarios} >= {"nominal", "geometric", "compliance"}


def test_runs_expand_agents_by_scenarios_by_seeds_and_merge_env_options():
    cfg = parse(
        env={"noise_mm": 0.02, "trajectory": "circle"},
        scenarios=[
            "nominal",
            {"name": "geo-lemni", "scenario": "geometric", "env": {"trajectory": "lemniscate"}},
        ],
        agents=["hold", {"name": "nominal", "label": "nom-slow", "env": {"noise_mm": 0.05}}],
    )
    runs = cfg.runs()
    assert [r.run_key for r in runs] == [
        "hold__nominal__seed0",
        "hold__nominal__seed1",
        "hold__geo-lemni__seed0",
        "hold__geo-lemni__seed1",
        "nom-slow__nominal__seed0",
        "nom-slow__nominal__seed1",
        "nom-slow__geo-lemni__seed0",
        "nom-slow__geo-lemni__seed1",
    ]
    r = runs[6]
    # [env] | scenario.env | agent.env | scenario
    assert r.env_kwargs == {"noise_mm": 0.05, "scenario": "geometric", "trajectory": "lemniscate"}
    assert r.agent == "nominal" and r.agent_label == "nom-slow"


def test_a_seed_count_draws_the_seeds_at_sweep_time_and_names_runs_by_episode():
    cfg = parse(seeds=3, agents=["hold"], scenarios=["nominal"])
    assert cfg.draw_seeds == 3 and cfg.seeds == () and cfg.n_seeds == 3
    with pytest.raises(ValueError, match="drawn when the sweep starts"):
        cfg.runs()
    drawn = [2**62 + 5, 2**40 + 1, 2**33]
    runs = cfg.runs(drawn)
    assert [r.run_key for r in runs] == [f"hold__nominal__ep{k}" for k in range(3)]
    assert [r.seed for r in runs] == drawn and [r.episode for r in runs] == [0, 1, 2]
    # the seed is in the run's hash: another seed under the same key is another run
    other = cfg.runs([drawn[0] + 1, *drawn[1:]])[0]
    assert other.run_key == runs[0].run_key and other.run_hash != runs[0].run_hash
    assert cfg.spec_for("hold", "nominal", drawn[1], 1) == runs[1]
    # fixed seeds keep their names
    assert [
        r.run_key for r in parse(seeds=[4, 7], agents=["hold"], scenarios=["nominal"]).runs()
    ] == [
        "hold__nominal__seed4",
        "hold__nominal__seed7",
    ]


def test_a_huge_seed_count_or_a_step_shorter_episode_is_refused_at_once():
    msg = refused(seeds=100_000_000)
    assert "seeds: 100000000 episodes per agent and scenario; at most 10000" in msg
    msg = refused(episode_seconds=0.01)
    assert "episode_seconds: 0.01 s is shorter than one control step (0.02 s)" in msg
    msg = refused(time_limit_s=-1, memory_limit_mb=10, isolate="maybe")
    assert "time_limit_s: must lie in (0, 1e+07) (seconds), got -1" in msg
    assert "memory_limit_mb: must be an integer >= 256 (MiB), got 10" in msg
    assert "isolate: must be one of class-path, all, none, got 'maybe'" in msg


def test_limits_and_isolation_reach_every_run_but_not_its_hash():
    cfg = parse(time_limit_s=5, memory_limit_mb=1024, agents=["hold", "tests._user_agent:Snoop"])
    runs = cfg.runs()
    assert {r.time_limit_s for r in runs} == {5.0} and {r.memory_limit_mb for r in runs} == {1024}
    assert {r.agent: r.isolate for r in runs} == {"hold": False, "tests._user_agent:Snoop": True}
    assert parse(isolate="all").runs()[0].isolate
    assert runs[0].run_hash == parse(agents=["hold", "tests._user_agent:Snoop"]).runs()[0].run_hash


def test_run_hash_names_the_run_not_the_config():
    a = parse().runs()[0]
    b = parse(name="other").runs()[0]
    c = parse(episode_seconds=3.0).runs()[0]
    assert a.run_hash == b.run_hash
    assert a.run_hash != c.run_hash
    assert parse().hash != parse(name="other").hash


def test_user_agent_by_class_path_is_accepted():
    cfg = parse(agents=[{"name": "agents.reference:HoldAgent", "settings": {}}])
    assert cfg.agents[0].label == "HoldAgent"
    assert cfg.agents[0].agent == "agents.reference:HoldAgent"


@pytest.mark.parametrize(
    ("changes", "key", "words"),
    [
        ({"agents": ["hold", "bogus"]}, "agents[1].name", "unknown agent 'bogus'"),
        ({"agents": ["no.such.module:Agent"]}, "agents[0].name", "cannot import module"),
        ({"agents": ["envs.task:Observation"]}, "agents[0].name", "not a subclass"),
        ({"scenarios": ["geometric", "wobbly"]}, "scenarios[1].name", "unknown scenario 'wobbly'"),
        (
            {"scenarios": [{"name": "x", "scenario": "wobbly"}]},
            "scenarios[0].scenario",
            "unknown scenario",
        ),
        ({"seeds": "0,1"}, "seeds", "expected an array or an integer"),
        ({"seeds": [0, 1.5]}, "seeds[1]", "non-negative integer"),
        ({"seeds": [0, 0]}, "seeds", "repeated"),
        ({"episode_seconds": "long"}, "episode_seconds", "expected a number"),
        ({"episode_seconds": 30.0}, "episode_seconds", "longer than the env's reference"),
        ({"metrics": ["rms_mm", "happiness"]}, "metrics[1]", "unknown metric 'happiness'"),
        ({"rank_by": "max_mm", "metrics": ["rms_mm"]}, "rank_by", "not one of the metrics"),
        ({"colour": "blue"}, "colour", "unknown key"),
        ({"agents": [{"name": "nominal", "setings": {}}]}, "agents[0].setings", "unknown key"),
        (
            {"agents": [{"name": "nominal", "settings": {"gain": "high"}}]},
            "agents[0].settings.gain",
            "expected a number",
        ),
        (
            {"agents": [{"name": "nominal", "settings": {"gian": 1.0}}]},
            "agents[0].settings",
            "unknown setting(s) gian",
        ),
        (
            {"agents": [{"name": "mpc", "settings": {"horizon": 12.5}}]},
            "agents[0].settings.horizon",
            "expected an integer",
        ),
        ({"env": {"noise_mm": "15um"}}, "env.noise_mm", "expected a number"),
        ({"env": {"measurements": 1}}, "env.measurements", "expected a boolean"),
        ({"env": {"nosie_mm": 0.01}}, "env.nosie_mm", "unknown env option"),
        ({"env": {"scenario": "geometric"}}, "env.scenario", "top-level 'scenarios'"),
        # values the env itself refuses: found at load, not in every run
        ({"env": {"noise_mm": -0.01}}, "env.noise_mm", "expected a number >= 0 (mm), got -0.01"),
        ({"env": {"trajectory": "zigzag"}}, "env.trajectory", "one of circle, lemniscate"),
        ({"env": {"measure_every": 0}}, "env.measure_every", "expected an integer >= 1"),
        ({"env": {"dropout": 1.5}}, "env.dropout", "in [0, 1) (a probability)"),
        (
            {
                "scenarios": [
                    "nominal",
                    {"name": "s", "scenario": "nominal", "env": {"latency_steps": -2}},
                ]
            },
            "scenarios[1].env.latency_steps",
            "expected an integer >= 0",
        ),
        (
            {"agents": ["hold", {"name": "nominal", "env": {"trajectory": "zig"}}]},
            "agents[1].env.trajectory",
            "got 'zig'",
        ),
        (
            {"env": {"overrides": {"thermal": {"kappa": 1e-5}}}},
            "env.overrides",
            "scenario 'nominal' has no 'thermal' effect",
        ),
        (
            {
                "scenarios": ["compliance"],
                "env": {"overrides": {"compliance": {"c2": "8e-6"}}},
            },
            "env.overrides",
            "overrides['compliance']['c2'] must be a finite number",
        ),
        (
            {"phases": [{"name": "a", "seconds": 1.0, "env": {"noise_mm": -1.0}}]},
            "phases[0].env.noise_mm",
            "expected a number >= 0",
        ),
        ({"agents": ["hold", "hold"]}, "agents", "'hold' appears twice"),
        ({"scenarios": []}, "scenarios", "empty"),
        ({"agents": None}, "agents", "missing (required)"),
        ({"name": "a/b"}, "name", "letters, digits"),
        (
            {"phases": [{"name": "cal", "seconds": 1.0, "judged": False}]},
            "phases",
            "no phase is judged",
        ),
        ({"phases": [{"name": "cal", "seconds": -1.0}]}, "phases[0].seconds", "positive number"),
        ({"campaign": {"kind": "tour"}}, "campaign.kind", "unknown campaign 'tour'"),
        ({"campaign": {"judge_posture": "moon"}}, "campaign", "unknown judge_posture 'moon'"),
        ({"campaign": {"judge_postur": "reach"}}, "campaign.judge_postur", "unknown key"),
    ],
)
def test_bad_config_is_refused_naming_the_key(changes, key, words):
    msg = refused(**changes)
    line = next((ln for ln in msg.splitlines() if ln.strip().startswith(f"- {key}:")), None)
    assert line is not None, f"no problem reported for key {key!r}:\n{msg}"
    assert words in line, line


def test_every_problem_is_reported_at_once():
    msg = refused(agents=["bogus"], scenarios=["wobbly"], seeds=[-1])
    for key in ("agents[0].name", "scenarios[0].name", "seeds[0]"):
        assert f"- {key}:" in msg


def test_bad_setting_value_is_caught_by_making_the_agent(tmp_path):
    raw = GOOD | {"agents": [{"name": "nominal", "settings": {"gain": 2.0}}]}
    with pytest.raises(ConfigError, match=r"agents\[0\]\.settings: agent 'nominal' refuses"):
        parse_config(raw, source="cfg.toml", check_agents=True)


def test_file_errors_name_the_file(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text('seeds = [0\nagents = ["hold"]\n')
    with pytest.raises(
        ConfigError, match=r"broken\.toml: bad experiment config:\n  - not valid TOML"
    ):
        load_config(p)
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "missing.toml")


def test_cli_refuses_a_bad_config_before_any_run_starts(tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(
        'seeds = [0]\nepisode_seconds = 1.0\nsettle_seconds = 0.5\nscenarios = ["geometric"]\n'
        'agents = ["hold", { name = "nominal", settings = { gain = "fast" } }]\n'
    )
    out = tmp_path / "runs"
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.cli", "sweep", str(cfg), "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "bad.toml" in proc.stderr and "agents[1].settings.gain" in proc.stderr
    assert not out.exists()  # nothing ran, nothing was written


def test_a_named_campaign_expands_into_its_phases():
    """The compliance story's config: nine measured calibration phases around different postures,
    then one judged blind phase in a region none of them visited."""
    from agents.runner import JUDGE_POSTURES

    cfg = load_config(CONFIGS / "compliance_story.toml")
    phases = cfg.phases
    assert len(phases) == 10 and [p.judged for p in phases] == [False] * 9 + [True]
    assert phases[-1].env["measurements"] is False
    assert phases[-1].env["posture"] == list(JUDGE_POSTURES["reach"])
    assert len({tuple(map(str, p.env["posture"])) for p in phases[:-1]}) == 9
    assert cfg.episode_seconds == phases[-1].seconds  # only the blind phase is judged
    calibrated = [a for a in cfg.agents if a.agent == "calibrated"]
    assert calibrated and all(a.settings["calibration_seconds"] == "each_phase" for a in calibrated)


def test_calibrated_each_phase_is_how_a_config_says_none():
    from agents.registry import make_agent

    assert make_agent("calibrated", calibration_seconds="each_phase").calibration_seconds is None
    with pytest.raises(ValueError, match="'sometimes'"):
        make_agent("calibrated", calibration_seconds="sometimes")


def test_settling_window_must_leave_part_of_the_judged_episode():
    msg = refused(settle_seconds=2.0)  # GOOD's episode is 2 s
    assert "- settle_seconds: 2 s is not shorter than the judged episode (2 s)" in msg
    # the default (2 s) against a 1 s episode is refused the same way
    assert "settle_seconds: 2 s" in refused(settle_seconds=None, episode_seconds=1.0)
    assert "- converge_mm: must be positive" in refused(converge_mm=0.0)


def test_default_settling_time_is_no_shipped_calibration_window():
    import inspect

    from agents.reference import CalibratedAgent
    from experiments.metrics import DEFAULT_SETTLE_SECONDS

    cfg = parse(settle_seconds=None, episode_seconds=5.0)
    assert cfg.settle_seconds == DEFAULT_SETTLE_SECONDS
    windows = {inspect.signature(CalibratedAgent).parameters["calibration_seconds"].default}
    for name in ("quick", "full"):
        for a in load_config(CONFIGS / f"{name}.toml").agents:
            if "calibration_seconds" in a.settings:
                windows.add(a.settings["calibration_seconds"])
    assert DEFAULT_SETTLE_SECONDS not in windows


def test_a_calibration_window_equal_to_the_settling_time_is_warned_about(caplog):
    agents = [{"name": "calibrated", "settings": {"calibration_seconds": 1.0}}]
    with caplog.at_level("WARNING", logger="experiments.config"):
        parse(agents=agents)
    assert "calibrated calibrates at 1 s, the settling time" in caplog.text


def test_convergence_comes_with_its_never_count_and_the_threshold_is_in_each_run():
    cfg = parse(metrics=["rms_mm", "converge_s"], converge_mm=0.1)
    assert cfg.metrics == ("rms_mm", "converge_s", "never_converged")
    assert all(r.converge_mm == 0.1 for r in cfg.runs())
    assert parse().runs()[0].run_hash != cfg.runs()[0].run_hash


@pytest.mark.parametrize("name", ["quick", "full", "compliance_story"])
def test_shipped_configs_have_three_seeds_and_the_whole_episode_metrics(name):
    cfg = load_config(CONFIGS / f"{name}.toml")
    assert cfg.n_seeds >= 3
    assert {"rms_mm", "rms_settled_mm", "max_settled_mm"} <= set(cfg.metrics)


def test_scenario_settings_are_merged_per_scenario_and_checked(tmp_path):
    cfg = tmp_path / "informed.toml"
    cfg.write_text(
        """
seeds = [0]
episode_seconds = 4.0
scenarios = ["geometric", "backlash"]
[[agents]]
name = "mpc"
label = "mpc-informed"
settings = { horizon = 8 }
scenario_settings = { backlash = { effects = "geometric,backlash" } }
"""
    )
    runs = {r.scenario_label: r.settings for r in load_config(cfg).runs()}
    assert runs == {
        "geometric": {"horizon": 8},
        "backlash": {"horizon": 8, "effects": "geometric,backlash"},
    }
    cfg.write_text(cfg.read_text().replace("backlash = {", "thermal = {"))
    with pytest.raises(ConfigError, match=r"scenario_settings\.thermal: not a scenario"):
        load_config(cfg)
    cfg.write_text(
        cfg.read_text().replace('thermal = { effects = "geometric,backlash" }', "backlash = 3")
    )
    with pytest.raises(ConfigError, match="table of tables"):
        load_config(cfg)


def test_cli_refuses_env_options_the_env_would_refuse_at_dry_run(tmp_path):
    """Item 4 of issue 13: these passed ``--dry-run``, then every run failed."""
    cfg = tmp_path / "bad.toml"
    cfg.write_text(
        'seeds = 3\nepisode_seconds = 2.0\nsettle_seconds = 0.5\nscenarios = ["geometric"]\n'
        'agents = ["hold"]\n[env]\nnoise_mm = -0.01\ntrajectory = "zigzag"\nmeasure_every = 0\n'
    )
    out = tmp_path / "runs"
    for extra in (["--dry-run"], []):
        proc = subprocess.run(
            [sys.executable, "-m", "experiments.cli", "sweep", str(cfg), "--out", str(out), *extra],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=120,
        )
        assert proc.returncode == 2, proc.stdout + proc.stderr
        for key in ("env.noise_mm", "env.trajectory", "env.measure_every"):
            assert f"- {key}: expected" in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr
    assert not out.exists()


def test_cli_refuses_a_negative_worker_count(tmp_path):
    out = tmp_path / "runs"
    cmd = [sys.executable, "-m", "experiments.cli", "sweep", str(CONFIGS / "quick.toml")]
    proc = subprocess.run(
        [*cmd, "--workers", "-3", "--out", str(out), "--dry-run"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    text = " ".join(proc.stderr.replace("│", " ").split())  # rich draws a box
    assert proc.returncode == 2 and "'--workers'" in text, proc.stderr
    assert "greater than or equal to 0" in text, proc.stderr
    from experiments.sweep import SweepError, run_sweep

    with pytest.raises(SweepError, match="workers must be an integer >= 0, got -3"):
        run_sweep(load_config(CONFIGS / "quick.toml"), tmp_path / "runs", workers=-3)
    assert not (tmp_path / "runs").exists()
