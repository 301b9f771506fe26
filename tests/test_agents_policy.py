"""Learned policies: the feedforward reference they build on, the observation option, the policy
files that load without unpickling (and refuse what would), training seeds that never touch the
leaderboard's, and the shipped policies reproducing their rows."""

from __future__ import annotations

import json
import pickle
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
from agents.policy import (
    POLICY_DIR,
    PolicyAgent,
    PolicyFileError,
    PolicyIO,
    load_policy_file,
    policy_kwargs_for_sb3,
    save_policy_file,
)
from agents.reference import FeedforwardAgent
from agents.registry import POLICIES, make_agent
from agents.runner import run_episode
from agents.training import (
    LEADERBOARD_ENV,
    LEADERBOARD_SEEDS,
    EpisodeSeeds,
    PolicyEnv,
    TrainConfig,
    TrainConfigError,
    evaluate_policy,
    load_train_config,
    make_policy_env,
    ship_policy,
)
from arm.errormodel import ErrorModel
from envs.wrappers import NominalToolObservation
from experiments.config import load_config, split_train_seed

CONFIGS = Path(__file__).resolve().parents[1] / "experiments" / "configs"
TRAIN_CONFIGS = sorted(p for p in CONFIGS.glob("*.toml") if "[train]" in p.read_text())
EXPERIMENT_CONFIGS = sorted(p for p in CONFIGS.glob("*.toml") if "[train]" not in p.read_text())


# -- feedforward ------------------------------------------------------------------------------------
def test_feedforward_feeds_the_measured_model_error_forward():
    """The offset is y - x_nom(q_y), computed here with the numpy error model (the agent uses the
    CasADi tool model): at every measurement the two agree."""
    env = gym.make("SixAxisTrack-v0", scenario="geometric", noise_mm=0.015)
    obs, info = env.reset(seed=7)
    agent = FeedforwardAgent()
    task = env.unwrapped.task
    agent.reset(task)
    model = ErrorModel(task.robot, "geometric")
    checked = 0
    for _ in range(60):
        obs, _, _, _, info = env.step(agent.act(obs, info))
        if info.get("measurement_valid"):
            agent.act(obs, info)  # takes the measurement in
            y = info["measurement"]
            x = model.predict(model.inputs(info["measurement_q"][None, :]), model.nominal())[0]
            np.testing.assert_allclose(agent.error, y - x, atol=1e-9)
            checked += 1
    assert checked >= 10
    assert 0.1e-3 < np.linalg.norm(agent.error) < 10e-3  # the arm's geometric error, mm-sized


def test_feedforward_beats_nominal_where_the_model_is_wrong():
    env = {"scenario": "geometric", "noise_mm": 0.015, "measure_every": 5}
    ff = run_episode(make_agent("feedforward"), env, seed=3, episode_seconds=6.0)
    nom = run_episode(make_agent("nominal"), env, seed=3, episode_seconds=6.0)
    assert ff.rms_mm(start=3.0) < 0.2 * nom.rms_mm(start=3.0)
    assert ff.report["measurements_used"] >= 50


# -- the observation option ----------------------------------------------------------------------
def test_nominal_tool_observation_is_the_true_tool_on_a_perfect_arm():
    """On the ``nominal`` scenario the arm is its description: the nominal tool point from the
    encoders is MuJoCo's tool point (up to the servo's tracking of the encoders, micrometres)."""
    env = NominalToolObservation(gym.make("SixAxisTrack-v0", scenario="nominal"))
    obs, info = env.reset(seed=1000)
    sl = env.obs_slices
    assert env.observation_space.shape == obs.shape == (sl["preview_minus_tool"].stop,)
    np.testing.assert_allclose(obs[sl["tool_nominal"]], info["true_tool"], atol=2e-5)
    np.testing.assert_allclose(
        obs[sl["ref_minus_tool"]], obs[sl["ref"]] - obs[sl["tool_nominal"]], atol=1e-6
    )
    pv = obs[sl["preview"]].reshape(-1, 3) - obs[sl["tool_nominal"]]
    np.testing.assert_allclose(obs[sl["preview_minus_tool"]].reshape(-1, 3), pv, atol=1e-6)
    for _ in range(20):
        obs, _, _, _, info = env.step(np.full(6, 0.1))
    np.testing.assert_allclose(obs[sl["tool_nominal"]], info["true_tool"], atol=1e-4)


