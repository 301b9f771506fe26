"""Kinematic MPC solve time per control step, QP against IPOPT, with the tracking error of each,
in one run: the same seeded SixAxisTrack-v0 episodes driven by the MPC with online calibration,
its linearised QP (the unconstrained step by an LDL' factorisation, DAQP when a bound binds, the
default; DAQP on every step; qpOASES and OSQP) and the full nonlinear program solved by IPOPT. A step's time is
everything the agent does in ``act``: the estimator's update when a tracker point arrives, the
model's point and Jacobian, the QP and its solution (so the "model update" is included).
Targets (issue 12): the default's median step at least 60x faster than IPOPT's median, its p95
at most 2x its median, at equal tracking error. Writes section ``mpc`` of results/benchmarks.md.

    python benchmarks/mpc.py [--seeds 3] [--scenario geometric]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from agents.registry import make_agent
from agents.runner import run_episode
from benchmarks._report import machine, write_section

#: (row name, MPCAgent settings): the default first
SOLVERS = {
    "daqp": {"solver": "daqp"},
    "daqp-every-step": {"solver": "daqp", "closed_form": False},
    "qpoases": {"solver": "qpoases"},
    "osqp": {"solver": "osqp"},
    "ipopt": {"solver": "ipopt"},
}
TARGET_SPEEDUP = 60.0
TARGET_P95 = 2.0
SETTLE_S = 2.0


def measure(solver: str, seed: int, scenario: str) -> dict:
    """One episode: per-step times (wall clock, as the leaderboard records them, and the CPU
    time of the thread, which other jobs on a shared machine do not inflate), the estimator's
    update on the steps that had a tracker point (``act`` at step k sees the info of step k-1),
    and the tracking RMS."""
    agent = make_agent("mpc", **SOLVERS[solver])
    cpu: list[float] = []
    act = agent.act

    def timed_act(obs, info):
        c0 = time.thread_time()
        out = act(obs, info)
        cpu.append(time.thread_time() - c0)
        return out

    agent.act = timed_act  # type: ignore[method-assign]
    r = run_episode(agent, {"scenario": scenario}, seed=seed)
    t = r.solve_time_s
    c = np.asarray(cpu)
    u = np.asarray(agent._update_times)
    had_point = np.r_[False, np.isfinite(r.measurement[:-1, 0])]
    return {
        "median": float(np.median(t)),
        "p95": float(np.percentile(t, 95)),
        "cpu_median": float(np.median(c)),
        "cpu_p95": float(np.percentile(c, 95)),
        "update_median": float(np.median(u[had_point])),
        "rms": r.rms_mm(start=SETTLE_S),
        "rms_whole": r.rms_mm(),
        "constrained": int(getattr(agent.mpc, "n_constrained", 0)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--scenario", default="geometric")
    args = ap.parse_args()
    # interleave the solvers seed by seed so that machine load falls on all of them alike
    res: dict[str, list[dict]] = {s: [] for s in SOLVERS}
    for seed in range(args.seeds):
        for s in SOLVERS:
            m = measure(s, seed, args.scenario)
            print(f"seed {seed} {s:8s} median {m['median'] * 1e3:.3f} ms, rms {m['rms']:.4f} mm")
            res[s].append(m)

    def med(s, k):
        return float(np.median([m[k] for m in res[s]]))

    ipopt_rms = np.array([m["rms"] for m in res["ipopt"]])
    rows = []
    for s in SOLVERS:
        rms = np.array([m["rms"] for m in res[s]])
        whole = np.array([m["rms_whole"] for m in res[s]])
        rows.append(
            {
                "name": s,
                "wall": (med(s, "median"), med(s, "p95")),
                "cpu": (med(s, "cpu_median"), med(s, "cpu_p95")),
                "update": med(s, "update_median"),
                "rms": rms.mean(),
                "whole": whole.mean(),
                "diff": rms - ipopt_rms,
            }
        )
    by = {r["name"]: r for r in rows}
    d, ip = by["daqp"], by["ipopt"]
    speed = {k: ip[k][0] / d[k][0] for k in ("wall", "cpu")}
    tail = {k: d[k][1] / d[k][0] for k in ("wall", "cpu")}
    ok_speed = {k: v >= TARGET_SPEEDUP for k, v in speed.items()}
    ok_p95 = {k: v <= TARGET_P95 for k, v in tail.items()}
    ok_equal = bool(np.all(np.abs(d["diff"]) <= 0.1 * ipopt_rms + 1e-3))
    constrained = sum(m["constrained"] for m in res["daqp"])
    load = os.getloadavg()[0]

    def verdict(ok: bool) -> str:
        return "met" if ok else "not met"

    lines = [
        "## Kinematic MPC: solve time per control step, QP vs IPOPT",
        "",
        f"`python benchmarks/mpc.py --seeds {args.seeds} --scenario {args.scenario}` on "
        f"{machine()}; load average {load:.1f} at the end (the machine is shared).",
        "",
        f"SixAxisTrack-v0, scenario `{args.scenario}`, seeds 0-{args.seeds - 1}, 10 s episodes "
        "(500 steps each); the MPC with online recursive least-squares calibration, horizon 10 "
        "steps (60 variables, 120 constraint rows). A step's time is the whole `act`: the "
        "estimator's update when a tracker point arrives, the model's point and Jacobian, the "
        "QP's data and its solution; *wall* is the clock the leaderboard records, *CPU* the "
        "thread's own time, which other jobs on a loaded machine do not inflate (they preempt a "
        "long IPOPT solve more often than a 0.1 ms step, which flatters the wall-clock ratio). "
        "Medians over seeds of per-episode statistics; the tracking RMS after the first "
        f"{SETTLE_S:g} s and over the whole episode, mean over seeds. `daqp` is the default: the "
        "QP's unconstrained minimiser by an LDL' factorisation of its Hessian, DAQP when it violates a "
        "bound (every QP row takes that step; the solver differs only there); `daqp-every-step` "
        "runs DAQP "
        "(through CasADi, cold) on every step, as the MPC did before.",
        "",
        "| solver | wall median / p95 (ms) | CPU median / p95 (ms) | p95 / median, wall / CPU | "
        "estimator update on a tracker step, median (ms) | speed-up vs IPOPT, wall / CPU "
        "(medians) | tracking RMS settled / whole (mm) | max abs difference to IPOPT's settled "
        "RMS (mm) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        name = "IPOPT (full NLP)" if r["name"] == "ipopt" else f"QP, {r['name']}"
        w, c = r["wall"], r["cpu"]
        lines.append(
            f"| {name} | {w[0] * 1e3:.3f} / {w[1] * 1e3:.3f} | {c[0] * 1e3:.3f} / {c[1] * 1e3:.3f}"
            f" | {w[1] / w[0]:.2f} / {c[1] / c[0]:.2f} | {r['update'] * 1e3:.3f} | "
            f"{ip['wall'][0] / w[0]:.1f}x / {ip['cpu'][0] / c[0]:.1f}x | {r['rms']:.4f} / "
            f"{r['whole']:.4f} | {np.abs(r['diff']).max():.4f} |"
        )
    lines += [
        "",
        f"Targets (the default, `daqp`): median step at least {TARGET_SPEEDUP:g}x faster than "
        f"IPOPT's: wall **{verdict(ok_speed['wall'])}** ({speed['wall']:.0f}x, "
        f"{d['wall'][0] * 1e3:.3f} ms), CPU **{verdict(ok_speed['cpu'])}** ({speed['cpu']:.0f}x, "
        f"{d['cpu'][0] * 1e3:.3f} ms); p95 at most {TARGET_P95:g}x the median: wall "
        f"**{verdict(ok_p95['wall'])}** ({tail['wall']:.2f}x), CPU **{verdict(ok_p95['cpu'])}** "
        f"({tail['cpu']:.2f}x); equal tracking error (within 10 % of IPOPT's or 1 um, every "
        f"seed): **{verdict(ok_equal)}**. A bound bound on {constrained} of {500 * args.seeds} "
        "steps (the solver ran there).",
        "Where the time goes: every CasADi function is called through its own buffers "
        "(`Function.buffer`; a plain call's numpy conversions cost 30-40 us, more than the "
        "evaluation); the QP's step is one compiled function (the model's point and Jacobian, the "
        "gradient and Hessian, CasADi's LDL' solve, the constraint check); the estimator's "
        "update is one compiled function (its information "
        "refactored by CasADi's LDL: the regularised forgetting's (1 - lam) I term is full rank, "
        "so a rank-one factor update cannot take it). The p95 falls on the tracker steps (every "
        "5th), which add the estimator's update (fifth column) to a step that itself got 4x "
        "cheaper; the update is now about as long as the rest of the step. IPOPT's p95 is its "
        "first, cold, solves and the transient.",
    ]
    path = write_section("mpc", "\n".join(lines))
    print("\n".join(lines))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
