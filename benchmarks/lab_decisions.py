"""How often the lab's decisions are right, over thousands of campaigns that nobody picked.

    python benchmarks/lab_decisions.py                 # 2,100 campaigns: results/lab_decisions.*
    python benchmarks/lab_decisions.py --count 100 --out /tmp/slice   # a seeded slice

The lab decides by rule: it refuses a campaign as contaminated, screens outliers, calls a
candidate significant, stops discovery and gives a verdict. Each campaign here is drawn from its
own recorded seed (``SEED0 + i``) over every dimension a user's campaign varies in:

* the effects: none (a clean campaign), one catalogued effect, or a pair of them, each on one or
  two of the joints it can act on (cyclic errors of one order from 2 to 40 per turn);
* each effect's size, 1x to 50x the noise floor (log-uniform; 15 % of them 0.03x to 1x, to find
  where the lab stops resolving): the RMS of what it moves beyond what the geometric model
  absorbs (its displacement with the geometric Jacobian's span projected out), over the floor
  ``sigma sqrt(3)``; a size beyond twice the high end of the effect's typical magnitude (no
  real arm's) is capped there and recorded as reached;
* 30 to 2,000 poses (log-uniform), noise from 5 to 50 um per axis;
* a payload that changes between poses (in a third of the campaigns), random approach
  directions (always measured), a temperature range of 0 to 25 K;
* a share (4 %, 30 to 120 poses: the simulation takes 0.25 s a pose) collected on the MuJoCo plant with the code ``sixaxis lab collect`` runs
  (:func:`envs.collect.collect_measurements`), some of them from two tracker stations or with a
  6-DoF probe; the rest from the error model (:class:`arm.errormodel.ErrorModel`);
* gross outliers (in a quarter of the campaigns, 0.5-20 % of the poses, 15-150 sigma off).

Each campaign is then handled as the printed output tells a user to: ``diagnose`` the geometric
model with the noise stated; while the verdict names an effect, fit the model it suggests and
diagnose again (at most four steps); where the verdict is ``unexplained``, run ``discover`` (its
printed next step); and, to count false discoveries, ``discover`` from the path's last model of
every campaign whose effects that model already holds. Recorded: every step's verdict, any
refusal, the last model's held-out (leave-one-out) RMS over the floor, and what discovery found.

Right answers. A campaign is *resolvable* when every planted effect is at least 5x the floor,
it has at least 100 poses and at most 10 % of them are planted gross outliers; there the right
verdict names a planted effect (``none`` on a clean campaign) and the printed path must end at
<= 1.2x the floor held out. A refusal is false when no gross outlier was planted. A discovery is
false when the last model already holds every planted effect on its joints (a cyclic error
with each of its orders; or none was planted). Below the
resolvable line the right answer may be "not resolved": the table of right verdicts by size and
poses shows where that line lies.

The records are appended to ``runs/lab_decisions-<commit>/records.jsonl`` as each campaign
ends, so an interrupted run resumes where it stopped (the seeds done are skipped); two worker
processes. The short "how often the lab is right" table of README.md and docs/lab.md is written
from the results by :func:`docs_block` (``--docs``; tests/test_lab_decisions.py keeps them equal).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import subprocess
import sys
import time
import warnings
from collections import Counter, defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from arm import seed_robot  # noqa: E402
from arm.description import RobotDescription  # noqa: E402
from arm.errormodel import ErrorModel  # noqa: E402
from arm.files import atomic_write_text  # noqa: E402
from arm.measurements import MeasurementSet  # noqa: E402
from arm.sampling import sample_parameters, sample_poses  # noqa: E402

SEED0 = 29_000_000
COUNT = 2100
WORKERS = 2
RUNS = ROOT / "runs"  # runs/lab_decisions-<commit>/records.jsonl
README = ROOT / "README.md"
LAB_DOC = ROOT / "docs" / "lab.md"
DOCS_BEGIN = "<!-- lab-decisions:begin -->"
DOCS_END = "<!-- lab-decisions:end -->"
OUT = ROOT / "results" / "lab_decisions"
EFFECTS = (
    "compliance",
    "transmission",
    "joint_scale",
    "backlash",
    "load_backlash",
    "thermal",
    "cyclic",
)
# the joints each effect can act on in the seed arm (compliance and load_backlash: those that
# gravity loads; the others: any)
JOINTS = {
    "compliance": (2, 3, 5),
    "load_backlash": (2, 3, 5),
    "transmission": (1, 2, 3, 4, 5),
    "joint_scale": (1, 2, 3, 4, 5),
    "backlash": (1, 2, 3, 4, 5),
    "cyclic": (1, 2, 3, 4, 5),
    "thermal": (),
}
PLANT_SHARE = 0.04  # of the campaigns collected on the MuJoCo plant (0.25 s a pose)
PLANT_POSES = (30, 120)
PLANT_SCENARIOS = ("geometric", "compliance", "transmission", "backlash", "thermal", "cyclic")
RESOLVABLE_SIZE = 5.0  # x the floor
RESOLVABLE_POSES = 100
MAX_PLANTED = 0.10
FLOOR_FACTOR = 1.2
MAX_STEPS = 4
CAP = 2.0  # x the high end of an effect's typical magnitude: the largest size planted
BELOW_SHARE = 0.15  # of the effects drawn at 0.03-1x the floor, to find the resolution line
SIZE_BINS = (0.0, 0.1, 0.3, 0.5, 1.0, 2.0, 5.0, 10.0, math.inf)
POSE_BINS = (30, 60, 100, 300, 1000, 2001)
TARGETS = {
    "false_refusals": ("<=", 0.0),
    "verdict_correct": (">=", 0.95),
    "next_step_floor": (">=", 0.95),
    "false_discoveries": ("<=", 0.03),
}


# -- one campaign -------------------------------------------------------------------------------
def draw(seed: int) -> dict[str, Any]:
    """The campaign of ``seed``: what is planted and how it is measured (no data yet)."""
    rng = np.random.default_rng([SEED0, seed])
    plant = bool(rng.random() < PLANT_SHARE)
    n = round(math.exp(rng.uniform(math.log(30), math.log(2000))))
    spec: dict[str, Any] = {
        "seed": seed,
        "source": "plant" if plant else "model",
        "noise_um": float(rng.uniform(5.0, 50.0)),
        "payload": bool(rng.random() < 1 / 3),
        "temperature_span": float(rng.uniform(0.0, 25.0)),
        "outlier_share": float(rng.uniform(0.005, 0.2)) if rng.random() < 0.25 else 0.0,
    }
    if plant:
        lo, hi = PLANT_POSES
        spec["n"] = min(n, round(math.exp(rng.uniform(math.log(lo), math.log(hi)))))
        spec["scenario"] = str(rng.choice(PLANT_SCENARIOS))
        spec["stations"] = int(rng.choice([0, 0, 2]))
        spec["orientation"] = bool(rng.random() < 0.25)
        spec["planted"] = []
        return spec
    spec["n"] = n
    kind = rng.choice(["clean", "one", "pair"], p=[0.2, 0.5, 0.3])
    names = [] if kind == "clean" else list(rng.choice(EFFECTS, 1 if kind == "one" else 2, False))
    planted = []
    for name in names:
        js = JOINTS[name]
        joints = sorted(rng.choice(js, min(len(js), int(rng.integers(1, 3))), replace=False))
        planted.append(
            {
                "effect": str(name),
                "joints": [int(j) for j in joints],
                "order": int(rng.integers(2, 41)) if name == "cyclic" else None,
                "size": float(
                    math.exp(rng.uniform(math.log(0.03), 0.0))
                    if rng.random() < BELOW_SHARE
                    else math.exp(rng.uniform(0.0, math.log(50.0)))
                ),
            }
        )
    spec["planted"] = planted
    return spec


def _label(p: dict[str, Any]) -> str:
    if p["effect"] == "thermal":
        return "thermal"
    if p["effect"] == "cyclic":
        return "cyclic[" + ";".join(f"{j}:{p['order']}" for j in p["joints"]) + "]"
    return f"{p['effect']}[{','.join(map(str, p['joints']))}]"


def _columns(spec: dict[str, Any], n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    cols = {f"dir{j}": rng.choice([-1.0, 1.0], n) for j in range(1, 7)}
    t0 = rng.uniform(15.0, 30.0)
    cols["temperature"] = t0 + spec["temperature_span"] * rng.random(n)
    cols["t"] = np.arange(n, dtype=float) * 10.0
    if spec["payload"]:
        cols["payload"] = rng.choice([0.0, *rng.uniform(0.5, 5.0, 2)], n)
    return cols


def visible_rms(model: ErrorModel, inputs, p: np.ndarray, names: list[str]) -> float:
    """The RMS 3-D displacement that the parameters ``names`` cause beyond the span of the
    geometric model's columns (what no geometric fit absorbs), at ``p``."""
    base = p.copy()
    base[model.layout.indices(names)] = model.nominal()[model.layout.indices(names)]
    d = (model.predict(inputs, p) - model.predict(inputs, base)).reshape(-1)
    _, J = model.predict(inputs, base, jacobian=True)
    geo = J[:, :, model.layout.slice("geometric")].reshape(d.size, -1)
    coef, *_ = np.linalg.lstsq(geo, d, rcond=None)
    r = d - geo @ coef
    return float(np.sqrt(np.sum(r**2) / (d.size / 3)))