# -- the policy's env -------------------------------------------------------------------------------
def test_policy_env_passes_the_sb3_checker_and_zero_residual_is_feedforward():
    from stable_baselines3.common.env_checker import check_env

    for variant in ("residual", "plain"):
        check_env(PolicyEnv(gym.make("SixAxisTrack-v0"), variant), warn=True)
    env_kw = {"scenario": "backlash", "noise_mm": 0.015, "measure_every": 5}
    ff = run_episode(make_agent("feedforward"), env_kw, seed=2, episode_seconds=4.0)
    env = PolicyEnv(gym.make("SixAxisTrack-v0", **env_kw), "residual")
    env.reset(seed=2)
    errs = []
    for _ in range(len(ff.time)):
        _, reward, *_, info = env.step(np.zeros(3))
        errs.append(info["true_error_mm"])
        assert reward == pytest.approx(-np.log1p(errs[-1] / 0.05))
    np.testing.assert_array_equal(errs, ff.true_error_mm)


def test_the_improvement_reward_is_the_gain_over_feedforward_on_the_same_episode():
    env_kw = {"scenario": "backlash", "noise_mm": 0.015, "measure_every": 5}
    ff = run_episode(make_agent("feedforward"), env_kw, seed=4, episode_seconds=3.0)
    cfg = TrainConfig(reward="improvement", reward_scale_mm=0.05, env=dict(LEADERBOARD_ENV))
    env = make_policy_env(cfg, "backlash")
    # a zero residual is the base itself: exactly no gain at any step
    env.reset(seed=4)
    for _ in range(len(ff.time)):
        _, reward, *_ = env.step(np.zeros(3))
        assert reward == 0.0
    # any other residual earns ln(1 + e_ff / s) - ln(1 + e / s), where e_ff is what the
    # feedforward agent, run alone on the same seed, made at that instant
    env.reset(seed=4)
    rng = np.random.default_rng(0)
    total = 0.0
    for k in range(len(ff.time)):
        _, reward, *_, info = env.step(rng.uniform(-0.6, 0.6, 3))
        want = np.log1p(ff.true_error_mm[k] / 0.05) - np.log1p(info["true_error_mm"] / 0.05)
        assert reward == pytest.approx(want, rel=1e-12, abs=1e-12)
        total += reward
    assert total < 0  # random offsets of up to 0.3 mm only hurt
    env.close()
    with pytest.raises(ValueError, match="residual"):
        PolicyEnv(gym.make("SixAxisTrack-v0"), "plain", reward="improvement")


def test_action_penalties_charge_the_residual_and_its_change():
    env_kw = {"scenario": "backlash", "noise_mm": 0.015, "measure_every": 5}
    plain = PolicyEnv(gym.make("SixAxisTrack-v0", **env_kw), "residual")
    charged = PolicyEnv(
        gym.make("SixAxisTrack-v0", **env_kw),
        "residual",
        action_penalty=0.3,
        action_change_penalty=0.2,
    )
    plain.reset(seed=3)
    charged.reset(seed=3)
    actions = [np.array([0.5, -0.2, 0.1]), np.array([0.5, -0.2, 0.1]), np.array([2.0, 0.0, 0.0])]
    prev = np.zeros(3)
    for a in actions:
        _, r0, *_ = plain.step(a)
        _, r1, *_ = charged.step(a)
        applied = np.clip(a, -1.0, 1.0)  # the env clips what it applies, and charges that
        size = float(np.sum(applied**2))
        change = float(np.sum((applied - prev) ** 2))
        assert r1 == pytest.approx(r0 - 0.3 * size - 0.2 * change, rel=1e-12, abs=1e-12)
        prev = applied


def test_a_full_residual_moves_the_target_by_offset_mm():
    io = PolicyIO("residual", offset_mm=0.5)
    env = gym.make("SixAxisTrack-v0", scenario="nominal", noise_mm=0.0)
    obs, info = env.reset(seed=5)
    io.reset(env.unwrapped.task)
    io.features(obs, info)
    seen = []
    base = io.base
    orig = base.track

    def spy(o, info, offset=None):
        seen.append(offset)
        return orig(o, info, offset)

    base.track = spy  # type: ignore[method-assign]
    io.action(np.array([1.0, -1.0, 0.5]))
    np.testing.assert_allclose(seen[0], -base.error + np.array([0.5, -0.5, 0.25]) * 1e-3)


