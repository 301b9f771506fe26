"""The episode loop and the registry: determinism, phases, plain-data results, clear errors."""

from __future__ import annotations

import inspect
import json
import pickle

import numpy as np
import pytest

from agents.base import Agent
from agents.registry import POLICIES, AgentError, agent_names, make_agent
from agents.runner import EpisodeResult, Phase, calibrate_then_blind, run_episode
from tests._agents_kinsim import register_kinematic_env


@pytest.fixture(scope="module")
def env_id():
    return register_kinematic_env()


class ConstantAgent(Agent):
    """A user's controller, loaded by import path in the tests below."""

    name = "constant"

    def __init__(self, value: float = 0.1) -> None:
        super().__init__()
        self.value = value

    def reset(self, task, seed=None, truth=None):
        self.task = task

    def act(self, obs, info):
        return np.full(6, self.value)


def test_same_seed_same_numbers(env_id):
    a = run_episode(make_agent("mpc"), {"scenario": "geometric"}, seed=3, env_id=env_id)
    b = run_episode(make_agent("mpc"), {"scenario": "geometric"}, seed=3, env_id=env_id)
    for field in ("time", "true_error_mm", "actions", "measurement"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.report["parameters"] == b.report["parameters"]
    c = run_episode(make_agent("mpc"), {"scenario": "geometric"}, seed=4, env_id=env_id)
    assert not np.array_equal(a.true_error_mm, c.true_error_mm)


def test_result_is_plain_data(env_id):
    r = run_episode(
        make_agent("nominal"), {"scenario": "geometric"}, seed=0, env_id=env_id, episode_seconds=1.0
    )
    assert len(r.time) == 50 and r.actions.shape == (50, 6)
    back = pickle.loads(pickle.dumps(r))
    assert isinstance(back, EpisodeResult)
    np.testing.assert_array_equal(back.true_error_mm, r.true_error_mm)
    json.dumps(r.to_dict(), allow_nan=True)  # JSON-serialisable
    assert set(r.truth_parameters) >= {"dalpha2", "bx"}


def test_phases_keep_the_arm_and_switch_the_tracker_off(env_id):
    phases = calibrate_then_blind(2.0, 2.0, judge_trajectory="lemniscate")
    r = run_episode(
        make_agent("mpc"), {"scenario": "geometric"}, seed=1, env_id=env_id, phases=phases
    )
    assert len(r.time) == 200
    assert np.all(np.diff(r.time) > 0)  # time runs on across phases
    cal, blind = r.phase == 0, r.phase == 1
    assert np.isfinite(r.measurement[cal]).any()
    assert not np.isfinite(r.measurement[blind]).any()
    assert np.array_equal(r.judged, blind)
    assert r.rms_mm() == pytest.approx(np.sqrt(np.mean(r.true_error_mm[blind] ** 2)))


def test_a_phase_that_changes_the_arm_is_refused(env_id):
    phases = [Phase("a", 0.2, {}), Phase("b", 0.2, {"scenario": "compliance"})]
    with pytest.raises(ValueError, match="change the sampled arm"):
        run_episode(
            make_agent("hold"), {"scenario": "geometric"}, seed=0, env_id=env_id, phases=phases
        )


def test_registry_names_settings_and_user_classes():
    assert set(agent_names()) == {
        "hold",
        "nominal",
        "feedforward",
        "calibrated",
        "mpc",
        "mpc-ipopt",
        "mpc-oracle",
        "mpc-diagnose",
        "policy",  # a policy file of your own (settings: path)
        *POLICIES,
    }
    assert {"ppo-residual"} <= set(POLICIES)
    assert make_agent("mpc-ipopt").name == "mpc-ipopt"
    assert make_agent("mpc-oracle").needs_truth
    assert make_agent("mpc-diagnose").name == "mpc-diagnose"
    assert not make_agent("mpc-diagnose").needs_truth
    user = make_agent("tests.test_agents_runner:ConstantAgent", value=0.2)
    assert isinstance(user, ConstantAgent) and user.value == 0.2
    with pytest.raises(AgentError, match="unknown agent 'mpcc'"):
        make_agent("mpcc")
    with pytest.raises(AgentError, match=r"unknown setting.*horizn"):
        make_agent("mpc", horizn=5)
    with pytest.raises(AgentError, match="no 'Nope'"):
        make_agent("tests.test_agents_runner:Nope")
    with pytest.raises(AgentError, match="not a subclass"):
        make_agent("tests.test_agents_runner:pytest")


def test_user_agent_runs_and_hold_is_the_floor(env_id):
    r = run_episode(
        make_agent("tests.test_agents_runner:ConstantAgent"),
        {},
        seed=0,
        env_id=env_id,
        episode_seconds=1.0,
    )
    h = run_episode(make_agent("hold"), {}, seed=0, env_id=env_id, episode_seconds=1.0)
    assert r.agent == "constant" and np.all(r.actions == 0.1)
    assert np.all(h.actions == 0.0)


def test_oracle_without_truth_is_refused():
    agent = make_agent("mpc-oracle")
    with pytest.raises(ValueError, match="truth"):
        agent.reset(type("T", (), {"robot": None})(), seed=0, truth=None)


def test_the_registry_is_one_table_of_specs():
    """Every agent is one AgentSpec (Gymnasium's EnvSpec as the model): its class loads, is an
    Agent, and takes the settings the spec makes it with; `sixaxis agents` lists every one."""
    from typer.testing import CliRunner

    from agents.base import Agent
    from agents.registry import AGENTS
    from experiments.cli import app

    for name, spec in AGENTS.items():
        assert spec.name == name and spec.summary
        cls = spec.load()
        assert issubclass(cls, Agent), name
        params = inspect.signature(cls.__init__).parameters
        assert set(spec.kwargs) <= set(params) or any(
            p.kind is p.VAR_KEYWORD for p in params.values()
        ), name
    listed = CliRunner().invoke(app, ["agents"], env={"COLUMNS": "200"})
    assert listed.exit_code == 0
    for name in AGENTS:
        assert f" {name} " in listed.stdout
