"""No truth to agents: a user's agent joined by class path sees only the controllers' info keys,
a task without the scenario and no truth object; an oracle declares itself, gets the truth (the
plant's exact payload included) and is marked on the leaderboard. The env's temperature is a
sensor (lag and noise) and its payload the operator's declaration (late and wrong in the payload
scenario)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
from agents.registry import make_agent
from agents.runner import run_episode
from envs.instrument import InstrumentError, TemperatureSensor
from envs.task import CONTROLLER_INFO_KEYS
from experiments.config import parse_config
from experiments.leaderboard import build_leaderboard, to_markdown
from experiments.sweep import run_sweep

HIDDEN = {
    "true_error_mm",
    "true_tool",
    "reward_tracking",
    "reward_jerk",
    "temperature",
    "payload",
    "trajectory",
}


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """A user's agent and a user's oracle, by class path, through a real sweep (local
    processes: what a user runs)."""
    root = tmp_path_factory.mktemp("truth")
    cfg = parse_config(
        {
            "name": "truth",
            "seeds": [0],
            "episode_seconds": 6.0,
            "settle_seconds": 1.0,
            "metrics": ["rms_mm", "rms_settled_mm", "converge_s"],
            "scenarios": ["payload", "thermal"],
            "agents": ["tests._user_agent:Snoop", "tests._user_agent:SnoopOracle"],
            "env": {"trajectory": "circle", "episode_seconds": 6.0},
        },
        source="truth.toml",
    )
    summary = run_sweep(cfg, root / "runs", workers=2)
    assert not summary.failed
    return root / "runs"


def test_a_users_agent_sees_no_truth_no_reward_and_no_scenario(sweep):
    from experiments.records import RunStore

    for scen in ("payload", "thermal"):
        rep = RunStore(sweep).load(f"Snoop__{scen}__seed0")["report"]
        keys = set(rep["info_keys"])
        assert keys <= CONTROLLER_INFO_KEYS
        assert {"measurement", "measurement_valid", "reference", "time"} <= keys
        assert not keys & HIDDEN and not any(k.startswith(("true_", "reward")) for k in keys)
        assert "scenario" not in rep["task_fields"]
        assert rep["truth_given"] == [False]
        # the measurement's columns are the sensors' (the lab's column names)
        assert set(rep["column_keys"]) >= {"t", "temperature", "payload", "dir1"}


def test_an_oracle_gets_the_truth_and_its_row_is_marked(sweep):
    from experiments.records import RunStore

    store = RunStore(sweep)
    rec = store.load("SnoopOracle__payload__seed0")
    rep = rec["report"]
    assert rec["oracle"] is True and store.load("Snoop__payload__seed0")["oracle"] is False
    assert rep["truth_given"] == [True] and rep["scenario"] == "payload"
    assert not set(rep["info_keys"]) & HIDDEN  # the info is filtered for oracles too
    md = to_markdown(build_leaderboard(sweep, allow_dirty=True))
    names = {ln.split("|")[1].strip() for ln in md.splitlines() if ln.startswith("| Snoop")}
    # (this checkout's local changes, if any, are marked too)
    assert {n.replace(" (local changes)", "") for n in names} == {"Snoop", "SnoopOracle (oracle)"}
    assert make_agent("mpc-oracle").needs_truth and not make_agent("mpc").needs_truth


def test_the_payload_change_is_declared_late_while_the_oracle_sees_it_at_once(sweep):
    from experiments.records import RunStore

    env = gym.make("SixAxisTrack-v0", scenario="payload", trajectory="circle", episode_seconds=6.0)
    env.reset(seed=0)
    truth = env.unwrapped.truth
    env.close()
    ((change, mass),) = truth.hidden.payload_schedule
    (_, first), (declared_at, declared) = truth.declared_payload
    assert first == truth.hidden.payload0 and declared_at > change + 0.5 - 1e-9
    rep = RunStore(sweep).load("SnoopOracle__payload__seed0")["report"]
    t = 0.02 * np.arange(len(rep["true_payload"]))  # act() before step k sees time k * dt
    true, seen = np.array(rep["true_payload"]), np.array(rep["observed_payload"], dtype=float)
    assert np.allclose(true[t < change - 0.03], truth.hidden.payload0)
    assert np.allclose(true[t > change + 0.03], mass)
    # what the agents observe: the start's payload until the declaration, then the declaration
    assert np.allclose(seen[t < declared_at - 0.03], np.float32(first))
    assert np.allclose(seen[t > declared_at + 0.03], np.float32(declared))
    late = (t > change + 0.03) & (t < declared_at - 0.03)
    assert late.sum() >= 0.5 / 0.02 - 4 and not np.allclose(seen[late], mass)


def test_the_declaration_can_be_made_on_time_and_right_without_moving_the_arm():
    def truth(overrides=None):
        env = gym.make("SixAxisTrack-v0", scenario="payload", overrides=overrides)
        env.reset(seed=3)
        return env.unwrapped.truth

    exact = truth({"payload": {"declare_delay": 0.0, "declare_error": 0.0}})
    drawn = truth()
    assert np.array_equal(exact.params, drawn.params)
    assert exact.hidden.payload0 == drawn.hidden.payload0
    assert exact.hidden.payload_schedule == drawn.hidden.payload_schedule
    ((change, mass),) = exact.hidden.payload_schedule
    assert exact.declared_payload == ((0.0, exact.hidden.payload0), (change, mass))
    assert drawn.declared_payload != exact.declared_payload


def test_temperature_sensor_lags_and_is_noisy_as_stated():
    # the step response of a first-order lag, noise off: 1 - exp(-t / lag)
    s = TemperatureSensor(noise=0.0, lag=3.0)
    s.reset(np.random.default_rng(0), 20.0)
    readings = [s.read(30.0, 0.02) for _ in range(150)]  # 3 s
    assert readings[-1] == pytest.approx(20.0 + 10.0 * (1 - math.exp(-1.0)), rel=1e-12)
    # noise: the sample standard deviation of 20,000 readings of a constant, within 2 %
    s = TemperatureSensor(noise=0.1, lag=3.0)
    s.reset(np.random.default_rng(1), 25.0)
    x = np.array([s.read(25.0, 0.02) for _ in range(20_000)])
    assert x.mean() == pytest.approx(25.0, abs=0.005) and x.std() == pytest.approx(0.1, rel=0.02)
    with pytest.raises(InstrumentError, match="temperature_lag"):
        TemperatureSensor(lag=-1.0)


def test_the_observed_temperature_is_the_sensor_and_the_plants_stays_in_the_info():
    def temperatures(**kw):
        env = gym.make("SixAxisTrack-v0", scenario="thermal", trajectory="circle", **kw)
        sl = env.unwrapped.task.obs_slices["temperature"]
        obs, info = env.reset(seed=2)
        rows = []
        for _ in range(100):
            obs, _, _, _, info = env.step(np.full(6, 0.3))
            rows.append((obs[sl][0], info["temperature"]))
        return np.array(rows)

    exact = temperatures(temperature_noise=0.0, temperature_lag=0.0)
    assert np.allclose(exact[:, 0], exact[:, 1].astype(np.float32), rtol=0, atol=1e-5)
    sensed = temperatures()
    assert np.array_equal(sensed[:, 1], exact[:, 1])  # the same plant, only the sensor differs
    resid = sensed[:, 0] - sensed[:, 1]
    assert 0.05 < resid.std() < 0.2
    task = gym.make("SixAxisTrack-v0").unwrapped.task
    assert (task.temperature_noise, task.temperature_lag) == (0.1, 3.0)


def test_run_episode_hands_act_only_the_controllers_keys():
    from tests._user_agent import Snoop

    agent = Snoop()
    r = run_episode(agent, {"scenario": "geometric"}, seed=0, episode_seconds=0.3)
    assert set(agent.report()["info_keys"]) <= CONTROLLER_INFO_KEYS
    assert np.isfinite(r.true_error_mm).all()  # the metrics keep the truth
