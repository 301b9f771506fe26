"""PPO (stable-baselines3) on SixAxisTrack-v0: training, the shipped policies, and the agent.

Two variants share one observation pipeline (:class:`PolicyFeatures`, a pure function of the
env's observation stream, so the same code runs in training and in evaluation):

* ``plain``: the policy's action is the env's action, normalised joint velocities (6).
* ``residual`` (residual RL, Johannink et al. 2019): the policy's action (3) is an offset of the
  Cartesian target, up to ``offset_mm``; the nominal resolved-rate controller
  (:class:`~agents.reference.NominalAgent`) tracks ``reference + offset``. A zero action is the
  nominal controller, so the policy only has to learn the correction, which the features make
  nearly linear: the model error that the last tracker measurement reveals.

Features (all from the observation; mm where lengths): encoder angles and velocities, the nominal
model's tracking error ``ref - x_nom(q)``, the preview relative to the reference now, the nominal
model's error at the last measurement ``meas - x_nom(q at its time)`` with its validity and age,
and the temperature. Observation normalisation is SB3's ``VecNormalize``; its statistics ship with
the policy (``agents/policies/<variant>.npz``, no pickle) next to the SB3 zip.

    sixaxis train ppo --config experiments/configs/ppo.toml      # checkpoints, eval, CSV logs
    make_agent("ppo-residual")                                   # the shipped policy

Torch runs on one thread (``torch.set_num_threads(1)``): small networks on two shared cores ran
30x slower with two.

It is one module, longer than most, because training, shipping and the agent share the feature
pipeline, which must be the same code in training and in evaluation.
"""

from __future__ import annotations

import json
import logging
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from agents.base import Agent, solve_time_stats
from agents.reference import NominalAgent
from agents.tool_model import cached_tool_model
from arm.errormodel import ErrorModel
from arm.errors import SixAxisError
from envs.task import Observation, TaskInfo, Truth

if TYPE_CHECKING:
    from stable_baselines3.common.policies import BasePolicy

__all__ = [
    "POLICY_DIR",
    "VARIANTS",
    "PPOAgent",
    "PPOConfig",
    "PPOConfigError",
    "PolicyEnv",
    "PolicyFeatures",
    "evaluate_policy",
    "load_config",
    "train",
]

log = logging.getLogger(__name__)

POLICY_DIR = Path(__file__).resolve().parent / "policies"
VARIANTS = ("plain", "residual")
MM = 1e3


class PPOConfigError(SixAxisError, ValueError):
    """A bad PPO setting: an unknown variant, or a config file that is missing, not TOML, or has
    unknown or mistyped keys."""


# --------------------------------------------------------------------------------------------------
class PolicyFeatures:
    """The policy's observation from the env's, step by step (stateful: it remembers recent
    encoder readings to pair a delayed measurement with the arm's pose at its time)."""

    def __init__(self, history_s: float = 1.0) -> None:
        self.history_s = history_s

    def reset(self, task: TaskInfo) -> None:
        self.task = task
        self.model = ErrorModel(task.robot, "geometric")
        self.p = self.model.nominal()
        self.tm = cached_tool_model(self.model)
        self.dt = float(task.dt)
        self.P = int(task.preview_steps)
        self._q: deque[np.ndarray] = deque(maxlen=max(2, round(self.history_s / self.dt) + 1))
        self._model_error = np.zeros(3)

    @property
    def size(self) -> int:
        return 6 + 6 + 3 + 3 * self.P + 3 + 2 + 1

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        o = Observation.parse(self.task, obs)
        self._q.append(np.array(o.q, dtype=float))
        x = self.tm.point(o.q, self.p)
        e_now = (o.ref - x) * MM
        pv = (o.references(self.P) - o.ref[None, :]).reshape(-1) * MM
        age = o.meas_age if np.isfinite(o.meas_age) else 1e3
        if o.meas_valid and age <= self.history_s:
            k = min(round(age / self.dt), len(self._q) - 1)
            q_then = self._q[-1 - k]
            self._model_error = (o.meas - self.tm.point(q_then, self.p)) * MM
        valid = float(o.meas_valid and age <= self.history_s)
        return np.concatenate(
            [
                o.q,
                o.qd,
                e_now,
                pv,
                self._model_error,
                [valid, min(age, self.history_s)],
                [o.temperature - 20.0],
            ]
        ).astype(np.float32)