def model_campaign(
    spec: dict[str, Any], robot: RobotDescription | None = None, seed0: int = SEED0
) -> tuple[MeasurementSet, list[dict[str, Any]]]:
    """The error model's campaign of ``spec`` on ``robot`` (default the seed arm): the data and
    the planted effects with the sizes reached (x the floor)."""
    rng = np.random.default_rng([seed0, spec["seed"], 1])
    robot = robot or seed_robot()
    labels = [_label(p) for p in spec["planted"]]
    truth = ErrorModel(robot, ",".join(["geometric", *labels]))
    geo = list(truth.layout.names[truth.layout.slice("geometric")])
    p = sample_parameters(truth, rng, only=geo)
    n = spec["n"]
    q = sample_poses(robot, n, rng)
    cols = _columns(spec, n, rng)
    inputs = truth.inputs(q, cols)
    sigma = spec["noise_um"] * 1e-6
    floor = sigma * math.sqrt(3)
    planted = []
    for pl, e in zip(spec["planted"], truth.effects[1:], strict=True):
        names = list(truth.layout.names[truth.layout.slice(e.name)])
        idx = truth.layout.indices(names)
        if e.name == "cyclic":
            unit = rng.normal(size=len(names))
            typical = np.full(len(names), 1e-4)
        else:
            draw_p = sample_parameters(truth, rng, only=names)
            unit = draw_p[idx] - truth.nominal()[idx]
            typical = np.array([max(e.typical_range(nm) or (0, 1e-4)) for nm in names])
        p[idx] = truth.nominal()[idx] + unit
        v = visible_rms(truth, inputs, p, names)
        scale = pl["size"] * floor / v if v > 0 else 0.0
        scale = min(scale, float(np.min(CAP * typical / np.maximum(np.abs(unit), 1e-300))))
        p[idx] = truth.nominal()[idx] + unit * scale
        planted.append(
            {**pl, "label": _label(pl), "size": visible_rms(truth, inputs, p, names) / floor}
        )
    xyz = truth.predict(inputs, p) + rng.normal(0.0, sigma, (n, 3))
    return MeasurementSet(q, xyz, cols, f"campaign {spec['seed']}"), planted


