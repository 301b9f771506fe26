"""What running an agent in a process of its own costs: the same episodes run with the agent in
the runner's process and in its own (``agents.isolation.IsolatedAgent``), interleaved, in one run.
Reports the wall time per control step of each, their difference (the pipe's round trip: the
observation and ``info`` pickled there, the action back as JSON), the one-off start of the
agent's process, and checks that both give the same numbers. Writes section ``isolation`` of
results/benchmarks.md.

    python benchmarks/isolation.py [--seconds 10] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from agents.base import Agent
from agents.isolation import IsolatedAgent
from agents.registry import make_agent
from agents.runner import run_episode
from benchmarks._report import machine, write_section

AGENTS = ("hold", "feedforward", "mpc")
ENV = {"scenario": "geometric", "noise_mm": 0.015, "measure_every": 5}


class Timed(Agent):
    """Delegates to ``inner`` and times each of its ``act`` calls (seen from the runner)."""

    def __init__(self, inner: Agent) -> None:
        super().__init__()
        self.inner, self.name, self.needs_truth = inner, inner.name, inner.needs_truth
        self.times: list[float] = []

    def reset(self, task, seed=None, truth=None):
        self.task = task
        self.inner.reset(task, seed=seed, truth=truth)

    def act(self, obs, info):
        t = time.perf_counter()
        a = self.inner.act(obs, info)
        self.times.append(time.perf_counter() - t)
        return a

    def report(self):
        return self.inner.report()


def measure(name: str, seconds: float, repeats: int) -> dict[str, float]:
    t = time.perf_counter()
    isolated = IsolatedAgent(name)
    start_s = time.perf_counter() - t
    here_s, there_s, same = [], [], True
    try:
        for k in range(repeats):
            here, there = Timed(make_agent(name)), Timed(isolated)
            a = run_episode(here, ENV, seed=k, episode_seconds=seconds)
            b = run_episode(there, ENV, seed=k, episode_seconds=seconds)
            here_s += here.times
            there_s += there.times
            same &= np.array_equal(a.true_error_mm, b.true_error_mm)
            same &= np.array_equal(a.actions, b.actions)
    finally:
        isolated.close()
    here_t, there_t = statistics.median(here_s), statistics.median(there_s)
    return {
        "here_us": here_t * 1e6,
        "there_us": there_t * 1e6,
        "cost_us": (there_t - here_t) * 1e6,
        "p95_us": (float(np.percentile(there_s, 95)) - float(np.percentile(here_s, 95))) * 1e6,
        "start_s": start_s,
        "same": bool(same),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    load0 = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    rows = {name: measure(name, args.seconds, args.repeats) for name in AGENTS}
    load1 = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        "## isolation",
        "",
        f"`python benchmarks/isolation.py` ({machine()}): {args.repeats} episodes of "
        f"{args.seconds:g} s on `geometric` per agent, the agent in the runner's process and in "
        "a process of its own (`agents.isolation`), interleaved; the time of each `act` call as "
        "the runner sees it (for the isolated agent: the observation and `info` sent, the agent's "
        "`act`, the action back), median over every step. For scale: an env step costs about "
        f"340 µs (section `env`). Load average {load0:.1f} and {load1:.1f} (at the start and the "
        "end) on this machine's cores: the 95th percentiles are the scheduler's as much as the "
        "pipe's when it is loaded.",
        "",
        "| agent | `act` in the runner's process (µs) | `act` in its own process (µs) | "
        "isolation's cost per step (µs, median) | at the 95th percentile (µs) | "
        "process start (s) | same numbers |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for name, r in rows.items():
        lines.append(
            f"| `{name}` | {r['here_us']:.0f} | {r['there_us']:.0f} | {r['cost_us']:.0f} | "
            f"{r['p95_us']:.0f} | {r['start_s']:.2f} | {'yes' if r['same'] else 'NO'} |"
        )
    lines += [
        "",
        "The cost is the pipe's round trip, about the same whatever the agent computes; the "
        "process starts once per run (a fresh interpreter that imports the agent's module and "
        "makes the agent).",
    ]
    write_section("isolation", "\n".join(lines))
    print("\n".join(lines))
    if not all(r["same"] for r in rows.values()):
        raise SystemExit("isolation changed the numbers")


if __name__ == "__main__":
    main()
