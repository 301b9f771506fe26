"""The learned policies against their targets, on the leaderboard's own episodes.

The runs are the leaderboard's (``experiments/configs/full.toml``: its scenarios, seeds, env
options, episode and settling time), made by the sweep's own ``execute_run``, for ``hold``,
``nominal``, ``feedforward`` and the shipped policies. Targets (issue "learning baselines that
learn"), on the settled RMS (``rms_settled_mm``), mean over the seeds:

* the best residual policy: at most 0.9x ``feedforward`` on ``backlash`` and ``all``, at most
  1.0x elsewhere; below ``nominal`` on every scenario; its whole-episode RMS (``rms_mm``) no
  worse than ``feedforward``'s on every scenario;
* every plain policy: below ``hold`` on every scenario, and on every seed;
* a residual that outputs zero is ``feedforward`` itself (tests/test_agents_policy.py checks it
  step for step): ratio 1.0, so it passes none of the 0.9x targets.

Writes ``results/policy_targets.md`` and ``.json``.

    python benchmarks/policy_targets.py [--workers 2] [--policies ppo-residual sac-residual sac]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results"
REFERENCES = ("hold", "nominal", "feedforward")
STRICT = ("backlash", "all")  # where feedforward is far from the oracle: 0.9x


def _run(spec):
    from experiments.sweep import execute_run

    out = execute_run(spec)
    return spec.agent_label, spec.scenario_label, spec.seed, out["metrics"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policies", nargs="*", default=["ppo-residual", "sac-residual", "sac"])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--config", type=Path, default=ROOT / "experiments/configs/full.toml")
    args = ap.parse_args()
    from experiments.config import AgentEntry, load_config

    cfg = load_config(args.config, check_agents=False)
    names = [*REFERENCES, *args.policies]
    import dataclasses

    cfg = dataclasses.replace(
        cfg, agents=tuple(AgentEntry(label=n, agent=n, settings={}, env={}) for n in names)
    )
    specs = cfg.runs()
    t0 = time.perf_counter()
    res: dict[str, dict[str, dict[int, dict]]] = {n: {} for n in names}
    with ProcessPoolExecutor(max_workers=max(1, args.workers)) as pool:
        for agent, sc, seed, metrics in pool.map(_run, specs, chunksize=4):
            res[agent].setdefault(sc, {})[seed] = metrics
    wall = time.perf_counter() - t0
    scenarios = [s.label for s in cfg.scenarios]

    def mean(agent, sc, key="rms_settled_mm"):
        return float(np.mean([m[key] for m in res[agent][sc].values()]))

    report: dict = {
        "config": str(args.config.relative_to(ROOT)),
        "seeds": list(cfg.seeds),
        "settle_seconds": cfg.settle_seconds,
        "wall_s": wall,
        "rms_settled_mm": {n: {sc: mean(n, sc) for sc in scenarios} for n in names},
        "rms_mm": {n: {sc: mean(n, sc, "rms_mm") for sc in scenarios} for n in names},
        "targets": {},
    }
    for n in args.policies:
        residual = "residual" in n
        checks = {}
        for sc in scenarios:
            s, ff = mean(n, sc), mean("feedforward", sc)
            if residual:
                limit = 0.9 if sc in STRICT else 1.0
                checks[sc] = {
                    "ratio_to_feedforward": s / ff,
                    "limit": limit,
                    "below_limit": s <= limit * ff,
                    "below_nominal": s < mean("nominal", sc),
                    "whole_episode_vs_feedforward": mean(n, sc, "rms_mm")
                    / mean("feedforward", sc, "rms_mm"),
                    "whole_episode_ok": mean(n, sc, "rms_mm") <= mean("feedforward", sc, "rms_mm"),
                }
            else:
                worst = max(
                    res[n][sc][k]["rms_settled_mm"] / res["hold"][sc][k]["rms_settled_mm"]
                    for k in res[n][sc]
                )
                checks[sc] = {
                    "ratio_to_hold": s / mean("hold", sc),
                    "worst_seed_ratio_to_hold": worst,
                    "below_hold_every_seed": worst < 1.0,
                }
        report["targets"][n] = checks
    from arm.measurements import atomic_write_text

    atomic_write_text(OUT / "policy_targets.json", json.dumps(report, indent=2) + "\n")

    head = "| agent | " + " | ".join(scenarios) + " |"
    rule = "|---|" + "---:|" * len(scenarios)
    lines = [
        "# Learned policies against their targets",
        "",
        f"Made by `python benchmarks/policy_targets.py` on the leaderboard's episodes "
        f"(`{report['config']}`: seeds {cfg.seeds[0]}-{cfg.seeds[-1]}, settling time "
        f"{cfg.settle_seconds:g} s), {wall:.0f} s on this machine.",
        "",
        "## Settled tracking RMS (mm), mean over the seeds",
        "",
        head,
        rule,
    ]
    for n in names:
        row = report["rms_settled_mm"][n]
        lines.append(f"| {n} | " + " | ".join(f"{row[sc]:.4g}" for sc in scenarios) + " |")
    lines += ["", "## Whole-episode tracking RMS (mm)", "", head, rule]
    for n in names:
        row = report["rms_mm"][n]
        lines.append(f"| {n} | " + " | ".join(f"{row[sc]:.4g}" for sc in scenarios) + " |")
    lines += ["", "## Targets", ""]
    for n, checks in report["targets"].items():
        lines += [f"### {n}", "", head, rule]
        if "residual" in n:
            keys = (
                ("settled / feedforward (limit)", "ratio_to_feedforward", "limit", "below_limit"),
                (
                    "whole episode / feedforward",
                    "whole_episode_vs_feedforward",
                    None,
                    "whole_episode_ok",
                ),
            )
            for label, k, lim, ok in keys:
                cells = []
                for sc in scenarios:
                    c = checks[sc]
                    txt = f"{c[k]:.3f}" + (f" ({c[lim]:.1f})" if lim else "")
                    cells.append(txt + ("" if c[ok] else " **miss**"))
                lines.append(f"| {label} | " + " | ".join(cells) + " |")
            cells = [
                f"{report['rms_settled_mm'][n][sc] / report['rms_settled_mm']['nominal'][sc]:.3f}"
                + ("" if checks[sc]["below_nominal"] else " **miss**")
                for sc in scenarios
            ]
            lines.append("| settled / nominal (< 1) | " + " | ".join(cells) + " |")
        else:
            for label, k in (
                ("mean / hold", "ratio_to_hold"),
                ("worst seed / hold", "worst_seed_ratio_to_hold"),
            ):
                cells = [
                    f"{checks[sc][k]:.3f}"
                    + ("" if checks[sc]["below_hold_every_seed"] else " **miss**")
                    for sc in scenarios
                ]
                lines.append(f"| {label} | " + " | ".join(cells) + " |")
        lines.append("")
    lines.append(
        "A residual policy that outputs zero is `feedforward` step for step: ratio 1.000 on every "
        "scenario, so it meets none of the 0.9x targets."
    )
    atomic_write_text(OUT / "policy_targets.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
