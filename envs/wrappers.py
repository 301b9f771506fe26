"""Observation options for SixAxisTrack-v0 that reinforcement-learning users expect.

:class:`NominalToolObservation` appends what a goal-reaching task usually hands its agent: where
the tool point is (as the *nominal* model computes it from the encoders: the agent's own belief,
never the plant's truth) and the reference relative to it::

    env = NominalToolObservation(gym.make("SixAxisTrack-v0", scenario="geometric"))
    obs, info = env.reset(seed=1000)
    obs[env.obs_slices["ref_minus_tool"]]        # r - x_nom(q), m

The appended parts (m, in the measurement frame):

| name                  | size | what                                                        |
|-----------------------|------|-------------------------------------------------------------|
| `tool_nominal`        | 3    | x_nom(q): the nominal model's tool point at the encoders    |
| `ref_minus_tool`      | 3    | r - x_nom(q)                                                |
| `preview_minus_tool`  | 3P   | the previewed references minus x_nom(q)                     |

The model is the nominal description's (``task.robot``, no error parameters): a controller could
compute the same thing, so the option adds no information the agent did not have, only its form.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from arm.errormodel import ErrorModel

__all__ = ["NominalToolObservation", "nominal_tool_point"]


def nominal_tool_point(model: ErrorModel, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The nominal model's tool point (3,) m at encoder angles ``q`` (6,)."""
    return np.asarray(model.predict(model.inputs(np.asarray(q, dtype=float)[None, :]), p))[0]


class NominalToolObservation(gym.ObservationWrapper):
    """SixAxisTrack-v0's observation followed by ``tool_nominal``, ``ref_minus_tool`` and
    ``preview_minus_tool`` (see the module docstring); ``obs_slices`` names every part."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        task = env.unwrapped.task  # type: ignore[attr-defined]
        self.task = task
        self.model = ErrorModel(task.robot, "geometric")
        self.p = self.model.nominal()
        n0 = int(task.obs_size)
        P = int(task.preview_steps)
        slices = dict(task.obs_slices)
        k = n0
        for name, n in (("tool_nominal", 3), ("ref_minus_tool", 3), ("preview_minus_tool", 3 * P)):
            slices[name] = slice(k, k + n)
            k += n
        self.obs_slices = slices
        base = env.observation_space
        assert isinstance(base, gym.spaces.Box)
        low = np.concatenate([base.low, np.full(k - n0, -np.inf, dtype=np.float32)])
        high = np.concatenate([base.high, np.full(k - n0, np.inf, dtype=np.float32)])
        self.observation_space = gym.spaces.Box(low, high, (k,), np.float32)

    def observation(self, observation: Any) -> np.ndarray:
        obs = np.asarray(observation, dtype=float)
        sl = self.task.obs_slices
        x = nominal_tool_point(self.model, self.p, obs[sl["q"]])
        ref = obs[sl["ref"]]
        preview = obs[sl["preview"]].reshape(-1, 3)
        extra = np.concatenate([x, ref - x, (preview - x[None, :]).reshape(-1)])
        return np.concatenate([obs, extra]).astype(np.float32)
