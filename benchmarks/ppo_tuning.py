"""gamma x learning rate of the plain PPO on the tool interface with the observation option
(``experiments/configs/ppo-scn.toml``, the agent ``ppo``'s recipe), tuned on short runs of equal
budget. The committed ``results/learning/tuning.md`` was made when the recipe's network was the
[256, 256] MLP (``ppo-plain.toml`` of its commit, which the report names); the structured network
took its gamma and rate.

Every point of the grid is the config with ``hyperparameters.gamma`` and a constant learning
rate set, trained for ``--budget`` steps (no patience: every point gets the same budget, so the
points compare at equal cost) on one training seed, evaluated every ``--eval-every`` steps on
``--eval-episodes`` episodes per scenario (seeds 900000 and up: never trained on, never on the
leaderboard). A point's figure is its best evaluation (the geometric mean over the scenarios of
the settled RMS, mm: what selects ``best.npz``) and its last (still falling at the end, or
levelled off). Runs go to ``--runs`` (``runs/tuning/<point>-seedS``) and are resumed where they
stopped (``--resume`` of ``sixaxis train``), so a grid cut off by the end of a session goes on
with the same command. Writes ``results/learning/tuning.json`` and ``tuning.md`` (``--out``).

    python benchmarks/ppo_tuning.py                                  # 2 x 3 grid + 2 points, 200k steps each
    python benchmarks/ppo_tuning.py --jobs 2                         # two points at a time
    python benchmarks/ppo_tuning.py --gammas 0.9 0.95 --rates 3e-4 --budget 100000
    python benchmarks/ppo_tuning.py --dry-run                        # the points and their commands
    python benchmarks/ppo_tuning.py --budget 4096 --eval-every 2048 --eval-episodes 1 \\
        --gammas 0.9 --rates 3e-4 --runs /tmp/tuning --out /tmp/tuning   # a smoke run, minutes

Cost (2 shared cores): a plain-PPO seed ran 430-580 env steps/s with its evaluations
(results/learning/README.md: 1.2M steps in 27-35 min), so a 200k-step point is about 6-8 min of
one core and the 8 points about 1 h of CPU, 30-35 min with ``--jobs 2`` on an idle machine
(under the load of other jobs, 120-330 steps/s a point).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "experiments" / "configs" / "ppo-scn.toml"
OUT = ROOT / "results" / "learning"
GAMMAS = (0.9, 0.95)
RATES = (1e-4, 3e-4, 1e-3)
#: beyond the grid, where it points: the 2 x 3 grid had gamma 0.9 lower (better) than 0.95 at
#: every rate, and 3e-4 best at both; so shorter horizons at 3e-4 rather than a gamma of 0.98
POINTS = ((0.8, 3e-4), (0.85, 3e-4))


def point_name(gamma: float, rate: float) -> str:
    return f"ppo-observe-g{gamma:g}-lr{rate:g}"


def point_config(args: argparse.Namespace, gamma: float, rate: float):
    """The grid point's config: the base config with gamma and a constant rate, no patience."""
    from agents.training import load_train_config

    cfg = load_train_config(args.config, seed=args.seed)
    cfg.name = point_name(gamma, rate)
    cfg.output = str(args.runs / f"{cfg.name}-seed{args.seed}")
    cfg.total_timesteps = args.budget
    cfg.eval_every = args.eval_every
    cfg.eval_episodes = args.eval_episodes
    cfg.checkpoint_every = min(cfg.checkpoint_every, args.eval_every)
    cfg.patience = 0  # equal budgets
    cfg.learning_rate_schedule = []
    cfg.hyperparameters = dict(cfg.hyperparameters) | {"gamma": gamma, "learning_rate": rate}
    cfg.check(f"{args.config} (gamma {gamma:g}, learning rate {rate:g})")
    return cfg


def train_point(job: tuple[argparse.Namespace, float, float]) -> dict:
    """Train (or resume) one point and read its curve."""
    args, gamma, rate = job
    from agents.training import train

    cfg = point_config(args, gamma, rate)
    out = Path(cfg.output)
    summary = out / "summary.json"
    done = json.loads(summary.read_text())["timesteps"] if summary.exists() else 0
    if done < args.budget:
        train(cfg, resume=(out / "checkpoint.zip").exists())
    return read_point(out, gamma, rate)


