"""A user's agents, joined to sweeps by class path (``tests._user_agent:Snoop``): they record
everything they are given, so tests can check that nothing hidden reaches them."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from agents.base import Agent
from envs.task import Observation, TaskInfo, Truth


class Snoop(Agent):
    """Holds still and reports the info keys, measurement columns and task fields it saw, and
    whether it was handed a truth object."""

    name = "snoop"

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task = task
        self.info_keys: set[str] = set()
        self.column_keys: set[str] = set()
        self.task_fields = sorted(f.name for f in dataclasses.fields(task))
        self.truths = [truth is not None]
        self.payloads: list[float] = []

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        self.task = task
        self.truths.append(truth is not None)

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        self.info_keys |= set(info)
        self.column_keys |= set(info.get("measurement_columns") or {})
        self.payloads.append(float(Observation.parse(self.task, obs).payload or 0.0))
        return np.zeros(6)

    def report(self) -> dict:
        return {
            "info_keys": sorted(self.info_keys),
            "column_keys": sorted(self.column_keys),
            "task_fields": self.task_fields,
            "truth_given": self.truths,
            "observed_payload": self.payloads,
        }


class SnoopOracle(Snoop):
    """The same, declaring itself an oracle: it reads the plant's payload from the truth."""

    name = "snoop-oracle"
    needs_truth = True

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        super().reset(task, seed, truth)
        self.truth = truth
        self.true_payloads: list[float] = []
        self.scenario = truth.scenario if truth is not None else None

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        self.true_payloads.append(float(self.truth.conditions()["payload"]))
        return super().act(obs, info)

    def report(self) -> dict:
        return super().report() | {"true_payload": self.true_payloads, "scenario": self.scenario}


class Hang(Agent):
    """Holds still, then never returns from ``act`` (from step ``after`` on). ``block_alarm``:
    hang where no signal stops it either (SIGALRM ignored: as deep in C code)."""

    name = "hang"

    def __init__(self, after: int = 3, block_alarm: bool = False) -> None:
        super().__init__()
        self.after, self.block_alarm = int(after), bool(block_alarm)

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task, self.steps = task, 0

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        import signal
        import time

        self.steps += 1
        if self.steps > self.after:
            if self.block_alarm:
                signal.signal(signal.SIGALRM, signal.SIG_IGN)
            while True:
                time.sleep(1.0)
        return np.zeros(6)


class Raises(Agent):
    """Raises in ``act`` at step ``at``."""

    name = "raises"

    def __init__(self, at: int = 3) -> None:
        super().__init__()
        self.at = int(at)

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task, self.steps = task, 0

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        self.steps += 1
        if self.steps >= self.at:
            raise RuntimeError(f"deliberate failure at step {self.steps}")
        return np.zeros(6)


class NaNAction(Raises):
    """Returns NaN for joint 2 at step ``at``."""

    name = "nan-action"

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        self.steps += 1
        a = np.zeros(6)
        if self.steps >= self.at:
            a[1] = np.nan
        return a


class MemoryHog(Raises):
    """Asks for ``gigabytes`` of memory at step ``at`` (and touches it)."""

    name = "memory-hog"

    def __init__(self, at: int = 3, gigabytes: float = 64.0) -> None:
        super().__init__(at)
        self.gigabytes = float(gigabytes)

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        self.steps += 1
        if self.steps >= self.at:
            self.hoard = np.ones(int(self.gigabytes * 2**30 / 8))
        return np.zeros(6)


class LateOracle(Snoop):
    """An oracle that takes the truth at reset and then says it is none."""

    name = "late-oracle"
    needs_truth = True

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        super().reset(task, seed, truth)
        self.needs_truth = False


class LateClaim(Snoop):
    """Says it needs the truth only after reset: too late to be given it."""

    name = "late-claim"

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        super().reset(task, seed, truth)
        self.needs_truth = True

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        super().next_phase(task, truth)


class ProcessSnoop(Snoop):
    """Looks through its own process for the episode: env, plant and truth objects among
    everything the garbage collector tracks, and the callers' frames for an env, a truth or an
    unfiltered info (one with the true error in it). Reports what it found and the seed."""

    name = "process-snoop"

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        super().reset(task, seed, truth)
        self.seed_given = seed
        self.found: dict[str, int] = {}

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        if not self.found:
            self.found = _look_around()
        return super().act(obs, info)

    def report(self) -> dict:
        return super().report() | {"found": self.found, "seed_given": self.seed_given}


def _look_around() -> dict[str, int]:
    import gc
    import inspect

    wanted = {"SixAxisTrackEnv", "Plant", "EpisodeTruth", "TimeLimit", "OrderEnforcing"}
    found = {name: 0 for name in sorted(wanted)}
    for obj in gc.get_objects():
        name = type(obj).__name__
        if name in wanted:
            found[name] += 1
    frames = 0
    for frame in inspect.stack():
        for value in frame.frame.f_locals.values():
            if type(value).__name__ in wanted or (
                isinstance(value, dict) and "true_error_mm" in value
            ):
                frames += 1
    found["frames"] = frames
    return found
