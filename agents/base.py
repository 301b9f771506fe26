"""The one small interface every controller has, so the benchmark loop is one loop.

    agent = make_agent("mpc")                       # agents.registry
    agent.reset(env.unwrapped.task, seed=0)         # a new episode (truth only for oracles)
    action = agent.act(obs, info)                   # (6,) in [-1, 1]: joint velocity / v_max
    agent.report()                                  # {"solve_time_median_s": ..., ...}

``reset`` starts an episode: everything learned is forgotten. ``next_phase`` continues the same
arm in a new phase (a new trajectory, measurements switched off): learned models are kept, the
time-varying state (last command, the pending measurement) is not. ``act`` receives the
observation and the ``info`` of the step that produced it (the reset's info at the first step);
agents use only what a real controller would have, never the truth (``truth`` is handed to oracles
alone).

The contract's types (:class:`~envs.task.TaskInfo`, the :class:`~envs.task.Truth` an oracle reads,
:class:`~envs.task.Observation`, which reads the flat observation by the env's ``task.obs_slices``)
live in :mod:`envs.task`, which imports no MuJoCo.
"""

from __future__ import annotations

import abc
import logging
from collections.abc import Mapping
from typing import Any

import numpy as np

from agents.errors import AgentError, AgentStateError
from arm.constraints import Constraint, check, refuse
from envs.task import TaskInfo, Truth

__all__ = ["Agent", "measurement_columns", "refuse_settings", "solve_time_stats"]

log = logging.getLogger(__name__)


def measurement_columns(info: Mapping[str, Any]) -> dict[str, float]:
    """The per-measurement columns (temperature, payload, dir1..6) of ``info`` as a dict.

    Accepts a mapping, or a sequence in the order (temperature, dir1..dir6, payload)."""
    cols = info.get("measurement_columns")
    if cols is None:
        return {}
    if isinstance(cols, Mapping):
        return {k: float(v) for k, v in cols.items()}
    arr = np.asarray(cols, dtype=float).reshape(-1)
    names = ("temperature", *(f"dir{i}" for i in range(1, 7)), "payload")
    return {n: float(v) for n, v in zip(names, arr, strict=False)}


def refuse_settings(declared: Mapping[str, Constraint], **values: Any) -> None:
    """Refuse every one of ``values`` (an agent's or an estimator's settings, by name) that
    breaks its ``declared`` constraint (:mod:`arm.constraints`), all named in one
    :class:`~agents.errors.AgentError`: ``forgetting must lie in (0, 1], got 2``. None passes: a
    setting left unset is the caller's to judge."""
    refuse(check(values, {k: ([c], True) for k, c in declared.items()}), AgentError)


def solve_time_stats(times: list[float] | np.ndarray, prefix: str = "solve_time") -> dict:
    """Median, p95 and max of per-step computation times (s)."""
    t = np.asarray(times, dtype=float)
    if t.size == 0:
        return {}
    return {
        f"{prefix}_median_s": float(np.median(t)),
        f"{prefix}_p95_s": float(np.percentile(t, 95)),
        f"{prefix}_max_s": float(t.max()),
    }


class Agent(abc.ABC):
    """A controller: ``reset`` per episode, ``act`` per step, ``report`` at the end."""

    name: str = "agent"

    #: whether the agent needs the plant's truth (oracles only); the runner passes it then
    needs_truth: bool = False

    def __init__(self) -> None:
        self._task: TaskInfo | None = None
        self.last_solve_time: float = 0.0  # s, the computation of the last act()

    @property
    def task(self) -> TaskInfo:
        """The task of the current episode, as :meth:`reset` (or :meth:`next_phase`) set it."""
        if self._task is None:
            raise AgentStateError(f"{self.name}: no task yet; call reset(task) first")
        return self._task

    @task.setter
    def task(self, task: TaskInfo) -> None:
        self._task = task

    @abc.abstractmethod
    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        """Start an episode on the arm described by ``task``."""

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        """Continue on the same arm in a new phase; keep what was learned (default: just the
        task)."""
        self.task = task

    @abc.abstractmethod
    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        """The normalised joint-velocity command (6,) in [-1, 1]."""

    def report(self) -> dict[str, float | list]:
        """What the agent did: solve-time statistics, identified parameters..."""
        return {}

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r})"
