"""A 6-DoF calibration against the positions alone, both judged on held-out positions by
leave-one-out: for a real set with few poses and no stated uncertainties (the Rokae set).

    rows, summary = pose_rows(data, robot)        # called by benchmarks/real_data.py

Without stated uncertainties a 6-DoF fit has no weights to weigh a radian against a metre. They
are estimated from the training poses alone, for every fold, by variance components (Förstner's
iteration: each group's sigma^2 = its residual sum of squares / its redundancy, the redundancy
the group's rows minus the trace of the hat matrix over them), so the held-out pose never chooses
them. The positions-only fit is the lab's plain geometric fit. Both models predict the held-out
pose's position; the per-pose squared errors are compared pairwise (mean difference and its
standard error: an ordering is claimed only where it resolves).
"""

from __future__ import annotations

import logging
import math
import time
import warnings

import numpy as np

from arm.description import RobotDescription
from arm.measurements import MeasurementSet
from lab import FitResult, NoiseRefutedError, fit

__all__ = ["pose_rows", "variance_components"]

log = logging.getLogger("real_data")

START_MM, START_MRAD = 0.05, 0.5  # where the iteration starts; it forgets them


def _quiet(fn, *a, **kw):
    """A fit as the benchmark runs it: its cautions (a poor pose set of 29 poses) not printed."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*a, **kw)


def variance_components(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: str = "geometric",
    iterations: int = 20,
    rtol: float = 1e-4,
) -> tuple[float, float, FitResult]:
    """The positions' and the orientations' per-axis sigma (mm, mrad) that the data's own
    residuals imply, and the 6-DoF fit weighted by them (see the module docstring)."""
    s_mm, s_mrad = START_MM, START_MRAD
    res = None
    for _ in range(iterations):
        try:
            res = _quiet(
                fit, data, robot, effects, outliers="keep", noise_mm=s_mm, noise_mrad=s_mrad
            )
        except NoiseRefutedError:  # a start far above the data's noise: the lab refuses it
            s_mm, s_mrad = s_mm / 10, s_mrad / 10  # (too small a start it never refutes)
            continue
        obs = res.observations
        assert obs is not None and obs.scale is not None and obs.rotation is not None
        J = res.jacobian[:, :, res.identifiable]  # the weighted rows' (N, 6, k)
        Q, _ = np.linalg.qr(J.reshape(-1, J.shape[2]))
        leverage = np.sum(Q**2, axis=1).reshape(-1, 6)
        measured = obs.scale > 0
        raw = np.where(measured, res.row_residuals / np.where(measured, obs.scale, 1.0), 0.0)
        new = []
        for cols in (slice(0, 3), slice(3, 6)):
            rows = measured[:, cols]
            redundancy = rows.sum() - leverage[:, cols][rows].sum()
            new.append(math.sqrt(float(np.sum(raw[:, cols] ** 2)) / max(redundancy, 1.0)))
        n_mm, n_mrad = 1e3 * new[0], 1e3 * new[1]
        done = abs(n_mm / s_mm - 1) < rtol and abs(n_mrad / s_mrad - 1) < rtol
        s_mm, s_mrad = n_mm, n_mrad
        if done:
            break
    assert res is not None
    return s_mm, s_mrad, res


def pose_rows(
    data: MeasurementSet, robot: RobotDescription, effects: str = "geometric"
) -> tuple[list[dict], dict]:
    """Leave-one-out of ``effects`` fitted to the 6-DoF rows (weights from the training poses'
    variance components) and to the positions alone: the 6-DoF row in the format of
    ``benchmarks/real_data.py`` (model, path, held-out RMS/mean/max of the positions, fit RMS,
    parameters, seconds), and a summary: both models' held-out figures, the paired comparison,
    the sigmas estimated, the held-out orientation RMS, rank and condition number of both."""
    if not data.has_orientation:
        raise ValueError(f"{data.source}: no orientation rows to compare with the positions")
    n = len(data)
    positions = MeasurementSet(data.q, data.xyz, data.columns, data.source, data.lines)
    e6, ep, turn, sig, train6, trainp = [], [], [], [], [], []
    t6 = tp = 0.0
    for k in range(n):
        keep = np.flatnonzero(np.arange(n) != k)
        held = data.subset([k])
        t = time.perf_counter()
        s_mm, s_mrad, res6 = variance_components(data.subset(keep), robot, effects)
        res6 = res6.validate(held)
        t6 += time.perf_counter() - t
        t = time.perf_counter()
        resp = _quiet(fit, positions.subset(keep), robot, effects, outliers="keep")
        tp += time.perf_counter() - t
        e6.append(1e3 * float(np.linalg.norm(res6.predict(held)[0] - held.xyz[0])))
        ep.append(1e3 * float(np.linalg.norm(resp.predict(held)[0] - held.xyz[0])))
        turn.append(res6.validation_orientation_rms_mrad)
        sig.append((s_mm, s_mrad))
        train6.append((res6.rms_mm, res6.rank, res6.condition_number))
        trainp.append((resp.rms_mm, resp.rank, resp.condition_number))
    a6, ap = np.array(e6), np.array(ep)
    d = a6**2 - ap**2  # per pose: 6-DoF minus positions, mm^2
    se = float(d.std(ddof=1) / math.sqrt(n))
    sig_a = np.array(sig)
    tr6, trp = np.array(train6), np.array(trainp)

    def figures(e: np.ndarray) -> dict:
        return {
            "rms_mm": float(np.sqrt(np.mean(e**2))),
            "mean_mm": float(e.mean()),
            "max_mm": float(e.max()),
        }

    row = {
        "model": f"{effects}, 6-DoF rows",
        "path": "leave-one-out: fit of positions and orientations, each weighted by the "
        "sigma its own training poses imply (variance components)",
        "effects": {effects: n},
        **figures(a6),
        "train_rms_mm": float(tr6[:, 0].mean()),
        "parameters": round(float(tr6[:, 1].mean()), 1),
        "seconds": t6,
    }
    summary = {
        "folds": n,
        "six_dof": figures(a6),
        "positions_only": figures(ap),
        "paired_mean_sq_diff_mm2": float(d.mean()),
        "paired_se_mm2": se,
        "resolved": bool(abs(d.mean()) > 2 * se),
        "six_dof_better_poses": int(np.sum(a6 < ap)),
        "sigma_mm": [float(sig_a[:, 0].min()), float(sig_a[:, 0].max())],
        "sigma_mrad": [float(sig_a[:, 1].min()), float(sig_a[:, 1].max())],
        "held_out_orientation_rms_mrad": float(np.sqrt(np.mean(np.square(turn)))),
        "rank": {"six_dof": float(tr6[:, 1].mean()), "positions_only": float(trp[:, 1].mean())},
        "condition_number": {
            "six_dof": float(np.median(tr6[:, 2])),
            "positions_only": float(np.median(trp[:, 2])),
        },
        "seconds": {"six_dof": t6, "positions_only": tp},
    }
    log.info(
        "%s: 6-DoF %.4f mm, positions only %.4f mm held out (leave-one-out)",
        data.source,
        summary["six_dof"]["rms_mm"],
        summary["positions_only"]["rms_mm"],
    )
    return [row], summary


def summary_lines(s: dict) -> list[str]:
    """The summary in words, for results/real_data.md."""
    verdict = (
        (
            "the 6-DoF rows predict held-out positions better"
            if s["paired_mean_sq_diff_mm2"] < 0
            else "the positions alone predict held-out positions better"
        )
        if s["resolved"]
        else "no ordering: the paired difference is within two standard errors"
    )
    return [
        f"- 6-DoF rows against the positions alone, both leave-one-out on held-out positions: "
        f"{s['six_dof']['rms_mm']:.4f} mm against {s['positions_only']['rms_mm']:.4f} mm RMS "
        f"(6-DoF closer on {s['six_dof_better_poses']} of {s['folds']} poses; per-pose squared "
        f"error difference {s['paired_mean_sq_diff_mm2']:+.5f} ± {s['paired_se_mm2']:.5f} mm², "
        f"{verdict}).",
        f"- The weights, from each fold's training poses (variance components): positions "
        f"{s['sigma_mm'][0]:.4f}-{s['sigma_mm'][1]:.4f} mm, orientations "
        f"{s['sigma_mrad'][0]:.3f}-{s['sigma_mrad'][1]:.3f} mrad per axis; held-out orientation "
        f"RMS {s['held_out_orientation_rms_mrad']:.3f} mrad. The orientation rows raise the "
        f"parameters identified from {s['rank']['positions_only']:.0f} to "
        f"{s['rank']['six_dof']:.0f} and the condition number goes from "
        f"{s['condition_number']['positions_only']:.0f} to {s['condition_number']['six_dof']:.0f} "
        "(medians over the folds).",
    ]