# -- policy files -----------------------------------------------------------------------------------
def _fresh_model(algo):
    import stable_baselines3 as sb3

    env = PolicyEnv(gym.make("SixAxisTrack-v0"), "residual")
    cls = {"ppo": sb3.PPO, "sac": sb3.SAC, "td3": sb3.TD3}[algo]
    kw = {"policy_kwargs": {"net_arch": [16, 16]}}
    if algo != "td3":
        kw["use_sde"] = True
    if algo == "sac":
        kw["learning_starts"] = 0
    return cls("MlpPolicy", env, seed=3, device="cpu", **kw), env


def _norm(n):
    rng = np.random.default_rng(0)
    return {
        "obs_mean": rng.normal(size=n),
        "obs_var": rng.uniform(0.5, 2.0, size=n),
        "obs_clip": 10.0,
        "obs_epsilon": 1e-8,
    }


def _meta(algo, n, m):
    return {
        "name": f"{algo}-test",
        "variant": "residual",
        "obs_size": n,
        "act_size": m,
        "offset_mm": 0.5,
        "policy_kwargs": {"net_arch": [16, 16]},
        "use_sde": algo != "td3",
    }


@pytest.mark.parametrize("algo", ["ppo", "sac", "td3"])
def test_policy_files_act_as_the_trained_network(tmp_path, algo):
    """Weights exported to .npz and loaded into a freshly built network give stable-baselines3's
    own deterministic actions, to float32 rounding: the loaded network infers in float64, the
    trained one in float32."""
    model, env = _fresh_model(algo)
    n, m = env.observation_space.shape[0], env.action_space.shape[0]
    norm = _norm(n)
    path = save_policy_file(tmp_path / "p.npz", algo, model.policy, norm, _meta(algo, n, m))
    net, meta = load_policy_file(path)
    assert meta["algo"] == algo and json.loads(path.with_suffix(".json").read_text())["format"]
    with np.load(path, allow_pickle=False) as data:
        assert all(data[k].dtype.kind == "f" for k in data.files)
    rng = np.random.default_rng(1)
    for _ in range(5):
        f = rng.normal(size=n).astype(np.float32) * 3
        x = np.clip((f - norm["obs_mean"]) / np.sqrt(norm["obs_var"] + 1e-8), -10, 10)
        want, _ = model.predict(x.astype(np.float32), deterministic=True)
        np.testing.assert_allclose(net.act(f), want, rtol=0, atol=1e-5)
        assert not np.array_equal(net.act(f), want.astype(float))  # not float32 any more


def test_a_structured_network_is_a_linear_law_plus_its_mlp(tmp_path):
    """policy_kwargs.structured (agents.structured, PPO): the action's mean is W_l x + W_n mlp(x)
    + b. With the MLP's weights into the action zeroed it is the closed-form linear map of the
    normalised observation; the exported file acts as SB3's own network does; its parameter
    count is the description's; SAC has no such network."""
    import stable_baselines3 as sb3
    import torch

    from agents.policy import network_parameters, policy_class

    env = PolicyEnv(gym.make("SixAxisTrack-v0"), "residual")
    kwargs = {"net_arch": [16, 16], "structured": True}
    cls = policy_class("ppo", kwargs)
    model = sb3.PPO(
        cls, env, seed=3, device="cpu", policy_kwargs=policy_kwargs_for_sb3(kwargs), use_sde=True
    )
    n, m = env.observation_space.shape[0], env.action_space.shape[0]
    weight = model.policy.action_net.weight
    assert tuple(weight.shape) == (m, n + 16)
    own = sum(p.numel() for p in model.policy.parameters() if p.requires_grad)
    sde = model.policy.log_std.numel()  # gSDE's exploration matrix: not in the acting network
    assert network_parameters("ppo", kwargs, n, m, "x") == own - sde
    norm = _norm(n)
    meta = _meta("ppo", n, m) | {"policy_kwargs": kwargs}
    path = save_policy_file(tmp_path / "s.npz", "ppo", model.policy, norm, meta)
    net, _ = load_policy_file(path)
    rng = np.random.default_rng(2)
    f = rng.normal(size=n) * 3
    x = np.clip((f - norm["obs_mean"]) / np.sqrt(norm["obs_var"] + 1e-8), -10, 10)
    want, _ = model.predict(x.astype(np.float32), deterministic=True)
    np.testing.assert_allclose(net.act(f), want, rtol=0, atol=1e-5)
    with torch.no_grad():
        weight[:, n:] = 0.0  # the MLP's path closed: what is left is linear in x
    net, _ = load_policy_file(save_policy_file(tmp_path / "l.npz", "ppo", model.policy, norm, meta))
    w = weight.detach().numpy().astype(float)[:, :n]
    b = model.policy.action_net.bias.detach().numpy().astype(float)
    np.testing.assert_allclose(net.act(f), np.clip(w @ x + b, -1, 1), rtol=0, atol=1e-5)
    with pytest.raises(TrainConfigError, match="PPO"):
        policy_class("sac", kwargs)
    bad = _meta("sac", n, m) | {"algo": "sac", "policy_kwargs": kwargs}
    (tmp_path / "q.json").write_text(json.dumps(bad | {"format": "sixaxis-policy/1"}))
    np.savez(tmp_path / "q.npz", obs_mean=np.zeros(n))
    with pytest.raises(PolicyFileError, match="structured"):
        load_policy_file(tmp_path / "q.npz")