def read_point(out: Path, gamma: float, rate: float) -> dict:
    """A trained point's evaluations: every step's geometric mean of settled RMS, the best, the
    last, its wall time."""
    with open(out / "curve.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    cols = [k for k in rows[0] if k.startswith("rms_settled_mm/") and not k.endswith("/mean")]
    curve = [
        (int(r["steps"]), math.exp(sum(math.log(float(r[c])) for c in cols) / len(cols)))
        for r in rows
    ]
    best = min(curve, key=lambda p: p[1])
    summary = json.loads((out / "summary.json").read_text())
    return {
        "gamma": gamma,
        "learning_rate": rate,
        "run": out.name,
        "steps": int(summary["timesteps"]),
        "wall_s": round(float(summary["wall_s"]), 1),
        "curve": [{"steps": s, "settled_geo_mean_mm": round(v, 6)} for s, v in curve],
        "best_mm": round(best[1], 6),
        "best_at": best[0],
        "last_mm": round(curve[-1][1], 6),
    }


def report(points: list[dict], args: argparse.Namespace, state: dict) -> str:
    lines = [
        "# Tuning the plain PPO on the tool interface with the observation option",
        "",
        f"Made by `python benchmarks/ppo_tuning.py` from `{Path(args.config).name}`: each point "
        f"trained {args.budget:,} steps (training seed {args.seed}, a constant learning rate, no "
        f"patience), evaluated every {args.eval_every:,} steps on {args.eval_episodes} episode(s) "
        "per scenario (seeds 900000+). Figure: the geometric mean over the scenarios of the "
        "settled RMS (mm), at the best evaluation and at the last.",
        "",
        f"Report from commit {state['commit'][:10]}"
        f"{' (local changes)' if state['dirty'] else ', clean'}; the points were trained "
        "(and resumed) at the commits a run's record names. Wall: the run's last session (a "
        "resumed run's earlier sessions are not in it), on 2 cores shared with other jobs.",
        "",
        "| gamma | learning rate | best (mm) | at step | last (mm) | wall, last session (s) |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for p in sorted(points, key=lambda p: (p["gamma"], p["learning_rate"])):
        lines.append(
            f"| {p['gamma']:g} | {p['learning_rate']:g} | {p['best_mm']:.4g} | "
            f"{p['best_at']:,} | {p['last_mm']:.4g} | {p['wall_s']:.0f} |"
        )
    if points:
        best = min(points, key=lambda p: p["best_mm"])
        lines += [
            "",
            f"Lowest: gamma {best['gamma']:g}, learning rate {best['learning_rate']:g} "
            f"({best['best_mm']:.4g} mm). One training seed and a short budget rank the points; "
            "they do not measure the agent (5 seeds of the chosen recipe do).",
        ]
    return "\n".join(lines) + "\n"


def _point(text: str) -> tuple[float, float]:
    """``"0.8:3e-4"`` as (gamma, rate)."""
    try:
        g, r = (float(v) for v in text.split(":"))
    except ValueError:
        raise SystemExit(f"--points: {text!r} is not gamma:rate (e.g. 0.8:3e-4)") from None
    return g, r


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=CONFIG)
    ap.add_argument("--gammas", type=float, nargs="+", default=list(GAMMAS))
    ap.add_argument("--rates", type=float, nargs="+", default=list(RATES))
    ap.add_argument(
        "--points",
        nargs="*",
        default=[f"{g:g}:{r:g}" for g, r in POINTS],
        help="points beyond the grid, gamma:rate each",
    )
    ap.add_argument("--budget", type=int, default=200_000, help="steps per point")
    ap.add_argument("--eval-every", type=int, default=50_000)
    ap.add_argument("--eval-episodes", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1, help="the training seed of every point")
    ap.add_argument("--jobs", type=int, default=1, help="points trained at once (processes)")
    ap.add_argument("--nice", type=int, default=10, help="each training's niceness increment")
    ap.add_argument("--runs", type=Path, default=ROOT / "runs" / "tuning")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--dry-run", action="store_true", help="check and list the points only")
    args = ap.parse_args()
    grid = [(g, r) for g in args.gammas for r in args.rates]
    grid += [p for p in (_point(text) for text in args.points) if p not in grid]
    for g, r in grid:  # every point checked before any trains
        cfg = point_config(args, g, r)
        print(f"{cfg.name}: {args.budget:,} steps -> {cfg.output}")
    if args.dry_run:
        return
    import os

    os.nice(args.nice)  # the trainings, and the processes that run them, yield to other work
    t0 = time.perf_counter()
    jobs = [(args, g, r) for g, r in grid]
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            points = list(pool.map(train_point, jobs))
    else:
        points = [train_point(j) for j in jobs]
    from arm.files import atomic_write_text, make_folders
    from experiments.records import git_state

    make_folders(args.out)
    state = git_state(ROOT)
    doc = {
        "commit": state["commit"],
        "dirty": state["dirty"],
        "config": Path(args.config).name,
        "budget": args.budget,
        "seed": args.seed,
        "eval_every": args.eval_every,
        "eval_episodes": args.eval_episodes,
        "wall_s_this_call": round(time.perf_counter() - t0, 1),
        "points": points,
    }
    atomic_write_text(args.out / "tuning.json", json.dumps(doc, indent=2) + "\n")
    text = report(points, args, state)
    atomic_write_text(args.out / "tuning.md", text)
    print(text)


if __name__ == "__main__":
    main()
