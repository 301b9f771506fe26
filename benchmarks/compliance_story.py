"""The lab's story in closed loop on the ``compliance`` scenario: calibrate over the workspace,
then track blind in a region the calibration never visited; a geometric-only model is left with
a visible error, adding the joints' compliance brings the error down to the oracle's.

Each episode is :func:`agents.runner.workspace_campaign`: nine measured calibration phases of
10 s around postures spread over the seed arm's workspace (one load), then 10 s blind (no
tracker) on a lemniscate around a judged posture (``reach``: far out and low; ``raised``: up and
back; ``inside``: between calibration postures). The figure is the true tool point's RMS error
over the blind phase after its first 2 s (mm). Agents: ``mpc-oracle`` (the plant's true model),
``mpc`` (online recursive least squares, with the default forgetting 0.995 and without
forgetting) and ``calibrated`` (the lab's batch fit of every calibration measurement, then a
resolved-rate tracker), each with ``effects`` geometric and geometric+compliance; ``nominal``
for scale. Writes section ``compliance-story`` of results/benchmarks.md and the per-seed figures
to results/compliance_story.json.

    python benchmarks/compliance_story.py [--seeds 12] [--regions reach,raised,inside]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from agents.registry import make_agent
from agents.runner import JUDGE_POSTURES, WORKSPACE_POSTURES, run_episode, workspace_campaign
from arm.files import atomic_write_text
from benchmarks._report import RESULTS, machine, write_section

SETTLE_S = 2.0
SCENARIO = "compliance"
GEO, COMP = "geometric", "geometric,compliance"
#: (label, registered name, settings); the first is the reference of the ratios
AGENTS: tuple[tuple[str, str, dict], ...] = (
    ("mpc-oracle", "mpc-oracle", {}),
    ("mpc, geometric", "mpc", {"effects": GEO}),
    ("mpc, geometric+compliance", "mpc", {"effects": COMP}),
    ("mpc, geometric, no forgetting", "mpc", {"effects": GEO, "forgetting": 1.0}),
    ("mpc, geometric+compliance, no forgetting", "mpc", {"effects": COMP, "forgetting": 1.0}),
    ("calibrated, geometric", "calibrated", {"effects": GEO, "calibration_seconds": None}),
    (
        "calibrated, geometric+compliance",
        "calibrated",
        {"effects": COMP, "calibration_seconds": None},
    ),
    ("nominal", "nominal", {}),
)


def blind_rms(name: str, settings: dict, seed: int, region: str) -> float:
    r = run_episode(
        make_agent(name, **settings),
        {"scenario": SCENARIO},
        seed=seed,
        phases=workspace_campaign(judge_posture=region),
    )
    return float("nan") if r.diverged else r.rms_mm(start=SETTLE_S)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--regions", default=",".join(JUDGE_POSTURES))
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)  # the lab's pose-set warnings are expected here
    regions = [r.strip() for r in args.regions.split(",") if r.strip()]
    seeds = list(range(args.seeds))
    res: dict[str, dict[str, list[float]]] = {g: {a[0]: [] for a in AGENTS} for g in regions}
    t0 = time.perf_counter()
    for region in regions:
        for seed in seeds:
            row = []
            for label, name, settings in AGENTS:
                v = blind_rms(name, settings, seed, region)
                res[region][label].append(v)
                row.append(f"{v:.3f}")
            print(f"{region:7s} seed {seed:2d}: " + " ".join(row), flush=True)
    wall = time.perf_counter() - t0

    ref = AGENTS[0][0]
    lines = [
        "## Compliance story: calibrate over the workspace, judge blind in a new region",
        "",
        f"`python benchmarks/compliance_story.py --seeds {args.seeds}` on {machine()}; "
        f"{wall / 60:.0f} min.",
        "",
        f"Scenario `{SCENARIO}` (elastic joints, c = 3e-6..1e-5 rad/(N m), one load), seeds "
        f"0-{seeds[-1]}. `workspace_campaign`: {len(WORKSPACE_POSTURES)} measured 10 s calibration phases "
        "around "
        "postures spread over the workspace (circle, lines, spline in turn), then 10 s blind "
        "(no tracker) on a lemniscate around a posture none of them visited. Blind RMS of the "
        f"true tool error after {SETTLE_S:g} s of the blind phase, mm: median over seeds "
        f"[min-max], and the ratio to `{ref}` seed by seed (median [min-max]).",
        "",
    ]
    for region in regions:
        o = np.asarray(res[region][ref])
        q = JUDGE_POSTURES[region]
        lines += [
            f"Judged region `{region}` (posture {list(q)} rad):",
            "",
            "| agent | blind RMS, mm | ratio to oracle |",
            "|---|---|---|",
        ]
        for label, _, _ in AGENTS:
            a = np.asarray(res[region][label])
            ratio = a / o
            lines.append(
                f"| {label} | {np.nanmedian(a):.3f} [{np.nanmin(a):.3f}-{np.nanmax(a):.3f}] "
                f"| {np.nanmedian(ratio):.2f} [{np.nanmin(ratio):.2f}-{np.nanmax(ratio):.2f}] |"
            )
        n_div = {k: int(np.isnan(v).sum()) for k, v in res[region].items() if np.isnan(v).any()}
        if n_div:
            lines.append(f"\nDiverged (left out): {n_div}")
        lines.append("")
    lines += [
        "Reading: where the judged posture's gravity load lies outside the calibration's "
        "(`reach`, `raised`), a geometric-only model, fitted as a compromise over the postures, "
        "is left with several times the oracle's error; with compliance in the model the "
        "calibration carries over to the new region. Between calibration postures (`inside`) "
        "the geometric compromise interpolates and the gap is small. The estimator's default "
        "forgetting (0.995: a memory of about 200 measurements, two postures' worth) lets the "
        "last postures outweigh the first; for a calibration campaign turn it off "
        "(`forgetting=1.0`). `calibrated` tracks with a resolved-rate law whose own floor lies "
        "above the MPC oracle's: compare its two rows with each other.",
    ]
    path = write_section("compliance-story", "\n".join(lines))
    raw = RESULTS / "compliance_story.json"
    atomic_write_text(
        raw,
        json.dumps(
            {
                "scenario": SCENARIO,
                "settle_s": SETTLE_S,
                "seeds": seeds,
                "agents": {label: [name, settings] for label, name, settings in AGENTS},
                "blind_rms_mm": {  # null: diverged
                    g: {k: [None if np.isnan(x) else x for x in v] for k, v in r.items()}
                    for g, r in res.items()
                },
            },
            indent=1,
        )
        + "\n",
    )
    print(f"wrote {path} and {raw}")


if __name__ == "__main__":
    main()
