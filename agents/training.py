"""Training learned policies on SixAxisTrack-v0 with stable-baselines3 (PPO, SAC, TD3).

    sixaxis train ppo --config experiments/configs/ppo-residual.toml --seed 1
    sixaxis train sac --config experiments/configs/sac-residual.toml --seed 1 --ship

A config's ``[train]`` table says what is learned (``algo``, ``variant``, ``scenarios``, the
env's options in ``[train.env]``, the reward) and ``[train.hyperparameters]`` is handed to the SB3
algorithm as it is (its keys are checked against the algorithm's signature; the network's
architecture is ``policy_kwargs``, the activation by name).

Off-policy residuals (SAC, TD3) can keep their actor still for the first ``critic_burn_in``
steps while the critic learns what the near-zero residual is worth (residual policy learning,
Silver et al. 2018: an untrained critic's gradient otherwise drives the actor far off the base
controller before the critic can tell).

Seeds. The run's ``seed`` seeds the network and the exploration. Every training episode is reset
with its own seed, ``episode_seed_base + SEED_STRIDE * seed + k`` for the k-th episode of the run
(over all its envs), so no training episode is ever a leaderboard episode (those are drawn from
2**32 up) or a public evaluation episode (seeds 0-4; the base must be at least 1000), and the
runs of different seeds never share an episode. In-training evaluations use seeds
``eval_seed_base + i``, disjoint from both.

Records (in ``output``, default ``runs/<name>-seed<seed>``): ``config.json``, ``curve.csv`` (every
``eval_every`` steps: each evaluation scenario's settled tracking RMS, their mean, the mean
return, the wall time and the env steps per second), ``best.npz``/``.json`` (the policy with the
lowest mean log settled RMS so far, in the shipped format), ``final.npz``/``.json``, and
``checkpoint.zip`` with ``checkpoint.npz`` (SB3's own save and the normalisation, for ``--resume``).

When to stop. ``total_timesteps`` is the budget; ``patience`` ends a run sooner, once that many
evaluations in a row have not improved on the best by ``patience_improvement`` (2 %, of the
geometric mean over the scenarios of the settled RMS; :class:`agents.callbacks.Patience`). The
default, 0, trains to the budget, as every config before the rule did (so a shipped policy's
recorded config still means what it meant); the tuning configs and new recipes declare 5. A
``learning_rate_schedule`` that falls to 0 would end the improvement itself, so with patience on
it must end on a floor (or stay constant).

Diagnostics. ``train(..., diagnostics=DIR)`` (``sixaxis train ppo --diagnostics DIR``) hands SB3's
own logger a folder: its standard scalars (PPO's ``train/approx_kl``, ``train/clip_fraction``,
``train/entropy_loss``, ``train/explained_variance``, the losses; SAC's and TD3's losses) in
``progress.csv``, and TensorBoard event files where ``tensorboard`` is installed.

Torch runs on one thread (``torch.set_num_threads(1)``): small networks on two shared cores ran
30x slower with two.
"""

from __future__ import annotations

import csv
import dataclasses
import inspect
import io
import itertools
import json
import logging
import math
import os
import time
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from agents.base import Agent
from agents.errors import TrainConfigError, TrainingError
from agents.policy import (
    POLICY_DIR,
    Algo,
    PolicyAgent,
    PolicyIO,
    PolicyNetwork,
    Variant,
    policy_class,
    policy_kwargs_for_sb3,
    save_policy_file,
)
from agents.reference import FeedforwardAgent
from arm.constraints import (
    NON_NEGATIVE,
    POSITIVE,
    Interval,
    check,
    constraints_of,
    declare,
    problems,
)
from arm.files import is_file
from envs.errors import EnvOptionError
from envs.task import TaskInfo, Truth, controller_info

__all__ = [
    "LEADERBOARD_ENV",
    "LEADERBOARD_SCENARIOS",
    "LEADERBOARD_SEEDS",
    "SEED_STRIDE",
    "EpisodeSeeds",
    "PerturbedObservations",
    "PolicyEnv",
    "TrainConfig",
    "TrainConfigError",
    "evaluate_policy",
    "load_train_config",
    "policy_evaluation_record",
    "rerecord_policy",
    "ship_policy",
    "train",
]

log = logging.getLogger(__name__)

#: the public episodes a shipped policy's file records its evaluation on (the scenarios, env and
#: episode of experiments/configs/full.toml, a test keeps them equal; the leaderboard itself
#: draws its seeds when it is swept, from 2**32 up)
LEADERBOARD_SCENARIOS = (
    "nominal",
    "geometric",
    "compliance",
    "transmission",
    "backlash",
    "thermal",
    "payload",
    "all",
    "cyclic",
)
LEADERBOARD_SEEDS = (0, 1, 2, 3, 4)
LEADERBOARD_ENV: dict[str, Any] = {"noise_mm": 0.015, "measure_every": 5}
SETTLE_SECONDS = 2.0
EPISODE_SECONDS = 10.0
#: episode seeds of two training seeds are this far apart
SEED_STRIDE = 100_000
#: the episodes a run with early termination may start (half a seed stride: the ten training
#: seeds of a config stay clear of the evaluation seeds from 900,000 up)
TERMINATING_EPISODES = SEED_STRIDE // 2
#: the lowest episode seed a training run may use
MIN_EPISODE_SEED = 1000
#: the training rewards (see :class:`PolicyEnv`)
Reward = Literal["log", "improvement", "env"]
REWARDS: tuple[str, ...] = typing.get_args(Reward)
AT_LEAST_1 = Interval(int, 1, None)
#: how the policy's features are scaled: SB3's running mean and variance (updated all through
#: training, from the first flailing steps on), or the fixed scales the interface declares
#: (``envs.wrappers.ToolDisplacement.feature_scale``; the tool variant only)
ObsNormalization = Literal["running", "fixed"]
#: the clip of fixed-scale features, in scales: wide (a tracking error of 100 mm is seen as 100),
#: so that a lost policy still sees how far off it is; in pilots, VecNormalize's default of 10
#: left policies running away from the path
FIXED_SCALE_CLIP = 1000.0
#: keys of [train.hyperparameters] that the trainer sets itself
_RESERVED = {"policy", "env", "seed", "device", "verbose", "tensorboard_log", "_init_setup_model"}