def _evil_pickle(marker: Path) -> bytes:
    class Payload:
        def __reduce__(self):
            return (Path.touch, (marker,))

    return pickle.dumps(Payload())


def _evil_zip(tmp_path: Path, marker: Path) -> Path:
    """A stable-baselines3-shaped zip whose payload creates ``marker`` if unpickled."""
    path = tmp_path / "policy.zip"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("data", json.dumps({"policy_class": {":serialized:": "gAR9lC4="}}))
        z.writestr("pytorch_variables.pth", _evil_pickle(marker))
        z.writestr("policy.pth", _evil_pickle(marker))
    return path


def _evil_npz(tmp_path: Path, marker: Path) -> Path:
    """A .npz whose array is a pickled object that creates ``marker`` if unpickled."""
    path = tmp_path / "evil.npz"
    np.savez(path, **{"weights/x": np.array([_Touch(marker)], dtype=object)})
    path.with_suffix(".json").write_text(json.dumps(_meta("ppo", 62, 3) | {"algo": "ppo"}))
    return path


class _Touch:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_unsafe_policy_files_are_refused_and_nothing_of_them_runs(tmp_path):
    marker = tmp_path / "pwned"
    evil = _evil_zip(tmp_path, marker)
    with pytest.raises(PolicyFileError, match="refusing"):
        load_policy_file(evil)
    with pytest.raises(PolicyFileError, match="refusing"):
        PolicyAgent(path=str(evil))
    renamed = evil.with_suffix(".npz")
    renamed.write_bytes(evil.read_bytes())
    renamed.with_suffix(".json").write_text(json.dumps(_meta("ppo", 62, 3) | {"algo": "ppo"}))
    with pytest.raises(PolicyFileError):
        load_policy_file(renamed)
    with pytest.raises(PolicyFileError, match="not a policy weight file"):
        load_policy_file(_evil_npz(tmp_path, marker))
    assert not marker.exists()


def test_a_policy_file_must_fit_its_description(tmp_path):
    model, env = _fresh_model("ppo")
    n, m = env.observation_space.shape[0], env.action_space.shape[0]
    path = save_policy_file(tmp_path / "p.npz", "ppo", model.policy, _norm(n), _meta("ppo", n, m))
    meta = json.loads(path.with_suffix(".json").read_text())
    path.with_suffix(".json").write_text(json.dumps(meta | {"policy_kwargs": {"net_arch": [8]}}))
    with pytest.raises(PolicyFileError, match="do not fit"):
        load_policy_file(path)
    path.with_suffix(".json").write_text(
        json.dumps(meta | {"policy_kwargs": {"activation_fn": "os.system"}})
    )
    with pytest.raises(PolicyFileError, match="activation_fn"):
        load_policy_file(path)
    path.with_suffix(".json").unlink()
    with pytest.raises(PolicyFileError, match="description"):
        load_policy_file(path)


# -- seeds ------------------------------------------------------------------------------------------
def _leaderboard_seeds() -> set[int]:
    seeds: set[int] = set(LEADERBOARD_SEEDS)
    for p in EXPERIMENT_CONFIGS:
        seeds |= set(load_config(p, check_agents=False).seeds)
    return seeds


