"""Two agents that try to take the plant's truth by the routes a sceptical audit found, kept as
tests (``tests/test_agents_isolation.py``): run by class path in a sweep, they must end up as
plain ``mpc``, never at ``mpc-oracle``'s numbers.

* :class:`SeedRebuilder` takes the episode seed it is given at ``reset``, or an env it finds in
  its own process (the garbage collector, the callers' frames), and rebuilds the env from the
  public code to read its truth.
* :class:`PathMatcher` takes no seed: it recovers it by matching the first reference point
  against the first ``max_seed`` seeds' paths (the published seeds used to be 0-4).

When either finds the truth it tracks with ``mpc-oracle`` on it; otherwise it is ``mpc``. Both
report what they found (``found_truth``, ``route``)."""

from __future__ import annotations

import gc
import inspect
from collections.abc import Mapping
from typing import Any

import numpy as np

from agents.base import Agent
from agents.mpc import MPCAgent
from envs.task import Observation, TaskInfo, Truth


class _Cheat(Agent):
    def __init__(self, scenario: str = "geometric", env: Mapping[str, Any] | None = None) -> None:
        super().__init__()
        self.scenario = scenario
        self.env_kwargs = dict(env or {})
        self.inner: MPCAgent = MPCAgent()
        self.route = ""

    def _truth_of(self, seed: int) -> Truth:
        import gymnasium as gym

        import envs  # noqa: F401

        env = gym.make("SixAxisTrack-v0", scenario=self.scenario, **self.env_kwargs)
        try:
            env.reset(seed=int(seed))
            return env.unwrapped.truth
        finally:
            env.close()

    def _first_ref(self, seed: int) -> np.ndarray:
        import gymnasium as gym

        import envs  # noqa: F401

        env = gym.make("SixAxisTrack-v0", scenario=self.scenario, **self.env_kwargs)
        try:
            obs, _ = env.reset(seed=int(seed))
            return Observation.parse(env.unwrapped.task, obs).ref.copy()
        finally:
            env.close()

    def _become_oracle(self, task: TaskInfo, truth: Truth, route: str) -> None:
        self.inner = MPCAgent(oracle=True)
        self.inner.reset(task, truth=truth)
        self.route = route

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        action = self.inner.act(obs, info)
        self.last_solve_time = self.inner.last_solve_time
        return action

    def report(self) -> dict:
        return {"found_truth": bool(self.route), "route": self.route}


def _truth_in_process() -> Truth | None:
    """The episode's truth found in this process: an env in the callers' frames (the runner's),
    else any live env's or truth object the garbage collector tracks."""
    for frame in inspect.stack():
        for value in frame.frame.f_locals.values():
            truth = getattr(getattr(value, "unwrapped", None), "truth", None)
            if truth is not None:
                return truth
    for obj in gc.get_objects():
        name = type(obj).__name__
        if name == "SixAxisTrackEnv" and getattr(obj, "truth", None) is not None:
            return obj.truth
        if name == "EpisodeTruth":
            return obj  # type: ignore[return-value]
    return None


class SeedRebuilder(_Cheat):
    """Rebuilds the env from the seed it is given, or reads a truth lying in its process."""

    name = "seed-rebuilder"

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task = task
        self.inner = MPCAgent()
        self.inner.reset(task)
        self.route = ""
        self.seed_given = seed
        self.first = True
        found = _truth_in_process()
        if found is not None:
            self._become_oracle(task, found, "process")

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        if self.first and not self.route and self.seed_given is not None:
            self.first = False
            ref = Observation.parse(self.task, obs).ref
            try:
                if np.allclose(self._first_ref(self.seed_given), ref, atol=1e-9):
                    self._become_oracle(self.task, self._truth_of(self.seed_given), "seed")
            except Exception:  # a seed no env takes: nothing learned
                pass
        return super().act(obs, info)


class PathMatcher(_Cheat):
    """Finds the episode seed among 0..max_seed-1 by the first reference point."""

    name = "path-matcher"

    def __init__(
        self, scenario: str = "geometric", env: Mapping[str, Any] | None = None, max_seed: int = 8
    ) -> None:
        super().__init__(scenario, env)
        self.max_seed = int(max_seed)

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task = task
        self.inner = MPCAgent()
        self.inner.reset(task)
        self.route = ""
        self.first = True

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        if self.first:
            self.first = False
            ref = Observation.parse(self.task, obs).ref
            for s in range(self.max_seed):
                if np.allclose(self._first_ref(s), ref, atol=1e-9):
                    self._become_oracle(self.task, self._truth_of(s), f"path (seed {s})")
                    break
        return super().act(obs, info)
