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

The observation layout is the env's ``task.obs_slices``; :class:`Observation` reads it by name.
"""

from __future__ import annotations

import abc
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Agent", "Observation", "measurement_columns", "solve_time_stats"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Observation:
    """The named parts of a flat observation vector (views, SI units)."""

    q: np.ndarray  # encoder angles (6,), rad
    qd: np.ndarray  # joint velocities (6,), rad/s
    ref: np.ndarray  # the reference tool point now (3,), m
    preview: np.ndarray  # the next references (preview_steps, 3), m
    meas: np.ndarray  # the last tracker measurement (3,), m
    meas_age: float  # its age, s
    meas_valid: bool
    temperature: float  # degC
    payload: float | None = None  # kg, as declared to the controller (None: not observed)

    @classmethod
    def parse(cls, task: Any, obs: np.ndarray) -> Observation:
        sl = task.obs_slices
        obs = np.asarray(obs, dtype=float)

        def part(name, default=None):
            if name not in sl:
                if default is None:
                    raise KeyError(f"the observation has no {name!r} (slices: {sorted(sl)})")
                return default
            return obs[sl[name]]

        return cls(
            q=part("q"),
            qd=part("qd", np.zeros(6)),
            ref=part("ref"),
            preview=part("preview").reshape(-1, 3),
            meas=part("meas", np.full(3, np.nan)),
            meas_age=float(part("meas_age", np.array([np.inf]))[0]),
            meas_valid=bool(part("meas_valid", np.zeros(1))[0] > 0.5),
            temperature=float(part("temperature", np.array([20.0]))[0]),
            payload=float(obs[sl["payload"]][0]) if "payload" in sl else None,
        )

    def references(self, n: int) -> np.ndarray:
        """The next ``n`` reference points (n, 3), the last preview point repeated if short."""
        pv = self.preview
        if len(pv) == 0:
            return np.repeat(self.ref[None, :], n, axis=0)
        if len(pv) >= n:
            return pv[:n]
        return np.vstack([pv, np.repeat(pv[-1:], n - len(pv), axis=0)])


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
        self.task: Any = None
        self.last_solve_time: float = 0.0  # s, the computation of the last act()

    @abc.abstractmethod
    def reset(self, task: Any, seed: int | None = None, truth: Any = None) -> None:
        """Start an episode on the arm described by ``task`` (the env's ``TaskInfo``)."""

    def next_phase(self, task: Any, truth: Any = None) -> None:
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
