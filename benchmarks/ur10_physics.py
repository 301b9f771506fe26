"""What moves the UR10 between sessions: the catalogue's physical effects on its three series.

    python benchmarks/ur10_physics.py                   # make real-data runs it after real_data.py

Writes ``results/ur10_physics.md`` and ``results/ur10_physics.json`` (atomically), naming the
commit they came from and whether the tree was clean; docs/lab.md quotes them.

The series of ``data/ur10`` (Landgraf et al. 2021, MIT) were measured months apart, each from its
own tracker station, at its own temperature and in its own region of the joint space. Series A
and B are subsampled to 1,000 poses each (random, seed 0), as ``benchmarks/real_data.py`` does;
the tracker's noise is stated (15 um + 6 um/m) and the stds of B and D are floored by it. Four questions:

* **Fitted on all three** (one base per station): the geometry alone and with each physical
  effect (thermal growth of the links, ``thermal``; the compliance of the two joints gravity
  loads most, ``compliance[2,3]``, and of every loaded joint, ``compliance[2,3,4,5]``; both):
  the fit's RMS and the parameters with their standard errors.
* **Leave one series out**: the same models fitted on two series and validated on the third, its
  station unseen: registered on 6 reference poses of it (``--references``,
  ``benchmarks.real_data.validated``), which are not scored, as ``--validate`` does it (a term out of its
  domain, here the thermal line beyond the fitted temperatures, left out of those rows), and
  with every term extrapolated (``--extrapolate``).
* **The tracker's station**: the geometric fit of two series, the third's predicted points
  registered on its measured ones by a similarity (a free scale) instead of a rigid motion, both
  fitted on every scored row (a diagnosis of what a free scale takes up, not a held-out figure);
  the scale it takes (ppm) and the RMS it gains. A laser tracker's scale error is a few ppm.
* **The geometry itself**: the geometric fit of A alone and of B alone; the DH parameters that
  differ most between them, in standard errors of the difference.
* **What the left-out session changed**: the model that transfers (``geometric,compliance[2,3]``)
  fitted on two series, then refitted on the whole third with every parameter held but its base
  and one group (the joints' zeros, the links' lengths and offsets, the axes' tilts, the tool,
  every geometric row): the RMS on that series that each group, moved, accounts for, beside the
  series' own fit of the same model (what a calibration of that session reaches).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from scipy.spatial.transform import Rotation

from arm.files import atomic_write_text
from arm.measurements import MeasurementSet, concatenate
from benchmarks._report import code_state, machine
from benchmarks.real_data import (
    UR10_NOISE,
    UR10_SEED,
    UR10_SERIES,
    reference_split,
    series_for_fitting,
    validated,
)
from lab import fit

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results"
ROBOT = "ur10_robot"
#: the models compared: the geometry alone, and with each physical effect of the catalogue
MODELS = (
    "geometric",
    "geometric,thermal",
    "geometric,compliance[2,3]",
    "geometric,compliance[2,3,4,5]",
    "geometric,compliance[2,3],thermal",
)
#: the physical parameters reported with their standard errors
REPORTED = ("kappa", "c2", "c3", "c4", "c5")
#: the model whose parameters a session may have moved (the one that transfers)
MOVED_MODEL = "geometric,compliance[2,3]"
#: the groups of its parameters refitted on the left-out series, by name
MOVED_GROUPS = {
    "the joints' zeros (dtheta)": ("dtheta",),
    "the links' lengths and offsets (da, dd)": ("da", "dd"),
    "the axes' tilts (dalpha, beta2)": ("dalpha", "beta"),
    "the tool (tx, ty, tz)": ("tx", "ty", "tz"),
    "every geometric row and the tool": ("dalpha", "da", "dd", "dtheta", "beta", "tx", "ty", "tz"),
}
#: DH parameters of A alone against B alone shown (the largest differences)
SHOWN_DIFFERENCES = 4
log = logging.getLogger("ur10_physics")


def _fit(data: MeasurementSet, effects: str):
    return fit(
        data,
        ROBOT,
        effects,
        accept_large=True,
        noise_mm=UR10_NOISE["noise_mm"],
        noise_ppm=UR10_NOISE["noise_ppm"],
    )


def _rms_mm(e: np.ndarray) -> float:
    return float(1e3 * math.sqrt(np.mean(np.sum(e**2, axis=1))))


def _reported(res) -> dict[str, dict[str, float | None]]:
    """The physical parameters the model has: value and standard error (None: not identified,
    or at the bound of a positive parameter)."""
    values, errors = res.parameters(), res.standard_errors()
    return {n: {"value": values[n], "std": errors[n]} for n in REPORTED if n in values}


def all_three(fitting: dict[str, MeasurementSet]) -> list[dict]:
    data = concatenate([fitting[k] for k in UR10_SERIES])
    out = []
    for m in MODELS:
        res = _fit(data, m)
        out.append(
            {
                "model": m,
                "poses": len(data),
                "fit_rms_mm": _rms_mm(res.residuals),
                "parameters": _reported(res),
            }
        )
        log.info("all three, %s: %.4f mm", m, out[-1]["fit_rms_mm"])
    return out


def similarity(pred: np.ndarray, meas: np.ndarray, scale: bool = True) -> tuple[float, np.ndarray]:
    """The scale s and the residuals of the similarity (s R p + t) of ``pred`` on ``meas`` that
    least-squares fits them (Umeyama): R from scipy's Kabsch, s in closed form (1 without
    ``scale``: the rigid motion)."""
    pc, mc = pred - pred.mean(axis=0), meas - meas.mean(axis=0)
    rot, _ = Rotation.align_vectors(mc, pc)
    rp = rot.apply(pc)
    s = float(np.sum(rp * mc) / np.sum(pc * pc)) if scale else 1.0
    return s, s * rp - mc


def _scored_points(v, data: MeasurementSet) -> tuple[np.ndarray, np.ndarray]:
    """(the predicted points, the measured ones) of the rows validation ``v`` scored: ``data``
    less the references that registered its station (:func:`benchmarks.real_data.validated`)."""
    meas = data.xyz if len(v.validation_residuals) == len(data) else reference_split(data)[1].xyz
    return meas + v.validation_residuals, meas


def leave_one_out(series, fitting) -> list[dict]:
    out = []
    for left in UR10_SERIES:
        train = concatenate([fitting[k] for k in UR10_SERIES if k != left])
        row: dict = {"left_out": left, "models": {}}
        for m in MODELS:
            res = _fit(train, m)
            v = validated(res, series[left])
            x = validated(res, series[left], extrapolate=True)
            assert v.validation_residuals is not None and x.validation_residuals is not None
            row["models"][m] = {
                "held_out_rms_mm": _rms_mm(v.validation_residuals),
                "extrapolated_rms_mm": _rms_mm(x.validation_residuals),
                "terms_left_out": list(v.validation_dropped),
            }
            if m == "geometric":
                # the station fitted on every scored row, rigid against a similarity: what a
                # free scale takes up (a diagnosis of the station, not a held-out figure)
                pred, meas = _scored_points(v, series[left])
                _, er = similarity(pred, meas, scale=False)
                s, es = similarity(pred, meas)
                row["station"] = {
                    "rigid_rms_mm": _rms_mm(er),
                    "similarity_rms_mm": _rms_mm(es),
                    "scale_ppm": 1e6 * (s - 1.0),
                }
            log.info("%s left out, %s: %s", left, m, row["models"][m])
        out.append(row)
    return out


def geometry_between(fitting) -> list[dict]:
    """The geometric fits of A alone and B alone: the DH parameters that differ most, in
    standard errors of the difference."""
    a, b = _fit(fitting["A"], "geometric"), _fit(fitting["B"], "geometric")
    va, vb = a.parameters(), b.parameters()
    sa, sb = a.standard_errors(), b.standard_errors()
    rows = []
    for n in va:
        if not n.startswith(("dalpha", "da", "dtheta", "dd", "beta")) or n not in vb:
            continue
        ea, eb = sa.get(n), sb.get(n)
        if ea is None or eb is None:
            continue
        z = (va[n] - vb[n]) / math.hypot(ea, eb)
        rows.append({"parameter": n, "A": va[n], "B": vb[n], "z": z})
    rows.sort(key=lambda r: -abs(r["z"]))
    return rows[:SHOWN_DIFFERENCES]


def _group(name: str, prefixes: tuple[str, ...]) -> bool:
    """Whether parameter ``name`` is of the group: by prefix, a length ``da`` not an angle
    ``dalpha``."""
    for pre in prefixes:
        if name.startswith(pre) and not (pre == "da" and name.startswith("dalpha")):
            return True
    return False


def what_moved(series, fitting) -> list[dict]:
    """Each fold's :data:`MOVED_MODEL` refitted on the whole left-out series, every parameter
    held at the two series' fit but the base (registered anew: the station is unseen) and one
    group of :data:`MOVED_GROUPS`; and the series' own fit of that model."""
    out = []
    for left in UR10_SERIES:
        train = concatenate([fitting[k] for k in UR10_SERIES if k != left])
        res = _fit(train, MOVED_MODEL)
        values = {
            str(n): float(v)
            for n, v in zip(res.model.layout.names, res.params, strict=True)
            if not (str(n).startswith("b") and not str(n).startswith("beta"))
        }
        row: dict = {"left_out": left, "groups": {}}
        for label, prefixes in {"the base alone": (), **MOVED_GROUPS}.items():
            free = [n for n in values if _group(n, prefixes)]
            r = fit(
                series[left],
                ROBOT,
                MOVED_MODEL,
                start=values,
                fixed=[n for n in values if n not in free],
                outliers="keep",
                accept_large=True,
                noise_mm=UR10_NOISE["noise_mm"],
                noise_ppm=UR10_NOISE["noise_ppm"],
            )
            row["groups"][label] = {"rms_mm": float(r.rms_mm), "free": len(free)}
        own = fit(
            series[left],
            ROBOT,
            MOVED_MODEL,
            outliers="keep",
            accept_large=True,
            noise_mm=UR10_NOISE["noise_mm"],
            noise_ppm=UR10_NOISE["noise_ppm"],
        )
        row["own_fit_rms_mm"] = float(own.rms_mm)
        log.info("%s left out, what moved: %s", left, row)
        out.append(row)
    return out


