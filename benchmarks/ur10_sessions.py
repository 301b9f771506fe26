"""A UR10 session left out, and k of its poses: what carries over between sessions, measured on
the real series without fitting anything on the rows scored.

    python benchmarks/ur10_sessions.py               # make real-data runs it after real_data.py
    python benchmarks/ur10_sessions.py --draws 2 --folds D --out /tmp/x     # one fold, quickly
    python benchmarks/ur10_sessions.py --folds A --out /tmp/a &   # the folds side by side, then
    python benchmarks/ur10_sessions.py --merge /tmp/[abd]/ur10_sessions.json  # joined in results/

Writes ``results/ur10_sessions.md`` and ``results/ur10_sessions.json`` (atomically, at the end),
naming the commit they came from and whether the tree was clean.

For each series L of ``data/ur10`` (A, B, D: each its own session and tracker station) left out:

* **The calibration** is made from the other two series whole, as docs/lab.md tells a user:
  the geometric fit (``lab.fit(..., "geometric")``: ``sixaxis lab fit B.csv D.csv --robot
  ur10_robot --noise-mm 0.015 --noise-ppm 6``) and the lab's path (``lab.screen``,
  ``lab.diagnose``, ``lab.discover``, then ``lab.fit`` of the discovery's suggestion with its
  module: ``sixaxis lab diagnose``, ``discover -o m.py``, ``fit --effects ... --effect-module
  m.py``), each the prior of an update (``lab.update.prior_of``: its covariance and the spread
  between the two sessions it was fitted on). Fitted once per fold, reused for every k and draw.
* **k = 0** (nothing of L fitted): :data:`REFERENCES` reference poses of L drawn at random
  register L's station (``FitResult.validate(rest, references=refs)``, ``--references``) and are
  left out of the score; the geometric calibration and the lab's are scored on the rest of L.
  The lab's **chosen** model is the one ``lab.prediction.expect`` chooses from the training rows
  alone (the lab's model, or the geometric one where the blocked check, each training session
  left out in turn, finds that its terms do not help: ``sixaxis lab fit ... --predict``); its
  **prediction** is ``expect``'s, made for the scored rows before they are read.
* **k = 20, 50, 100, 300** poses of L drawn at random, L's other poses scored:
  the **prior alone**: each calibration, L's station registered on the k poses as references
  (``validate(rest, references=poses)``, as at k = 0); beside it the lab's calibration as
  ``lab.update`` places it (its base fitted on the k poses, every term kept:
  ``Update.prior_result``, what ``lab update --validate`` prints as the calibration alone);
  the k poses **alone** (``lab.fit`` geometric; and the lab's path on them, as above), the
  **update** (``lab.update.update(prior, poses)``: ``sixaxis lab update CAL.toml NEW.csv``) of
  the lab's calibration and of the geometric one, and the update's **prediction**
  (``lab.uncertainty.predicted_rms(update, rest, unseen=False)``: ``lab update --predict``).

Each k has :data:`DRAWS` seeded draws (draw d of k for series L: ``default_rng([SEED, L, k,
d])``); each figure is the median over the draws with the worst draw beside it. A fit the lab
refuses on k poses (too few for its model) is counted as missing, and named. Held-out figures
are 3-D RMS in mm, validated as ``--validate`` does (terms that do not hold outside the fitted
domain left out of those rows).

The targets (issue 38), per fold and k, on the medians: the update never worse than the better
of the prior alone and the lab's path on the k poses alone by more than 5 %; at 0 < k <= 50,
better than both by 15 % at least; measured / predicted within [0.67, 1.5]; at k = 0 the
chosen model never above the geometric one.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import math
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from arm.files import atomic_write_text
from arm.measurements import MeasurementSet, concatenate
from benchmarks._report import code_state, machine
from benchmarks.real_data import (
    UR10,
    UR10_NOISE,
    UR10_REFERENCES,
    UR10_SERIES,
    _json,
    _read,
    _ur10_paths,
    lab_fit,
)

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results"
ROBOT = "ur10_robot"
KS = (0, 20, 50, 100, 300)
DRAWS = 10
SEED = 38
#: k = 0: the reference poses that register the left-out series' station (and stay unscored)
REFERENCES = UR10_REFERENCES
#: the figures of one draw, by column (None: that fit was refused on the k poses)
COLUMNS = {
    "geometric": "geometric calibration (prior alone)",
    "prior": "the lab's calibration (prior alone)",
    "prior_update": "the lab's calibration as lab.update places it (Update.prior_result)",
    "geometric_alone": "the k poses alone, geometric",
    "lab_alone": "the k poses alone, the lab's path",
    "update": "update of the lab's calibration",
    "update_geometric": "update of the geometric calibration",
    "predicted": "predicted",
}
log = logging.getLogger("ur10_sessions")


# -- one fold's calibration ------------------------------------------------------------------------
def _noise() -> dict[str, float]:
    return dict(UR10_NOISE)


def _geometric(data: MeasurementSet):
    """The geometric fit of ``data`` as a user makes it (``sixaxis lab fit``, the UR10's noise)."""
    return lab_fit(
        data, ROBOT, "geometric", None, UR10_NOISE["noise_mm"], noise_ppm=UR10_NOISE["noise_ppm"]
    )


def calibrate(train: MeasurementSet, work: Path, tag: str) -> dict[str, Any]:
    """The geometric calibration and the lab's path on ``train``, each with its prior
    (:func:`lab.update.prior_of`)."""
    from lab.update import prior_of

    t0 = time.perf_counter()
    geo, _, note = _geometric(train)
    rows = _ur10_paths(train, work, tag)
    labr = rows[-1].pop("result")
    for r in rows:
        r.pop("result", None)
    priors = {"geometric": prior_of(geo), "lab": prior_of(labr)}
    return {
        "geometric": _refits_once(geo),
        "lab": _refits_once(labr),
        "priors": priors,
        "path": rows,
        "seconds": time.perf_counter() - t0,
        "note": note,
    }


def _refits_once(result):
    """``result`` with its refits made once per set of terms: validating a row outside the
    fitted domain refits the calibration without the terms that do not hold there
    (``FitResult.without``), on every training row (13,000 where A is fitted), and every draw
    asks again for the same terms. The same terms give the same refit: the figures are those of
    the result as it is."""
    if result.refit is None:
        return result
    made: dict[tuple[str, ...], np.ndarray] = {}

    def refit(names):
        key = tuple(names)
        if key not in made:
            made[key] = result.refit(key)
        return made[key].copy()

    return dataclasses.replace(result, refit=refit)


# -- the figures of one draw -------------------------------------------------------------------------
def _rms(result, data: MeasurementSet, references: MeasurementSet | None = None) -> float:
    return float(result.validate(data, references=references).validation_rms_mm)


@contextlib.contextmanager
def _blocked_once():
    """``lab.prediction.expect`` runs its blocked check (each training session left out in turn,
    four fits, whose fits also give the folds' covariance) on every call; it depends on the
    training rows and the model alone, never on the target: computed once a fold and reused for
    each draw's target."""
    import lab.prediction as pred

    original = pred.blocked_folds_check
    cache: dict[tuple[int, int], Any] = {}

    def once(data, result, options=None):
        key = (id(data), id(result))
        if key not in cache:
            cache[key] = original(data, result, options)
        return cache[key]

    pred.blocked_folds_check = once
    try:
        yield
    finally:
        pred.blocked_folds_check = original


def k0_draw(cal: dict, train: MeasurementSet, left: MeasurementSet, rng) -> dict[str, Any]:
    """Nothing of the left-out series fitted: :data:`REFERENCES` of its poses register its
    station, the rest is scored."""
    from lab.options import LabOptions
    from lab.prediction import expect

    idx = rng.choice(len(left), REFERENCES, replace=False)
    refs = left.subset(np.sort(idx))
    rest = left.subset(np.setdiff1d(np.arange(len(left)), idx))
    e = expect(
        cal["lab"],
        train,
        rest,
        unseen=True,
        options=LabOptions(**_noise()),
        geometric=cal["geometric"],
        u=cal["priors"]["lab"].uncertainty,
    )
    out = {
        "geometric": _rms(cal["geometric"], rest, refs),
        "prior": _rms(cal["lab"], rest, refs),
        "chosen": "lab" if e.chosen == "model" else "geometric",
        "predicted": e.prediction.rms_mm,
        "band": [e.prediction.low_mm, e.prediction.high_mm],
        "blocked_mm": e.blocked,
    }
    out["measured"] = out["prior" if out["chosen"] == "lab" else "geometric"]
    return out


def _alone(poses: MeasurementSet, rest: MeasurementSet, work: Path, tag: str) -> dict[str, Any]:
    """The k poses fitted alone: geometric, and the lab's path (None: refused, with why)."""
    from arm.errors import SixAxisError

    out: dict[str, Any] = {}
    try:
        geo, _, _ = _geometric(poses)
        out["geometric_alone"] = _rms(geo, rest)
    except SixAxisError as exc:
        out["geometric_alone"], out["geometric_alone_refused"] = None, str(exc)[:200]
    try:
        rows = _ur10_paths(poses, work, tag)
        out["lab_alone"] = _rms(rows[-1]["result"], rest)
        out["lab_alone_effects"] = rows[-1]["effects"]
    except SixAxisError as exc:
        out["lab_alone"], out["lab_alone_refused"] = None, str(exc)[:200]
    return out


def k_draw(cal: dict, left: MeasurementSet, k: int, rng, work: Path, tag: str) -> dict[str, Any]:
    """k poses of the left-out series drawn, the rest scored: the prior alone, the poses alone,
    the updates and the update's prediction."""
    from lab.uncertainty import predicted_rms
    from lab.update import update

    idx = rng.choice(len(left), k, replace=False)
    poses = left.subset(np.sort(idx))
    rest = left.subset(np.setdiff1d(np.arange(len(left)), idx))
    t, c = time.perf_counter(), time.process_time()
    u = update(cal["priors"]["lab"], poses)
    seconds, cpu = time.perf_counter() - t, time.process_time() - c
    load = os.getloadavg()[0]  # what else ran: the wall time's context
    assert u.prior_result is not None
    ug = update(cal["priors"]["geometric"], poses)
    out = {
        # the calibration alone, its station registered on the k poses as references
        # (--references: the mechanism k = 0 uses), and as lab.update places it (its base
        # fitted on the k poses, every term of the calibration kept: Update.prior_result)
        "geometric": _rms(cal["geometric"], rest, poses),
        "prior": _rms(cal["lab"], rest, poses),
        "prior_update": _rms(u.prior_result, rest),
        "update": _rms(u.result, rest),
        "update_geometric": _rms(ug.result, rest),
        "predicted": predicted_rms(u.result, rest, unseen=False).rms_mm,
        "update_seconds": seconds,
        "update_cpu_seconds": cpu,
        "load_1min": load,
        "moved": u.moved,
        "loo_mm": u.choices.get("calibration"),
        "dropped": list(u.dropped),
        "released": list(u.released),
    }
    out["measured"] = out["update"]
    return out | _alone(poses, rest, work, tag)


# -- one fold --------------------------------------------------------------------------------------
def run_fold(series: dict[str, MeasurementSet], left: str, draws: int, work: Path) -> dict:
    train = concatenate([series[s] for s in UR10_SERIES if s != left])
    log.info("%s left out: calibrating on %d poses", left, len(train))
    c0 = time.process_time()
    cal = calibrate(train, work, f"_prior_without_{left.lower()}")
    out: dict[str, Any] = {
        "left_out": left,
        "train_poses": len(train),
        "left_out_poses": len(series[left]),
        "lab_effects": cal["path"][-1]["effects"],
        "lab_path": cal["path"],
        "calibration_seconds": cal["seconds"],
        "k": {},
    }
    if cal["note"]:
        out["note"] = cal["note"]
    with _blocked_once():
        for k in KS:
            runs = []
            for d in range(draws):
                rng = np.random.default_rng([SEED, ord(left), k, d])
                tag = f"_{left.lower()}_{k}_{d}"
                if k == 0:
                    runs.append(k0_draw(cal, train, series[left], rng))
                else:
                    runs.append(k_draw(cal, series[left], k, rng, work, tag))
            out["k"][str(k)] = {"draws": runs, "summary": summarise(runs)}
            log.info("%s left out, k = %d: %s", left, k, out["k"][str(k)]["summary"])
    out["cpu_seconds"] = time.process_time() - c0
    return out


# -- the summary -----------------------------------------------------------------------------------
def _stat(values: list[float | None]) -> dict[str, Any] | None:
    v = [x for x in values if x is not None and math.isfinite(x)]
    if not v:
        return None
    return {"median": float(np.median(v)), "worst": float(np.max(v)), "n": len(v)}


def summarise(runs: list[dict]) -> dict[str, Any]:
    s: dict[str, Any] = {c: _stat([r.get(c) for r in runs]) for c in [*COLUMNS, "measured"]}
    ratios = [r["measured"] / r["predicted"] for r in runs if r.get("predicted")]
    s["ratio"] = {
        "median": float(np.median(ratios)),
        "min": float(np.min(ratios)),
        "max": float(np.max(ratios)),
        "within": int(sum(0.67 <= x <= 1.5 for x in ratios)),
        "n": len(ratios),
    }
    if "chosen" in runs[0]:
        s["chosen_lab"] = int(sum(r["chosen"] == "lab" for r in runs))
    return s


def targets(fold: dict) -> dict[str, Any]:
    """The issue's targets on the medians of one fold (module docstring)."""
    out: dict[str, Any] = {}
    for k, entry in fold["k"].items():
        s = entry["summary"]
        t: dict[str, Any] = {}
        r = s["ratio"]["median"]
        t["prediction_in_band"] = bool(0.67 <= r <= 1.5)
        if k == "0":
            measured = s["measured"]["median"]
            t["chosen_not_above_geometric"] = bool(measured <= s["geometric"]["median"])
        else:
            upd = s["update"]["median"]
            rivals = [x["median"] for x in (s["prior"], s["lab_alone"]) if x is not None]
            best = min(rivals)
            t["update_over_best"] = upd / best
            t["update_within_5pct"] = bool(upd <= 1.05 * best)
            if int(k) <= 50:
                t["update_15pct_better_than_both"] = bool(
                    all(upd <= 0.85 * x for x in rivals) and s["lab_alone"] is not None
                )
        out[k] = t
    return out


# -- the report ------------------------------------------------------------------------------------
def _cell(s: dict | None) -> str:
    return "refused" if s is None else f"{s['median']:.3f} ({s['worst']:.3f})"


def markdown(report: dict) -> str:
    lines = [
        "# A UR10 session left out, and k of its poses",
        "",
        f"Made by `python benchmarks/ur10_sessions.py` (`make real-data`) in {report['wall_s']:.0f} s "
        f"({report['cpu_s']:.0f} s of CPU) on {report['machine']}"
        + ("" if report["clean"] else " (with local changes)")
        + (
            f"; {report['merged_runs']} runs of single folds, side by side, joined (`--merge`)"
            if report.get("merged_runs")
            else ""
        )
        + ".",
        "",
        "Each series of `data/ur10` left out in turn; the calibration from the other two whole "
        "(`lab.fit` geometric, and the lab's path: screen, diagnose, discover, fit). "
        f"k = 0: {REFERENCES} reference poses of the left-out series register its station and are "
        "not scored; k > 0: k poses of it drawn at random, its other poses scored. Nothing is "
        f"fitted on the rows scored. Held-out 3-D RMS in mm: the median of {report['draws']} "
        "draws, the worst draw in brackets. The lab's calibration per fold: "
        + "; ".join(
            f"{f['left_out']} left out: `{_short(f['lab_effects'])}`" for f in report["folds"]
        )
        + ".",
        "",
        "| left out | k | geometric calibration | the lab's calibration | the lab's calibration "
        "as lab.update places it | k alone: geometric | k alone: the lab's path | update | "
        "update of the geometric | moved | predicted | measured / predicted (median, range) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for f in report["folds"]:
        for k, e in f["k"].items():
            s = e["summary"]
            r = s["ratio"]
            lab = _cell(s["prior"])
            if k == "0":
                lab += f"; chosen in {s['chosen_lab']} of {r['n']} draws"
            moved = [d["moved"] for d in e["draws"] if "moved" in d]
            lines.append(
                f"| {f['left_out']} | {k} | {_cell(s['geometric'])} | {lab} | "
                + (
                    " | | | | | | "
                    if k == "0"
                    else f"{_cell(s['prior_update'])} | "
                    f"{_cell(s['geometric_alone'])} | {_cell(s['lab_alone'])} | "
                    f"{_cell(s['update'])} | {_cell(s['update_geometric'])} | "
                    + (f"{sum(moved)} of {len(moved)} | " if moved else " | ")
                )
                + f"{_cell(s['predicted'])} | {r['median']:.2f} ({r['min']:.2f}-{r['max']:.2f}) |"
            )
    lines += [
        "",
        "The calibrations alone are registered on the k poses as references (`--references`, "
        "as at k = 0); the column beside them is the lab's calibration as `lab.update` places "
        "it (its base fitted on the k poses, every term kept: what `lab update --validate` "
        "prints as the calibration alone). The targets compare the update with the first.",
        "",
        "Moved: the draws whose update moved the calibration's terms; in the others the "
        "new poses, each left out in turn, were predicted no better by moving them, and the "
        "update is the calibration as it is, its base placed (`Update.moved`).",
        "",
        "At k = 0 the prediction is that of the chosen model (lab.prediction.expect), "
        "and measured is the chosen model's figure; at k > 0 both are the update's "
        "(of the lab's calibration).",
        "",
        *_timing_lines(report),
        "## Targets (on the medians)",
        "",
    ]
    lines += _target_lines(report)
    return "\n".join(lines).rstrip() + "\n"


def _timing_lines(report: dict) -> list[str]:
    """The time an update of 50 poses took (issue 38's target: <= 5 s on the UR10)."""
    draws = [d for f in report["folds"] for d in f["k"].get("50", {}).get("draws", [])]
    times = [d["update_seconds"] for d in draws if "update_seconds" in d]
    if not times:
        return []
    cpu = [d["update_cpu_seconds"] for d in draws if "update_cpu_seconds" in d]
    load = [d["load_1min"] for d in draws if "load_1min" in d]
    priors = ", ".join(f"{f['train_poses']:,}" for f in report["folds"])
    text = (
        f"An update of 50 poses (`lab.update.update`, the lab's calibration as prior, fitted on "
        f"{priors} poses) took a median {float(np.median(times)):.2f} s, at most "
        f"{max(times):.2f} s over {len(times)} draws (wall clock"
    )
    if cpu and load:
        text += (
            f"; the process's CPU time a median {float(np.median(cpu)):.2f} s, at most "
            f"{max(cpu):.2f} s; the load average over the last minute at the updates "
            f"{min(load):.1f}-{max(load):.1f} on {os.cpu_count()} cores"
        )
    else:
        text += ", on this machine while the other folds ran beside it"
    return [text + ") (target <= 5 s).", ""]


def _target_lines(report: dict) -> list[str]:
    out = [
        "| left out | k | update / better of (prior, lab's path alone) | within 5 % | "
        "15 % better than both (0 < k <= 50) | measured / predicted in [0.67, 1.5] | "
        "chosen <= geometric (k = 0) |",
        "|---|---|---|---|---|---|---|",
    ]
    yes = {True: "yes", False: "**no**", None: ""}
    for f in report["folds"]:
        for k, t in f["targets"].items():
            ratio = t.get("update_over_best")
            out.append(
                f"| {f['left_out']} | {k} | {'' if ratio is None else f'{ratio:.2f}'} | "
                f"{yes[t.get('update_within_5pct')]} | "
                f"{yes[t.get('update_15pct_better_than_both')]} | "
                f"{yes[t['prediction_in_band']]} | {yes[t.get('chosen_not_above_geometric')]} |"
            )
    held = report["held"]
    out += ["", *(f"- {name}: **{'met' if ok else 'NOT met'}**" for name, ok in held.items())]
    return out


def _short(effects: str, limit: int = 70) -> str:
    return effects if len(effects) <= limit else effects[: limit - 3] + "..."


def _held(folds: list[dict]) -> dict[str, bool]:
    ts = [t for f in folds for t in f["targets"].values()]
    return {
        "update never worse than the better of (prior alone, lab's path alone) by > 5 %": all(
            t.get("update_within_5pct", True) for t in ts
        ),
        "update better than both by >= 15 % at 0 < k <= 50": all(
            t.get("update_15pct_better_than_both", True) for t in ts
        ),
        "measured / predicted in [0.67, 1.5]": all(t["prediction_in_band"] for t in ts),
        "k = 0: the chosen model never above the geometric": all(
            t.get("chosen_not_above_geometric", True) for t in ts
        ),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=DRAWS, help="draws per fold and k")
    ap.add_argument("--folds", default="".join(UR10_SERIES), help="the series left out (ABD)")
    ap.add_argument("--out", type=Path, default=OUT, help="where ur10_sessions.md/.json go")
    ap.add_argument(
        "--merge",
        type=Path,
        nargs="+",
        help="join the ur10_sessions.json of runs of single folds (--folds A, B, D run side by "
        "side, of one commit: each fold's draws are seeded by the fold) into --out; runs nothing",
    )
    args = ap.parse_args(argv)
    if args.merge:
        return _write(merge([json.loads(p.read_text()) for p in args.merge]), args.out)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    from lab import LabWarning

    warnings.simplefilter("ignore", LabWarning)
    log.setLevel(logging.INFO)
    for name in ("lab", "arm"):
        logging.getLogger(name).setLevel(logging.ERROR)
    state = code_state(ROOT)
    t0, c0 = time.perf_counter(), time.process_time()
    series = {k: _read(UR10 / f"series_{k}.csv", f"data/ur10/series_{k}.csv") for k in UR10_SERIES}
    folds = []
    with tempfile.TemporaryDirectory() as tmp:
        for left in args.folds:
            f = run_fold(series, left, args.draws, Path(tmp))
            f["targets"] = targets(f)
            folds.append(f)
    report = {
        "commit": state["commit"],
        "clean": state["clean"],
        "machine": machine(),
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "draws": args.draws,
        "ks": list(KS),
        "references": REFERENCES,
        "noise": UR10_NOISE,
        "seed": SEED,
        "folds": folds,
        "held": _held(folds),
    }
    return _write(report, args.out)


def _write(report: dict, out: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(
        out / "ur10_sessions.json", json.dumps(report, indent=2, default=_json) + "\n"
    )
    text = markdown(report)
    atomic_write_text(out / "ur10_sessions.md", text)
    print(text)
    return 0


def merge(reports: list[dict]) -> dict:
    """One report of the folds of ``reports`` (runs of single folds, of one commit and
    settings): the wall time is the longest run's, the CPU time their sum."""
    first = reports[0]
    same = ("commit", "clean", "draws", "ks", "references", "seed")
    for r in reports[1:]:
        bad = [k for k in same if r[k] != first[k]]
        if bad:
            raise SystemExit(f"error: the runs differ in {', '.join(bad)}: not one benchmark")
    order = {s: i for i, s in enumerate(UR10_SERIES)}
    folds = sorted((f for r in reports for f in r["folds"]), key=lambda f: order[f["left_out"]])
    return first | {
        "wall_s": max(r["wall_s"] for r in reports),
        "cpu_s": sum(r["cpu_s"] for r in reports),
        "folds": folds,
        "held": _held(folds),
        "merged_runs": len(reports),
    }


if __name__ == "__main__":
    raise SystemExit(main())
