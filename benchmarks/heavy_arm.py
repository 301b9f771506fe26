"""The lab on a heavy industrial arm without its mass model: is gravity deflection found?

    python benchmarks/heavy_arm.py                     # 300 campaigns: results/heavy_arm.*
    python benchmarks/heavy_arm.py --count 20 --out /tmp/heavy   # a seeded slice

Every campaign of ``benchmarks/lab_decisions.py`` is of the seed arm, a small one. Here the arm
is ``r2000ic_like`` (a FANUC R-2000iC/165F's data-sheet lengths, 2.66 m reach, masses of that
order (about 1,100 kg) and a 165 kg payload, arm/robots/), drawn from the error model with the same
machinery (:func:`lab_decisions.model_campaign`: geometric errors of their typical size, each
planted effect scaled to a size over the noise floor), and the lab is given the arm **without
its masses**, as a user with a data-sheet URDF has it, and with its parallelogram coupling
(J3 reported against the horizon, ``theta3 = q3 - q2``; the rows are the controller's angles). Every campaign plants gravity deflection
(``compliance`` on joints 2 and 3, or 2, 3 and 5), 0.03x to 50x the floor, and in 40 % one more
effect of the catalogue; 60 to 1,000 poses, 10 to 50 um of noise per axis, a temperature span of
0 to 25 K. It is handled as the printed output tells a user: ``diagnose`` the geometric model
with the noise stated, fit what the verdict suggests and diagnose again (at most four steps).

Right answers (issue 41's targets): where compliance is at least 5x the floor and the campaign
has at least 100 poses, the last model holds a gravity-deflection effect in >= 95 % of the
campaigns; where every planted effect is at least 5x the floor, the path ends within 1.2x the
floor held out in >= 90 %. Not drawn here: campaigns on the MuJoCo plant, whose model is the
seed arm's.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import lab_decisions as ld  # noqa: E402

from arm.description import RobotDescription, load_robot  # noqa: E402
from arm.files import atomic_write_text  # noqa: E402

SEED0 = 41_000_000
COUNT = 300
ROBOT = "r2000ic_like"
OUT = ROOT / "results" / "heavy_arm"
OTHER = ("transmission", "joint_scale", "backlash", "thermal", "cyclic")
OTHER_SHARE = 0.4
#: the names of the effects that model gravity deflection (with the masses, or without them)
DEFLECTION = ("compliance", "lumped_compliance")
TARGETS = {"compliance_found": 0.95, "path_floor": 0.90}


def draw(seed: int) -> dict[str, Any]:
    """The campaign of ``seed``: what is planted and how it is measured (no data yet)."""
    rng = np.random.default_rng([SEED0, seed])
    spec: dict[str, Any] = {
        "seed": seed,
        "source": "model",
        "n": round(math.exp(rng.uniform(math.log(60), math.log(1000)))),
        "noise_um": float(rng.uniform(10.0, 50.0)),
        "payload": False,  # the robot file's 165 kg
        "temperature_span": float(rng.uniform(0.0, 25.0)),
        "outlier_share": 0.0,
    }
    planted = [_planted(rng, "compliance", [2, 3] if rng.random() < 0.5 else [2, 3, 5])]
    if rng.random() < OTHER_SHARE:
        planted.append(other_effect(rng))
    spec["planted"] = planted
    return spec


def other_effect(rng: np.random.Generator) -> dict[str, Any]:
    """One more effect of the catalogue (:data:`OTHER`) on one or two of its joints."""
    name = str(rng.choice(OTHER))
    js = ld.JOINTS[name]
    joints = sorted(int(j) for j in rng.choice(js, min(len(js), int(rng.integers(1, 3))), False))
    return _planted(rng, name, joints)


def _planted(rng: np.random.Generator, name: str, joints: list[int]) -> dict[str, Any]:
    below = rng.random() < ld.BELOW_SHARE
    size = math.exp(rng.uniform(math.log(0.03), 0.0) if below else rng.uniform(0.0, math.log(50)))
    order = int(rng.integers(2, 41)) if name == "cyclic" else None
    return {"effect": name, "joints": joints, "order": order, "size": float(size)}


#: the arm's parallelogram: its controller gives J3 against the horizon, theta3 = q3 - q2
COUPLING = ((3, 2, -1.0),)


def coupled(robot: RobotDescription) -> RobotDescription:
    """The arm as its controller reports it: the rows' q3 is J3 against the horizon (the
    robot file's ``[[couplings]]``, docs/format.md), as the real R-2000iC's are."""
    return replace(robot, couplings=COUPLING)


def without_masses(robot: RobotDescription) -> RobotDescription:
    """The arm as a data sheet gives it: the lengths, no link masses (the payload is declared)."""
    return replace(
        robot, joints=tuple(replace(j, mass=0.0, com=(0.0, 0.0, 0.0)) for j in robot.joints)
    )


def run_campaign(seed: int) -> dict[str, Any]:
    rec: dict[str, Any] = {**draw(seed), "path": [], "refusal": None}
    try:
        return _run_campaign(seed, rec)
    except Exception as exc:  # recorded, with what was known: a rule no one foresaw
        rec.update(error=f"{type(exc).__name__}: {exc}", held_out=None, seconds=0.0)
        return rec


def _run_campaign(seed: int, rec: dict[str, Any]) -> dict[str, Any]:
    return follow_path(rec, coupled(load_robot(ROBOT)), SEED0)


def follow_path(rec: dict[str, Any], robot: RobotDescription, seed0: int) -> dict[str, Any]:
    """The error model's campaign of ``rec`` on ``robot`` (its masses make the truth), handed to
    the lab without the masses and followed as the printed output says (the module docstring):
    ``rec`` completed with the planted sizes, the path, the last model and its held-out RMS."""
    import logging

    from lab import diagnose
    from lab.errors import FitError

    logging.disable(logging.WARNING)
    warnings.simplefilter("ignore")
    t0, c0 = time.perf_counter(), time.process_time()
    data, planted = ld.model_campaign(rec, robot, seed0)
    rec["planted"] = planted
    lab_arm = without_masses(robot)
    noise_mm = rec["noise_um"] * 1e-3
    floor_mm = noise_mm * math.sqrt(3)
    effects, last = "geometric", None
    try:
        for _ in range(ld.MAX_STEPS):
            d = diagnose(data, lab_arm, effects, noise_mm=noise_mm)
            last = d
            rec["path"].append(
                {
                    "effects": effects,
                    "verdict": d.verdict,
                    "suggestion": d.suggestion,
                    "held_out": d.cv_rms_mm / floor_mm,
                    "skipped": dict(getattr(d, "skipped", {}) or {}),
                }
            )
            if d.verdict in ("none", "noise", "unexplained") or not d.suggestion:
                break
            effects = d.suggestion
    except FitError as exc:
        rec["refusal"] = str(exc)
    rec["held_out"] = rec["path"][-1]["held_out"] if rec["path"] else None
    rec["final_effects"] = list(last.effects) if last is not None else None
    rec["seconds"] = time.perf_counter() - t0
    rec["cpu_seconds"] = time.process_time() - c0
    return rec


def deflection_found(r: dict[str, Any]) -> bool:
    return any(e.split("[")[0] in DEFLECTION for e in r.get("final_effects") or ())


def compliance_size(r: dict[str, Any]) -> float:
    return next(p["size"] for p in r["planted"] if p["effect"] == "compliance")


def summarise(records: list[dict[str, Any]]) -> dict[str, Any]:
    big = [
        r
        for r in records
        if r["n"] >= ld.RESOLVABLE_POSES and compliance_size(r) >= ld.RESOLVABLE_SIZE
    ]
    res = [r for r in records if ld.resolvable({**r, "n_outliers": 0})]
    found = ld.fraction(sum(deflection_found(r) for r in big), len(big))
    floor = ld.fraction(
        sum(r["held_out"] is not None and r["held_out"] <= ld.FLOOR_FACTOR for r in res), len(res)
    )
    met = {
        "compliance_found": found["rate"] is not None
        and found["rate"] >= TARGETS["compliance_found"],
        "path_floor": floor["rate"] is not None and floor["rate"] >= TARGETS["path_floor"],
    }
    return {
        "campaigns": len(records),
        "errors": sum(bool(r.get("error")) for r in records),
        "refusals": sum(bool(r.get("refusal")) for r in records),
        "compliance_found": found,
        "path_floor": floor,
        "targets": TARGETS,
        "targets_met": met,
    }


def report(records: list[dict[str, Any]], summary: dict[str, Any], commit: str) -> str:
    def pct(f: dict[str, Any]) -> str:
        if not f["of"]:
            return "n/a (none drawn)"
        lo, hi = f["ci95"]
        return f"{f['count']} of {f['of']} ({100 * f['rate']:.1f} %, 95 % CI {100 * lo:.1f}-{100 * hi:.1f})"

    misses = [
        r
        for r in records
        if r["n"] >= ld.RESOLVABLE_POSES
        and compliance_size(r) >= ld.RESOLVABLE_SIZE
        and not deflection_found(r)
    ]
    lines = [
        "# The lab on a heavy arm without its mass model",
        "",
        f"`benchmarks/heavy_arm.py` at commit `{commit}`: {summary['campaigns']} campaigns of "
        f"`{ROBOT}` drawn from the error model (seeds {SEED0} + 0..{summary['campaigns'] - 1}); "
        "the lab is given the arm without link masses. How they are drawn and judged: the "
        "script's docstring.",
        "",
        "| what | measured | target |",
        "|---|---|---|",
        f"| gravity deflection found (compliance >= 5x the floor, >= 100 poses) | "
        f"{pct(summary['compliance_found'])} | >= 95 % |",
        f"| the path within 1.2x the floor held out (every planted effect >= 5x) | "
        f"{pct(summary['path_floor'])} | >= 90 % |",
        "",
        f"Refused: {summary['refusals']}; errors: {summary['errors']}.",
    ]
    if misses:
        lines += ["", "Missed deflections (first 20):", ""]
        for r in misses[:20]:
            sizes = ", ".join(f"{p['effect']} {p['size']:.1f}x" for p in r["planted"])
            lines.append(
                f"- seed {r['seed']}: {r['n']} poses, {sizes}; path "
                + " -> ".join(f"{s['verdict']}" for s in r["path"])
                + (f"; refused: {r['refusal']}" if r.get("refusal") else "")
                + (f"; error: {r['error']}" if r.get("error") else "")
            )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=COUNT)
    ap.add_argument("--out", type=Path, default=OUT, help="results path without suffix")
    ap.add_argument("--workers", type=int, default=ld.WORKERS)
    ap.add_argument("--records", type=Path, help="default runs/heavy_arm-<commit>/records.jsonl")
    args = ap.parse_args()
    commit = ld._commit()
    path = args.records or ld.RUNS / f"heavy_arm-{commit}" / "records.jsonl"
    records = ld.run(list(range(args.count)), path, args.workers, run_campaign, every=25)
    summary = summarise(records)
    payload = {"schema_version": 1, "commit": commit, "seed0": SEED0, **summary}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(payload, indent=1) + "\n")
    atomic_write_text(args.out.with_suffix(".md"), report(records, summary, commit))
    print(
        json.dumps(
            {k: summary[k] for k in ("compliance_found", "path_floor", "targets_met")}, indent=1
        )
    )


if __name__ == "__main__":
    main()