def test_no_training_seed_is_a_leaderboard_seed():
    assert TRAIN_CONFIGS, "no training configs found"
    board = _leaderboard_seeds()
    assert {0, 1, 2, 3, 4} <= board
    runs = []
    for p in TRAIN_CONFIGS:
        for seed in range(10):
            cfg = load_train_config(p, seed=seed)
            train, ev = set(cfg.training_seeds()), set(cfg.evaluation_seeds())
            assert not train & board, (p.name, seed)
            assert not ev & board and not ev & train, (p.name, seed)
            runs.append(train)
    # the three shipped training seeds of one config never share an episode
    for p in TRAIN_CONFIGS:
        a, b, c = (set(load_train_config(p, seed=s).training_seeds()) for s in (1, 2, 3))
        assert not (a & b or b & c or a & c)


def test_shipped_policies_are_judged_on_the_leaderboards_episodes():
    from agents import training

    full = load_config(CONFIGS / "full.toml", check_agents=False)
    # the leaderboard draws its seeds when it is swept (from 2**32 up, never a training or
    # evaluation seed); a shipped policy's file records its episodes on the public seeds 0-4
    assert full.draw_seeds >= 20 and training.LEADERBOARD_SEEDS == (0, 1, 2, 3, 4)
    assert training.LEADERBOARD_SCENARIOS == tuple(s.scenario for s in full.scenarios)
    assert training.LEADERBOARD_ENV == full.env
    assert training.EPISODE_SECONDS == full.episode_seconds
    assert training.SETTLE_SECONDS == full.settle_seconds


def test_training_envs_are_reset_with_the_runs_seeds():
    cfg = TrainConfig(total_timesteps=2000, n_envs=2, seed=2)
    seeds = cfg.training_seeds()
    seq = EpisodeSeeds(seeds.start, seeds.stop)
    envs_ = [make_policy_env(cfg, sc, seq) for sc in ("nominal", "backlash")]
    used = []
    for env in envs_ * 2:
        env.reset(seed=0)  # the vector env's seed is ignored
        used.append(env.last_seed)
    assert used == list(range(seeds.start, seeds.start + 4))
    assert seeds.start >= 1000


def test_bad_training_configs_are_refused(tmp_path):
    p = tmp_path / "c.toml"
    cases = {
        "[train]\nlearnig_rate = 1e-3\n": r"unknown key.*learnig_rate",
        "[train]\nn_envs = 'four'\n": "n_envs must be an integer",
        "[train]\nvariant = 'fancy'\n": "variant",
        "[train]\nepisode_seed_base = 3\n": "leaderboard",
        "[train]\nalgo = 'sac'\n[train.hyperparameters]\nclip_range = 0.2\n": "SAC takes no clip_range",
        "[train]\nscenarios = ['geometric', 'bogus']\n": r"scenarios\[1\]",
        "[train]\n[train.env]\nnoise = 0.1\n": "env",
        "[train]\naction_penalty = -0.1\n": "action_penalty must be >= 0",
        "[train]\ncritic_burn_in = 1000\n": "PPO has no critic",
        "[train]\nreward = 'better'\n": "reward must be one of log, improvement, env",
        "[train]\nvariant = 'plain'\nreward = 'improvement'\n": "for residual policies",
    }
    for text, match in cases.items():
        p.write_text(text)
        with pytest.raises(TrainConfigError, match=match):
            load_train_config(p)
    for cfg in TRAIN_CONFIGS:
        load_train_config(cfg)


# -- the shipped policies ---------------------------------------------------------------------------
def test_the_shipped_policies_are_weight_files():
    assert {"ppo-residual"} <= set(POLICIES)
    assert {"sac-residual", "td3-residual"} & set(POLICIES)  # the off-policy residual
    full = load_config(CONFIGS / "full.toml", check_agents=False)
    # every one on the leaderboard, over its training seeds (each seed's network a file of its own)
    ranked = {split_train_seed(a.label)[0] for a in full.agents}
    assert set(POLICIES) <= ranked
    for a in full.agents:
        if split_train_seed(a.label)[1] is not None:
            assert a.agent == "policy" and Path(a.settings["path"]).stem == a.label
            assert (POLICY_DIR.parents[1] / a.settings["path"]).exists(), a.label
    for name in POLICIES:
        path = POLICY_DIR / f"{name}.npz"
        assert path.exists(), name
        assert path.stat().st_size < 1_000_000
        _, meta = load_policy_file(path)
        assert meta["name"] == name and ("residual" in name) == (meta["variant"] == "residual")
    assert not list(POLICY_DIR.glob("*.zip")) and not list(POLICY_DIR.glob("*.pkl"))


