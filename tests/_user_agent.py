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