@dataclass
class TrainConfig:
    """A training run (``[train]`` of a config file); see the module docstring. What each key
    takes is declared beside it (:mod:`arm.constraints`: the ``Literal`` modes, the ranges);
    :meth:`check` adds the rules between keys."""

    algo: Algo = "ppo"
    variant: Variant = "residual"
    name: str = ""
    scenarios: tuple[str, ...] = LEADERBOARD_SCENARIOS
    env: dict[str, Any] = field(default_factory=lambda: dict(LEADERBOARD_ENV))
    total_timesteps: int = declare(300_000, AT_LEAST_1)
    n_envs: int = declare(8, AT_LEAST_1)
    seed: int = declare(1, Interval(int, 0, None))
    episode_seed_base: int = declare(
        10_000, Interval(int, MIN_EPISODE_SEED, None, why="seeds below are the leaderboard's")
    )
    offset_mm: float = declare(0.5, POSITIVE)
    tool_step_mm: float = declare(5.0, POSITIVE)
    terminate_mm: float = declare(0.0, NON_NEGATIVE)
    obs_normalization: ObsNormalization = "running"
    observe: tuple[str, ...] = ()
    reward: Reward = "log"
    reward_scale_mm: float = declare(0.05, POSITIVE)
    action_penalty: float = declare(0.0, NON_NEGATIVE)
    action_change_penalty: float = declare(0.0, NON_NEGATIVE)
    critic_burn_in: int = declare(0, Interval(int, 0, None))
    normalize_reward: bool = True
    init_output_scale: float = declare(0.01, POSITIVE)
    action_noise_std: float = declare(0.1, NON_NEGATIVE)
    eval_every: int = declare(25_000, AT_LEAST_1)
    eval_seed_base: int = declare(
        900_000, Interval(int, MIN_EPISODE_SEED, None, why="seeds below are the leaderboard's")
    )
    eval_episodes: int = declare(1, AT_LEAST_1)
    checkpoint_every: int = declare(50_000, AT_LEAST_1)
    patience: int = declare(0, Interval(int, 0, None, why="evaluations; 0: never stops early"))
    patience_improvement: float = declare(0.02, Interval(float, 0.0, 1.0, closed="left"))
    learning_rate_schedule: list[list[float]] = field(default_factory=list)
    output: str = ""
    hyperparameters: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.name:
            self.name = f"{self.algo}-residual" if self.variant == "residual" else self.algo
        if not self.output:
            self.output = f"runs/{self.name}-seed{self.seed}"
        self.scenarios = tuple(self.scenarios)
        self.observe = tuple(self.observe)

    @property
    def episode_steps(self) -> int:
        """Control steps of a training (and evaluation) episode."""
        return round(float(self.env.get("episode_seconds", EPISODE_SECONDS)) / 0.02)

    def scenarios_unique(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(self.scenarios))

    def max_episodes(self) -> int:
        """An upper bound of the episodes a run starts (each env's last one may be cut short);
        with early termination (``terminate_mm``) a run may start up to
        :data:`TERMINATING_EPISODES` (running out is an error naming it)."""
        if self.terminate_mm:
            return TERMINATING_EPISODES
        return math.ceil(self.total_timesteps / self.episode_steps) + 2 * self.n_envs

    def training_seeds(self) -> range:
        """Every episode seed this run may reset an env with."""
        start = self.episode_seed_base + SEED_STRIDE * self.seed
        return range(start, start + self.max_episodes())

    def evaluation_seeds(self) -> range:
        return range(self.eval_seed_base, self.eval_seed_base + self.eval_episodes)

    def check(self, source: str = "config") -> None:
        """Refuse what cannot run, naming every key at fault: the declared kinds and ranges of
        each key, then the rules between keys."""
        found = problems(self) + self._rules()
        if found:
            raise TrainConfigError(f"{source}: [train] " + "; ".join(found))

    def _rules(self) -> list[str]:
        """The rules between keys (the scenarios the env knows, seeds apart from the
        leaderboard's and the evaluation's, what each algorithm and variant takes)."""
        from envs.scenarios import SCENARIOS

        out = [
            f"scenarios[{i}]: unknown scenario {sc!r}; known: {', '.join(SCENARIOS)}"
            for i, sc in enumerate(self.scenarios)
            if sc not in SCENARIOS
        ]
        if not self.scenarios:
            out.append("scenarios: empty")
        if out or problems(self):  # the rest needs every key of its kind
            return out
        if self.max_episodes() > SEED_STRIDE:
            out.append(f"total_timesteps: more than {SEED_STRIDE} episodes overlap the next seed's")
        train, ev = self.training_seeds(), self.evaluation_seeds()
        if ev.start < train.stop and train.start < ev.stop:
            out.append(
                f"eval_seed_base {self.eval_seed_base}: evaluation seeds overlap training seeds"
            )
        out += self._schedule_rules()
        if "action_noise" in self.hyperparameters:
            out.append("hyperparameters: action_noise is set by the trainer (action_noise_std)")
        if self.reward == "improvement" and self.variant != "residual":
            out.append("reward 'improvement' (over the base controller) is for residual policies")
        if self.terminate_mm and self.reward != "log":
            out.append("terminate_mm is for the log reward (its alive bonus)")
        if self.obs_normalization == "fixed" and self.variant != "tool":
            out.append("obs_normalization 'fixed' is for the tool variant (its declared scales)")
        out += self._observe_rules()
        if self.critic_burn_in and self.algo == "ppo":
            out.append(
                "critic_burn_in is for the off-policy algorithms (sac, td3): PPO has no critic"
            )
        cls = _algorithm(self.algo)
        params = inspect.signature(cls.__init__).parameters
        unknown = sorted(set(self.hyperparameters) - set(params) - _RESERVED)
        reserved = sorted(set(self.hyperparameters) & _RESERVED)
        if unknown:
            out.append(f"hyperparameters: {cls.__name__} takes no {', '.join(unknown)}")
        if reserved:
            out.append(
                f"hyperparameters: {', '.join(reserved)} are set by the trainer (SB3's logs: "
                "`sixaxis train ... --diagnostics DIR`)"
            )
        try:
            policy_kwargs_for_sb3(self.hyperparameters.get("policy_kwargs", {}))
            policy_class(self.algo, self.hyperparameters.get("policy_kwargs", {}))
        except ValueError as exc:
            out.append(f"hyperparameters.policy_kwargs: {exc}")
        if not out:
            try:
                import envs  # noqa: F401

                gym.make("SixAxisTrack-v0", scenario=self.scenarios[0], **self.env).close()
            except (TypeError, ValueError) as exc:
                out.append(f"env: {exc}")
        return out

    def _observe_rules(self) -> list[str]:
        from envs.wrappers import observed

        if not self.observe:
            return []
        if self.variant != "tool":
            return ["observe is for the tool variant (the interface's observation option)"]
        try:
            observed(self.observe)
        except EnvOptionError as exc:
            return [str(exc)]
        return []

    def _schedule_rules(self) -> list[str]:
        sched = self.learning_rate_schedule
        if not sched:
            return []
        key = "learning_rate_schedule"
        if not all(isinstance(p, list | tuple) and len(p) == 2 for p in sched):
            return [f"{key}: a list of [step, learning rate] pairs, e.g. [[0, 3e-4], [1e6, 0]]"]
        out = []
        for i, (step, lr) in enumerate(sched):
            if not (isinstance(step, int | float) and math.isfinite(step) and step >= 0):
                out.append(f"{key}[{i}]: the step {step!r} is not a count of steps >= 0")
            if not (isinstance(lr, int | float) and math.isfinite(lr) and lr >= 0):
                out.append(f"{key}[{i}]: the learning rate {lr!r} is not a number >= 0")
        steps = [p[0] for p in sched]
        if not out and any(b <= a for a, b in itertools.pairwise(steps)):
            out.append(f"{key}: the steps {steps} do not increase")
        if "learning_rate" in self.hyperparameters:
            out.append(f"hyperparameters.learning_rate: {key} sets it; give one of the two")
        if self.algo != "ppo":
            out.append(f"{key} is for ppo (its updates after each rollout)")
        if not out and self.patience and sched[-1][1] == 0:
            out.append(
                f"{key} ends at 0 with patience on: a rate of 0 stops the improvement itself; "
                "end on a floor (e.g. [[0, 3e-4], [1e6, 3e-5]]) or set patience = 0 to train to "
                "the budget"
            )
        return out

    def learning_rate_at(self, step: float) -> float:
        """The learning rate at an absolute step count of the run: ``learning_rate_schedule``
        interpolated linearly between its points (constant before the first and after the
        last), else ``hyperparameters.learning_rate`` (SB3's default, 3e-4, if not given).
        Absolute, not SB3's progress_remaining (relative to each ``learn`` call): a run
        resumed at step N, or stopped there, has had the same rates up to N as any longer
        run of the same config."""
        if self.learning_rate_schedule:
            steps, rates = zip(*self.learning_rate_schedule, strict=True)
            return float(np.interp(step, steps, rates))
        return float(self.hyperparameters.get("learning_rate", 3e-4))

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["scenarios"] = list(self.scenarios)
        d["observe"] = list(self.observe)
        return d


