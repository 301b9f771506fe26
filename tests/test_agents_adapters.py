"""``agents.from_sb3``: a freshly trained stable-baselines3 model of either interface becomes an
agent that acts as the model does, runs an episode through the runner, repeats it exactly, and
is swept and reproduced as the agent ``policy``; what cannot be written is refused by name."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import agents
import envs  # noqa: F401
from agents.policy import PolicyFileError
from agents.registry import AgentError, make_agent
from agents.runner import run_episode
from envs.task import controller_info


def _model(algo: str, env: gym.Env, steps: int = 128):
    import torch
    from stable_baselines3 import PPO, SAC

    torch.set_num_threads(1)
    if algo == "ppo":
        model = PPO(
            "MlpPolicy",
            env,
            n_steps=64,
            batch_size=64,
            n_epochs=1,
            seed=0,
            device="cpu",
            policy_kwargs={"net_arch": [16, 16], "activation_fn": torch.nn.ReLU},
        )
    else:
        model = SAC(
            "MlpPolicy",
            env,
            learning_starts=32,
            batch_size=16,
            buffer_size=500,
            seed=0,
            device="cpu",
            policy_kwargs={"net_arch": [16, 16]},
        )
    return model.learn(steps)


@pytest.fixture(scope="module")
def tool_model():
    env = gym.make("SixAxisTrack-v0", interface="tool", observe=["joints"], episode_seconds=0.5)
    return _model("ppo", env)


def test_an_sb3_tool_policy_acts_as_the_model_and_repeats_exactly(tool_model, tmp_path):
    agent = agents.from_sb3(tool_model, interface="tool", observe=["joints"], path=tmp_path / "m")
    assert (tmp_path / "m.npz").exists() and (tmp_path / "m.json").exists()
    # the agent's action is the model's own deterministic one on the wrapper's observation
    env = gym.make("SixAxisTrack-v0", interface="tool", observe=["joints"], scenario="backlash")
    raw = gym.make("SixAxisTrack-v0", scenario="backlash")
    obs, _ = env.reset(seed=3)
    robs, rinfo = raw.reset(seed=3)
    agent.reset(raw.unwrapped.task)
    for _ in range(15):
        cmd = agent.act(robs, controller_info(rinfo))
        a, _ = tool_model.predict(obs, deterministic=True)
        np.testing.assert_allclose(agent.io.prev_action, np.clip(a, -1, 1), atol=1e-5)
        obs, *_ = env.step(agent.io.prev_action)
        robs, _, _, _, rinfo = raw.step(cmd)
    kw = {"scenario": "payload"}
    first = run_episode(
        make_agent("policy", path=str(tmp_path / "m.npz")), kw, seed=1, episode_seconds=1.0
    )
    again = run_episode(
        make_agent("policy", path=str(tmp_path / "m")), kw, seed=1, episode_seconds=1.0
    )
    np.testing.assert_array_equal(first.true_error_mm, again.true_error_mm)
    assert np.isfinite(first.true_error_mm).all()


@pytest.mark.slow
def test_an_sb3_policy_of_the_joint_interface_with_its_normalisation(tmp_path):
    """SAC on the env's own interface, trained in a VecNormalize: its statistics are saved with
    it and the agent acts as the model on the normalised observation."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(
        DummyVecEnv([lambda: gym.make("SixAxisTrack-v0", episode_seconds=0.5)]), norm_reward=False
    )
    model = _model("sac", venv, steps=64)
    agent = agents.from_sb3(model, interface="joint", path=tmp_path / "j.npz", vec_normalize=venv)
    raw = gym.make("SixAxisTrack-v0", scenario="geometric")
    robs, rinfo = raw.reset(seed=0)
    agent.reset(raw.unwrapped.task)
    venv.training = False
    for _ in range(10):
        cmd = agent.act(robs, controller_info(rinfo))
        a, _ = model.predict(venv.normalize_obs(robs[None]), deterministic=True)
        np.testing.assert_allclose(cmd, a[0], atol=1e-5)
        robs, _, _, _, rinfo = raw.step(cmd)
    meta = json.loads((tmp_path / "j.json").read_text())
    assert meta["variant"] == "joint" and meta["algo"] == "sac" and meta["act_size"] == 6


@pytest.mark.slow
def test_an_sb3_policy_is_swept_and_reproduced(tool_model, tmp_path):
    from typer.testing import CliRunner

    from experiments.cli import app
    from experiments.config import load_config
    from experiments.sweep import run_sweep

    agents.from_sb3(tool_model, interface="tool", observe=["joints"], path=tmp_path / "mine.npz")
    config = tmp_path / "mine.toml"
    config.write_text(
        'name = "mine"\nseeds = [0]\nepisode_seconds = 1.0\nsettle_seconds = 0.5\n'
        'scenarios = ["geometric"]\n'
        f'[[agents]]\nname = "policy"\nlabel = "sb3-ppo"\nsettings = {{ path = "{tmp_path / "mine.npz"}" }}\n'
    )
    summary = run_sweep(load_config(config), tmp_path / "runs", workers=0)
    assert not summary.failed
    record = next((tmp_path / "runs").glob("sb3-ppo__geometric__*.json"))
    result = CliRunner().invoke(app, ["reproduce", str(record)])
    assert result.exit_code == 0, result.output
    assert "reproduced" in result.output


def test_what_cannot_be_written_is_refused_by_name(tool_model, tmp_path):
    with pytest.raises(PolicyFileError, match="joint interface's action"):
        agents.from_sb3(tool_model, interface="joint", path=tmp_path / "x")
    with pytest.raises(PolicyFileError, match="interface 'cartesian'"):
        agents.from_sb3(tool_model, interface="cartesian", path=tmp_path / "x")
    with pytest.raises(PolicyFileError, match="not a PPO, SAC or TD3"):
        agents.from_sb3(object(), path=tmp_path / "x")


def test_a_policy_is_named_or_given_as_a_file_never_both(tmp_path):
    """``policy`` is a shipped policy's name, ``path`` a file (as written, .npz added if absent):
    a file given as ``policy``, both at once, or a shipped agent given a file, are refused with
    what to write instead."""
    from agents.policy import POLICY_DIR, PolicyAgent

    shipped = POLICY_DIR / "ppo.npz"
    with pytest.raises(PolicyFileError, match="give it as path"):
        PolicyAgent(policy=str(shipped))
    with pytest.raises(AgentError, match="give one"):
        make_agent("ppo", path=str(shipped))
    with pytest.raises(PolicyFileError, match="no shipped policy 'nope'"):
        PolicyAgent(policy="nope")
    assert PolicyAgent(path=str(shipped)).path == shipped
    assert PolicyAgent(path=str(shipped.with_suffix(""))).path == shipped
    assert make_agent("policy", path=str(shipped)).name == "ppo"
    zipped = tmp_path / "model.zip"
    zipped.write_bytes(b"PK")
    with pytest.raises(PolicyFileError, match="refusing"):
        PolicyAgent(path=str(zipped))
    with pytest.raises(AgentError, match="give policy"):
        make_agent("policy")
