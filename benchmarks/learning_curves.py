"""Learning curves of the shipped policies over their training seeds, the wall time and steps per
second of each run, and which seed is the median one (the one shipped).

Each run (``sixaxis train ALGO --config experiments/configs/NAME.toml --seed S``) writes
``curve.csv`` (deterministic evaluations on seeds never trained on, every ``eval_every`` steps)
and ``summary.json`` (wall time, steps/s). This script gathers the runs of each config:

* ``results/learning/<name>.csv``: per evaluation step, the mean and the spread (min, max) over
  the seeds of the settled tracking RMS (mean over the scenarios, mm) and of the return;
* ``results/learning/curves.png``: both against steps, one line and band per policy;
* ``results/learning/runs.json`` and ``results/learning/README.md``: per run, its steps, wall time,
  steps/s and its best evaluation score (mean log settled RMS); the median seed by that score.

    python benchmarks/learning_curves.py --runs runs ppo-residual sac-residual ppo
    python benchmarks/learning_curves.py --runs runs --ship ppo-residual   # ship the median seed
        # (as agents/policies/ppo-residual.npz) and every seed (agents/policies/seeds/ppo-residual@sK)
    python benchmarks/learning_curves.py --runs runs --keep --ship ppo-residual  # retrained one
    python benchmarks/learning_curves.py --runs runs ppo=ppo-scn --ship ppo  # the agent ppo from
        # the runs of the config named ppo-scn (runs/ppo-scn-seed*)
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

OUT = Path(__file__).resolve().parents[1] / "results" / "learning"
#: every training seed's policy, ``<name>@s<seed>.npz``: the leaderboard's agent over its seeds
SEEDS = Path(__file__).resolve().parents[1] / "agents" / "policies" / "seeds"


def read_curve(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise ValueError(f"{path}: no evaluations yet")
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def score(curve: dict[str, np.ndarray]) -> float:
    """The best evaluation's mean log settled RMS over the scenarios (what selects best.npz)."""
    cols = [k for k in curve if k.startswith("rms_settled_mm/") and not k.endswith("/mean")]
    per_eval = np.mean([np.log(curve[k]) for k in cols], axis=0)
    return float(per_eval.min())


def agent_and_runs(arg: str) -> tuple[str, str]:
    """``"ppo=ppo-scn"``: the agent ``ppo`` from the runs ``ppo-scn-seed*``; ``"ppo"``: both."""
    agent, _, runs = arg.partition("=")
    return agent, runs or agent


def gather(runs: Path, name: str) -> list[dict]:
    out = []
    for d in sorted(runs.glob(f"{name}-seed*")):
        if not (d / "curve.csv").exists():
            continue
        curve = read_curve(d / "curve.csv")
        summary = (
            json.loads((d / "summary.json").read_text()) if (d / "summary.json").exists() else {}
        )
        out.append(
            {"run": d.name, "dir": d, "curve": curve, "summary": summary, "score": score(curve)}
        )
    return out


def aggregate(name: str, runs: list[dict]) -> list[dict]:
    # the evaluation steps every run has (a resumed run also has the one where it first stopped)
    common = sorted(set.intersection(*(set(r["curve"]["steps"].tolist()) for r in runs)))
    rows = []
    for steps in common:
        at = [int(np.flatnonzero(r["curve"]["steps"] == steps)[0]) for r in runs]
        rms = np.array(
            [r["curve"]["rms_settled_mm/mean"][i] for r, i in zip(runs, at, strict=True)]
        )
        ret = np.array([r["curve"]["return/mean"][i] for r, i in zip(runs, at, strict=True)])
        rows.append(
            {
                "steps": int(steps),
                "rms_settled_mm_mean": float(rms.mean()),
                "rms_settled_mm_min": float(rms.min()),
                "rms_settled_mm_max": float(rms.max()),
                "return_mean": float(ret.mean()),
                "return_min": float(ret.min()),
                "return_max": float(ret.max()),
            }
        )
    return rows


