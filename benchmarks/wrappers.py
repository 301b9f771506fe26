"""The cost of SixAxisTrack-v0's reinforcement-learning options beside the env's own step: the
operational-space interface (``gym.make(..., interface="tool")``,
:class:`envs.wrappers.ToolDisplacementAction`) and :class:`envs.wrappers.NominalToolObservation`,
each timed per step against ``gym.make`` of the raw env sending the same joint commands, in one
run, interleaved. Target: each option costs at most 1.3x the raw env step. Writes section
``wrappers`` of results/benchmarks.md and results/wrappers.json.

    python benchmarks/wrappers.py [--steps 500] [--repeats 11]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym
import numpy as np

import envs  # noqa: F401
from arm.files import atomic_write_text
from benchmarks._report import machine, write_section
from envs.wrappers import NominalToolObservation, ToolDisplacementAction

#: rigid joints (the cheapest physics, so the options' share is largest) and elastic ones
SCENARIOS = ("geometric", "compliance")
TARGET = 1.3
OPTIONS = ("tool", "nominal_tool_observation")


def _time(env, actions: np.ndarray) -> float:
    env.reset(seed=0)
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    return (time.perf_counter() - t) / len(actions)


def measure(scenario: str, steps: int, repeats: int) -> dict[str, float]:
    kw = {"scenario": scenario, "trajectory": "circle"}
    tool = gym.make("SixAxisTrack-v0", interface="tool", **kw)
    raw = gym.make("SixAxisTrack-v0", **kw)
    nto = NominalToolObservation(gym.make("SixAxisTrack-v0", **kw))
    # smooth tool displacements of up to 1 mm a step; the raw envs get the joint commands they
    # make (the same servo commands, so the same physics)
    displacements = 0.2 * np.sin(np.outer(np.arange(steps) * 0.05, (1.0, 2.0, 3.0)))
    wrapper = tool
    while not isinstance(wrapper, ToolDisplacementAction):
        wrapper = wrapper.env  # type: ignore[assignment]
    tool.reset(seed=0)
    commands = []
    for a in displacements:
        tool.step(a)
        commands.append(wrapper.interface.v_prev / wrapper.interface.v_max)
    joint = np.asarray(commands, dtype=np.float32)
    times: dict[str, list[float]] = {"raw": [], "tool": [], "nominal_tool_observation": []}
    for _ in range(repeats):  # interleaved, so that load changes hit all alike
        times["raw"].append(_time(raw, joint))
        times["tool"].append(_time(tool, displacements.astype(np.float32)))
        times["nominal_tool_observation"].append(_time(nto, joint))
    out: dict[str, float] = {"raw_us": min(times["raw"]) * 1e6}
    for name in OPTIONS:
        out[f"{name}_us"] = min(times[name]) * 1e6
        out[f"{name}_ratio"] = min(times[name]) / min(times["raw"])
        out[f"{name}_ratio_median"] = statistics.median(times[name]) / statistics.median(
            times["raw"]
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=11)
    args = ap.parse_args()
    rows = {}
    for sc in SCENARIOS:
        r = rows[sc] = measure(sc, args.steps, args.repeats)
        print(
            f"{sc:11s} raw {r['raw_us']:6.1f} us/step  tool {r['tool_us']:6.1f} "
            f"({r['tool_ratio']:.2f}x)  NominalToolObservation {r['nominal_tool_observation_us']:6.1f}"
            f" ({r['nominal_tool_observation_ratio']:.2f}x)"
        )
    where = machine()
    lines = [
        "## wrappers: the reinforcement-learning options' cost beside the env step",
        "",
        f"Machine: {where}. `python benchmarks/wrappers.py --steps {args.steps} --repeats "
        f'{args.repeats}`: one control step through `gym.make("SixAxisTrack-v0", '
        'interface="tool")` (the operational-space interface: observation in mm from the '
        "nominal model's tool point and Jacobian, the displacement through its damped "
        "pseudo-inverse within the servo's limits) and through "
        '`NominalToolObservation(gym.make("SixAxisTrack-v0"))`, beside `gym.make` of the raw env '
        "sending the same joint commands (same path, same physics), interleaved; the fastest of "
        "the repeats (the machine is shared), the ratio of medians beside it. Target: each option "
        f"<= {TARGET}x the raw env step.",
        "",
        "| scenario | raw env us/step | option | us/step | ratio | ratio of medians | target |",
        "|---|---:|---|---:|---:|---:|---|",
    ]
    for sc, r in rows.items():
        for name, label in zip(
            OPTIONS, ('interface="tool"', "NominalToolObservation"), strict=True
        ):
            ratio = r[f"{name}_ratio"]
            lines.append(
                f"| {sc} | {r['raw_us']:.1f} | {label} | {r[f'{name}_us']:.1f} | {ratio:.2f} | "
                f"{r[f'{name}_ratio_median']:.2f} | {'met' if ratio <= TARGET else 'missed'} |"
            )
    path = write_section("wrappers", "\n".join(lines))
    out = Path(__file__).resolve().parents[1] / "results" / "wrappers.json"
    doc = {"schema_version": 1, "machine": where, "target": TARGET, "scenarios": rows}
    atomic_write_text(out, json.dumps(doc, indent=2) + "\n")
    print(f"wrote {path} and {out}")


if __name__ == "__main__":
    main()