def _algorithm(algo: str) -> Any:
    import stable_baselines3 as sb3

    return {"ppo": sb3.PPO, "sac": sb3.SAC, "td3": sb3.TD3}[algo]


def load_train_config(path: str | Path, **overrides: Any) -> TrainConfig:
    """A checked :class:`TrainConfig` from the ``[train]`` table of a TOML file (with
    ``overrides``: the CLI's ``--seed`` and the like); unknown keys and wrong types are
    refused, naming the file and the key."""
    import tomllib

    from arm.files import read_input_text

    path = Path(path)
    try:
        doc = tomllib.loads(read_input_text(path, "config file", "toml", TrainConfigError))
    except tomllib.TOMLDecodeError as exc:
        raise TrainConfigError(f"{path}: not valid TOML: {exc}") from exc
    table = doc.get("train")
    if not isinstance(table, dict):
        raise TrainConfigError(f"{path}: needs a [train] table")
    fields = {f.name: f for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise TrainConfigError(f"{path}: [train] has unknown key(s) {', '.join(unknown)}")
    wrong = check(table, constraints_of(TrainConfig))  # each key's kind, before building it
    if wrong:
        raise TrainConfigError(f"{path}: [train] " + "; ".join(wrong))
    values = dict(table) | {k: v for k, v in overrides.items() if v is not None}
    if "output" not in table and "output" not in values:
        values["output"] = ""
    cfg = TrainConfig(**values)
    cfg.check(str(path))
    return cfg


# --------------------------------------------------------------------------------------------------
class PolicyEnv(gym.Wrapper):
    """SixAxisTrack-v0 as the policy sees it: :class:`~agents.policy.PolicyIO`'s features in, its
    action out, and every reset seeded from the run's own sequence (``seeds``: a callable giving
    the next episode's seed; none: the seed given to ``reset``).

    The reward is the env's (``reward="env"``: minus the true error in mm, and the jerk penalty),
    ``-ln(1 + e / scale)`` of the true error ``e`` (``"log"``): it resolves 0.05-0.5 mm errors
    as well as millimetres, or the improvement over the base controller (``"improvement"``,
    residual policies only): ``ln(1 + e_base / scale) - ln(1 + e / scale)``, where ``e_base`` is
    the true error the ``feedforward`` base makes at the same instant of the same episode (a
    shadow copy of the env, reset with the same seed, driven by the base alone: common random
    numbers). A zero residual earns exactly 0 at every step, so the return measures what the
    residual adds and not how hard the episode is (the arm's errors, the path, the noise), which
    the policy cannot see and which otherwise drowns the 0.01 mm it can gain.
    ``action_penalty`` and ``action_change_penalty`` subtract ``c * |a|^2`` and
    ``c * |a - a_prev|^2`` of the policy's own action (in [-1, 1]): the policy keeps zero (the
    base controller) unless moving off it pays. ``terminate_mm`` (log reward only) ends an
    episode once the true error exceeds it, as locomotion tasks end on a fall and motion
    imitation on a lost reference (DeepMimic's early termination), and adds the alive bonus
    ``ln(1 + terminate_mm / scale)`` to each step, so the reward is positive while tracking and
    ending early never pays: a policy that has not learned to follow the path yet spends its
    samples near the path, not 100 mm off it where every action earns the same. The
    leaderboard's episodes never end early. The reward uses the plant's truth, as any
    simulated training may; the policy's observation never does (it is computed from
    :func:`~envs.task.controller_info` of each step's info)."""

    def __init__(
        self,
        env: gym.Env,
        variant: str = "residual",
        offset_mm: float = 0.5,
        reward: str = "log",
        reward_scale_mm: float = 0.05,
        seeds: Callable[[], int] | None = None,
        action_penalty: float = 0.0,
        action_change_penalty: float = 0.0,
        shadow: gym.Env | None = None,
        tool_step_mm: float = 5.0,
        terminate_mm: float = 0.0,
        observe: tuple[str, ...] = (),
    ) -> None:
        super().__init__(env)
        if terminate_mm and reward != "log":
            raise TrainConfigError("terminate_mm is for the log reward (its alive bonus)")
        if reward == "improvement" and (variant != "residual" or shadow is None):
            raise TrainConfigError(
                "the improvement reward needs a residual policy and a shadow env"
            )
        self.io = PolicyIO(variant, offset_mm, tool_step_mm, observe)
        self.shadow = shadow if reward == "improvement" else None
        self.shadow_base = FeedforwardAgent()
        task = env.unwrapped.task  # type: ignore[attr-defined]
        n = self.io.observation_size(task)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (n,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (self.io.action_size,), np.float32)
        self.reward_kind = reward
        self.reward_scale_mm = float(reward_scale_mm)
        self.seeds = seeds
        self.action_penalty = float(action_penalty)
        self.action_change_penalty = float(action_change_penalty)
        self.terminate_mm = float(terminate_mm)
        self.last_seed: int | None = None

    def _log_error(self, info: Mapping[str, Any]) -> float:
        e = float(info.get("true_error_mm", math.nan))
        if not math.isfinite(e):  # diverged
            e = 1e3
        return math.log1p(e / self.reward_scale_mm)

    def reward(self, env_reward: float, info: Mapping[str, Any]) -> float:
        if self.reward_kind == "env":
            return float(env_reward)
        if self.reward_kind == "improvement":
            return self._log_error(self._shadow_info) - self._log_error(info)
        if self.terminate_mm:  # alive: the bonus of the worst error it may keep, minus its own
            return math.log1p(self.terminate_mm / self.reward_scale_mm) - self._log_error(info)
        return -self._log_error(info)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if self.seeds is not None:
            seed = self.seeds()
        self.last_seed = seed
        obs, info = self.env.reset(seed=seed, options=options)
        task = self.env.unwrapped.task  # type: ignore[attr-defined]
        self.io.reset(task)
        if self.shadow is not None:
            self._shadow_obs, self._shadow_info = self.shadow.reset(seed=seed, options=options)
            self.shadow_base.reset(self.shadow.unwrapped.task)  # type: ignore[attr-defined]
        return self.io.features(obs, controller_info(info)).astype(np.float32), info

    def step(self, action):
        before = self.io.prev_action.copy()
        obs, reward, terminated, truncated, info = self.env.step(self.io.action(action))
        if self.shadow is not None:
            base_action = self.shadow_base.act(self._shadow_obs, controller_info(self._shadow_info))
            self._shadow_obs, _, _, _, self._shadow_info = self.shadow.step(base_action)
        a = self.io.prev_action  # the clipped action applied
        r = self.reward(float(reward), info)
        r -= self.action_penalty * float(a @ a)
        r -= self.action_change_penalty * float((a - before) @ (a - before))
        if (
            self.terminate_mm
            and not float(info.get("true_error_mm", math.inf)) <= self.terminate_mm
        ):
            terminated = True  # lost: the episode ends, and with it the bonus
        return (
            self.io.features(obs, controller_info(info)).astype(np.float32),  # trained in float32
            r,
            terminated,
            truncated,
            info,
        )

    def close(self) -> None:
        if self.shadow is not None:
            self.shadow.close()
        super().close()


def _fixed_mean_std() -> type:
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    class Fixed(RunningMeanStd):
        """A mean and variance that training does not update (fixed feature scales)."""

        def __init__(self, mean: np.ndarray, var: np.ndarray) -> None:
            super().__init__(shape=mean.shape)
            self.mean, self.var = np.array(mean, dtype=float), np.array(var, dtype=float)

        def update(self, arr: np.ndarray) -> None:
            return None

    return Fixed


def fixed_mean_std(mean: np.ndarray, var: np.ndarray) -> Any:
    """SB3's ``RunningMeanStd`` holding ``mean`` and ``var`` fixed: VecNormalize scales by them
    and never updates them."""
    return _fixed_mean_std()(mean, var)


class EpisodeSeeds:
    """The run's episode seeds: ``start, start + 1, ...`` shared by all its envs (one process)."""

    def __init__(self, start: int, stop: int) -> None:
        self.next, self.stop = start, stop

    def __call__(self) -> int:
        if self.next >= self.stop:
            raise TrainingError(f"training ran out of episode seeds at {self.next}")
        s = self.next
        self.next += 1
        return s


def make_policy_env(
    cfg: TrainConfig, scenario: str, seeds: Callable[[], int] | None = None
) -> PolicyEnv:
    import envs  # noqa: F401

    def make() -> gym.Env:
        return gym.make(
            "SixAxisTrack-v0", scenario=scenario, max_episode_steps=cfg.episode_steps, **cfg.env
        )

    return PolicyEnv(
        make(),
        cfg.variant,
        cfg.offset_mm,
        cfg.reward,
        cfg.reward_scale_mm,
        seeds,
        cfg.action_penalty,
        cfg.action_change_penalty,
        shadow=make() if cfg.reward == "improvement" else None,
        tool_step_mm=cfg.tool_step_mm,
        terminate_mm=cfg.terminate_mm,
        observe=cfg.observe,
    )


# --------------------------------------------------------------------------------------------------
def _meta(cfg: TrainConfig, obs_size: int, act_size: int) -> dict[str, Any]:
    hp = cfg.hyperparameters
    return {
        "name": cfg.name,
        "variant": cfg.variant,
        "obs_size": obs_size,
        "act_size": act_size,
        "offset_mm": cfg.offset_mm,
        "tool_step_mm": cfg.tool_step_mm,
        "observe": list(cfg.observe),
        "policy_kwargs": dict(hp.get("policy_kwargs", {})),
        "use_sde": bool(hp.get("use_sde", False)),
        "config": cfg.to_dict(),
    }


def _normalisation(venv: Any) -> dict[str, np.ndarray]:
    return {
        "obs_mean": np.array(venv.obs_rms.mean, dtype=float),
        "obs_var": np.array(venv.obs_rms.var, dtype=float),
        "obs_count": np.array(venv.obs_rms.count, dtype=float),
        "obs_clip": np.array(venv.clip_obs, dtype=float),
        "obs_epsilon": np.array(venv.epsilon, dtype=float),
        "ret_mean": np.array(venv.ret_rms.mean, dtype=float),
        "ret_var": np.array(venv.ret_rms.var, dtype=float),
        "ret_count": np.array(venv.ret_rms.count, dtype=float),
    }


def evaluate_network(
    network: PolicyNetwork,
    meta: Mapping[str, Any],
    scenarios: tuple[str, ...],
    seeds: tuple[int, ...],
    env_kwargs: Mapping[str, Any],
    reward_scale_mm: float = 0.05,
    episode_seconds: float = EPISODE_SECONDS,
    settle_seconds: float = SETTLE_SECONDS,
    perturb_rel: float = 0.0,
) -> dict[str, dict[str, list[float]]]:
    """Deterministic episodes of a policy: per scenario, per seed, the settled and whole-episode
    tracking RMS (mm) and the return under the log reward. ``perturb_rel`` > 0 multiplies every
    observation by ``1 + perturb_rel * (+-1)`` (signs drawn from the episode's seed): how far a
    rounding difference between CPUs carries through the closed loop."""
    from agents.runner import run_episode

    out: dict[str, dict[str, list[float]]] = {}
    for sc in scenarios:
        rows: dict[str, list[float]] = {"rms_settled_mm": [], "rms_mm": [], "return": []}
        for s in seeds:
            agent: Agent = PolicyAgent.from_network(str(meta.get("name", "policy")), network, meta)
            if perturb_rel:
                agent = PerturbedObservations(agent, perturb_rel, seed=s)
            r = run_episode(
                agent, dict(env_kwargs) | {"scenario": sc}, seed=s, episode_seconds=episode_seconds
            )
            e = np.nan_to_num(r.true_error_mm, nan=1e3)
            rows["rms_settled_mm"].append(r.rms_mm(start=settle_seconds))
            rows["rms_mm"].append(r.rms_mm())
            rows["return"].append(float(-np.log1p(e / reward_scale_mm).sum()))
        out[sc] = rows
    return out


def train(
    cfg: TrainConfig,
    progress: Callable[[int, int], None] | None = None,
    resume: bool = False,
    stop_at: int | None = None,
    diagnostics: str | Path | None = None,
) -> Path:
    """Train as configured (see the module docstring for what is written); ``progress(done,
    total)`` is called as steps are taken; ``resume`` continues from ``output``'s checkpoint
    (SB3's own save of this run, which unpickles: resume only runs you made); ``stop_at`` stops
    the run there (its checkpoint, ``final`` and summary written) to be resumed later with a
    config that trains the steps taken the same (:func:`resume_differences`: more steps, other
    evaluations, a learning rate that changes only from the checkpoint on; the summary records
    what changed). A resumed run starts new episodes, and its random streams afresh; its
    patience starts again from the best evaluation so far. ``diagnostics``: a folder for SB3's
    own logger (``progress.csv`` of its standard scalars: KL, clip fraction, entropy,
    explained variance, losses; TensorBoard event files too where ``tensorboard`` is
    installed). Returns the output directory."""
    import torch

    torch.set_num_threads(1)
    cfg.check()
    out = _output_folder(cfg)
    resuming = resume and os.path.exists(out / "checkpoint.zip")
    # refused before anything is built, loaded or written
    differences = _resume_check(out, cfg) if resuming else {}
    seeds = cfg.training_seeds()
    sequence = EpisodeSeeds(seeds.start, seeds.stop)
    venv, obs_size, act_size = _training_envs(cfg, sequence)
    run = _Run(cfg, out, venv, sequence, _meta(cfg, obs_size, act_size))
    run.diagnostics = None if diagnostics is None else Path(diagnostics)
    run.start(act_size, resuming, differences)
    # after the resume's check: a refused resume leaves the run's records as they were
    from arm.files import atomic_write_text

    atomic_write_text(out / "config.json", json.dumps(cfg.to_dict(), indent=2) + "\n")
    run.start_curve(resume)
    try:
        run.learn(progress, stop_at)
        run.finish(differences)
    finally:
        venv.close()
    return out


def _output_folder(cfg: TrainConfig) -> Path:
    """The run's folder, made; refused (a name too long, a file in the way, a read-only place)
    before any training."""
    from arm.files import folder_problem, make_folders, shown

    out = Path(cfg.output)
    why = folder_problem(out) or (f"{out} is not a directory" if is_file(out) else None)
    if why:
        raise TrainConfigError(f"output {shown(out)}: cannot write the run there: {why}")
    make_folders(out)
    return out


def _training_envs(cfg: TrainConfig, sequence: EpisodeSeeds) -> tuple[Any, int, int]:
    """The vectorised training envs (round-robin over the scenarios, normalised; with fixed
    scales, the interface's own, never updated), and the observation's and action's sizes."""
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    def env_fn(scenario: str) -> Callable[[], gym.Env]:
        return lambda: Monitor(make_policy_env(cfg, scenario, sequence))

    fns = [env_fn(cfg.scenarios[k % len(cfg.scenarios)]) for k in range(cfg.n_envs)]
    fixed = cfg.obs_normalization == "fixed"
    venv = VecNormalize(
        DummyVecEnv(fns),
        gamma=float(cfg.hyperparameters.get("gamma", 0.99)),
        norm_obs=True,
        norm_reward=cfg.normalize_reward,
        clip_obs=FIXED_SCALE_CLIP if fixed else 10.0,
    )
    probe = venv.venv.envs[0]  # type: ignore[attr-defined]
    if fixed:  # the interface's declared scales, never updated (saved as the policy's own)
        from envs.wrappers import ToolDisplacement

        tool = ToolDisplacement(probe.unwrapped.task, cfg.tool_step_mm, observe=cfg.observe)
        venv.obs_rms = fixed_mean_std(tool.feature_offset, tool.feature_scale**2)
    return venv, int(probe.observation_space.shape[0]), int(probe.action_space.shape[0])


def _hyperparameters(cfg: TrainConfig, act_size: int) -> dict[str, Any]:
    """SB3's keywords: the config's, with a schedule's step-0 rate (then set before each update,
    callbacks.LearningRateAt), the policy's keywords as SB3 takes them, and TD3's noise."""
    from stable_baselines3.common.noise import NormalActionNoise

    hp = dict(cfg.hyperparameters)
    hp |= {"learning_rate": cfg.learning_rate_at(0)} if cfg.learning_rate_schedule else {}
    hp["policy_kwargs"] = policy_kwargs_for_sb3(hp.get("policy_kwargs", {}))
    if cfg.algo == "td3":  # TD3 explores with Gaussian noise on its deterministic action
        sigma = cfg.action_noise_std * np.ones(act_size)
        hp["action_noise"] = NormalActionNoise(np.zeros(act_size), sigma)
    return hp


class _Run:
    """One training session of a run: its model, envs and records (curve, best, checkpoint,
    final, summary), as the steps of :func:`train`."""

    def __init__(
        self,
        cfg: TrainConfig,
        out: Path,
        venv: Any,
        sequence: EpisodeSeeds,
        meta: dict[str, Any],
    ) -> None:
        self.cfg, self.out, self.venv, self.sequence, self.meta = cfg, out, venv, sequence, meta
        self.model: Any = None
        self.done_before = 0
        self.best = math.inf
        self.curve_path = out / "curve.csv"
        self.t_start = 0.0
        self.patience = _patience(cfg)
        self.last_evaluated = -1
        self.diagnostics: Path | None = None

    def start(self, act_size: int, resuming: bool, differences: Mapping[str, Any]) -> None:
        """The model: loaded from the checkpoint with its normalisation and episode seeds, or
        built anew with its output layer shrunk."""
        cfg, out, venv = self.cfg, self.out, self.venv
        hp = _hyperparameters(cfg, act_size)
        cls = _algorithm(cfg.algo)
        if not resuming:
            network = policy_class(cfg.algo, cfg.hyperparameters.get("policy_kwargs", {}))
            self.model = cls(network, venv, seed=cfg.seed, device="cpu", verbose=0, **hp)
            _shrink_output(self.model, cfg.algo, cfg.init_output_scale)
            self._log_diagnostics()
            return
        self.model = cls.load(out / "checkpoint.zip", env=venv, device="cpu")
        self._log_diagnostics()
        state = np.load(out / "checkpoint.npz", allow_pickle=False)
        obs_rms: Any = venv.obs_rms  # one RunningMeanStd: the observation is a flat Box
        ret_rms: Any = venv.ret_rms
        obs_rms.mean, obs_rms.var = state["obs_mean"].copy(), state["obs_var"].copy()
        obs_rms.count = float(state["obs_count"])
        ret_rms.mean, ret_rms.var = float(state["ret_mean"]), float(state["ret_var"])
        ret_rms.count = float(state["ret_count"])
        self.sequence.next = int(state["next_seed"])
        self.done_before = int(self.model.num_timesteps)
        log.info(
            "resuming %s at %d steps (%s)", out, self.done_before, differences or "same config"
        )

    def start_curve(self, resume: bool) -> None:
        """``curve.csv``'s header, unless a resumed run's curve goes on."""
        from arm.files import atomic_write_text

        columns = [
            "steps",
            "wall_s",
            "steps_per_s",
            *[f"rms_settled_mm/{sc}" for sc in self.cfg.scenarios_unique()],
            "rms_settled_mm/mean",
            "rms_mm/mean",
            "return/mean",
        ]
        if not resume or not os.path.exists(self.curve_path):
            header = io.StringIO()
            csv.writer(header).writerow(columns)
            atomic_write_text(self.curve_path, header.getvalue())  # then appended to, row by row
        self.t_start = time.perf_counter()

    def _log_diagnostics(self) -> None:
        """SB3's own logger into ``diagnostics`` (when given): its standard scalars (PPO's
        approx_kl, clip_fraction, entropy_loss, explained_variance, the losses; SAC's and TD3's
        losses, ent_coef) as ``progress.csv``, and as TensorBoard event files where the
        ``tensorboard`` package is installed."""
        if self.diagnostics is None:
            return
        import importlib.util

        from stable_baselines3.common.logger import configure

        from arm.files import make_folders

        make_folders(self.diagnostics)
        formats = ["csv"] + (["tensorboard"] if importlib.util.find_spec("tensorboard") else [])
        self.model.set_logger(configure(str(self.diagnostics), formats))
        log.info("SB3's diagnostics (%s) in %s", ", ".join(formats), self.diagnostics)

    def network(self) -> PolicyNetwork:
        return PolicyNetwork(self.cfg.algo, self.model.policy, _normalisation(self.venv))

    def evaluate(self, steps: int) -> None:
        """The evaluation episodes at ``steps``: a row of the curve, and ``best.npz`` if best."""
        cfg, model = self.cfg, self.model
        model.policy.set_training_mode(False)
        res = _evaluate_in_training(cfg, self.network(), self.meta)
        model.policy.set_training_mode(True)
        settled = {sc: float(np.mean(v["rms_settled_mm"])) for sc, v in res.items()}
        score = _score(res)
        wall = time.perf_counter() - self.t_start
        row = [
            steps,
            f"{wall:.1f}",
            f"{(steps - self.done_before) / max(wall, 1e-9):.1f}",
            *[f"{settled[sc]:.6g}" for sc in cfg.scenarios_unique()],
            f"{np.mean(list(settled.values())):.6g}",
            f"{np.mean([np.mean(v['rms_mm']) for v in res.values()]):.6g}",
            f"{np.mean([np.mean(v['return']) for v in res.values()]):.6g}",
        ]
        with open(self.curve_path, "a", newline="") as fh:
            csv.writer(fh).writerow(row)
        log.info("%d steps: settled RMS %s", steps, settled)
        self.last_evaluated = steps
        if self.patience.update(math.exp(score)):
            log.info(
                "stopping at %d steps: %d evaluations without a %.0f %% improvement",
                steps,
                self.patience.waited,
                100 * self.patience.improvement,
            )
        if score < self.best:
            self.best = score
            save_policy_file(
                self.out / "best.npz",
                cfg.algo,
                model.policy,
                _normalisation(self.venv),
                self.meta | {"timesteps": steps, "selected_by": "lowest mean log settled RMS"},
            )

    def checkpoint(self) -> None:
        """SB3's own save and the normalisation with the next episode seed, for ``--resume``."""
        from arm.files import atomic_path

        buf = io.BytesIO()
        self.model.save(buf)
        with atomic_path(self.out / "checkpoint.zip") as tmp:
            tmp.write_bytes(buf.getvalue())
        state: dict[str, Any] = _normalisation(self.venv) | {
            "next_seed": np.array(self.sequence.next)
        }
        with atomic_path(self.out / "checkpoint.npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **state)

    def learn(self, progress: Callable[[int, int], None] | None, stop_at: int | None) -> None:
        """The steps of this session (to ``stop_at`` or the budget), evaluated and checkpointed
        as configured, then evaluated at its end."""
        from stable_baselines3.common.callbacks import BaseCallback, CallbackList

        from agents.callbacks import CriticBurnIn, EveryCrossing, LearningRateAt, Progress, StopWhen

        cfg = self.cfg
        callbacks: list[BaseCallback] = []
        if cfg.algo != "ppo":  # the critic's burn-in: the actor learns once it is over
            callbacks.append(CriticBurnIn(cfg.critic_burn_in))
        callbacks += [
            EveryCrossing(cfg.eval_every, cfg.n_envs, self.evaluate),
            EveryCrossing(cfg.checkpoint_every, cfg.n_envs, lambda n: self.checkpoint()),
            StopWhen(lambda: self.patience.stopped),
        ]
        if progress is not None:
            callbacks.append(Progress(progress, cfg.total_timesteps))
        if self.done_before == 0:
            self.evaluate(0)
        else:  # best.npz stays the best of the whole run, and the patience's bar
            self.best = _best_so_far(self.out / "best.npz", cfg, self.meta)
            if math.isfinite(self.best):
                self.patience.update(math.exp(self.best))
        callbacks += [LearningRateAt(cfg.learning_rate_at)] if cfg.learning_rate_schedule else []
        self.model.learn(
            total_timesteps=min(cfg.total_timesteps, stop_at or cfg.total_timesteps)
            - self.done_before,
            callback=CallbackList(callbacks),
            reset_num_timesteps=self.done_before == 0,
        )
        if self.model.num_timesteps != self.last_evaluated:
            self.evaluate(int(self.model.num_timesteps))

    def finish(self, differences: Mapping[str, Any]) -> None:
        """The checkpoint, ``final.npz`` and the summary (the whole run's wall time)."""
        from arm.files import atomic_write_text

        model, done_before = self.model, self.done_before
        self.checkpoint()
        save_policy_file(
            self.out / "final.npz",
            self.cfg.algo,
            model.policy,
            _normalisation(self.venv),
            self.meta | {"timesteps": int(model.num_timesteps)},
        )
        wall = time.perf_counter() - self.t_start
        before = _wall_before(self.out / "summary.json") if done_before else 0.0
        summary: dict[str, Any] = {
            "timesteps": int(model.num_timesteps),
            "wall_s": before + wall,  # the whole run's, over its sessions
            "steps_per_s": (int(model.num_timesteps) - done_before) / wall,
            "resumed_at": done_before,
            "wall_s_this_session": wall,
            # the patience rule (evaluations without a relative improvement) ended the run
            "stopped_by_patience": self.patience.stopped,
        }
        # what the config changed at the resume (nothing that trains the steps before it)
        summary |= {"resumed_with": dict(differences)} if done_before else {}
        atomic_write_text(self.out / "summary.json", json.dumps(summary, indent=2) + "\n")
        log.info("trained %d steps in %.0f s", model.num_timesteps, wall)


def _patience(cfg: TrainConfig) -> Any:
    from agents.callbacks import Patience

    return Patience(cfg.patience, cfg.patience_improvement)


def _evaluate_in_training(
    cfg: TrainConfig, network: PolicyNetwork, meta: Mapping[str, Any]
) -> dict[str, dict[str, list[float]]]:
    """The run's evaluation episodes of ``network`` (:func:`evaluate_network`)."""
    return evaluate_network(
        network,
        meta,
        cfg.scenarios_unique(),
        tuple(cfg.evaluation_seeds()),
        cfg.env,
        cfg.reward_scale_mm,
        episode_seconds=cfg.episode_steps * 0.02,
        settle_seconds=min(SETTLE_SECONDS, cfg.episode_steps * 0.02 / 2),
    )


def _score(res: Mapping[str, Mapping[str, list[float]]]) -> float:
    """An evaluation's score, lower is better: the mean over scenarios of log settled RMS."""
    return float(np.mean([np.log(np.mean(v["rms_settled_mm"])) for v in res.values()]))


def _best_so_far(path: Path, cfg: TrainConfig, meta: Mapping[str, Any]) -> float:
    """The score of a resumed run's ``best.npz`` on this session's evaluation episodes (the
    config may have changed them), the bar a later policy must pass; inf if there is none."""
    if not os.path.exists(path):
        return math.inf
    from agents.policy import load_policy_file

    network, _ = load_policy_file(path)
    score = _score(_evaluate_in_training(cfg, network, meta))
    log.info("the best policy so far (%s) scores %.4f", path, score)
    return score


def _resume_check(out: Path, cfg: TrainConfig) -> dict[str, list[Any]]:
    """:func:`resume_differences` of the run in ``out`` (its checkpoint's step, its config)."""
    at = _checkpoint_steps(out / "checkpoint.zip")
    return resume_differences(_read_json(out / "config.json"), cfg, at, out)


def _checkpoint_steps(path: Path) -> int:
    """The step count of SB3's saved model ``path`` (its ``data`` member, JSON), unloaded."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            return int(json.loads(z.read("data"))["num_timesteps"])
    except (OSError, KeyError, ValueError, TypeError, zipfile.BadZipFile) as exc:
        raise TrainConfigError(f"{path}: not a checkpoint this trainer wrote: {exc}") from exc


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        out = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return out if isinstance(out, dict) else None


#: keys of a run's config that do not change what its first N steps train: how long it runs,
#: how it is evaluated and checkpointed, where it writes (the learning rate is compared step by
#: step, see :func:`resume_differences`)
_NOT_THE_RECIPE = {
    "total_timesteps",
    "eval_every",
    "eval_episodes",
    "eval_seed_base",
    "checkpoint_every",
    "output",
    "learning_rate_schedule",
}


def resume_differences(
    before: Mapping[str, Any] | None, cfg: TrainConfig, at: int, where: Path | str = "run"
) -> dict[str, list[Any]]:
    """What a resumed run's config changes from the config the run was trained with up to its
    checkpoint's step ``at`` (``before``: that run's ``config.json``): ``{key: [before, now]}``
    of the keys that do not change the training so far (its length, its evaluations, and the
    learning rate after ``at``). Refuses, naming the keys, a config whose recipe up to ``at``
    differs: those steps would not be the first ``at`` steps of a run of this config."""
    if before is None:
        raise TrainConfigError(f"{where}: resuming needs the run's config.json, which is missing")
    try:
        then = TrainConfig(**before)
    except TypeError as exc:
        raise TrainConfigError(f"{where}/config.json: not a training config: {exc}") from exc
    a, b = then.to_dict(), cfg.to_dict()
    ha, hb = dict(a.pop("hyperparameters")), dict(b.pop("hyperparameters"))
    ha.pop("learning_rate", None), hb.pop("learning_rate", None)
    changed = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
    wrong = [k for k in changed if k not in _NOT_THE_RECIPE]
    wrong += [
        f"hyperparameters.{k}" for k in sorted(ha.keys() | hb.keys()) if ha.get(k) != hb.get(k)
    ]
    # PPO's update after the rollout that starts at step s runs at the rate at s
    # (callbacks.LearningRateAt): the steps taken were trained at the rates of [0, last start]
    last = max(0, at - cfg.n_envs * int(cfg.hyperparameters.get("n_steps", 2048)))
    points = {0.0, float(last)} | {
        float(p[0]) for c in (then, cfg) for p in c.learning_rate_schedule if p[0] <= last
    }
    if any(
        not math.isclose(then.learning_rate_at(s), cfg.learning_rate_at(s), rel_tol=1e-12)
        for s in points
    ):
        wrong.append(f"the learning rate of the updates up to step {at}")
    if wrong:
        raise TrainConfigError(
            f"{where}: cannot resume at step {at} with this config: it trains the steps already "
            f"taken differently ({', '.join(wrong)}); start a new run (another output)"
        )
    out: dict[str, list[Any]] = {k: [a.get(k), b.get(k)] for k in changed}
    out.pop("learning_rate_schedule", None)
    rates = [c.learning_rate_schedule or c.learning_rate_at(at) for c in (then, cfg)]
    if rates[0] != rates[1]:  # the same up to ``at``: a schedule (or rate) from there on
        out["learning_rate"] = rates
    return out


def _wall_before(path: Path) -> float:
    """The wall time of a resumed run's earlier sessions (its last ``summary.json``), s."""
    try:
        return float(json.loads(path.read_text())["wall_s"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0.0


def _shrink_output(model: Any, algo: str, scale: float) -> None:
    """Scale the action layer's weights and bias by ``scale``: the policy starts with a
    near-zero action (the residual: the base controller itself; plain: standing still)."""
    import torch

    head = model.policy.action_net if algo == "ppo" else model.policy.actor.mu
    # SAC with gSDE and TD3 wrap the last Linear layer in a Sequential (with a squashing function)
    modules = list(head.modules()) if isinstance(head, torch.nn.Sequential) else [head]
    layers = [m for m in modules if isinstance(m, torch.nn.Linear)][-1:]
    with torch.no_grad():
        for layer in layers:
            layer.weight.mul_(scale)
            layer.bias.mul_(scale)
    if algo == "td3":  # the actor's target starts as a copy
        model.policy.actor_target.load_state_dict(model.policy.actor.state_dict())


# --------------------------------------------------------------------------------------------------
def evaluate_policy(
    path: str | Path,
    scenarios: tuple[str, ...] = LEADERBOARD_SCENARIOS,
    seeds: tuple[int, ...] = LEADERBOARD_SEEDS,
    env_kwargs: Mapping[str, Any] | None = None,
    episode_seconds: float = EPISODE_SECONDS,
    settle_seconds: float = SETTLE_SECONDS,
    perturb_rel: float = 0.0,
) -> dict[str, dict[str, list[float]]]:
    """A policy file's deterministic leaderboard episodes (per scenario, per seed: settled and
    whole-episode RMS, mm); the same numbers every time on one machine (``perturb_rel``: see
    :func:`evaluate_network`)."""
    from agents.policy import load_policy_file

    network, meta = load_policy_file(path)
    env = dict(LEADERBOARD_ENV if env_kwargs is None else env_kwargs)
    return evaluate_network(
        network,
        meta,
        scenarios,
        seeds,
        env,
        episode_seconds=episode_seconds,
        settle_seconds=settle_seconds,
        perturb_rel=perturb_rel,
    )


class PerturbedObservations(Agent):
    """An agent that sees every observation multiplied by ``1 + rel * (+-1)``, the signs drawn
    from ``seed``: a rounding difference of relative size ``rel`` at every step, as another CPU
    would make one. A closed loop that is not chaotic carries it on at about that size."""

    def __init__(self, inner: Agent, rel: float, seed: int = 0) -> None:
        super().__init__()
        self.inner, self.rel = inner, float(rel)
        self.name = inner.name
        self.needs_truth = inner.needs_truth
        self._rng = np.random.default_rng([0xC0FFEE, int(seed)])

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task = task
        self.inner.reset(task, seed, truth)

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        self.task = task
        self.inner.next_phase(task, truth)

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        signs = self._rng.choice((-1.0, 1.0), size=np.shape(obs))
        out = self.inner.act(np.asarray(obs, dtype=float) * (1.0 + self.rel * signs), info)
        self.last_solve_time = self.inner.last_solve_time
        return out

    def report(self) -> dict[str, float | list]:
        return self.inner.report()


def ship_policy(
    run_dir: str | Path,
    which: str = "best",
    name: str | None = None,
    seeds_trained: int = 1,
    wall_s_all_seeds: float | None = None,
    picked: str | None = None,
    folder: str | Path | None = None,
    evaluate: bool = True,
) -> Path:
    """Copy a run's ``best`` or ``final`` policy into ``agents/policies/<name>.npz`` (and .json)
    with its deterministic evaluation on the public episodes and its training budget (the run's
    steps and wall time, from its ``summary.json``; how many seeds were trained to choose it and
    their wall time in all; ``picked``, which seed of them this is: ``"best"`` or ``"median"``)
    recorded in the .json: the leaderboard says what the shipped row is from it.

    ``folder`` ships elsewhere (``agents/policies/seeds/``: every training seed of an agent, which
    the leaderboard ranks as the agent, ``ppo@s3``); ``evaluate=False`` leaves out the evaluation
    on the public episodes (a seed's rows are the sweep's own)."""
    from agents.policy import load_policy_file
    from arm.files import atomic_path, atomic_write_text

    run_dir = Path(run_dir)
    if which not in ("best", "final"):
        raise TrainConfigError(f"which must be 'best' or 'final', got {which!r}")
    src = run_dir / f"{which}.npz"
    _, meta = load_policy_file(src)  # refuses anything unsafe or inconsistent
    name = name or str(meta["name"])
    dst = Path(folder or POLICY_DIR) / f"{name}.npz"
    dst.parent.mkdir(parents=True, exist_ok=True)
    meta = dict(meta) | {"name": name, "source": f"{run_dir.name}/{which}.npz"}
    # where the run wrote its records, as the default would name it (no path of this machine)
    meta["config"] = dict(meta.get("config") or {}) | {"output": f"runs/{run_dir.name}"}
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text()) if os.path.exists(summary_path) else {}
    wall = summary.get("wall_s")
    meta["training"] = {
        "run": run_dir.name,
        "timesteps": int(summary.get("timesteps", meta.get("timesteps", 0))),
        "wall_s": None if wall is None else round(float(wall), 1),
        "seeds_trained": int(seeds_trained),
        "wall_s_all_seeds": wall_s_all_seeds if wall_s_all_seeds is not None else wall,
    }
    if picked is not None:
        meta["training"]["picked"] = str(picked)
    meta.pop("leaderboard", None)  # a record is of the file it was made for
    if evaluate:
        meta["leaderboard"] = policy_evaluation_record(src)  # the same weights
    with atomic_path(dst) as tmp:
        tmp.write_bytes(src.read_bytes())
    atomic_write_text(dst.with_suffix(".json"), json.dumps(meta, indent=2) + "\n")
    return dst


def policy_evaluation_record(path: str | Path, commit: str | None = None) -> dict[str, Any]:
    """The ``leaderboard`` record of a policy file's .json: its deterministic episodes on the
    public seeds (float64 inference), with the settings that made them and, where given, the
    clean commit of the code that evaluated it."""
    record: dict[str, Any] = {
        "env": LEADERBOARD_ENV,
        "seeds": list(LEADERBOARD_SEEDS),
        "episode_seconds": EPISODE_SECONDS,
        "settle_seconds": SETTLE_SECONDS,
        "inference": "float64",
    }
    if commit is not None:
        record["commit"] = commit
    record["episodes"] = evaluate_policy(path)
    return record


def rerecord_policy(name_or_path: str | Path, commit: str | None = None) -> Path:
    """Evaluate a shipped policy (``agents/policies/<name>.npz``, or a policy file) again and
    rewrite the ``leaderboard`` record of its .json atomically; the weights are not touched.
    Used when the evaluation itself changes (float32 to float64 inference)."""
    from agents.policy import load_policy_file
    from arm.files import atomic_write_text

    p = Path(name_or_path)
    path = p if p.suffix == ".npz" else POLICY_DIR / f"{name_or_path}.npz"
    _, meta = load_policy_file(path)  # refuses anything unsafe or inconsistent
    meta = dict(meta)
    meta["leaderboard"] = policy_evaluation_record(path, commit)
    atomic_write_text(path.with_suffix(".json"), json.dumps(meta, indent=2) + "\n")
    return path