def plant_campaign(spec: dict[str, Any]) -> tuple[MeasurementSet, list[dict[str, Any]]]:
    """The MuJoCo plant's campaign of ``spec`` (as ``sixaxis lab collect`` measures it)."""
    from envs.collect import collect_measurements
    from envs.scenarios import draw_truth

    rng = np.random.default_rng([SEED0, spec["seed"], 2])
    nominal = seed_robot().to_modified()
    truth = draw_truth(spec["scenario"], nominal, rng)
    payloads = None
    if spec["payload"]:
        payloads = rng.choice([0.0, *rng.uniform(0.5, 3.0, 2)], spec["n"])
    data = collect_measurements(
        truth=truth,
        n=spec["n"],
        noise_mm=spec["noise_um"] * 1e-3,
        seed=spec["seed"],
        payloads=payloads,
        stations=spec["stations"],
        orientation=spec["orientation"],
    )
    floor = spec["noise_um"] * 1e-6 * math.sqrt(3)
    # the effects' sizes at the encoder readings, in the world frame (no station column)
    cols = {k: v for k, v in data.columns.items() if k != "station"}
    inputs = truth.model.inputs(data.q, cols)
    planted = []
    for e in truth.model.effects[1:]:
        names = list(truth.model.layout.names[truth.model.layout.slice(e.name)])
        v = visible_rms(truth.model, inputs, truth.params, names) / floor
        if v > 0.05:  # an effect the scenario holds at a size that moves the tool at all
            planted.append({"effect": e.name, "label": e.label, "size": v})
    return data, planted


