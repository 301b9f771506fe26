"""Cyclic joint errors through the lab (issue 20): simulated arms whose joints carry cyclic errors
of orders up to 40, and the public UR5 set through the user's own path.

    python benchmarks/cyclic.py                 # writes section `lab-cyclic`
    python benchmarks/cyclic.py --campaigns 20  # fewer simulated arms

**Simulated arms.** Each campaign: the seed arm with random geometric errors of their typical
size, two joints drawn from 1-5 with two distinct orders each drawn from 2-40, amplitudes from the
cyclic effect's typical range (0.05-0.3 mrad) with random phases, 300 random poses, 15 um of
noise per axis (the noise given), 1,000 held-out poses of the same arm. (Joint 6 is left out: on
the seed arm its angle moves the tool point by its 50 mm offset only, so 0.3 mrad moves it 15 um,
the noise itself; no method finds it from 300 poses.) For each: ``lab.discover`` from geometric;
whether it names exactly the hidden joints and orders; the held-out RMS of the written module's
fit against the noise floor (sigma * sqrt(3)); whether a re-diagnosis with the module says
``none``; and whether ``lab.diagnose`` from geometric suggests exactly the hidden effect.

**The UR5 set** (data/ur5: 1,000 grid poses to fit, 20 random poses to test), as a user runs
it: ``sixaxis lab diagnose data/ur5/calibration.csv --robot ur5 --noise-mm 0.03``, then the
discover it prints (from geometric, ``-o discovered.py``), then ``sixaxis lab fit ...
--effect-module discovered.py --effects geometric,discovered --validate data/ur5/test.csv``; and
the fit of the diagnosis's own suggestion. Beside them the geometric model's held-out RMS and the
published hybrid's (0.1549 mm, mean 3-D error); FIGAROH's figure is measured side by side in
``benchmarks/real_data.py`` (results/real_data.md).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from arm import load_robot, read_measurements, seed_robot
from arm.effects import EFFECTS, load_effect_module
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from arm.sampling import sample_parameters, sample_poses
from benchmarks._report import machine, write_section
from lab import diagnose, discover, fit

SIGMA = 15e-6
FLOOR_MM = 1e3 * SIGMA * math.sqrt(3)
UR5 = Path(__file__).resolve().parents[1] / "data" / "ur5"
PUBLISHED_MM = 0.1549  # the hybrid (MDH + ASTGCN) of the data set's thesis, mean 3-D error


def campaign(seed: int) -> tuple[str, MeasurementSet, MeasurementSet]:
    rng = np.random.default_rng(seed)
    robot = seed_robot()
    joints = sorted(int(j) for j in rng.choice(np.arange(1, 6), 2, replace=False))
    orders = {
        j: sorted(int(k) for k in rng.choice(np.arange(2, 41), 2, replace=False)) for j in joints
    }
    hidden = "cyclic[" + ";".join(f"{j}:{k[0]},{k[1]}" for j, k in orders.items()) + "]"
    truth = ErrorModel(robot, f"geometric,{hidden}")
    p = sample_parameters(truth, rng)

    def measure(n: int) -> MeasurementSet:
        q = sample_poses(robot, n, rng)
        xyz = truth.predict(truth.inputs(q), p) + rng.normal(0.0, SIGMA, (n, 3))
        return MeasurementSet(q, xyz, {}, f"campaign {seed}")

    return hidden, measure(300), measure(1000)


def simulated(n: int, tmp: Path) -> tuple[list[str], dict]:
    robot = seed_robot()
    rows, ratios, exact, none, diag_exact, times = [], [], 0, 0, 0, []
    for seed in range(n):
        hidden, data, val = campaign(seed)
        dg = diagnose(data, robot, "geometric", noise_mm=1e3 * SIGMA)
        t = time.perf_counter()
        d = discover(data, robot, "geometric", noise_mm=1e3 * SIGMA)
        times.append(time.perf_counter() - t)
        found = d.scan.spec if d.scan is not None else None
        before = set(EFFECTS)
        try:
            load_effect_module(d.write_module(tmp / f"found{seed}.py"))
            res = fit(data, robot, d.suggestion, noise_mm=1e3 * SIGMA, validate=val)
            again = diagnose(data, robot, d.suggestion, noise_mm=1e3 * SIGMA)
        finally:
            for name in set(EFFECTS) - before:
                del EFFECTS[name]
        ratio = res.validation_rms_mm / FLOOR_MM
        ratios.append(ratio)
        exact += found == hidden
        none += again.verdict == "none"
        diag_exact += dg.suggestion == f"geometric,{hidden}"
        rows.append(
            f"| {seed} | `{hidden}` | `{found}` | {ratio:.3f} | {again.verdict} | "
            f"`{dg.suggestion}` |"
        )
        print(rows[-1], flush=True)
    summary = {
        "n": n,
        "exact": exact,
        "none": none,
        "diag_exact": diag_exact,
        "max_ratio": max(ratios),
        "median_ratio": statistics.median(ratios),
        "median_time": statistics.median(times),
    }
    return rows, summary


def ur5(tmp: Path) -> dict:
    robot = load_robot("ur5")
    cal = read_measurements(UR5 / "calibration.csv")
    test = read_measurements(UR5 / "test.csv")
    out: dict = {}
    out["geometric"] = fit(cal, robot, "geometric", validate=test).validation_rms_mm
    t = time.perf_counter()
    d = diagnose(cal, robot, "geometric", noise_mm=0.03)
    out["diagnose_s"] = time.perf_counter() - t
    out["verdict"], out["suggestion"] = d.verdict, d.suggestion
    out["suggested"] = fit(cal, robot, d.suggestion, noise_mm=0.03, validate=test)
    before = set(EFFECTS)
    try:
        t = time.perf_counter()
        disc = discover(cal, robot, ",".join(d.effects), noise_mm=0.03)
        out["discover_s"] = time.perf_counter() - t
        out["discovery"] = disc
        load_effect_module(disc.write_module(tmp / "discovered.py"))
        out["module"] = fit(cal, robot, disc.suggestion, noise_mm=0.03, validate=test)
    finally:
        for name in set(EFFECTS) - before:
            del EFFECTS[name]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaigns", type=int, default=40)
    args = ap.parse_args()
    warnings.simplefilter("ignore")  # the lab's cautions (poor pose sets...) are not results
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        rows, s = simulated(args.campaigns, Path(tmp))
        u = ur5(Path(tmp))
    elapsed = time.perf_counter() - t0
    disc = u["discovery"]
    body = [
        "## Lab: cyclic joint errors (simulated arms and the UR5 set)",
        "",
        f"`python benchmarks/cyclic.py --campaigns {args.campaigns}` on {machine()}; "
        f"{elapsed:.0f} s. See the script's docstring for the set-up.",
        "",
        f"**Simulated arms** ({s['n']} campaigns: two of joints 1-5, two orders of 2-40 each, "
        "0.05-0.3 mrad, 300 random poses, 15 um noise):",
        "",
        "| target (issue 20) | measured | outcome |",
        "|---|---|---|",
        f"| joint and order found exactly (discover) | {s['exact']} of {s['n']} | "
        f"{'met' if s['exact'] == s['n'] else 'missed'} |",
        f"| held-out RMS at most 1.2x the noise floor ({FLOOR_MM:.4f} mm) | max "
        f"{s['max_ratio']:.3f}x, median {s['median_ratio']:.3f}x | "
        f"{'met' if s['max_ratio'] <= 1.2 else 'missed'} |",
        f"| re-diagnosis with the written module says `none` | {s['none']} of {s['n']} | "
        f"{'met' if s['none'] == s['n'] else 'missed'} |",
        f"| (the diagnosis from geometric suggests exactly the hidden effect) | "
        f"{s['diag_exact']} of {s['n']} | - |",
        "",
        f"Median time of a discovery (300 poses, orders to 64): {s['median_time']:.2f} s.",
        "",
        "| seed | hidden | discovered | held-out / floor | re-diagnosis | diagnosis suggests |",
        "|---|---|---|---|---|---|",
        *rows,
        "",
        "**The UR5 set** (held-out: the 20 random test poses, 3-D RMS):",
        "",
        "| model (the user's path) | held-out RMS (mm) |",
        "|---|---|",
        f"| geometric | {u['geometric']:.4f} |",
        f"| the diagnosis's suggestion (`lab fit --effects ...` as printed) | "
        f"{u['suggested'].validation_rms_mm:.4f} |",
        f"| discover (as the diagnosis prints it), then fit with the written module | "
        f"{u['module'].validation_rms_mm:.4f} |",
        f"| published hybrid (MDH + ASTGCN), mean 3-D error | {PUBLISHED_MM:.4f} |",
        "",
        f"Target (issue 20): at most 0.075 mm through the user's path: "
        f"{u['module'].validation_rms_mm:.4f} mm, "
        f"{'met' if u['module'].validation_rms_mm <= 0.075 else 'missed'}. The diagnosis "
        f"({u['diagnose_s']:.1f} s) says `{u['verdict']}` and suggests `{u['suggestion']}`; "
        f"discover ({u['discover_s']:.1f} s) says `{disc.verdict}` with {len(disc.terms)} terms "
        f"(fit RMS {disc.rms_after_mm:.4f} mm"
        + (f"; {disc.noise_note}" if disc.noise_note else "")
        + ").",
    ]
    path = write_section("lab-cyclic", "\n".join(body))
    print("\n".join(body))
    print(f"\nwritten to {path}")


if __name__ == "__main__":
    main()
