"""The lab's speed: fit of geometric + compliance on 1,000 poses, a diagnosis of the whole
catalogue and a discovery over the library of candidate terms, beside scipy's
``least_squares`` with finite differences on the same problem.

    python benchmarks/lab.py            # writes section `lab` of results/benchmarks.md

The problem: the seed arm with random geometric errors of the SPEC's typical size and compliance
of joints 2 and 3, 15 um of noise per axis; 1,000 poses, each with a random approach direction
and a temperature (so that every catalogued effect can be tested). Every solver starts from the
nominal arm and fits the same identifiable parameters; times are medians of repeated runs in one
process.
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from arm import seed_robot
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from arm.sampling import sample_parameters, sample_poses
from benchmarks._report import machine, write_section
from lab import diagnose, discover, fit
from tests import _hidden_forms as hidden

N = 1000
SIGMA = 15e-6
REPEAT = 7


def problem(n: int, seed: int = 0) -> tuple[MeasurementSet, MeasurementSet]:
    robot = seed_robot()
    rng = np.random.default_rng(seed)
    truth = ErrorModel(robot, "geometric,compliance[2,3]")
    p = sample_parameters(truth, rng)

    def measure(m):
        q = sample_poses(robot, m, rng)
        cols = {f"dir{j}": rng.choice([-1.0, 1.0], m) for j in range(1, 7)}
        cols["temperature"] = rng.uniform(15.0, 35.0, m)
        xyz = truth.predict(truth.inputs(q, cols), p) + rng.normal(0, SIGMA, (m, 3))
        return MeasurementSet(q, xyz, cols, "benchmark")

    return measure(n), measure(500)


def timed(fn, repeat: int = REPEAT) -> tuple[float, object]:
    fn()  # warm-up: imports, caches
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def scipy_finite_differences(data: MeasurementSet, free: np.ndarray):
    """The peer: scipy's least_squares (MINPACK's LM, 2-point finite differences) on the
    residuals of the same model and the same free parameters, from the nominal arm."""
    model = ErrorModel(seed_robot(), "geometric,compliance")
    inputs = model.inputs(data.q, data.columns)
    p0 = model.nominal()
    calls = [0]

    def fun(x):
        calls[0] += 1
        p = p0.copy()
        p[free] = x
        return (model.predict(inputs, p) - data.xyz).ravel()

    res = least_squares(fun, p0[free], jac="2-point", method="lm", x_scale="jac")
    res.calls = calls[0]  # scipy's nfev leaves out MINPACK's finite-difference calls
    return res


def main() -> None:
    data, val = problem(N)
    effects = "geometric,compliance"
    t_fit, res = timed(lambda: fit(data, None, effects))
    t_minpack, res_mp = timed(lambda: fit(data, None, effects, solver="minpack"))
    free = res.identifiable
    t_fd, res_fd = timed(lambda: scipy_finite_differences(data, free), repeat=3)
    rms_fd = 1e3 * math.sqrt(np.mean(np.sum(res_fd.fun.reshape(-1, 3) ** 2, axis=1)))
    t_diag, diag = timed(lambda: diagnose(data, None, "geometric", noise_mm=1e3 * SIGMA))
    small, _ = problem(200, seed=1)
    t_fit200, _ = timed(lambda: fit(small, None, effects))
    t_diag200, _ = timed(lambda: diagnose(small, None, "geometric", noise_mm=1e3 * SIGMA))
    n_cands = diag.n_tested
    # discovery: 1,000 poses with a 2nd harmonic on joint 2 hidden (tests/_hidden_forms.py)
    h2 = hidden.campaign(seed_robot(), "harmonic2_q2", seed=0, n=N, n_validation=1).data
    t_disc, disc = timed(lambda: discover(h2, None, "geometric", noise_mm=1e3 * SIGMA), repeat=3)
    t_diag_h2, _ = timed(lambda: diagnose(h2, None, "geometric", noise_mm=1e3 * SIGMA), repeat=3)
    floor = SIGMA * math.sqrt(3) * 1e3

    model = ErrorModel(seed_robot(), effects)
    inputs = model.inputs(data.q, data.columns)
    p0 = model.nominal()
    t_pred, _ = timed(lambda: model.predict(inputs, p0), repeat=20)
    t_jac, _ = timed(lambda: model.predict(inputs, p0, jacobian=True), repeat=20)
    rows = [
        (
            "lab.fit (analytic Jacobian, Gauss-Newton-first LM)",
            t_fit,
            f"{res.evaluations} with Jacobian",
            res.rms_mm,
        ),
        (
            "lab.fit, solver=minpack (analytic Jacobian, scipy lmder)",
            t_minpack,
            f"{res_mp.evaluations} with Jacobian",
            res_mp.rms_mm,
        ),
        (
            "scipy least_squares, 2-point finite differences (peer)",
            t_fd,
            f"{res_fd.calls} without",
            rms_fd,
        ),
    ]
    body = [
        "## Lab: identification and diagnosis",
        "",
        f"Machine: {machine()}. Seed arm, {N} poses, 15 um noise per axis, random geometric "
        "errors and compliance of joints 2 and 3 hidden; medians of repeated runs. "
        f"`{effects}` has {res.n_parameters} parameters, {res.rank} identifiable.",
        "",
        "| fit of geometric + compliance, 1,000 poses | time (s) | model evaluations | RMS (mm) | speed-up over the peer |",
        "|---|---|---|---|---|",
    ]
    for name, t, nfev, rms in rows:
        body.append(f"| {name} | {t:.4f} | {nfev} | {rms:.4f} | {t_fd / t:.1f}x |")
    body += [
        "",
        "| diagnose (fit geometric, test the catalogue, hints) | time (s) | candidates tested | verdict |",
        "|---|---|---|---|",
        f"| 1,000 poses | {t_diag:.3f} | {n_cands} | {diag.verdict} ({diag.suggestion}) |",
        f"| 200 poses | {t_diag200:.3f} | - | - |",
        "",
        "| discover (fit geometric, library, selection, refit with the terms) | time (s) | "
        "candidates | found | diagnose on the same data (s) |",
        "|---|---|---|---|---|",
        f"| 1,000 poses, 2nd harmonic on joint 2 hidden | {t_disc:.3f} | {disc.n_candidates} | "
        f"{'; '.join(disc.formulas.values())} | {t_diag_h2:.3f} |",
        "",
        f"Target: discover on 1,000 poses under 2 s (measured {t_disc:.3f} s, "
        f"{t_disc / t_diag_h2:.1f}x a diagnosis of the same data).",
        "",
        f"Targets: fit under 0.2 s (measured {t_fit:.3f} s), diagnosis of the whole catalogue under "
        f"1 s (measured {t_diag:.3f} s). Fit of 200 poses: {t_fit200:.3f} s. All solvers reach "
        f"the same RMS; the noise floor of held-out points is {floor:.4f} mm (validation RMS "
        f"{res.validate(val).validation_rms_mm:.4f} mm). One model evaluation of 1,000 poses: "
        f"{t_pred * 1e3:.2f} ms, {t_jac * 1e3:.2f} ms with the analytic Jacobian; finite "
        "differences cost one evaluation per parameter per Jacobian. The lab's own LM takes "
        "Gauss-Newton steps first (these problems are nearly linear once the base is registered) "
        "and needs 3-5 evaluations where MINPACK's damped start needs more. A fit also registers "
        "the base, analyses identifiability twice and computes standard errors; a diagnosis fits, "
        "then tests every candidate by linear algebra on that one fit (no refits).",
    ]
    path = write_section("lab", "\n".join(body))
    print("\n".join(body))
    print(f"\nwritten to {path}")


if __name__ == "__main__":
    main()
