"""SixAxisTrack-v0 step cost against the raw physics it runs: ``gym.make`` env steps per second
beside ``mujoco.mj_step(model, data, nstep=20)`` on the same compiled model (the same substeps,
the same state, the same servo commands), measured in one run, interleaved, for a few scenarios.
Target: the env costs at most 1.5x the raw physics. Writes section ``env`` of
results/benchmarks.md, and a rendered frame to results/frame.png (``--no-frame`` skips it).

    python benchmarks/env.py [--steps 500] [--repeats 7] [--no-frame]
"""

from __future__ import annotations

import argparse
import copy
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen frame; must precede the mujoco import
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym
import mujoco
import numpy as np

import envs  # noqa: F401
from benchmarks._report import machine, write_section

SCENARIOS = ("geometric", "compliance", "all")
TARGET = 1.5


def _time_env(env, actions: np.ndarray) -> float:
    env.reset(seed=0)
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    return (time.perf_counter() - t) / len(actions)


def _time_raw(model, data, ctrls: np.ndarray, substeps: int) -> float:
    t = time.perf_counter()
    for c in ctrls:
        data.ctrl[:] = c
        mujoco.mj_step(model, data, nstep=substeps)
    return (time.perf_counter() - t) / len(ctrls)


def _time_reset(env, n: int = 20) -> float:
    t = time.perf_counter()
    for seed in range(n):
        env.reset(seed=seed)
    return (time.perf_counter() - t) / n


def measure(scenario: str, steps: int, repeats: int) -> dict[str, float]:
    env = gym.make("SixAxisTrack-v0", scenario=scenario, trajectory="circle")
    u = env.unwrapped
    rng = np.random.default_rng(0)
    # smooth small commands, as a tracking controller sends
    actions = (0.1 * np.sin(np.outer(np.arange(steps) * 0.05, np.arange(1, 7)))).astype(np.float32)
    actions += rng.normal(0, 0.01, actions.shape).astype(np.float32)
    # the raw loop gets the same servo commands (velocity reference twice, see envs.plant)
    v = np.clip(actions, -1, 1) * u.task.v_max
    ctrls = np.concatenate([v, v], axis=1)
    env_t, raw_t = [], []
    for _ in range(repeats):  # interleaved, so that load changes hit both alike
        env_t.append(_time_env(env, actions))
        env.reset(seed=0)
        data = copy.copy(u.plant.data)
        raw_t.append(_time_raw(u.plant.model, data, ctrls, u.task.substeps))
    e, r = min(env_t), min(raw_t)
    return {
        "env_us": e * 1e6,
        "raw_us": r * 1e6,
        "ratio": e / r,
        "ratio_median": statistics.median(env_t) / statistics.median(raw_t),
        "reset_ms": _time_reset(env) * 1e3,
        "nv": u.plant.model.nv,
    }


def _resolved_rate(task, obs) -> np.ndarray:
    """Nominal resolved-rate tracking (what a controller knowing only the nominal arm does)."""
    from arm.kinematics import Chain, link_frames

    sl = task.obs_slices
    q = obs[sl["q"]].astype(float)
    f = link_frames(Chain.from_description(task.robot), q[None])
    p = f.point(task.robot.tool_points[0])[0]
    J = np.cross(f.z[0], p - f.o[0, 1:]).T
    target = obs[sl["preview"]][:3].astype(float)
    v = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(3), (target - p) / task.dt)
    return np.clip(v / task.v_max, -1, 1).astype(np.float32)


def save_frame(path: Path, scenario: str = "all", seed: int = 3, steps: int = 220) -> None:
    """A frame of the nominal controller tracking a lemniscate: the arm, the reference path
    (green), the latest tracker measurements (red)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env = gym.make(
        "SixAxisTrack-v0", scenario=scenario, trajectory="lemniscate", render_mode="rgb_array"
    )
    obs, _ = env.reset(seed=seed)
    for _ in range(steps):
        obs, *_ = env.step(_resolved_rate(env.unwrapped.task, obs))
    path.parent.mkdir(parents=True, exist_ok=True)
    plt.imsave(path, env.render())
    env.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=11)
    ap.add_argument("--no-frame", action="store_true", help="do not write results/frame.png")
    args = ap.parse_args()
    rows = []
    for sc in SCENARIOS:
        r = measure(sc, args.steps, args.repeats)
        rows.append((sc, r))
        print(
            f"{sc:11s} env {r['env_us']:7.1f} us/step ({1e6 / r['env_us']:6.0f} steps/s)  "
            f"raw {r['raw_us']:7.1f} us ({1e6 / r['raw_us']:6.0f}/s)  ratio {r['ratio']:.2f} "
            f"(of medians {r['ratio_median']:.2f})  reset {r['reset_ms']:.1f} ms"
        )
    lines = [
        "## env: SixAxisTrack-v0 step cost vs raw MuJoCo physics",
        "",
        f"Machine: {machine()}. `python benchmarks/env.py --steps {args.steps} "
        f"--repeats {args.repeats}`: one control step (0.02 s = 20 physics steps of 1 ms) through "
        "`gym.make` (TimeLimit, OrderEnforcing, PassiveEnvChecker wrappers; action check, servo "
        "limits, effects, tracker, observation, reward, info) beside "
        "`mujoco.mj_step(model, data, nstep=20)` on the same compiled model from the same state "
        "with the same servo commands, interleaved; the fastest of the repeats (the machine is "
        "shared: the minimum is the cost least disturbed by other work; the ratio of medians is "
        f"beside it). Target: env <= {TARGET}x raw.",
        "",
        "| scenario | dofs | env us/step | env steps/s | raw mj_step us | raw steps/s | ratio "
        "| ratio of medians | reset ms | target |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for sc, r in rows:
        ok = "met" if r["ratio"] <= TARGET else "missed"
        lines.append(
            f"| {sc} | {r['nv']} | {r['env_us']:.1f} | {1e6 / r['env_us']:.0f} | "
            f"{r['raw_us']:.1f} | {1e6 / r['raw_us']:.0f} | {r['ratio']:.2f} | "
            f"{r['ratio_median']:.2f} | {r['reset_ms']:.1f} | {ok} |"
        )
    lines += [
        "",
        "`geometric`: rigid joints (6 dofs). `compliance`: motor- and link-side hinges with the "
        "gear mesh as a tendon (12 dofs). `all`: plus backlash and bearing friction, transmission "
        "error re-linearised every step, thermal growth moving the bodies every step, a payload "
        "change. A reset draws the truth and a reachable trajectory (batched IK check) and places "
        "the arm at rest.",
    ]
    path = write_section("env", "\n".join(lines))
    print(f"wrote {path}")
    if not args.no_frame:
        frame = Path(__file__).resolve().parents[1] / "results" / "frame.png"
        save_frame(frame)
        print(f"wrote {frame}")


if __name__ == "__main__":
    main()
