"""No route to the truth: a class-path agent runs in a process of its own, given only the
observation, the controllers' part of ``info`` and a seed that reveals nothing; the agents that
took the truth by the seed, by the path or from their own process now get ``mpc``'s numbers, not
the oracle's; an oracle is whatever the agent said before reset. Isolation changes no number of
the shipped agents."""

from __future__ import annotations

import numpy as np
import pytest

from agents.isolation import IsolatedAgent
from agents.registry import make_agent
from agents.runner import AgentFailure, agent_seed, run_episode
from experiments.config import parse_config
from experiments.records import RunStore, jsonable
from experiments.sweep import execute_run, run_sweep

ENV = {"trajectory": "circle", "noise_mm": 0.015, "measure_every": 5}


def config(agents, seeds=2, scenarios=("geometric",), **extra):
    raw = {
        "name": "iso",
        "seeds": seeds,
        "episode_seconds": 3.0,
        "settle_seconds": 1.5,
        "metrics": ["rms_mm", "rms_settled_mm", "calib_rms_mm", "tracker_points"],
        "scenarios": list(scenarios),
        "agents": list(agents),
        "env": dict(ENV),
    } | extra
    return parse_config(raw, source="iso.toml")


def test_isolation_changes_no_number_of_the_shipped_agents():
    for name, scenario in (
        ("feedforward", "geometric"),
        ("mpc-oracle", "payload"),
        ("mpc", "thermal"),
    ):
        cfg = config([name], seeds=[3], scenarios=[scenario], isolate="none")
        (spec,) = cfg.runs()
        here = execute_run(spec)
        (iso_spec,) = config([name], seeds=[3], scenarios=[scenario], isolate="all").runs()
        assert iso_spec.isolate and not spec.isolate and iso_spec.run_hash == spec.run_hash
        there = execute_run(iso_spec)
        assert there.pop("isolated") is True and here.pop("isolated") is False
        for k in ("metrics", "report", "calibration", "episode", "oracle"):
            assert jsonable(there[k]) == jsonable(here[k]), (name, k)  # NaN as null
        for k in ("time", "true_error_mm", "judged"):
            assert np.array_equal(there["series"][k], here["series"][k]), (name, k)
        if name == "mpc":  # the isolated agent's model came back to be judged
            assert np.isfinite(there["metrics"]["calib_rms_mm"])


def test_agents_get_a_seed_that_reveals_nothing_and_oracle_status_is_fixed_before_reset(tmp_path):
    cfg = config(
        [
            "tests._user_agent:ProcessSnoop",
            "tests._user_agent:LateOracle",
            "tests._user_agent:LateClaim",
        ],
        seeds=1,
    )
    summary = run_sweep(cfg, tmp_path, workers=0)  # in this process: isolation still holds
    assert not summary.failed
    store = RunStore(tmp_path)
    snoop = store.load("ProcessSnoop__geometric__ep0")
    seed = snoop["spec"]["seed"]
    assert 2**32 <= seed < 2**63  # drawn at sweep time, recorded in the run's spec
    rep = snoop["report"]
    assert rep["seed_given"] == agent_seed(seed) != seed
    assert rep["truth_given"] == [False] and snoop["isolated"] is True
    # no env, plant, truth or unfiltered info anywhere in the agent's process
    assert rep["found"] == dict.fromkeys(rep["found"], 0)
    late = store.load("LateOracle__geometric__ep0")
    assert late["oracle"] is True and late["report"]["truth_given"] == [True]
    claim = store.load("LateClaim__geometric__ep0")
    assert claim["oracle"] is False and claim["report"]["truth_given"] == [False]


def test_in_one_process_the_snoop_finds_the_episode():
    """What isolation keeps out: run in the runner's process, the same agent finds the env, the
    plant and the truth (so the test above can fail)."""
    from tests._user_agent import ProcessSnoop

    r = run_episode(ProcessSnoop(), {"scenario": "geometric", **ENV}, seed=0, episode_seconds=0.1)
    found = r.report["found"]
    assert found["SixAxisTrackEnv"] >= 1 and found["EpisodeTruth"] >= 1 and found["frames"] >= 1


CHEATS = ("tests._cheats:SeedRebuilder", "tests._cheats:PathMatcher")


def test_the_cheats_reach_the_oracle_where_a_route_is_open():
    """In the runner's process on a public seed, both cheats take the truth and track exactly
    as the oracle does: the routes the audit found, still open there."""
    from tests._cheats import PathMatcher, SeedRebuilder

    kw = {"scenario": "geometric", **ENV}
    oracle = run_episode(make_agent("mpc-oracle"), kw, seed=2, episode_seconds=1.0)
    for cheat in (SeedRebuilder(env=ENV), PathMatcher(env=ENV, max_seed=4)):
        r = run_episode(cheat, kw, seed=2, episode_seconds=1.0)
        assert r.report["found_truth"], type(cheat).__name__
        assert np.allclose(r.true_error_mm, oracle.true_error_mm, rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_the_cheats_in_a_sweep_get_mpcs_numbers_not_the_oracles(tmp_path):
    cfg = config(
        [
            "mpc",
            "mpc-oracle",
            *({"name": c, "settings": {"env": dict(ENV)}} for c in CHEATS),
        ],
        seeds=1,
    )
    assert not run_sweep(cfg, tmp_path, workers=2).failed
    store = RunStore(tmp_path)
    for k in range(1):
        mpc = store.load(f"mpc__geometric__ep{k}")["metrics"]
        oracle = store.load(f"mpc-oracle__geometric__ep{k}")["metrics"]
        assert oracle["rms_mm"] < 0.7 * mpc["rms_mm"]  # the truth is worth something here
        for cheat in ("SeedRebuilder", "PathMatcher"):
            rec = store.load(f"{cheat}__geometric__ep{k}")
            assert rec["report"] == {"found_truth": False, "route": ""}
            assert rec["oracle"] is False
            assert rec["metrics"]["rms_mm"] == mpc["rms_mm"]
            assert rec["metrics"]["rms_settled_mm"] == mpc["rms_settled_mm"]


def test_an_isolated_agent_that_fails_says_so_and_its_process_ends():
    with IsolatedAgent("tests._user_agent:Raises", {"at": 2}) as agent:
        proc = agent._proc
        with pytest.raises(AgentFailure, match="act raised RuntimeError: deliberate failure"):
            run_episode(agent, {"scenario": "geometric", **ENV}, seed=0, episode_seconds=1.0)
    assert proc is not None and proc.poll() is not None
    with pytest.raises(AgentFailure, match=r"unknown setting\(s\) gain"):
        IsolatedAgent("tests._user_agent:Raises", {"gain": 1})
