"""Training runs: what they write, that the same seed gives the same policy, that a run resumes
from its checkpoint, and that the shipped policies' configs are the files that made them."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from agents.policy import POLICY_DIR, load_policy_file
from agents.registry import POLICIES
from agents.training import TrainConfig, TrainConfigError, load_train_config, train

ROOT = Path(__file__).resolve().parents[1]


def _tiny(tmp_path, algo="ppo", name="run", **kw):
    hp = {
        "ppo": {"n_steps": 64, "batch_size": 64, "n_epochs": 1},
        "sac": {"learning_starts": 64, "batch_size": 32, "buffer_size": 2000},
        "td3": {"learning_starts": 64, "batch_size": 32, "buffer_size": 2000},
    }[algo]
    hp["policy_kwargs"] = {"net_arch": [16, 16]}
    return TrainConfig(
        algo=algo,
        scenarios=("geometric", "backlash"),
        n_envs=2,
        total_timesteps=256,
        eval_every=128,
        checkpoint_every=128,
        env={"noise_mm": 0.015, "measure_every": 5, "episode_seconds": 1.0},
        output=str(tmp_path / name),
        hyperparameters=hp,
        **kw,
    )


def _rows(path):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        r.pop("wall_s"), r.pop("steps_per_s")
    return rows


@pytest.mark.slow
def test_a_training_run_writes_its_records_and_repeats_exactly(tmp_path):
    # the shipped residuals' reward, with its shadow episode: the same seed, the same numbers
    out = train(_tiny(tmp_path, name="a", reward="improvement"))
    for f in ("config.json", "curve.csv", "best.npz", "best.json", "final.npz", "summary.json"):
        assert (out / f).exists(), f
    assert (out / "checkpoint.zip").exists() and (out / "checkpoint.npz").exists()
    rows = _rows(out / "curve.csv")
    assert [int(r["steps"]) for r in rows] == [0, 128, 256]
    assert all(0 < float(r["rms_settled_mm/mean"]) < 10 for r in rows)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["timesteps"] == 256 and summary["steps_per_s"] > 0
    again = train(_tiny(tmp_path, name="b", reward="improvement"))
    assert _rows(again / "curve.csv") == rows  # the same seed, the same numbers
    a, b = np.load(out / "final.npz"), np.load(again / "final.npz")
    for k in a.files:
        np.testing.assert_array_equal(a[k], b[k])
    other = train(_tiny(tmp_path, name="c", seed=2, reward="improvement"))
    assert _rows(other / "curve.csv") != rows


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_off_policy_runs_write_loadable_policies(tmp_path, algo):
    out = train(_tiny(tmp_path, algo))
    net, meta = load_policy_file(out / "final.npz")
    assert meta["algo"] == algo and meta["timesteps"] == 256
    assert net.act(np.zeros(meta["obs_size"], dtype=np.float32)).shape == (3,)


@pytest.mark.slow
def test_the_critic_burn_in_keeps_the_actor_still(tmp_path):
    cfg = _tiny(tmp_path, "sac", name="s")
    cfg.total_timesteps = cfg.eval_every = 64
    start = train(cfg)
    kept = train(_tiny(tmp_path, "sac", name="k", critic_burn_in=10_000))
    moved = train(_tiny(tmp_path, "sac", name="m"))

    def actor(out):
        with np.load(out / "final.npz") as f:
            return {k: f[k] for k in f.files if k.startswith("weights/")}

    a0, a1, a2 = actor(start), actor(kept), actor(moved)
    for k in a0:  # SAC updated nothing of the actor before its 64 learning_starts steps
        np.testing.assert_array_equal(a1[k], a0[k])
    assert any(not np.array_equal(a2[k], a0[k]) for k in a0)


@pytest.mark.slow
def test_a_run_resumes_from_its_checkpoint(tmp_path):
    cfg = _tiny(tmp_path, name="r")
    cfg.total_timesteps = 512
    first = json.loads((train(cfg, stop_at=256) / "summary.json").read_text())
    assert first["timesteps"] == 256 and first["resumed_at"] == 0
    out = train(cfg, resume=True)
    steps = [int(r["steps"]) for r in _rows(out / "curve.csv")]
    assert steps == [0, 128, 256, 384, 512]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["resumed_at"] == 256 and summary["timesteps"] == 512
    # the run's wall time is both sessions'
    assert summary["wall_s"] == pytest.approx(first["wall_s"] + summary["wall_s_this_session"])
    assert json.loads((out / "config.json").read_text())["total_timesteps"] == 512


def test_each_shipped_policy_names_the_config_that_made_it():
    """``sixaxis train`` reproduces a shipped policy from its config: the policy records the
    config it was trained with, and that is the repository's config file with the shipped seed.
    (A run's learning rate and other settings do not depend on its total steps, so a run stopped
    at step N is the first N steps of any longer one.)"""
    from pathlib import Path

    configs = Path(__file__).resolve().parents[1] / "experiments" / "configs"
    for name in POLICIES:
        _, meta = load_policy_file(POLICY_DIR / f"{name}.npz")
        # a key added to [train] after the policy was trained had its default (which keeps the
        # behaviour that policy was trained with)
        defaults = TrainConfig().to_dict()
        recorded = {k: v for k, v in defaults.items() if k not in meta["config"]} | meta["config"]
        source = configs / f"{recorded['name']}.toml"  # the recipe's file is named as its runs
        cfg = load_train_config(source, seed=recorded["seed"])
        # the run may have been launched for more steps and stopped: its evaluations up to the
        # file's total_timesteps, and so the policy selected among them, are the same
        same = {"output": "", "total_timesteps": 0}
        assert cfg.to_dict() | same == recorded | same, name
        # PPO collects whole rollouts: its last one may end past total_timesteps
        rollout = (
            cfg.n_envs * int(cfg.hyperparameters.get("n_steps", 0)) if cfg.algo == "ppo" else 0
        )
        assert meta["timesteps"] <= cfg.total_timesteps + rollout, name
        assert cfg.total_timesteps <= recorded["total_timesteps"], name


@pytest.mark.slow
def test_a_tool_policy_trains_with_fixed_scales_and_early_termination(tmp_path):
    """The plain policy's recipe: the tool interface, the interface's fixed feature scales (the
    file's normalisation is exactly them, never updated) and episodes ended once lost."""
    from envs.wrappers import ToolDisplacement

    cfg = _tiny(
        tmp_path,
        variant="tool",
        reward="log",
        obs_normalization="fixed",
        terminate_mm=5.0,
        action_change_penalty=1.0,
    )
    out = train(cfg)
    network, meta = load_policy_file(out / "final.npz")
    assert meta["variant"] == "tool" and meta["act_size"] == 3 and meta["tool_step_mm"] == 5.0
    import gymnasium as gym

    import envs  # noqa: F401

    task = gym.make("SixAxisTrack-v0").unwrapped.task
    scale = ToolDisplacement(task, 5.0).feature_scale
    np.testing.assert_array_equal(network.mean, np.zeros_like(scale))
    np.testing.assert_array_equal(network.var, scale**2)


def test_early_termination_ends_a_lost_episode_and_pays_while_tracking():
    import math

    import gymnasium as gym

    import envs  # noqa: F401
    from agents.training import PolicyEnv

    env = PolicyEnv(gym.make("SixAxisTrack-v0", scenario="nominal"), "tool", terminate_mm=2.0)
    env.reset(seed=3)
    bonus = math.log1p(2.0 / 0.05)
    rewards, ended = [], False
    for _ in range(200):  # standing still: the path runs away
        _, r, terminated, _, info = env.step(np.zeros(3))
        rewards.append(r)
        if terminated:
            ended = True
            assert info["true_error_mm"] > 2.0
            break
    assert ended
    assert all(0 < r <= bonus for r in rewards[:-1])
    assert rewards[-1] < 0  # beyond the threshold the step itself costs
    with pytest.raises(ValueError, match="log reward"):
        PolicyEnv(gym.make("SixAxisTrack-v0"), "tool", reward="env", terminate_mm=2.0)


@pytest.mark.slow
def test_a_learning_rate_schedule_follows_the_absolute_step_count_across_a_resume(tmp_path):
    """The update of the rollout that starts at step s runs at the schedule's rate at s, whether
    the run was stopped and resumed or not (SB3's own schedules restart with each learn call)."""
    from stable_baselines3 import PPO

    sched = [[0, 1e-3], [512, 0.0]]
    cfg = _tiny(tmp_path, name="s", learning_rate_schedule=sched)
    cfg.total_timesteps = 512
    train(cfg, stop_at=256)

    def lr(out):  # the optimiser's rate at the last update (saved with the model)
        return PPO.load(out / "checkpoint.zip", device="cpu").policy.optimizer.param_groups[0]["lr"]

    # rollouts of 2 envs x 64 steps: the last update before 256 is the rollout from 128
    assert lr(tmp_path / "s") == pytest.approx(1e-3 * (1 - 128 / 512))
    out = train(cfg, resume=True)
    assert lr(out) == pytest.approx(1e-3 * (1 - 384 / 512))
    assert json.loads((out / "summary.json").read_text())["resumed_with"] == {}


@pytest.mark.slow
def test_a_resume_takes_a_longer_recipe_and_refuses_another_one(tmp_path):
    """A run resumes with a config whose recipe up to the checkpoint is the same (more steps, a
    learning rate that anneals from there on: recorded in its summary) and refuses one that
    trained the steps taken differently, naming what, with the run's records untouched."""
    from agents.training import TrainConfigError

    cfg = _tiny(tmp_path, name="r")
    train(cfg)  # 256 steps at SB3's constant 3e-4
    before = (tmp_path / "r" / "config.json").read_text()
    other = _tiny(tmp_path, name="r")
    other.hyperparameters = other.hyperparameters | {"gamma": 0.9}
    with pytest.raises(TrainConfigError, match=r"hyperparameters\.gamma"):
        train(other, resume=True)
    early = _tiny(tmp_path, name="r", learning_rate_schedule=[[0, 3e-4], [100, 0.0]])
    early.total_timesteps = 512
    with pytest.raises(TrainConfigError, match="learning rate of the updates up to step 256"):
        train(early, resume=True)
    assert (tmp_path / "r" / "config.json").read_text() == before
    longer = _tiny(tmp_path, name="r", learning_rate_schedule=[[256, 3e-4], [512, 0.0]])
    longer.total_timesteps = 512
    out = train(longer, resume=True)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["timesteps"] == 512
    assert summary["resumed_with"] == {
        "total_timesteps": [256, 512],
        "learning_rate": [3e-4, [[256, 3e-4], [512, 0.0]]],
    }


def test_a_learning_rate_schedule_is_checked_where_it_is_written(tmp_path):
    base = (ROOT / "experiments" / "configs" / "ppo-scn.toml").read_text()
    schedule = "learning_rate_schedule = [[100_000, 3e-4], [700_000, 3e-5]]"
    assert schedule in base
    cases = {
        "[[600, 3e-4], [300, 0.0]]": "do not increase",
        "[[600, 3e-4, 1]]": r"\[step, learning rate\] pairs",
        "[[600, -1.0]]": r"learning_rate_schedule\[0\]: the learning rate -1.0",
    }
    for value, message in cases.items():
        path = tmp_path / "c.toml"
        path.write_text(base.replace(schedule, f"learning_rate_schedule = {value}"))
        with pytest.raises(TrainConfigError, match=message) as info:
            load_train_config(path)
        assert "c.toml" in str(info.value)
    path.write_text(base.replace("n_steps = 256", "learning_rate = 3e-4\nn_steps = 256"))
    with pytest.raises(TrainConfigError, match="give one of the two"):
        load_train_config(path)
    cfg = load_train_config(ROOT / "experiments" / "configs" / "ppo-scn.toml")
    # 3e-4 to 100k steps, linearly to 3e-5 at 700k, and there on (of the absolute step count)
    assert [cfg.learning_rate_at(s) for s in (0, 100_000, 400_000, 700_000, 2_000_000)] == [
        3e-4,
        3e-4,
        pytest.approx(1.65e-4),
        pytest.approx(3e-5),
        pytest.approx(3e-5),
    ]


def test_the_patience_rule_stops_on_a_plateau_and_not_while_improving():
    """A synthetic sequence of evaluations (settled RMS, mm): steady gains of 5 % never stop it;
    gains of 1 % an evaluation add up against the bar and never stop it either; a plateau with
    noise below 2 % stops it after exactly N evaluations; N = 0 never stops."""
    from agents.callbacks import Patience, StopWhen

    improving = Patience(5)
    assert not any(improving.update(1.0 * 0.95**k) for k in range(40))
    slow = Patience(5)
    assert not any(slow.update(1.0 * 0.99**k) for k in range(60))
    plateau = Patience(3)
    errors = [1.0, 0.8, 0.79, 0.81, 0.795]  # 0.8 is the bar; none beats it by 2 %
    said = [plateau.update(e) for e in errors]
    assert said == [False, False, False, False, True]
    callback = StopWhen(lambda: plateau.stopped)
    assert callback._on_step() is False  # SB3 ends the training on False
    assert StopWhen(lambda: improving.stopped)._on_step() is True
    later = Patience(3)
    for e in [1.0, 1.0, 1.0, 0.5]:  # a real improvement before the third evaluation resets it
        assert not later.update(e)
    assert [later.update(e) for e in (0.5, 0.5, 0.5)] == [False, False, True]
    never = Patience(0)
    assert not any(never.update(1.0) for _ in range(20))
    nan = Patience(2)
    assert [nan.update(e) for e in (float("nan"), 1.0, 1.0, 1.0)] == [False, False, False, True]


def test_patience_refuses_a_schedule_that_falls_to_zero(tmp_path):
    base = (ROOT / "experiments" / "configs" / "ppo-scn.toml").read_text()
    schedule = "learning_rate_schedule = [[100_000, 3e-4], [700_000, 3e-5]]"
    assert schedule in base and "patience = 5 " in base
    path = tmp_path / "p.toml"
    path.write_text(base.replace(schedule, schedule.replace("3e-5", "0.0")))
    with pytest.raises(TrainConfigError, match="ends at 0 with patience on"):
        load_train_config(path)
    path.write_text(
        base.replace("patience = 5 ", "patience = 0 ").replace(
            schedule, schedule.replace("3e-5", "0.0")
        )
    )
    assert load_train_config(path).learning_rate_at(5e6) == 0.0  # no patience: it may
    assert load_train_config(ROOT / "experiments" / "configs" / "ppo-scn.toml").learning_rate_at(
        5e6
    ) == pytest.approx(3e-5)


@pytest.mark.slow
def test_a_run_stops_by_patience_and_says_so(tmp_path):
    """A run whose evaluations cannot improve (a learning rate of 0 after the first update)
    stops after ``patience`` evaluations without 2 %, long before its budget."""
    cfg = _tiny(tmp_path, name="p", patience=2, learning_rate_schedule=[[0, 1e-12]])
    cfg.total_timesteps = 100_000
    out = train(cfg)
    steps = [int(r["steps"]) for r in _rows(out / "curve.csv")]
    assert steps == [0, 128, 256]  # the bar at 0, two evaluations without a 2 % gain
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped_by_patience"] is True and summary["timesteps"] == 256


@pytest.mark.slow
def test_a_run_writes_sb3s_diagnostics_when_asked(tmp_path):
    """``diagnostics=DIR``: SB3's own logger writes its standard scalars (PPO's KL, clip fraction,
    entropy, explained variance) to DIR/progress.csv, one row per update; TensorBoard's event
    files too where it is installed."""
    import importlib.util

    cfg = _tiny(tmp_path, name="d")
    train(cfg, diagnostics=tmp_path / "logs")
    with open(tmp_path / "logs" / "progress.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) >= 2
    for key in (
        "train/approx_kl",
        "train/clip_fraction",
        "train/entropy_loss",
        "train/explained_variance",
    ):
        assert any(r.get(key) not in (None, "") for r in rows), key
    events = list((tmp_path / "logs").glob("events.out.tfevents.*"))
    assert bool(events) == (importlib.util.find_spec("tensorboard") is not None)


@pytest.mark.slow
def test_a_tool_policy_with_the_observe_option_trains_at_its_declared_scales(tmp_path):
    """``observe`` reaches the policy: the file records it, its normalisation is the
    interface's declared offsets and scales, and the shipped agent rebuilds the same features."""
    from agents.policy import PolicyAgent
    from agents.runner import run_episode
    from envs.wrappers import ToolDisplacement

    cfg = _tiny(
        tmp_path,
        variant="tool",
        reward="log",
        obs_normalization="fixed",
        observe=("joints", "payload", "temperature"),
    )
    out = train(cfg)
    network, meta = load_policy_file(out / "final.npz")
    assert meta["observe"] == ["joints", "payload", "temperature"] and meta["obs_size"] == 54
    import gymnasium as gym

    import envs  # noqa: F401

    task = gym.make("SixAxisTrack-v0").unwrapped.task
    tool = ToolDisplacement(task, 5.0, observe=("joints", "payload", "temperature"))
    np.testing.assert_array_equal(network.mean, tool.feature_offset)
    np.testing.assert_array_equal(network.var, tool.feature_scale**2)
    r = run_episode(
        PolicyAgent(path=str(out / "final")), {"scenario": "thermal"}, seed=0, episode_seconds=0.5
    )
    assert np.isfinite(r.true_error_mm).all()


TINY_TOML = """[train]
algo = "ppo"
scenarios = ["geometric"]
n_envs = 2
total_timesteps = 256
eval_every = 128
checkpoint_every = 128
[train.env]
episode_seconds = 1.0
[train.hyperparameters]
n_steps = 64
batch_size = 64
n_epochs = 1
policy_kwargs = { net_arch = [16, 16] }
"""


@pytest.mark.slow
def test_sixaxis_train_writes_diagnostics_where_asked(tmp_path):
    from typer.testing import CliRunner

    from experiments.cli import app

    config = tmp_path / "tiny.toml"
    config.write_text(TINY_TOML)
    logs = tmp_path / "logs"
    args = ["train", "ppo", "--config", str(config), "--output", str(tmp_path / "run")]
    res = CliRunner().invoke(app, [*args, "--diagnostics", str(logs)])
    assert res.exit_code == 0, res.output
    header = (logs / "progress.csv").read_text().splitlines()[0].split(",")
    assert {"train/approx_kl", "train/clip_fraction", "train/explained_variance"} <= set(header)


def test_the_tuning_grid_trains_each_point_at_its_gamma_and_rate_for_equal_budgets(tmp_path):
    """benchmarks/ppo_tuning.py: each point is ppo-scn.toml with its gamma and a constant
    learning rate, the same budget and no patience (equal cost), in a folder of its own."""
    import argparse

    from benchmarks.ppo_tuning import CONFIG, point_config

    args = argparse.Namespace(
        config=CONFIG, seed=1, runs=tmp_path, budget=200_000, eval_every=50_000, eval_episodes=2
    )
    a, b = point_config(args, 0.95, 1e-3), point_config(args, 0.98, 1e-4)
    assert (a.hyperparameters["gamma"], a.learning_rate_at(0), a.learning_rate_at(1e6)) == (
        0.95,
        1e-3,
        1e-3,
    )
    assert b.hyperparameters["gamma"] == 0.98 and b.learning_rate_at(5e5) == 1e-4
    assert a.patience == b.patience == 0 and a.total_timesteps == b.total_timesteps == 200_000
    assert a.observe == ("joints", "payload", "temperature") and a.output != b.output
    assert load_train_config(CONFIG).patience == 5