def plant_outliers(data: MeasurementSet, spec: dict[str, Any]) -> tuple[MeasurementSet, int]:
    share = spec["outlier_share"]
    if not share:
        return data, 0
    rng = np.random.default_rng([SEED0, spec["seed"], 3])
    n = len(data)
    k = max(1, round(share * n))
    idx = rng.choice(n, k, replace=False)
    u = rng.normal(size=(k, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    xyz = data.xyz.copy()
    xyz[idx] += u * rng.uniform(15.0, 150.0, (k, 1)) * spec["noise_um"] * 1e-6
    return MeasurementSet(data.q, xyz, data.columns, data.source), k


def run_campaign(seed: int) -> dict[str, Any]:
    """One campaign, followed as its printed output says (module docstring); an exception of
    the lab's that no rule foresaw is recorded as the campaign's error, with what was known."""
    rec: dict[str, Any] = {**draw(seed), "n_outliers": 0, "refusal": None, "path": []}
    try:
        return _run_campaign(seed, rec)
    except Exception as exc:
        rec.update(
            error=f"{type(exc).__name__}: {exc}",
            held_out=None,
            discoveries=None,
            seconds=0.0,
        )
        return rec


def _run_campaign(seed: int, rec: dict[str, Any]) -> dict[str, Any]:
    import logging

    from lab import ContaminatedError, diagnose, discover
    from lab.errors import FitError

    logging.disable(logging.WARNING)
    warnings.simplefilter("ignore")
    t0, c0 = time.perf_counter(), time.process_time()
    spec = draw(seed)
    data, planted = plant_campaign(spec) if spec["source"] == "plant" else model_campaign(spec)
    rec["planted"] = planted
    data, k = plant_outliers(data, spec)
    rec["n_outliers"] = k
    noise_mm = spec["noise_um"] * 1e-3
    opts: dict[str, Any] = {"noise_mm": noise_mm}
    if spec.get("orientation"):
        opts["noise_mrad"] = 0.1
    floor_mm = noise_mm * math.sqrt(3)
    effects = "geometric"
    path = rec["path"]
    last = None
    try:
        for _ in range(MAX_STEPS):
            d = diagnose(data, "seed", effects, **opts)
            last = d
            path.append(
                {
                    "effects": effects,
                    "verdict": d.verdict,
                    "suggestion": d.suggestion,
                    "held_out": d.cv_rms_mm / floor_mm,
                    "left_out": len(d.outlier_list),
                    "resolution": getattr(d, "resolution", None),
                }
            )
            if d.verdict in ("none", "noise", "unexplained") or not d.suggestion:
                break
            effects = d.suggestion
    except ContaminatedError as exc:
        rec["refusal"] = str(exc)
    except FitError as exc:
        rec["error"] = str(exc)
    rec["held_out"] = path[-1]["held_out"] if path else None
    rec["discoveries"] = None
    held = {pl["effect"] for pl in planted}
    final = effects if last is not None else None
    if last is not None:
        have = {e.split("[")[0] for e in last.effects}
        if last.verdict == "unexplained" or held <= have:
            try:
                found = discover(data, "seed", ",".join(last.effects), **opts)
                rec["discoveries"] = [f"{t.expression} (joint {t.joint})" for t in found.terms]
                rec["discovery_verdict"] = found.verdict
            except FitError as exc:
                rec["discovery_error"] = str(exc)
        rec["final_effects"] = list(last.effects)
    rec["final"] = final
    rec["seconds"] = time.perf_counter() - t0
    rec["cpu_seconds"] = time.process_time() - c0
    return rec


# -- the verdicts ---------------------------------------------------------------------------------
def resolvable(r: dict[str, Any]) -> bool:
    return (
        r["n"] >= RESOLVABLE_POSES
        and r["n_outliers"] <= MAX_PLANTED * r["n"]
        and all(p["size"] >= RESOLVABLE_SIZE for p in r["planted"])
    )


def first_verdict(r: dict[str, Any]) -> str:
    if r["refusal"]:
        return "refused"
    if r.get("error") or not r["path"]:
        return "error"
    return r["path"][0]["verdict"]


def verdict_right(r: dict[str, Any]) -> bool:
    v = first_verdict(r)
    names = {p["effect"] for p in r["planted"]}
    return v in names if names else v == "none"


def reaches_floor(r: dict[str, Any]) -> bool:
    return r["held_out"] is not None and not r["refusal"] and r["held_out"] <= FLOOR_FACTOR


def _cyclic_terms(label: str) -> set[tuple[int, int]]:
    """The (joint, order) pairs of a cyclic label: ``cyclic[2:7,31;4:2-4]``."""
    inside = label[label.index("[") + 1 : -1] if "[" in label else ""
    out = set()
    for part in filter(None, inside.split(";")):
        j, _, orders = part.partition(":")
        for o in filter(None, orders.split(",")):
            lo, _, hi = o.partition("-")  # a run of orders: 9-11
            out |= {(int(j), k) for k in range(int(lo), int(hi or lo) + 1)}
    return out


def holds_planted(r: dict[str, Any]) -> bool:
    """Whether the path's last model holds every planted effect on its joints (a cyclic error:
    each of its joints' orders)."""
    final = r.get("final_effects")
    if final is None:
        return False
    cyclic = set().union(*(_cyclic_terms(e) for e in final if e.startswith("cyclic")))
    joints: dict[str, set[int] | None] = {}  # None: all joints
    for e in final:
        name, js = _joints(e)
        before = joints.get(name, set())
        joints[name] = None if js is None or before is None else before | js
    for p in r["planted"]:
        if p["effect"] == "cyclic":
            if not _cyclic_terms(p["label"]) <= cyclic:
                return False
            continue
        name, js = _joints(p["label"])
        if name not in joints:
            return False
        have = joints[name]
        if have is not None and (js is None or not js <= have):
            return False
    return True


def _joints(label: str) -> tuple[str, set[int] | None]:
    """An effect label's name and joints (None: every joint): ``compliance[2,3]``."""
    name, _, rest = label.partition("[")
    if not rest:
        return name, None
    return name, {int(j) for j in rest.rstrip("]").split(",") if j.strip().isdigit()}


def false_discovery(r: dict[str, Any]) -> bool | None:
    """True/False where discovery ran from a model that holds every planted effect; else None
    (a term found where the model lacks a planted effect, or a cyclic error's order, is the
    missing structure, not a false discovery)."""
    if r.get("discoveries") is None or not holds_planted(r):
        return None
    return bool(r["discoveries"])


def fraction(k: int, n: int) -> dict[str, Any]:
    if n:
        ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="exact")
        lo, hi = float(ci.low), float(ci.high)
    else:
        lo = hi = float("nan")
    return {"count": k, "of": n, "rate": k / n if n else None, "ci95": [lo, hi]}


def summarise(records: list[dict[str, Any]]) -> dict[str, Any]:
    clean_of = [r for r in records if r["n_outliers"] == 0]
    res = [r for r in records if resolvable(r)]
    fd = [r for r in records if false_discovery(r) is not None]
    fd_clean = [r for r in fd if not r["planted"]]
    fd_cat = [r for r in fd if r["planted"]]
    out = {
        "campaigns": len(records),
        "plant_campaigns": sum(r["source"] == "plant" for r in records),
        "false_refusals": fraction(sum(bool(r["refusal"]) for r in clean_of), len(clean_of)),
        "verdict_correct": fraction(sum(verdict_right(r) for r in res), len(res)),
        "next_step_floor": fraction(sum(reaches_floor(r) for r in res), len(res)),
        "false_discoveries": fraction(sum(bool(false_discovery(r)) for r in fd), len(fd)),
        "false_discoveries_clean": fraction(
            sum(bool(false_discovery(r)) for r in fd_clean), len(fd_clean)
        ),
        "false_discoveries_catalogue": fraction(
            sum(bool(false_discovery(r)) for r in fd_cat), len(fd_cat)
        ),
        "refusals_with_planted_outliers": fraction(
            sum(bool(r["refusal"]) for r in records if r["n_outliers"] > MAX_PLANTED * r["n"]),
            sum(r["n_outliers"] > MAX_PLANTED * r["n"] for r in records),
        ),
    }
    out["targets_met"] = {
        k: (out[k]["rate"] is not None)
        and (out[k]["rate"] <= v if op == "<=" else out[k]["rate"] >= v)
        for k, (op, v) in TARGETS.items()
    }
    return out


def failures(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every campaign that misses a target, with the reason."""
    out = []
    for r in records:
        why = []
        if r["refusal"] and r["n_outliers"] == 0:
            why.append("false refusal: " + r["refusal"].split(": ", 1)[-1][:160])
        if r.get("error"):
            why.append("error: " + r["error"][:160])
        if resolvable(r) and not verdict_right(r):
            why.append(f"verdict {first_verdict(r)}")
        if resolvable(r) and not reaches_floor(r) and not r["refusal"]:
            ho = r["held_out"]
            why.append(
                "path ends at "
                + (f"{ho:.2f}x the floor" if ho is not None else "no fit")
                + f" ({' -> '.join(s['verdict'] for s in r['path'])})"
            )
        if false_discovery(r):
            why.append("false discovery: " + ", ".join(r["discoveries"]))
        if why:
            out.append({"seed": r["seed"], "campaign": describe(r), "reason": "; ".join(why)})
    return out


def describe(r: dict[str, Any]) -> str:
    eff = ", ".join(f"{p['label']} {p['size']:.1f}x" for p in r["planted"]) or "clean"
    where = (
        f"plant {r['scenario']}"
        + (f", {r['stations']} stations" if r.get("stations") else "")
        + (", 6-DoF" if r.get("orientation") else "")
        if r["source"] == "plant"
        else "model"
    )
    extra = (", payload" if r["payload"] else "") + (
        f", {r['n_outliers']} gross" if r["n_outliers"] else ""
    )
    return f"{where}: {eff}; {r['n']} poses, {r['noise_um']:.0f} um{extra}"


def size_label(i: int) -> str:
    """The size bin ``i`` for people: ``< 0.3x``, ``0.3-0.5x``, ..., ``>= 10x``."""
    lo, hi = SIZE_BINS[i], SIZE_BINS[i + 1]
    if lo == 0:
        return f"< {hi:g}x"
    return f">= {lo:g}x" if math.isinf(hi) else f"{lo:g}-{hi:g}x"


def _bin(x: float, edges: tuple[float, ...]) -> int | None:
    for i in range(len(edges) - 1):
        if edges[i] <= x < edges[i + 1]:
            return i
    return None


def confusion(records: list[dict[str, Any]]) -> tuple[list[str], dict[str, Counter]]:
    """First verdicts by planted effect and size bin (single effects and clean campaigns,
    without more than the stated share of gross outliers)."""
    rows: dict[str, Counter] = defaultdict(Counter)
    for r in records:
        if r["n_outliers"] > MAX_PLANTED * r["n"]:
            continue
        if not r["planted"]:
            key = "clean"
        elif len(r["planted"]) == 1:
            p = r["planted"][0]
            b = _bin(p["size"], SIZE_BINS)
            key = f"{p['effect']} {'?' if b is None else size_label(b)}"
        else:
            key = "pairs"
        rows[key][first_verdict(r)] += 1
    cols = sorted({v for c in rows.values() for v in c}, key=lambda v: (v != "none", v))
    return cols, rows


def _row_order(key: str) -> tuple[int, str, int]:
    """Clean first, then each effect by size, pairs last."""
    if key == "clean":
        return (0, "", 0)
    if key == "pairs":
        return (2, "", 0)
    name, _, size = key.partition(" ")
    labels = [size_label(i) for i in range(len(SIZE_BINS) - 1)]
    return (1, name, labels.index(size) if size in labels else len(labels))


def resolution_table(records: list[dict[str, Any]]) -> list[list[str]]:
    """Right first verdicts by the smallest planted effect's size and the number of poses
    (campaigns with an effect, at most the stated share of gross outliers)."""
    cells: dict[tuple[int, int], list[bool]] = defaultdict(list)
    for r in records:
        if not r["planted"] or r["n_outliers"] > MAX_PLANTED * r["n"]:
            continue
        s = _bin(min(p["size"] for p in r["planted"]), SIZE_BINS)
        m = _bin(r["n"], POSE_BINS)
        if s is not None and m is not None:
            cells[(s, m)].append(verdict_right(r))
    table = []
    for s in range(len(SIZE_BINS) - 1):
        row = [size_label(s)]
        for m in range(len(POSE_BINS) - 1):
            v = cells.get((s, m), [])
            row.append(f"{100 * np.mean(v):.0f} % ({len(v)})" if v else "")
        table.append(row)
    return table


def resolution_check(records: list[dict[str, Any]]) -> str:
    """How often the first diagnosis named a planted effect, for single effects below and above
    the resolution the diagnosis states (campaigns without planted gross outliers)."""
    below, above = [], []
    for r in records:
        if len(r["planted"]) != 1 or r["n_outliers"] or not r["path"]:
            continue
        line = r["path"][0].get("resolution")
        if line is None:
            continue
        (below if r["planted"][0]["size"] < line else above).append(verdict_right(r))
    rows = [
        ["under the stated resolution", _share(below)],
        ["at or over it", _share(above)],
    ]
    return _md_table(["single effect", "named by the first diagnosis"], rows)


def _share(v: list[bool]) -> str:
    return f"{sum(v)} of {len(v)} ({100 * np.mean(v):.0f} %)" if v else "none"


def _md_table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _pct(f: dict[str, Any]) -> str:
    if not f["of"]:
        return "n/a (0 campaigns)"
    lo, hi = f["ci95"]
    return f"{f['count']} of {f['of']} ({100 * f['rate']:.1f} %, 95 % interval {100 * lo:.1f}-{100 * hi:.1f} %)"


def report(
    records: list[dict[str, Any]],
    summary: dict[str, Any],
    commit: str,
    minutes: float,
    records_commit: str | None = None,
) -> str:
    fails = failures(records)
    cols, conf = confusion(records)
    pose_hdr = [f"{POSE_BINS[i]}-{POSE_BINS[i + 1] - 1}" for i in range(len(POSE_BINS) - 1)]
    lines = [
        "# How often the lab is right",
        "",
        f"Measured by `benchmarks/lab_decisions.py` from clean commit {records_commit or commit}"
        + (
            f" (the report written from its records by commit {commit})"
            if records_commit and records_commit != commit
            else ""
        )
        + ": "
        f"{summary['campaigns']} campaigns drawn from seeds {SEED0} + 0..{COUNT - 1} "
        f"({summary['plant_campaigns']} collected on the MuJoCo plant, the rest from the error "
        f"model), {minutes:.1f} min of CPU time on 2 cores (2 worker processes). The script's docstring says how the "
        "campaigns are drawn and what counts as right; rerun any one with "
        "`python benchmarks/lab_decisions.py --seeds SEED`.",
        "",
        "## Targets",
        "",
        _md_table(
            ["decision", "measured", "target", "met"],
            [
                [
                    "false refusals (refused, no gross outlier planted)",
                    _pct(summary["false_refusals"]),
                    "0",
                    _yes(summary, "false_refusals"),
                ],
                [
                    f"right verdicts (effects >= {RESOLVABLE_SIZE:g}x the floor, >= {RESOLVABLE_POSES} poses)",
                    _pct(summary["verdict_correct"]),
                    ">= 95 %",
                    _yes(summary, "verdict_correct"),
                ],
                [
                    f"printed path reaching <= {FLOOR_FACTOR}x the floor held out (same campaigns)",
                    _pct(summary["next_step_floor"]),
                    ">= 95 %",
                    _yes(summary, "next_step_floor"),
                ],
                [
                    "false discoveries (model holds every planted effect)",
                    _pct(summary["false_discoveries"]),
                    "<= 3 %",
                    _yes(summary, "false_discoveries"),
                ],
                ["  of which on clean campaigns", _pct(summary["false_discoveries_clean"]), "", ""],
                [
                    "  of which on catalogue effects only",
                    _pct(summary["false_discoveries_catalogue"]),
                    "",
                    "",
                ],
                [
                    "refusals where > 10 % gross outliers were planted",
                    _pct(summary["refusals_with_planted_outliers"]),
                    "",
                    "",
                ],
            ],
        ),
        "",
        "## Verdicts by effect and size",
        "",
        "The first diagnosis's verdict (columns) by the effect planted and its size over the floor "
        "(rows; single effects and clean campaigns, all pose counts, at most 10 % gross outliers).",
        "",
        _md_table(
            ["planted", *cols],
            [[k] + [str(conf[k].get(c, "")) for c in cols] for k in sorted(conf, key=_row_order)],
        ),
        "",
        "## Where the lab cannot be right: the resolution line",
        "",
        "Right first verdicts (and campaigns) by the smallest planted effect's size over the floor "
        "(rows) and the number of poses (columns). Below the line the verdict `none` means "
        "*not resolved*, not *absent*; the diagnosis says so when a campaign is there.",
        "",
        _md_table(["size \\ poses", *pose_hdr], resolution_table(records)),
        "",
        "The diagnosis states its own line: where its verdict is `none` it prints the smallest "
        "effect it resolves from those poses at that noise (nine times in ten, by the power of its "
        "test). Against the campaigns:",
        "",
        resolution_check(records),
        "",
        f"## Every failing campaign ({len(fails)})",
        "",
    ]
    if fails:
        lines.append(
            _md_table(
                ["seed", "campaign", "reason"],
                [[str(f["seed"]), f["campaign"], f["reason"]] for f in fails],
            )
        )
    else:
        lines.append("None.")
    return "\n".join(lines) + "\n"


def _yes(summary: dict[str, Any], key: str) -> str:
    return "yes" if summary["targets_met"][key] else "**no**"


def readme_table(summary: dict[str, Any]) -> str:
    """The short "how often the lab is right" table of README.md and docs/lab.md."""
    rows = [
        ("refuses a campaign with no gross outlier", summary["false_refusals"]),
        (
            f"names the missing effect (>= {RESOLVABLE_SIZE:g}x the floor, >= {RESOLVABLE_POSES} poses)",
            summary["verdict_correct"],
        ),
        (f"printed path ends at <= {FLOOR_FACTOR}x the floor held out", summary["next_step_floor"]),
        ("discovers a term where nothing is missing", summary["false_discoveries"]),
    ]
    out = ["| the lab ... | how often | campaigns |", "|---|---|---|"]
    for what, f in rows:
        rate = "n/a" if f["rate"] is None else f"{100 * f['rate']:.1f} %"
        out.append(f"| {what} | {rate} | {f['count']} of {f['of']} |")
    return "\n".join(out)


def docs_block(data: dict[str, Any]) -> str:
    """The README's and docs/lab.md's section, from results/lab_decisions.json."""
    return (
        f"{DOCS_BEGIN}\n"
        "<!-- written by `python benchmarks/lab_decisions.py --docs` from "
        "results/lab_decisions.json; tests/test_lab_decisions.py keeps them equal -->\n"
        f"{data['readme_table']}\n\n"
        f"Measured on {data['campaigns']} campaigns drawn from recorded seeds (effects and pairs "
        "of them at 0.03-50x the noise floor, 30-2,000 poses, 5-50 um, payloads, temperatures, "
        f"stations, 6-DoF rows, gross outliers; {data['plant_campaigns']} on the MuJoCo plant), "
        f"from clean commit {data.get('records_commit', data['commit'])}: "
        "[results/lab_decisions.md](results/lab_decisions.md) lists every failing campaign "
        "with its seed.\n"
        f"{DOCS_END}\n"
    )


def update_docs(data: dict[str, Any], paths: tuple[Path, ...] = (README, LAB_DOC)) -> None:
    """Replace the section between the markers of each of ``paths`` with :func:`docs_block`
    (links made relative to each file)."""
    for path in paths:
        text = path.read_text()
        i, j = text.find(DOCS_BEGIN), text.find(DOCS_END)
        if i < 0 or j < 0:
            raise SystemExit(f"{path}: no {DOCS_BEGIN} ... {DOCS_END} section to write")
        block = docs_block(data)
        if path.parent != ROOT:
            block = block.replace("(results/", "(../results/")
        atomic_write_text(path, text[:i] + block.rstrip("\n") + text[j + len(DOCS_END) :])


# -- the run ----------------------------------------------------------------------------------------
def load(path: Path) -> dict[int, dict[str, Any]]:
    out: dict[int, dict[str, Any]] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            if line.strip():
                try:
                    r = json.loads(line)
                except json.JSONDecodeError:  # a line cut by an interrupted run
                    continue
                out[int(r["seed"])] = r
    return out


def run(
    seeds: list[int],
    records: Path,
    workers: int = WORKERS,
    campaign: Callable[[int], dict[str, Any]] | None = None,
    every: int = 50,
) -> list[dict[str, Any]]:
    """The records of ``seeds``: those in ``records`` kept, the others run by ``campaign``
    (default this benchmark's) in ``workers`` processes and appended as each ends (resumable)."""
    campaign = campaign or run_campaign
    done = load(records)
    todo = [s for s in seeds if s not in done]
    records.parent.mkdir(parents=True, exist_ok=True)
    if todo:
        ctx = mp.get_context("spawn")
        with records.open("a") as fh, ctx.Pool(workers, maxtasksperchild=50) as pool:
            for i, rec in enumerate(pool.imap_unordered(campaign, todo, chunksize=1)):
                fh.write(json.dumps(rec) + "\n")
                fh.flush()
                done[rec["seed"]] = rec
                if (i + 1) % every == 0:
                    print(f"{i + 1} of {len(todo)} campaigns", flush=True)
    return [done[s] for s in seeds]


def _commit() -> str:
    rev = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT
    )
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    return rev.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=COUNT, help="campaigns (seeds 0..count-1)")
    ap.add_argument("--first", type=int, default=0, help="the first seed")
    ap.add_argument("--seeds", type=int, nargs="*", help="rerun these seeds only (printed)")
    ap.add_argument("--records", type=Path, help="default runs/lab_decisions-<commit>/...")
    ap.add_argument("--out", type=Path, default=OUT, help="results path without suffix")
    ap.add_argument("--workers", type=int, default=WORKERS)
    ap.add_argument(
        "--docs", action="store_true", help="only write README.md's and docs/lab.md's table"
    )
    args = ap.parse_args()
    if args.docs:
        update_docs(json.loads(args.out.with_suffix(".json").read_text()))
        return
    if args.seeds:
        for s in args.seeds:
            print(json.dumps(run_campaign(s), indent=1))
        return
    seeds = list(range(args.first, args.first + args.count))
    commit = _commit()
    path = args.records or RUNS / f"lab_decisions-{commit}" / "records.jsonl"
    records = run(seeds, path, args.workers)
    # the cost on two cores of its own: the campaigns' CPU time over the two workers (the wall
    # time depends on what else the machine runs)
    minutes = sum(r.get("cpu_seconds", r["seconds"]) for r in records) / 60 / 2
    summary = summarise(records)
    fails = failures(records)
    made_by = path.parent.name.removeprefix("lab_decisions-")
    payload = {
        "schema_version": 1,
        "commit": commit,
        # the commit whose lab made the records (they are resumed by commit): the same as
        # ``commit`` unless the report was written again from them by a later one
        "records_commit": made_by,
        "seed0": SEED0,
        "seeds": [args.first, args.first + args.count],
        **summary,
        "cpu_minutes_on_2_cores": minutes,
        "failing": fails,
        "readme_table": readme_table(summary),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(payload, indent=1) + "\n")
    atomic_write_text(
        args.out.with_suffix(".md"), report(records, summary, commit, minutes, made_by)
    )
    if args.out == OUT and not commit.endswith("-dirty"):
        update_docs(payload)
    print(
        json.dumps(
            {
                k: payload[k]
                for k in (
                    "campaigns",
                    "false_refusals",
                    "verdict_correct",
                    "next_step_floor",
                    "false_discoveries",
                    "targets_met",
                )
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