@dataclass
class ActionMap:
    """From the policy's action to the env's: identity (plain) or a target offset tracked by the
    nominal controller (residual)."""

    variant: str = "residual"
    offset_mm: float = 3.0
    nominal: NominalAgent = field(default_factory=NominalAgent)

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise PPOConfigError(
                f"unknown PPO variant {self.variant!r}; choose {', '.join(VARIANTS)}"
            )

    @property
    def size(self) -> int:
        return 6 if self.variant == "plain" else 3

    def reset(self, task: TaskInfo) -> None:
        self.task = task
        if self.variant == "residual":
            self.nominal.reset(task)

    def __call__(self, action: np.ndarray, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        a = np.clip(np.asarray(action, dtype=float).reshape(-1), -1.0, 1.0)
        if self.variant == "plain":
            return a
        o = Observation.parse(self.task, obs)
        delta = a * self.offset_mm / MM
        shifted = Observation(
            q=o.q,
            qd=o.qd,
            ref=o.ref + delta,
            preview=o.preview + delta,
            meas=o.meas,
            meas_age=o.meas_age,
            meas_valid=o.meas_valid,
            temperature=o.temperature,
            payload=o.payload,
        )
        nom = self.nominal
        v = nom.command(shifted, nom._columns(o, info))
        moving = np.abs(v) > 1e-6
        nom.dirs[moving] = np.sign(v[moving])
        nom.v_prev = v
        return np.clip(v / np.asarray(self.task.v_max, dtype=float), -1.0, 1.0)


def _task_of(env: gym.Env) -> TaskInfo:
    """The :class:`TaskInfo` that SixAxisTrack-v0 (or a stand-in) publishes as ``unwrapped.task``."""
    task = getattr(env.unwrapped, "task", None)
    if not isinstance(task, TaskInfo):
        raise TypeError(f"{env.unwrapped!r} publishes no TaskInfo as env.unwrapped.task")
    return task


class PolicyEnv(gym.Wrapper):
    """SixAxisTrack-v0 as the policy sees it: :class:`PolicyFeatures` in, :class:`ActionMap` out."""

    def __init__(self, env: gym.Env, variant: str = "residual", offset_mm: float = 3.0) -> None:
        super().__init__(env)
        self.features = PolicyFeatures()
        self.actions = ActionMap(variant, offset_mm)
        task = _task_of(env)
        self.features.reset(task)
        n = self.features.size
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (n,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (self.actions.size,), np.float32)
        self._obs: np.ndarray | None = None
        self._info: Mapping[str, Any] = {}

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        task = _task_of(self.env)
        self.features.reset(task)
        self.actions.reset(task)
        self._obs, self._info = obs, info
        return self.features(obs), info

    def step(self, action):
        if self._obs is None:
            raise RuntimeError("PolicyEnv: call reset() before step()")
        env_action = self.actions(action, self._obs, self._info)
        obs, reward, terminated, truncated, info = self.env.step(env_action)
        self._obs, self._info = obs, info
        return self.features(obs), reward, terminated, truncated, info


# --------------------------------------------------------------------------------------------------
@dataclass
class PPOConfig:
    """Training settings (``experiments/configs/ppo.toml``, table ``[ppo]``)."""

    variant: str = "residual"
    scenarios: tuple[str, ...] = ("geometric", "compliance")
    env_kwargs: dict = field(default_factory=dict)
    total_timesteps: int = 500_000
    n_envs: int = 8
    subprocess: bool = False
    seed: int = 0
    learning_rate: float = 3e-4
    n_steps: int = 256
    batch_size: int = 256
    n_epochs: int = 10
    gamma: float = 0.98
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    net_arch: tuple[int, ...] = (64, 64)
    log_std_init: float = -1.0
    offset_mm: float = 3.0
    checkpoint_every: int = 100_000
    eval_every: int = 50_000
    eval_episodes: int = 4
    eval_seed: int = 10_000
    output: str = "runs/ppo"

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise PPOConfigError(f"ppo.variant must be one of {VARIANTS}, got {self.variant!r}")
        self.scenarios = tuple(self.scenarios)
        self.net_arch = tuple(int(x) for x in self.net_arch)


def load_config(path: str | Path) -> PPOConfig:
    """A :class:`PPOConfig` from the ``[ppo]`` table of a TOML file; unknown keys are refused."""
    import dataclasses
    import tomllib

    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise PPOConfigError(f"{path}: config file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise PPOConfigError(f"{path}: not valid TOML: {exc}") from exc
    table = doc.get("ppo")
    if not isinstance(table, dict):
        raise PPOConfigError(f"{path}: needs a [ppo] table")
    known = {f.name: f for f in dataclasses.fields(PPOConfig)}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise PPOConfigError(f"{path}: [ppo] has unknown key(s) {', '.join(unknown)}")
    defaults = PPOConfig()
    for k, v in table.items():
        want = type(getattr(defaults, k))
        ok = isinstance(v, want) or (
            want is float and isinstance(v, int) and not isinstance(v, bool)
        )
        if want is tuple and isinstance(v, list):
            ok = True
        if not ok:
            raise PPOConfigError(
                f"{path}: [ppo] {k} must be {want.__name__}, got {type(v).__name__} {v!r}"
            )
    return PPOConfig(**table)


def _make_env_fn(cfg: PPOConfig, rank: int):
    def make():
        import envs  # noqa: F401

        scenario = cfg.scenarios[rank % len(cfg.scenarios)]
        env = gym.make("SixAxisTrack-v0", scenario=scenario, **cfg.env_kwargs)
        return PolicyEnv(env, cfg.variant, cfg.offset_mm)

    return make


def _set_threads() -> None:
    import torch

    torch.set_num_threads(1)


def train(cfg: PPOConfig, progress=None, resume: str | Path | None = None) -> Path:
    """Train PPO as configured; writes checkpoints, ``progress.csv`` (SB3's logger),
    ``evaluations.npz`` and the final ``model.zip`` + ``vecnormalize.npz`` under ``cfg.output``.
    ``progress(done, total)`` is called every step if given; ``resume`` (a previous output
    directory) continues its final policy and observation statistics for ``total_timesteps``
    more steps. Returns the output directory."""
    _set_threads()
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.running_mean_std import RunningMeanStd
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    out = Path(cfg.output)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(_config_dict(cfg), indent=2))

    def monitored(k):
        fn = _make_env_fn(cfg, k)
        return lambda: Monitor(fn())

    fns = [monitored(k) for k in range(cfg.n_envs)]
    venv_cls = SubprocVecEnv if cfg.subprocess else DummyVecEnv
    venv = VecNormalize(venv_cls(fns), gamma=cfg.gamma, norm_obs=True, norm_reward=True)
    venv.seed(cfg.seed)
    eval_fns = [monitored(k) for k in range(max(1, len(cfg.scenarios)))]
    eval_env = VecNormalize(DummyVecEnv(eval_fns), training=False, norm_reward=False)
    eval_env.seed(cfg.eval_seed)
    model = PPO(
        "MlpPolicy",
        venv,
        learning_rate=cfg.learning_rate,
        n_steps=cfg.n_steps,
        batch_size=cfg.batch_size,
        n_epochs=cfg.n_epochs,
        gamma=cfg.gamma,
        gae_lambda=cfg.gae_lambda,
        clip_range=cfg.clip_range,
        ent_coef=cfg.ent_coef,
        policy_kwargs={"net_arch": list(cfg.net_arch), "log_std_init": cfg.log_std_init},
        seed=cfg.seed,
        device="cpu",
        verbose=0,
    )
    if resume is not None:
        resume = Path(resume)
        model = PPO.load(resume / "model.zip", env=venv, device="cpu")
        norm = np.load(resume / "vecnormalize.npz")
        rms = venv.obs_rms
        assert isinstance(rms, RunningMeanStd), "a Box observation has one running mean"
        rms.mean, rms.var = norm["mean"].copy(), norm["var"].copy()
        rms.count = float(norm["count"]) if "count" in norm.files else 1e6
        log.info("resuming %s at %d steps", resume, model.num_timesteps)
    logger = configure(str(out), ["csv", "log"])
    model.set_logger(logger)

    class _SyncNorm(EvalCallback):
        """Evaluate with the current normalisation statistics; keep them with the best model."""

        def _on_step(self) -> bool:
            if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                eval_env.obs_rms = venv.obs_rms.copy()
            best = self.best_mean_reward
            ok = super()._on_step()
            if self.best_mean_reward > best:
                save_normalisation(venv, out / "best" / "vecnormalize.npz")
            return ok

    per_env = max(1, cfg.n_envs)
    callbacks = [
        CheckpointCallback(
            max(cfg.checkpoint_every // per_env, 1),
            str(out / "checkpoints"),
            name_prefix="ppo",
            save_vecnormalize=True,
        ),
        _SyncNorm(
            eval_env,
            n_eval_episodes=cfg.eval_episodes,
            eval_freq=max(cfg.eval_every // per_env, 1),
            log_path=str(out),
            best_model_save_path=str(out / "best"),
            deterministic=True,
        ),
    ]
    if progress is not None:
        from stable_baselines3.common.callbacks import BaseCallback

        class _Progress(BaseCallback):
            def _on_step(self) -> bool:
                progress(self.num_timesteps, cfg.total_timesteps)
                return True

        callbacks.append(_Progress())
    t0 = time.perf_counter()
    try:
        model.learn(
            total_timesteps=cfg.total_timesteps,
            callback=callbacks,
            reset_num_timesteps=resume is None,
        )
        log.info("trained %d steps in %.0f s", cfg.total_timesteps, time.perf_counter() - t0)
        model.save(out / "model.zip")
        save_normalisation(venv, out / "vecnormalize.npz")
    finally:
        logger.close()  # flushes progress.csv and log.txt, also when training stops early
        venv.close()
        eval_env.close()
    return out


def _config_dict(cfg: PPOConfig) -> dict:
    import dataclasses

    d = dataclasses.asdict(cfg)
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def save_normalisation(venv, path: Path) -> None:
    """The observation normalisation of a ``VecNormalize`` as plain arrays (no pickle)."""
    np.savez(
        path,
        mean=venv.obs_rms.mean,
        var=venv.obs_rms.var,
        count=np.array(venv.obs_rms.count),
        clip_obs=np.array(venv.clip_obs),
        epsilon=np.array(venv.epsilon),
    )


def _policy_source(run_dir: Path, which: str) -> tuple[Path, dict[str, np.ndarray]]:
    """The policy zip and its normalisation statistics: ``best`` (the best evaluation, with the
    statistics saved then), ``final``, or a checkpoint's step count."""
    if which == "best" and (run_dir / "best" / "vecnormalize.npz").exists():
        src, norm = run_dir / "best" / "best_model.zip", run_dir / "best" / "vecnormalize.npz"
    elif which in ("best", "final"):
        src, norm = run_dir / "model.zip", run_dir / "vecnormalize.npz"
    else:
        src = run_dir / "checkpoints" / f"ppo_{which}_steps.zip"
        pkl = run_dir / "checkpoints" / f"ppo_vecnormalize_{which}_steps.pkl"
        if not src.exists() or not pkl.exists():
            raise FileNotFoundError(f"no checkpoint {which} in {run_dir / 'checkpoints'}")
        import pickle

        with open(pkl, "rb") as fh:  # written by our own training run
            vn = pickle.load(fh)
        stats = {
            "mean": vn.obs_rms.mean,
            "var": vn.obs_rms.var,
            "clip_obs": np.array(vn.clip_obs),
            "epsilon": np.array(vn.epsilon),
        }
        return src, stats
    data = np.load(norm)
    return src, {k: data[k] for k in data.files}


def ship_policy(run_dir: str | Path, variant: str, which: str = "best") -> Path:
    """Copy a trained policy (SB3's zip, which ``PPO.load`` needs whole) and its normalisation into
    ``agents/policies/`` as ``ppo-<variant>.zip`` / ``.npz`` / ``.json``; ``which`` is ``best``,
    ``final`` or a checkpoint's step count."""
    _set_threads()
    from stable_baselines3 import PPO

    run_dir = Path(run_dir)
    src, stats = _policy_source(run_dir, which)
    model = PPO.load(src, device="cpu")
    POLICY_DIR.mkdir(exist_ok=True)
    dst = POLICY_DIR / f"ppo-{variant}"
    model.save(dst.with_suffix(".zip"), exclude=["env", "_last_obs", "_last_original_obs"])
    np.savez(dst.with_suffix(".npz"), allow_pickle=False, **stats)
    cfg = json.loads((run_dir / "config.json").read_text())
    meta = {
        "variant": variant,
        "source": str(src),
        "timesteps": int(model.num_timesteps),
        "config": cfg,
    }
    dst.with_suffix(".json").write_text(json.dumps(meta, indent=2) + "\n")
    meta["leaderboard"] = {
        "env": LEADERBOARD_ENV,
        "seeds": list(LEADERBOARD_SEEDS),
        "episode_seconds": 10.0,
        "rms_mm": evaluate_policy(variant, path=str(dst.with_suffix(".zip"))),
    }
    dst.with_suffix(".json").write_text(json.dumps(meta, indent=2) + "\n")
    return dst.with_suffix(".zip")


# --------------------------------------------------------------------------------------------------
class PPOAgent(Agent):
    """A trained PPO policy as an agent (the shipped one by default), deterministic actions."""

    name = "ppo"

    def __init__(
        self,
        variant: str = "plain",
        path: str | None = None,
        deterministic: bool = True,
        offset_mm: float | None = None,
    ) -> None:
        super().__init__()
        if variant not in VARIANTS:
            raise PPOConfigError(f"unknown PPO variant {variant!r}; choose {', '.join(VARIANTS)}")
        self.variant = variant
        self.name = "ppo" if variant == "plain" else "ppo-residual"
        self.path = Path(path) if path else POLICY_DIR / f"ppo-{variant}.zip"
        self.deterministic = bool(deterministic)
        self._offset_mm = offset_mm
        self._policy: BasePolicy | None = None

    def _load(self) -> None:
        _set_threads()
        from stable_baselines3 import PPO

        if not self.path.exists():
            raise FileNotFoundError(
                f"no trained PPO policy at {self.path}; train one with "
                "`sixaxis train ppo --config experiments/configs/ppo.toml`"
            )
        self._policy = PPO.load(self.path, device="cpu").policy
        self._policy.set_training_mode(False)
        norm = np.load(self.path.with_suffix(".npz"))
        self._mean, self._var = norm["mean"], norm["var"]
        self._clip, self._eps = float(norm["clip_obs"]), float(norm["epsilon"])
        meta_path = self.path.with_suffix(".json")
        meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
        offset = meta.get("config", {}).get("offset_mm", 3.0)
        self.offset_mm = float(self._offset_mm if self._offset_mm is not None else offset)

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        if self._policy is None:
            self._load()
        self.task = task
        self.features = PolicyFeatures()
        self.features.reset(task)
        self.actions = ActionMap(self.variant, self.offset_mm)
        self.actions.reset(task)
        self._times: list[float] = []

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        self.task = task
        self.features.reset(task)
        self.actions.reset(task)

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        import torch

        t0 = time.perf_counter()
        f = self.features(obs)
        x = np.clip((f - self._mean) / np.sqrt(self._var + self._eps), -self._clip, self._clip)
        policy = self._policy
        assert policy is not None, "reset() loads the policy"
        with torch.no_grad():
            a, _ = policy.predict(x.astype(np.float32), deterministic=self.deterministic)
        out = self.actions(a, obs, info)
        self.last_solve_time = time.perf_counter() - t0
        self._times.append(self.last_solve_time)
        return out

    def report(self) -> dict[str, float | list]:
        return solve_time_stats(self._times)


#: the leaderboard's episodes (experiments/configs/full.toml): the shipped policies' rows
LEADERBOARD_SCENARIOS = (
    "nominal",
    "geometric",
    "compliance",
    "transmission",
    "backlash",
    "thermal",
    "payload",
    "all",
)
LEADERBOARD_SEEDS = (0, 1, 2, 3, 4)
LEADERBOARD_ENV = {"noise_mm": 0.015, "measure_every": 5}


def evaluate_policy(
    variant: str = "residual",
    scenarios: tuple[str, ...] = LEADERBOARD_SCENARIOS,
    seeds: tuple[int, ...] = LEADERBOARD_SEEDS,
    env_kwargs: Mapping[str, Any] | None = None,
    path: str | None = None,
    episode_seconds: float = 10.0,
) -> dict[str, float]:
    """Deterministic evaluation of a policy: tracking RMS (mm, the whole episode, as the
    leaderboard's ``rms_mm``) by scenario, mean over ``seeds``. The same numbers every time:
    deterministic actions, seeded episodes."""
    from agents.runner import run_episode

    env = dict(LEADERBOARD_ENV if env_kwargs is None else env_kwargs)
    out = {}
    for sc in scenarios:
        rms = []
        for s in seeds:
            agent = PPOAgent(variant, path=path)
            r = run_episode(agent, env | {"scenario": sc}, seed=s, episode_seconds=episode_seconds)
            rms.append(r.rms_mm())
        out[sc] = float(np.mean(rms))
    return out
