"""Any stable-baselines3 policy on the leaderboard: :func:`from_sb3` writes a model trained on
either interface of SixAxisTrack-v0 as a policy file of this project and returns its agent.

    model = PPO("MlpPolicy", gym.make("SixAxisTrack-v0", interface="tool")).learn(100_000)
    agent = agents.from_sb3(model, interface="tool", path="mine.npz")
    run_episode(agent, {"scenario": "backlash"}, seed=0)

The file is the shipped policies' format (:mod:`agents.policy`: the acting network's weights as
plain arrays and the observation normalisation in ``.npz``, the architecture as data in
``.json``): it loads without unpickling, and a sweep runs it as the agent ``policy`` with the
setting ``path`` (``{name = "policy", label = "mine", settings = {path = "mine.npz"}}``), so its
rows are reproduced as any other's. The policy acts on what the interface's wrapper would have
given it (:class:`agents.policy.PolicyIO` computes the same numbers from the controllers' part of
``info``), deterministically (the distribution's mode), in float64.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from agents.policy import (
    ACTIVATIONS,
    POLICY_KWARGS,
    PolicyAgent,
    PolicyFileError,
    save_policy_file,
)
from envs.wrappers import INTERFACES, observed

__all__ = ["from_sb3"]

#: the interfaces' policy variants (agents.policy): the tool interface's relative observation,
#: or the env's own observation and action
_VARIANT = {"tool": "tool", "joint": "joint"}
#: the action sizes of the interfaces
_ACTIONS = {"tool": 3, "joint": 6}


def from_sb3(
    model: Any,
    interface: str = "tool",
    path: str | Path = "policy.npz",
    name: str | None = None,
    tool_step_mm: float = 5.0,
    observe: tuple[str, ...] | list[str] = (),
    vec_normalize: Any = None,
) -> PolicyAgent:
    """Write the stable-baselines3 ``model`` (PPO, SAC or TD3 with an MLP policy) as the policy
    file ``path`` (``.npz`` added if absent, and its ``.json``) and return its agent.

    ``interface`` is the one it was trained on: ``"tool"`` (``gym.make("SixAxisTrack-v0",
    interface="tool", tool_step_mm=..., observe=...)``: give the same ``tool_step_mm`` and
    ``observe``) or ``"joint"`` (the env itself). ``vec_normalize``: the ``VecNormalize`` it was
    trained in, whose observation statistics are saved with it (its running statistics, frozen
    as they are now); without one, the observation is the policy's input as it is. Refused, by
    a :class:`~agents.policy.PolicyFileError` naming what: another algorithm, an observation
    that is not a flat Box, actions that are not the interface's ``Box(-1, 1)``, policy keyword
    arguments that cannot be written as data."""
    if interface not in INTERFACES:
        raise PolicyFileError(
            f"from_sb3: interface {interface!r} is not one of {', '.join(INTERFACES)}"
        )
    if observe and interface != "tool":
        raise PolicyFileError("from_sb3: observe is an option of the tool interface")
    algo = _algo(model)
    obs_size = _observation_size(model)
    _check_actions(model, interface)
    kwargs = _policy_kwargs_as_data(algo, getattr(model, "policy_kwargs", None) or {})
    target = Path(str(path) if str(path).endswith(".npz") else f"{path}.npz")
    label = name or target.stem
    meta = {
        "name": label,
        "variant": _VARIANT[interface],
        "obs_size": obs_size,
        "act_size": _ACTIONS[interface],
        "tool_step_mm": float(tool_step_mm),
        "observe": list(observed(observe)),
        "policy_kwargs": kwargs,
        "use_sde": bool(getattr(model, "use_sde", False)),
        "timesteps": int(getattr(model, "num_timesteps", 0)),
        "source": f"stable-baselines3 {type(model).__name__} (agents.from_sb3)",
    }
    save_policy_file(target, algo, model.policy, _normalisation(vec_normalize, obs_size), meta)
    return PolicyAgent(path=str(target), name=label)


def _algo(model: Any) -> str:
    from stable_baselines3 import PPO, SAC, TD3

    for cls, algo in ((PPO, "ppo"), (SAC, "sac"), (TD3, "td3")):
        if isinstance(model, cls):
            return algo
    raise PolicyFileError(
        f"from_sb3: a {type(model).__name__} is not a PPO, SAC or TD3 model of stable-baselines3"
    )


def _observation_size(model: Any) -> int:
    import gymnasium as gym
    from stable_baselines3.common.torch_layers import FlattenExtractor

    space = model.observation_space
    if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
        raise PolicyFileError(f"from_sb3: the observation must be a flat Box, got {space}")
    extractor = getattr(model.policy, "features_extractor", None)
    if extractor is None and hasattr(model.policy, "actor"):
        extractor = model.policy.actor.features_extractor
    if not isinstance(extractor, FlattenExtractor):
        raise PolicyFileError(
            f"from_sb3: the policy's features extractor is a {type(extractor).__name__}; a "
            "policy file holds MlpPolicy networks (FlattenExtractor)"
        )
    return int(space.shape[0])


def _check_actions(model: Any, interface: str) -> None:
    import gymnasium as gym

    space = model.action_space
    want = _ACTIONS[interface]
    if (
        not isinstance(space, gym.spaces.Box)
        or space.shape != (want,)
        or not (np.all(space.low == -1.0) and np.all(space.high == 1.0))
    ):
        raise PolicyFileError(
            f"from_sb3: the {interface} interface's action is Box(-1, 1, ({want},)); the model "
            f"acts in {space}"
        )


def _policy_kwargs_as_data(algo: str, kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """The model's policy keyword arguments as a policy file writes them (the activation by its
    name), refused where they cannot be."""
    import torch.nn as nn

    names = {nn.Tanh: "tanh", nn.ReLU: "relu", nn.ELU: "elu", nn.LeakyReLU: "leaky_relu"}
    out: dict[str, Any] = {}
    for key, value in kwargs.items():
        if key == "use_sde":  # SAC copies it here; the file records it beside (meta use_sde)
            continue
        if key not in POLICY_KWARGS[algo]:
            raise PolicyFileError(
                f"from_sb3: policy_kwargs {key!r} cannot be written in a policy file ({algo} "
                f"takes {', '.join(sorted(POLICY_KWARGS[algo]))})"
            )
        if key == "activation_fn":
            if value not in names:
                raise PolicyFileError(
                    f"from_sb3: activation_fn {value!r} is not one of {', '.join(ACTIVATIONS)}"
                )
            value = names[value]
        elif key == "net_arch":
            value = (
                {k: list(v) for k, v in value.items()}
                if isinstance(value, Mapping)
                else list(value)
            )
        out[key] = value
    return out


def _normalisation(vec_normalize: Any, obs_size: int) -> dict[str, Any]:
    """The observation normalisation of ``vec_normalize`` (SB3's VecNormalize), or none: the
    identity (mean 0, variance 1, no epsilon, a clip no float reaches)."""
    if vec_normalize is None or not getattr(vec_normalize, "norm_obs", False):
        return {
            "obs_mean": np.zeros(obs_size),
            "obs_var": np.ones(obs_size),
            "obs_clip": float(np.finfo(np.float32).max),
            "obs_epsilon": 0.0,
        }
    rms = vec_normalize.obs_rms
    mean, var = np.asarray(rms.mean, dtype=float), np.asarray(rms.var, dtype=float)
    if mean.shape != (obs_size,):
        raise PolicyFileError(
            f"from_sb3: vec_normalize holds statistics of {mean.shape} observations, the model "
            f"takes ({obs_size},)"
        )
    return {
        "obs_mean": mean,
        "obs_var": var,
        "obs_clip": float(vec_normalize.clip_obs),
        "obs_epsilon": float(vec_normalize.epsilon),
    }