def _value(p: str, v: float) -> str:
    if p.startswith(("da", "dd")) and not p.startswith("dalpha"):
        return f"{1e3 * v:.3f} mm"
    return f"{1e3 * v:.3f} mrad"


def markdown(report: dict) -> str:
    lines = [
        "# What moves the UR10 between sessions",
        "",
        f"Made by `python benchmarks/ur10_physics.py` (`make real-data`) in "
        f"{report['wall_s']:.0f} s on {report['machine']}.",
        "Data: data/ur10 (Landgraf et al. 2021, MIT), fitted on "
        + ", ".join(f"{k} {n}" for k, n in report["fit_poses"].items())
        + " poses (A and B subsampled as real_data.py does, seed 0); noise stated "
        f"{UR10_NOISE['noise_mm']} mm + {UR10_NOISE['noise_ppm']} um/m; one base per tracker "
        "station. RMS: 3-D, mm. A parameter without a standard error was not identified or sits at its bound (a compliance at 0).",
        "",
        f"**Fitted on all three series** ({report['all_three'][0]['poses']} poses)",
        "",
        "| model | fit RMS | parameters (value ± standard error) |",
        "|---|---|---|",
    ]
    for r in report["all_three"]:
        ps = ", ".join(
            f"{n} = {p['value']:.3g}" + ("" if p["std"] is None else f" ± {p['std']:.2g}")
            for n, p in r["parameters"].items()
        )
        lines.append(f"| `{r['model']}` | {r['fit_rms_mm']:.4f} | {ps} |")
    folds = report["leave_one_out"]
    lines += [
        "",
        "**Leave one series out** (fitted on the other two; held-out RMS on the left-out series "
        "as `--validate --references` does it: its station registered on 6 of its poses, which "
        "are not scored; and with every term extrapolated)",
        "",
        "| model | " + " | ".join(f"{f['left_out']} left out" for f in folds) + " |",
        "|---|" + "---|" * len(folds),
    ]
    for m in MODELS:
        cells = []
        for f in folds:
            r = f["models"][m]
            c = f"{r['held_out_rms_mm']:.4f}"
            if abs(r["extrapolated_rms_mm"] - r["held_out_rms_mm"]) > 5e-5:
                c += f" (extrapolated {r['extrapolated_rms_mm']:.4f})"
            cells.append(c)
        lines.append(f"| `{m}` | " + " | ".join(cells) + " |")
    lines += [
        "",
        "**The tracker's station** (the geometric fit of two series; the third's predicted "
        "points fitted to its measured ones, rigidly or with a scale, on every scored row: what "
        "a free scale takes up, not a held-out figure)",
        "",
        "| left out | rigid RMS | similarity RMS | scale (ppm) |",
        "|---|---|---|---|",
    ]
    for f in folds:
        s = f["station"]
        lines.append(
            f"| {f['left_out']} | {s['rigid_rms_mm']:.4f} | {s['similarity_rms_mm']:.4f} | "
            f"{s['scale_ppm']:+.0f} |"
        )
    lines += [
        "",
        "**The geometry itself** (geometric fits of A alone and B alone: the largest "
        "differences, in standard errors of the difference)",
        "",
        "| parameter | A | B | difference / its standard error |",
        "|---|---|---|---|",
    ]
    for r in report["geometry_a_b"]:
        p = r["parameter"]
        lines.append(f"| {p} | {_value(p, r['A'])} | {_value(p, r['B'])} | {r['z']:+.1f} |")
    moved = report.get("what_moved")
    if moved:
        lines += [
            "",
            f"**What the left-out session changed** (`{MOVED_MODEL}` fitted on the other two, "
            "refitted on the whole left-out series with every parameter held but its base and "
            "the group named; RMS on that series)",
            "",
            "| refitted on the left-out series | "
            + " | ".join(f"{m['left_out']} left out" for m in moved)
            + " |",
            "|---|" + "---|" * len(moved),
        ]
        for label in moved[0]["groups"]:
            lines.append(
                f"| {label} | "
                + " | ".join(f"{m['groups'][label]['rms_mm']:.4f}" for m in moved)
                + " |"
            )
        lines.append(
            "| the series' own fit (every parameter) | "
            + " | ".join(f"{m['own_fit_rms_mm']:.4f}" for m in moved)
            + " |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=OUT, help="where ur10_physics.md/.json go")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    from lab import LabWarning

    warnings.simplefilter("ignore", LabWarning)
    log.setLevel(logging.INFO)
    for name in ("lab", "arm"):
        logging.getLogger(name).setLevel(logging.ERROR)
    state = code_state(ROOT)  # before this script writes its own results
    t0 = time.perf_counter()
    series, fitting = series_for_fitting(np.random.default_rng(UR10_SEED))  # as real_data's
    report = {
        "commit": state["commit"],
        "clean": state["clean"],
        "machine": machine(),
        "fit_poses": {k: len(d) for k, d in fitting.items()},
        "noise": UR10_NOISE,
        "all_three": all_three(fitting),
        "leave_one_out": leave_one_out(series, fitting),
        "geometry_a_b": geometry_between(fitting),
        "what_moved": what_moved(series, fitting),
    }
    report["wall_s"] = time.perf_counter() - t0
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out / "ur10_physics.json", json.dumps(report, indent=2) + "\n")
    text = markdown(report)
    atomic_write_text(args.out / "ur10_physics.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