def test_every_training_seed_ships_as_a_network_of_its_agent(tmp_path):
    """A seed's run ships to a folder of seeds as ``<agent>@s<seed>``, says which seed it is and
    of how many, and runs on the leaderboard as the agent ``policy`` with that label: the same
    network, acting exactly as the run's best policy."""
    run = tmp_path / "runs" / "ppo-residual-seed3"
    run.mkdir(parents=True)
    for ext in (".npz", ".json"):
        (run / f"best{ext}").write_bytes((POLICY_DIR / f"ppo-residual{ext}").read_bytes())
    dst = ship_policy(
        run,
        "best",
        "ppo-residual@s3",
        seeds_trained=5,
        picked="seed 3 of 5",
        folder=tmp_path / "seeds",
        evaluate=False,
    )
    assert dst == tmp_path / "seeds" / "ppo-residual@s3.npz"
    meta = json.loads(dst.with_suffix(".json").read_text())
    assert meta["name"] == "ppo-residual@s3" and "leaderboard" not in meta
    assert meta["training"]["seeds_trained"] == 5 and meta["training"]["picked"] == "seed 3 of 5"
    env = LEADERBOARD_ENV | {"scenario": "backlash"}
    shipped = run_episode(make_agent("ppo-residual"), env, seed=7).rms_mm(start=2.0)
    seed = run_episode(make_agent("policy", path=str(dst)), env, seed=7).rms_mm(start=2.0)
    assert seed == shipped


@pytest.mark.parametrize("name", POLICIES)
def test_shipped_policy_reproduces_its_leaderboard_row(name):
    path = POLICY_DIR / f"{name}.npz"
    row = json.loads(path.with_suffix(".json").read_text())["leaderboard"]
    sc = "backlash"
    got = evaluate_policy(
        path,
        scenarios=(sc,),
        seeds=tuple(row["seeds"][:2]),
        env_kwargs=row["env"],
        episode_seconds=row["episode_seconds"],
        settle_seconds=row["settle_seconds"],
    )[sc]
    # float64 inference: on another CPU (other vector units, another BLAS) the row holds to the
    # tolerance `sixaxis reproduce` promises there (tests/test_policy_reproducibility.py)
    for key in ("rms_settled_mm", "rms_mm", "return"):
        np.testing.assert_allclose(got[key], row["episodes"][sc][key][:2], rtol=1e-6)


@pytest.mark.slow
def test_shipped_residuals_beat_feedforward_where_it_is_far_from_the_oracle():
    """The residuals learned something: on held-out episodes (never trained on, never on the
    leaderboard) of backlash and all, each shipped residual's settled error is well below that of
    feedforward, its own zero-output self. (The leaderboard's targets are measured by
    benchmarks/policy_targets.py.)"""
    env = dict(LEADERBOARD_ENV)
    seeds = range(950_000, 950_004)
    residuals = [n for n in POLICIES if "residual" in n]
    assert len(residuals) >= 2
    for sc in ("backlash", "all"):
        ff = [
            run_episode(make_agent("feedforward"), env | {"scenario": sc}, seed=s).rms_mm(start=2.0)
            for s in seeds
        ]
        for name in residuals:
            got = [
                run_episode(make_agent(name), env | {"scenario": sc}, seed=s).rms_mm(start=2.0)
                for s in seeds
            ]
            assert np.mean(got) < 0.95 * np.mean(ff), (name, sc, np.mean(got) / np.mean(ff))


def test_shipped_policies_act_within_bounds():
    """Commands within [-1, 1]; a residual policy stays within its +-0.5 mm of feedforward's
    target, so it tracks about as feedforward does, never like an untrained plain policy. (The
    targets against feedforward, nominal and hold are measured by benchmarks/policy_targets.py.)"""
    env = {"scenario": "payload", "noise_mm": 0.015, "measure_every": 5}
    ff = run_episode(make_agent("feedforward"), env, seed=1, episode_seconds=4.0)
    for name in POLICIES:
        agent = make_agent(name)
        assert isinstance(agent, PolicyAgent)
        r = run_episode(agent, env, seed=1, episode_seconds=4.0)
        assert np.all(np.abs(r.actions) <= 1.0) and not r.diverged, name
        if "residual" in name:
            assert r.rms_mm(start=2.0) < ff.rms_mm(start=2.0) + 0.5, name