def resume_lines(runs: list[dict]) -> list[str]:
    """What each resumed run's config changed at its last resume (its ``summary.json``'s
    ``resumed_with``: nothing that trains the steps before it, the trainer checks that), and its
    evaluations from there on."""
    out = []
    for r in runs:
        s = r["summary"]
        if not s.get("resumed_at") or "resumed_with" not in s:
            continue
        at = int(s["resumed_at"])
        changed = "; ".join(
            f"`{k}` {json.dumps(v[0])} -> {json.dumps(v[1])}" for k, v in s["resumed_with"].items()
        )
        c = r["curve"]
        after = [
            f"{int(st):,}: {v:.3g}"
            for st, v in zip(c["steps"], c["rms_settled_mm/mean"], strict=True)
            if st >= at
        ]
        out.append(
            f"- {r['run']} resumed at {at:,} steps with {changed or 'the same config'}; settled "
            f"RMS (mean over scenarios, mm) from there: {', '.join(after)}"
        )
    if not out:
        return []
    return [
        "",
        "## Resumed runs",
        "",
        "A run resumes only with a config that trains the steps already taken exactly as "
        "before (`agents.training.resume_differences`); what it changed from there on:",
        "",
        *out,
    ]


def pilot_sections(folder: Path) -> list[str]:
    """The README's sections on the pilots in ``folder``: the plain PPO's horizon, the
    off-policy residuals' algorithm."""
    lines: list[str] = []
    every_pilot = sorted(folder.glob("*.csv"))
    pilots = [p for p in every_pilot if p.stem.startswith(("sac-", "td3-"))]
    plain = [p for p in every_pilot if p.stem.startswith("ppo-gamma")]
    tool = [p for p in every_pilot if p.stem.startswith("ppo-tool-")]
    if tool:
        lines += [
            "",
            "## The plain policy on the tool interface: its recipe, chosen by measurement",
            "",
            "Pilot runs of the plain PPO on the operational-space interface "
            "(`results/learning/pilots/ppo-tool-*`, each with its config and a line saying what "
            "differs: seed 1, 2 evaluation episodes per scenario; stopped once clear), settled "
            "RMS (mm) of the evaluations, mean over the scenarios:",
            "",
        ]
        last = max(int(read_curve(p)["steps"].max()) for p in tool)
        ks = range(0, last // 1000 + 1, 50)
        lines += [
            "| pilot | what differs | " + " | ".join(f"{k}k" for k in ks) + " |",
            "|---|---|" + "---:|" * len(ks),
        ]
        for p in tool:
            c = read_curve(p)
            note = p.with_suffix(".txt")
            what = note.read_text().strip() if note.exists() else ""
            at = {int(st): v for st, v in zip(c["steps"], c["rms_settled_mm/mean"], strict=True)}
            cells = [f"{at[k * 1000]:.3g}" if k * 1000 in at else "" for k in ks]
            lines.append(f"| {p.stem} | {what} | " + " | ".join(cells) + " |")
    if plain:
        lines += [
            "",
            "## The plain policy's horizon, chosen by measurement",
            "",
            "Pilot runs of the plain PPO (`results/learning/pilots/`, their configs beside their "
            "curves: seed 1, 300k steps, the plain recipe of their day but for gamma), settled RMS "
            "(mm) of the "
            "evaluations, mean over the scenarios; the plain policy shipped before was trained "
            "with gamma 0.99:",
            "",
            "| pilot | " + " | ".join(f"{int(s):,}" for s in read_curve(plain[0])["steps"]) + " |",
            "|---|" + "---:|" * len(read_curve(plain[0])["steps"]),
        ]
        for p in plain:
            c = read_curve(p)
            lines.append(
                f"| {p.stem} | " + " | ".join(f"{v:.2f}" for v in c["rms_settled_mm/mean"]) + " |"
            )
        best = min(plain, key=lambda p: float(read_curve(p)["rms_settled_mm/mean"][-1]))
        lines += ["", f"The lowest final error: {best.stem}; its gamma is the shipped config's."]
    if pilots:
        lines += [
            "",
            "## The off-policy algorithm, chosen by measurement",
            "",
            "Pilot runs of the off-policy residuals (`results/learning/pilots/`, their configs "
            "beside their curves: seed 1, 100k steps, each scenario once, 3 evaluation episodes "
            "per scenario; `no-burn-in`: the same without `critic_burn_in`, stopped once it was "
            "clear), settled RMS (mm) of the evaluations:",
            "",
            "| pilot | steps | backlash | all | mean over scenarios |",
            "|---|---:|---:|---:|---:|",
        ]
        for p in pilots:
            c = read_curve(p)
            for i in range(len(c["steps"])):
                lines.append(
                    f"| {p.stem} | {int(c['steps'][i]):,} | "
                    f"{c['rms_settled_mm/backlash'][i]:.4f} | {c['rms_settled_mm/all'][i]:.4f} | "
                    f"{c['rms_settled_mm/mean'][i]:.4f} |"
                )
        last = {
            p.stem: float(read_curve(p)["rms_settled_mm/mean"][-1])
            for p in pilots
            if "no-burn-in" not in p.stem
        }
        order = sorted(last, key=last.__getitem__)
        lines += [
            "",
            "Step 0 is the untrained residual (near-zero output: `feedforward`). The mean over the "
            "scenarios at the last evaluation, with the burn-in: "
            + ", ".join(f"{k} {last[k]:.4f} mm" for k in order)
            + f"; {order[0].split('-')[0].upper()} ships.",
        ]
    return lines


#: training seeds per learned agent (rliable's minimum for an interval over seeds)
SEEDS_PER_AGENT = 5
#: the tuning grid of benchmarks/ppo_tuning.py: points x steps each
TUNING_STEPS = 9 * 200_000


def cost_lines(table: list[dict], seeds: int = SEEDS_PER_AGENT) -> list[str]:
    """What ``seeds`` training seeds of each policy cost, from the wall times of its measured
    seeds (each run alone on a core of two shared ones), and the tuning grid of the plain
    policy at its measured steps/s."""
    lines = [
        "",
        f"## The cost of {seeds} seeds per agent",
        "",
        f"Estimated from the measured runs above: {seeds} x the wall time of a seed (its range "
        "over the seeds measured), one run per core; two at a time on the 2 cores halves the "
        "wall clock, not the CPU. The plain policy's patience rule (`ppo-scn.toml`) can end "
        "a seed sooner than its cap; the figures are for the whole budget.",
        "",
        f"| policy | seeds measured | wall time a seed (min) | {seeds} seeds, CPU (h) | "
        f"{seeds} seeds, two at a time (h) |",
        "|---|---:|---:|---:|---:|",
    ]
    total_lo = total_hi = 0.0
    for name in dict.fromkeys(r["name"] for r in table):
        walls = [float(r["wall_s"]) for r in table if r["name"] == name]
        lo, hi = min(walls), max(walls)
        total_lo, total_hi = total_lo + seeds * lo, total_hi + seeds * hi
        lines.append(
            f"| {name} | {len(walls)} | {_span(lo / 60, hi / 60, '.0f')} | "
            f"{_span(seeds * lo / 3600, seeds * hi / 3600)} | "
            f"{_span(seeds * lo / 7200, seeds * hi / 7200)} |"
        )
    plain = [float(r["steps_per_s"]) for r in table if r["name"] == "ppo"]
    lines += [
        "",
        f"In all: {total_lo / 3600:.1f}-{total_hi / 3600:.1f} h of CPU, "
        f"{total_lo / 7200:.1f}-{total_hi / 7200:.1f} h on the 2 cores.",
    ]
    if plain:
        lo, hi = TUNING_STEPS / max(plain) / 3600, TUNING_STEPS / min(plain) / 3600
        lines.append(
            f"The tuning grid of the plain policy (`benchmarks/ppo_tuning.py`: 3 gammas x 3 "
            f"learning rates x 200k steps) at its measured {min(plain):.0f}-{max(plain):.0f} "
            f"steps/s: {lo:.1f}-{hi:.1f} h of CPU, {lo / 2:.1f}-{hi / 2:.1f} h with `--jobs 2`."
        )
    lines.append(
        "`ppo-scn.toml` caps a seed at 2.4M steps, twice the previous plain policy's measured 1.2M: "
        "up to twice its row if the patience rule never ends it. A session of 3 hours fits one "
        "agent's seeds two at a time (the plain policy's over two sessions: `--stop-at` and "
        "`--resume`, with the checkpoints kept outside the repository)."
    )
    return lines


def _span(lo: float, hi: float, fmt: str = ".1f") -> str:
    """``lo-hi`` as printed, or one number where both print the same."""
    a, b = format(lo, fmt), format(hi, fmt)
    return a if a == b else f"{a}-{b}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*", default=["ppo-residual", "sac-residual", "ppo"])
    ap.add_argument("--runs", type=Path, default=Path("runs"), help="the training runs' folder")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--ship", nargs="*", default=[], help="ship a seed of these names")
    ap.add_argument(
        "--pick",
        choices=("median", "best"),
        default="median",
        help="which seed --ship ships: the median by the evaluation score, or the best",
    )
    ap.add_argument(
        "--keep",
        action="store_true",
        help="a policy with no runs in --runs keeps its recorded curve and rows in --out",
    )
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from arm.files import atomic_write_text

    args.out.mkdir(parents=True, exist_ok=True)
    # residuals (tenths of a mm) and plain policies (tens of mm) on rows of their own
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    table = []
    recorded = (
        json.loads((args.out / "runs.json").read_text())
        if (args.out / "runs.json").exists()
        else []
    )
    for name, prefix in map(agent_and_runs, args.names):
        runs = gather(args.runs, prefix)
        if not runs:
            if not args.keep or not (args.out / f"{name}.csv").exists():
                print(f"{name}: no runs in {args.runs}")
                continue
            # --keep: this policy's curve and rows as recorded (its runs are not here)
            print(f"{name}: no runs in {args.runs}; keeping its recorded curve and rows")
            with open(args.out / f"{name}.csv", newline="") as fh:
                rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(fh)]
            table += [r for r in recorded if r["name"] == name]
            runs = [r for r in recorded if r["name"] == name]
        else:
            rows = aggregate(name, runs)
            buf = io.StringIO()
            w = csv.DictWriter(buf, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
            atomic_write_text(args.out / f"{name}.csv", buf.getvalue())
        x = np.array([r["steps"] for r in rows])
        ax1, ax2 = axes[0 if "residual" in name else 1]
        for ax, key in ((ax1, "rms_settled_mm"), (ax2, "return")):
            mean = np.array([r[f"{key}_mean"] for r in rows])
            lo = np.array([r[f"{key}_min"] for r in rows])
            hi = np.array([r[f"{key}_max"] for r in rows])
            (line,) = ax.plot(x, mean, label=f"{name} ({len(runs)} seeds)")
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2)
        if "dir" not in runs[0]:  # kept from runs.json
            continue
        ordered = sorted(runs, key=lambda r: r["score"])
        median = ordered[len(ordered) // 2] if args.pick == "median" else ordered[0]
        for r in runs:
            s = r["summary"]
            table.append(
                {
                    "name": name,
                    "run": r["run"],
                    "steps": int(s.get("timesteps", r["curve"]["steps"][-1])),
                    "wall_s": round(float(s.get("wall_s", r["curve"]["wall_s"][-1])), 1),
                    "steps_per_s": round(
                        float(s.get("steps_per_s", r["curve"]["steps_per_s"][-1])), 1
                    ),
                    "best_score": round(r["score"], 4),
                    "best_rms_settled_mm": round(float(np.exp(r["score"])), 4),
                    "median": r is median,
                    "picked": args.pick if r is median else "",
                }
            )
        if name in args.ship:
            from agents.training import ship_policy

            walls = [float(r["summary"].get("wall_s", r["curve"]["wall_s"][-1])) for r in runs]
            dst = ship_policy(
                median["dir"],
                "best",
                name,
                seeds_trained=len(runs),
                wall_s_all_seeds=round(sum(walls), 1),
                picked=args.pick,
            )
            print(f"{name}: shipped the {args.pick} seed {median['run']} to {dst}")
            for r in runs:  # every seed, for the leaderboard's agent over its seeds
                seed = int(json.loads((r["dir"] / "best.json").read_text())["config"]["seed"])
                dst = ship_policy(
                    r["dir"],
                    "best",
                    f"{name}@s{seed}",
                    seeds_trained=len(runs),
                    wall_s_all_seeds=round(sum(walls), 1),
                    picked=f"seed {seed} of {len(runs)}",
                    folder=SEEDS,
                    evaluate=False,
                )
                print(f"{name}: seed {seed} to {dst}")
    for (ax1, ax2), kind in zip(axes, ("residual policies", "plain policies"), strict=True):
        ax1.set_yscale("log")
        ax1.set_xlabel("training steps")
        ax1.set_ylabel(f"{kind}: settled tracking RMS,\nmean over scenarios (mm)")
        ax2.set_xlabel("training steps")
        ax2.set_ylabel(f"{kind}: return per episode\n(log reward, 0.05 mm scale)")
        for ax in (ax1, ax2):
            ax.grid(True, alpha=0.3)
            if ax.lines:
                ax.legend(fontsize=8)
    fig.suptitle("Evaluations on seeds never trained on: mean and range over the training seeds")
    fig.tight_layout()
    fig.savefig(args.out / "curves.png", dpi=110)
    atomic_write_text(args.out / "runs.json", json.dumps(table, indent=2) + "\n")
    seeds = sorted({int(r["run"].rsplit("-seed", 1)[1]) for r in table if "-seed" in r["run"]})
    lines = [
        "# Learning curves",
        "",
        "Made by `python benchmarks/learning_curves.py` from the runs of "
        "`sixaxis train ALGO --config experiments/configs/NAME.toml --seed S` "
        f"(S = {', '.join(map(str, seeds))}).",
        "Evaluations: every `eval_every` steps, `eval_episodes` deterministic episodes per "
        "scenario (each config says how many) on seeds 900000+ (never trained on, never on the "
        "leaderboard). Score: the mean over the scenarios of log settled RMS; the policy of a "
        "run's best evaluation is its `best.npz`, and the median seed by that score is shipped "
        "as the agent's single policy; every seed is shipped too (`agents/policies/seeds/`) and the "
        "leaderboard ranks the agent over them (the plain `ppo`'s seeds on held-out episodes: "
        "`results/ppo_seeds.md`).",
        "",
        "![learning curves](curves.png)",
        "",
        "| policy | run | steps | wall time (s) | steps/s | best settled RMS (geo. mean, mm) | shipped |",
        "|---|---|---:|---:|---:|---:|---|",
    ]
    for r in table:
        lines.append(
            f"| {r['name']} | {r['run']} | {r['steps']:,} | {r['wall_s']:.0f} | "
            f"{r['steps_per_s']:.0f} | {r['best_rms_settled_mm']:.4f} | "
            f"{'yes (' + (r.get('picked') or 'median') + ')' if r['median'] else ''} |"
        )
    total = sum(r["wall_s"] for r in table)
    lines += ["", f"Training wall time in all: {total / 3600:.2f} h (2 shared CPU cores)."]
    lines += cost_lines(table)
    lines += resume_lines(
        [r for arg in args.names for r in gather(args.runs, agent_and_runs(arg)[1])]
    )
    lines += pilot_sections(args.out / "pilots")
    atomic_write_text(args.out / "README.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
