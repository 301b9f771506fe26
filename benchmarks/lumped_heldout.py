"""``lumped_compliance``'s choice judged on data its design never saw (issue 41).

    nice -n 10 python benchmarks/lumped_heldout.py                 # everything: results/lumped_heldout.*
    nice -n 10 python benchmarks/lumped_heldout.py --parts real --count 0   # the real folds alone
    SIXAXIS_REAL_DATA=DIR python benchmarks/lumped_heldout.py ...  # with the Rokae rows

The rule judged is the lab's, unchanged: the diagnosis tests ``lumped_compliance`` on an arm
without masses, its first group (:func:`arm.effects.lumped.first_group`) always free, the rest
of its base set freed only where a blocked cross-validation of the fitted rows says it predicts
better (:mod:`lab.lumped_choice`). It was designed while looking at four real folds (UR5 grid ->
random, the UR10 series A, B, D each left out: ``benchmarks/mass_free_compliance.py``) and 60,
then 300, drawn campaigns of the heavy arm ``r2000ic_like`` (``benchmarks/heavy_arm.py``, seeds
41,000,000 + 0..299). None of those is used here.

**Real folds**, each fitted on rows of one part and scored on another (3-D RMS, mm), with the
arm's masses removed for the lab (``compliance`` with the URDF's masses for comparison):

* UR5, the data set's split reversed: fitted on the 20 random poses, scored on the 1,000 grid ones;
* UR10, one series fitted (A: its draw of 1,000 poses, as ``real_data.py``) and each other one
  scored, registered on :data:`REFERENCES` of its poses drawn at random, which are not scored
  (``FitResult.validate(..., references=...)``);
* UR10, the three series split by joint-space region: in each series the rows below its median of
  q2 (the shoulder) and those above (likewise q3, the elbow), one side of all three fitted and the
  other scored (the same stations: nothing registered anew);
* Rokae (30 poses, no masses, not in this repository: ``--rokae`` or ``SIXAXIS_REAL_DATA`` as in
  ``real_data.py``): leave-one-out, every model and the diagnosis rerun without the pose scored.

Each fold fits ``geometric``; ``geometric,lumped_compliance`` as the lab fits it (the rule: which
of the rest it held is recorded); and, to judge the rule's choice between them, the first group
alone and the whole base set free. The diagnosis's choice: ``diagnose`` of ``geometric`` on the
fitted rows (the noise stated), its suggestion fitted and scored. Judged: the choice is *right*
when it names ``lumped_compliance`` where the rule's fit scores at least :data:`MARGIN` better
than geometric, or declines where it does not score better; within the margin either is right.
The rest's choice is right when it scores within the margin of the better of its two options.

**Drawn campaigns** (seeds :data:`SEED0` + i): the error model's campaigns of
``benchmarks/lab_decisions.py`` (:func:`lab_decisions.model_campaign`) on the seed arm, the UR5 and
the UR10 in turn (their masses make the truth), run as ``heavy_arm.py`` runs them
(:func:`heavy_arm.follow_path`: the lab given the arm without masses, the printed path followed).
Half plant ``compliance`` (joints 2, 3 or 2, 3, 5; 0.03x to 50x the floor), half do not; 40 % of
each one more catalogued effect; 60 to 1,000 poses, 10 to 50 um. Counted: gravity deflection in
the last model where compliance is >= 5x the floor (>= 100 poses), and where none was planted.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import heavy_arm as ha  # noqa: E402
import lab_decisions as ld  # noqa: E402

from arm.description import RobotDescription, load_robot  # noqa: E402
from arm.effects import parse_effects  # noqa: E402
from arm.effects.lumped import LumpedCompliance, base_columns, first_group, parameter_name  # noqa: E402
from arm.files import atomic_write_text  # noqa: E402
from arm.measurements import MeasurementSet, concatenate  # noqa: E402
from benchmarks._report import code_state, machine  # noqa: E402
from benchmarks.mass_free_compliance import without_masses  # noqa: E402
from benchmarks.real_data import (  # noqa: E402
    ROKAE_NOISE_MM,
    UR5,
    UR5_NOISE_MM,
    UR10_NOISE,
    UR10_SEED,
    UR10_SERIES,
    _read,
    _rokae_dir,
    _rokae_robot,
    lab_fit,
    series_for_fitting,
)
from lab import diagnose  # noqa: E402
from lab.errors import FitError  # noqa: E402

OUT = ROOT / "results" / "lumped_heldout"
SEED0 = 41_100_000
COUNT = 1800
ARMS = ("seed", "ur5", "ur10_robot")
PRESENT_SHARE = 0.5
OTHER_SHARE = 0.4
#: reference poses that register a left-out series' station (never scored)
REFERENCES = 30
#: a held-out RMS this much lower (relatively) is better; within it, the models are alike
MARGIN = 0.01
#: the target of issue 41 (deflection found where >= 5x the floor) and, for a false choice, the
#: lab's false-discovery bound (benchmarks/lab_decisions.py)
TARGETS = {"found": 0.95, "false": 0.03}
LUMPED = "geometric,lumped_compliance"
#: campaigns 0..995 judged the unchanged rule (bd358c7) before it was fixed: design for the fix
SEEN_BEFORE_FIX = 996
AFTER_FIX = f"campaigns {SEEN_BEFORE_FIX} and on"
#: what was held out of which rule (issue 41's history, said with the figures)
HELD_OUT = (
    "What was held out: the rule was designed on the UR5 grid -> random, the UR10 series left "
    "out and r2000ic_like campaigns 41,000,000 + 0..299, none of them here. Judged unchanged "
    "(bd358c7) on the UR5 reversed, the UR10 series across, Rokae and campaigns 0..995, it "
    "freed the rest on series B alone for a 1.6 % gain and missed A and D by 2.1x and 2.9x the "
    "first group's error, and freed all of it on 20 and 29 rows; fixed in c1fe753 "
    "(`lab.lumped_choice.REST_GAIN`, the rest held on too few rows). For the rule as fixed, "
    "those folds and campaigns are design; held out of it: the UR10 region split (kept back, "
    "first run here) and campaigns 996 and on."
)
log = logging.getLogger("lumped_heldout")


# -- real folds ---------------------------------------------------------------------------------
@dataclass
class Fold:
    """Rows fitted and rows scored; ``references`` register the scored rows' station."""

    name: str
    kind: str
    train: MeasurementSet
    test: MeasurementSet
    robot: RobotDescription
    noise: dict[str, float]
    references: MeasurementSet | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def _fit(fold: Fold, arm: RobotDescription, effects) -> tuple[Any, str]:
    noise = fold.noise
    res, _, note = lab_fit(
        fold.train, arm, effects, None, noise["noise_mm"], noise_ppm=noise.get("noise_ppm", 0.0)
    )
    return res, note


def _score(res, fold: Fold) -> np.ndarray:
    """The scored rows' 3-D errors, mm (references left out by validate itself)."""
    v = res.validate(fold.test, references=fold.references)
    return 1e3 * np.linalg.norm(v.validation_residuals, axis=1)


def _rest_names(arm: RobotDescription) -> tuple[list[str], list[str]]:
    first = first_group(arm)
    base = base_columns(arm)
    every = [parameter_name(j, t) for j in range(1, 7) for t in base[j]]
    return first, [n for n in every if n not in first]


def _diagnosis(fold: Fold, arm: RobotDescription) -> tuple[str, str]:
    noise = fold.noise
    kw = {"noise_mm": noise["noise_mm"], "noise_ppm": noise.get("noise_ppm", 0.0)}
    try:
        d = diagnose(fold.train, arm, "geometric", **kw)
    except FitError as exc:
        if "not a plausible model" not in str(exc):
            raise
        d = diagnose(fold.train, arm, "geometric", accept_large=True, **kw)
    return d.verdict, d.suggestion or "geometric"


class _Captured(logging.Handler):
    """The rule's own account of its blocked cross-validation (lab.lumped_choice logs it)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def _try(out: dict[str, Any], label: str, fold: Fold, arm: RobotDescription, effects) -> Any:
    """The fit of ``effects`` scored into ``out`` under ``label``; None where refused."""
    try:
        res, note = _fit(fold, arm, effects)
    except FitError as exc:  # refused (too few rows for its parameters, ...): scored as none
        out["notes"][label] = f"refused: {exc}"
        return None
    out["errors"][label] = _score(res, fold)
    if note:
        out["notes"][label] = note
    return res


def fold_errors(fold: Fold) -> dict[str, Any]:
    """Every model's scored errors on ``fold`` (mm per row), the rule's hold and the diagnosis."""
    bare = without_masses(fold.robot)
    first, rest = _rest_names(bare)
    out: dict[str, Any] = {"errors": {}, "notes": {}, "rest_held": None}
    _try(out, "geometric", fold, bare, "geometric")
    rule = logging.getLogger("lab.lumped_choice")
    cap, level = _Captured(), rule.level
    rule.addHandler(cap)
    rule.setLevel(logging.INFO)
    try:
        res = _try(out, "lumped (rule)", fold, bare, LUMPED)
    finally:
        rule.removeHandler(cap)
        rule.setLevel(level)
    out["cv"] = cap.messages[:1]
    if res is not None:
        out["rest_held"] = bool(set(rest) & set(res.identifiability.held))
    _try(out, "first group", fold, bare, ["geometric", LumpedCompliance(names=first)])
    _try(out, "whole base set", fold, bare, ["geometric", LumpedCompliance(names=first + rest)])
    if any(j.mass > 0 for j in fold.robot.joints):
        _try(out, "compliance (masses)", fold, fold.robot, "geometric,compliance")
    verdict, choice = _diagnosis(fold, bare)
    out["verdict"], out["choice"] = verdict, choice
    _try(out, "diagnosis's choice", fold, bare, choice)
    effects = parse_effects(choice)
    if any(e.name == "lumped_compliance" for e in effects):
        twin = [e for e in effects if e.name != "lumped_compliance"]
    else:
        twin = [*effects, LumpedCompliance()]
    _try(out, "choice's twin", fold, bare, twin)
    return out


def rms(e: Any) -> float:
    return float(np.sqrt(np.mean(np.asarray(e) ** 2)))


def _compare(with_: float, without: float) -> str:
    if with_ < without * (1 - MARGIN):
        return "helps"
    return "worse" if with_ > without * (1 + MARGIN) else "alike"


def judge(row: dict[str, Any]) -> dict[str, Any]:
    """On the scored rows: does lumped_compliance help geometric (alone), did the diagnosis
    decide right about it (its choice against the same choice with or without it), and did the
    rule pick the better of the first group and the whole base set?"""
    m, inf = row["rms_mm"], math.inf  # a refused model scores as no help
    alone = _compare(m.get("lumped (rule)", inf), m["geometric"])
    chosen = "lumped_compliance" in row["choice"]
    c, t = m.get("diagnosis's choice", inf), m.get("choice's twin", inf)
    if c == inf:
        choice = "choice refused"
    else:
        effect = _compare(c, t) if chosen else _compare(t, c)
        choice = {
            (True, "helps"): "right",
            (True, "worse"): "wrong",
            (False, "helps"): "missed",
            (False, "worse"): "right (declined)",
        }.get((chosen, effect), "alike")
    first, whole = m.get("first group", inf), m.get("whole base set", inf)
    if row["rest_held"] is None:
        rest = "refused"
    else:
        picked, other = (first, whole) if row["rest_held"] else (whole, first)
        rest = "right" if picked <= other * (1 + MARGIN) else "wrong"
    return {"alone": alone, "choice_judged": choice, "rest_judged": rest}


def _row(fold: Fold, out: dict[str, Any], scored: int) -> dict[str, Any]:
    row = {
        "fold": fold.name,
        "kind": fold.kind,
        "fitted": len(fold.train),
        "scored": scored,
        "rms_mm": {k: rms(v) for k, v in out["errors"].items()},
        "rest_held": out["rest_held"],
        "verdict": out["verdict"],
        "choice": out["choice"],
        "notes": out["notes"],
        "cv": out["cv"],
        **fold.extra,
    }
    return row | judge(row)


def run_fold(fold: Fold) -> dict[str, Any]:
    t0 = time.process_time()
    out = fold_errors(fold)
    row = _row(fold, out, len(out["errors"]["geometric"]))
    row["cpu_s"] = time.process_time() - t0
    log.info("%s: %s", fold.name, {k: round(v, 4) for k, v in row["rms_mm"].items()})
    return row


def ur5_reversed() -> Fold:
    train = _read(UR5 / "test.csv", "data/ur5/test.csv")
    test = _read(UR5 / "calibration.csv", "data/ur5/calibration.csv")
    noise = {"noise_mm": UR5_NOISE_MM}
    return Fold("UR5: random -> grid", "split reversed", train, test, load_robot("ur5"), noise)


def ur10_across() -> list[Fold]:
    """One series fitted, each other scored, registered on reference poses of its own."""
    series, fitted = series_for_fitting(np.random.default_rng(UR10_SEED))
    robot = load_robot("ur10_robot")
    rng = np.random.default_rng([UR10_SEED, 41])
    folds = []
    for a in UR10_SERIES:
        for b in UR10_SERIES:
            if a == b:
                continue
            refs = series[b].subset(np.sort(rng.choice(len(series[b]), REFERENCES, False)))
            folds.append(
                Fold(
                    f"UR10: {a} -> {b}",
                    "one series fitted, another scored",
                    fitted[a],
                    series[b],
                    robot,
                    UR10_NOISE,
                    refs,
                )
            )
    return folds


def ur10_regions() -> list[Fold]:
    """The series split at each one's median of q2 (then q3): one side fitted, the other scored."""
    _, fitted = series_for_fitting(np.random.default_rng(UR10_SEED))
    robot = load_robot("ur10_robot")
    folds = []
    for joint in (2, 3):
        sides: dict[str, list[MeasurementSet]] = {"low": [], "high": []}
        for k in UR10_SERIES:
            d = fitted[k]
            q = d.q[:, joint - 1]
            low = q < np.median(q)
            sides["low"].append(d.subset(np.flatnonzero(low)))
            sides["high"].append(d.subset(np.flatnonzero(~low)))
        for a, b in (("low", "high"), ("high", "low")):
            folds.append(
                Fold(
                    f"UR10: q{joint} {a} -> {b}",
                    "joint-space region",
                    concatenate(sides[a]),
                    concatenate(sides[b]),
                    robot,
                    UR10_NOISE,
                )
            )
    return folds


def rokae(folder: Path | None) -> dict[str, Any] | None:
    """Leave-one-out over the Rokae poses: each model and the diagnosis without the pose scored."""
    if folder is None:
        return None
    data = _read(folder / "measurements.csv", "rokae/measurements.csv")
    robot = _rokae_robot(folder)
    t0 = time.process_time()
    errors: dict[str, list[float]] = {}
    choices: dict[str, int] = {}
    held = 0
    notes: set[str] = set()
    for k in range(len(data)):
        keep = np.flatnonzero(np.arange(len(data)) != k)
        fold = Fold(
            f"Rokae {k}",
            "",
            data.subset(keep),
            data.subset([k]),
            robot,
            {"noise_mm": ROKAE_NOISE_MM},
        )
        out = fold_errors(fold)
        for label, e in out["errors"].items():
            errors.setdefault(label, []).append(float(e[0]))
        choices[out["choice"]] = choices.get(out["choice"], 0) + 1
        held += bool(out["rest_held"])
        notes |= {f"{m}: {n.split(':')[0]}" for m, n in out["notes"].items()}
    n = len(data)
    for label in [k for k, v in errors.items() if len(v) < n]:  # not one figure of every pose
        notes.add(f"{label}: refused in {n - len(errors.pop(label))} of {n} folds")
    row = {
        "fold": "Rokae: leave-one-out",
        "kind": "another arm (no masses)",
        "fitted": n - 1,
        "scored": n,
        "rms_mm": {k: rms(v) for k, v in errors.items()},
        "rest_held": None if "lumped (rule)" not in errors else held > n / 2,
        "rest_held_folds": held,
        "verdict": "",
        "choice": max(choices, key=lambda c: choices[c]),
        "choices": choices,
        "notes": {"(some folds)": "; ".join(sorted(notes))} if notes else {},
        "cv": [],
        "cpu_s": time.process_time() - t0,
    }
    return row | judge(row)


# -- drawn campaigns ----------------------------------------------------------------------------
def draw(seed: int) -> dict[str, Any]:
    """The campaign of ``seed``: the arm, whether compliance is planted, what else (no data)."""
    rng = np.random.default_rng([SEED0, seed])
    spec: dict[str, Any] = {
        "seed": seed,
        "source": "model",
        "arm": ARMS[seed % len(ARMS)],
        "n": round(math.exp(rng.uniform(math.log(60), math.log(1000)))),
        "noise_um": float(rng.uniform(10.0, 50.0)),
        "payload": False,
        "temperature_span": float(rng.uniform(0.0, 25.0)),
        "outlier_share": 0.0,
    }
    planted = []
    if rng.random() < PRESENT_SHARE:
        planted.append(ha._planted(rng, "compliance", [2, 3] if rng.random() < 0.5 else [2, 3, 5]))
    if rng.random() < OTHER_SHARE:
        planted.append(ha.other_effect(rng))
    spec["planted"] = planted
    return spec


def run_campaign(seed: int) -> dict[str, Any]:
    rec: dict[str, Any] = {**draw(seed), "path": [], "refusal": None}
    try:
        return ha.follow_path(rec, load_robot(rec["arm"]), SEED0)
    except Exception as exc:  # recorded, with what was known: a rule no one foresaw
        rec.update(error=f"{type(exc).__name__}: {exc}", held_out=None, seconds=0.0)
        return rec


def compliance_size(r: dict[str, Any]) -> float | None:
    return next((p["size"] for p in r["planted"] if p["effect"] == "compliance"), None)


def summarise(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Found where planted at >= 5x the floor (>= 100 poses), chosen where not planted, the path
    at the floor where every planted effect is >= 5x: over all arms and per arm."""

    def counts(rs: list[dict[str, Any]]) -> dict[str, Any]:
        big = [
            r
            for r in rs
            if r["n"] >= ld.RESOLVABLE_POSES and (compliance_size(r) or 0) >= ld.RESOLVABLE_SIZE
        ]
        small = [r for r in rs if (compliance_size(r) or math.inf) < 1.0]
        absent = [r for r in rs if compliance_size(r) is None]
        res = [r for r in rs if ld.resolvable({**r, "n_outliers": 0})]
        return {
            "campaigns": len(rs),
            "found": ld.fraction(sum(map(ha.deflection_found, big)), len(big)),
            "named": ld.fraction(sum(map(named, big)), len(big)),
            "found_below_floor": ld.fraction(sum(map(ha.deflection_found, small)), len(small)),
            "false": ld.fraction(sum(map(ha.deflection_found, absent)), len(absent)),
            "false_clean": _false(absent, other=False),
            "false_beside_other": _false(absent, other=True),
            "path_floor": ld.fraction(
                sum(r["held_out"] is not None and r["held_out"] <= ld.FLOOR_FACTOR for r in res),
                len(res),
            ),
            "refusals": sum(bool(r.get("refusal")) for r in rs),
            "errors": sum(bool(r.get("error")) for r in rs),
        }

    out = {"all": counts(records), "misses": [miss(r) for r in records if missed(r)]}
    out |= {a: counts([r for r in records if r["arm"] == a]) for a in ARMS}
    out[AFTER_FIX] = counts([r for r in records if r["seed"] >= SEEN_BEFORE_FIX])
    found, false = out["all"]["found"]["rate"], out["all"]["false"]["rate"]
    out["targets_met"] = {
        "found": found is not None and found >= TARGETS["found"],
        "false": false is not None and false <= TARGETS["false"],
    }
    return out


def named(r: dict[str, Any]) -> bool:
    """A step of the path suggested a gravity deflection (fitted or not: an ``unexplained``
    verdict ends the path before its suggestion is fitted)."""
    return any(
        e.split("[")[0] in ha.DEFLECTION
        for step in r["path"]
        for e in (step["suggestion"] or "").split(",")
    )


def missed(r: dict[str, Any]) -> bool:
    big = r["n"] >= ld.RESOLVABLE_POSES and (compliance_size(r) or 0) >= ld.RESOLVABLE_SIZE
    return big and not ha.deflection_found(r)


def miss(r: dict[str, Any]) -> str:
    sizes = ", ".join(f"{p['label']} {p['size']:.1f}x" for p in r["planted"])
    path = " -> ".join(s["verdict"] for s in r["path"]) or "no diagnosis"
    why = f"; refused: {r['refusal'].split(';')[0]}" if r.get("refusal") else ""
    return (
        f"seed {r['seed']}, {r['arm']}, {r['n']} poses: {sizes}; {path}"
        + (" (suggested)" if named(r) else "")
        + why
    )


def _false(absent: list[dict[str, Any]], other: bool) -> dict[str, Any]:
    rs = [r for r in absent if bool(r["planted"]) == other]
    return ld.fraction(sum(map(ha.deflection_found, rs)), len(rs))


# -- report -------------------------------------------------------------------------------------
def pct(f: dict[str, Any]) -> str:
    if not f["of"]:
        return "n/a"
    lo, hi = f["ci95"]
    return f"{f['count']} of {f['of']} ({100 * f['rate']:.1f} %, CI {100 * lo:.1f}-{100 * hi:.1f})"


COLUMNS = (
    "geometric",
    "compliance (masses)",
    "lumped (rule)",
    "first group",
    "whole base set",
    "diagnosis's choice",
    "choice's twin",
)


def real_lines(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "| fold | fitted / scored | "
        + " | ".join(COLUMNS)
        + " | rest (judged) | lumped alone | in the choice |",
        "|---|---|" + "---|" * len(COLUMNS) + "---|---|---|",
    ]
    for r in rows:
        m = r["rms_mm"]
        cells = " | ".join(f"{m[c]:.4f}" if c in m else "refused" for c in COLUMNS)
        held = {None: "-", True: "held", False: "free"}[r["rest_held"]]
        lines.append(
            f"| {r['fold']} | {r['fitted']} / {r['scored']} | {cells} | {held} "
            f"({r['rest_judged']}) | {r['alone']} | {r['choice_judged']} |"
        )
    lines += [
        "",
        "The diagnosis's choices (verdict: suggestion) and the rule's cross-validation:",
        "",
    ]
    for r in rows:
        choice = _choices(r["choices"]) if "choices" in r else f"{r['verdict']}: `{r['choice']}`"
        lines.append(f"- {r['fold']}: {choice}" + "".join(f"; {c}" for c in r.get("cv", [])))
    notes = [f"- {r['fold']}, {k}: {v}" for r in rows for k, v in r["notes"].items()]
    return lines + (["", "Notes:", "", *notes] if notes else [])


def _choices(c: dict[str, int]) -> str:
    return "; ".join(f"`{k}` x{v}" for k, v in sorted(c.items(), key=lambda kv: -kv[1]))


def drawn_lines(summary: dict[str, Any]) -> list[str]:
    lines = [
        "| arm | campaigns | found (>= 5x, >= 100 poses) | of them suggested | found (< 1x) "
        "| chosen where absent | of them: alone | beside another effect | path <= 1.2x the floor |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for a in ("all", *ARMS, AFTER_FIX):
        s = summary[a]
        lines.append(
            f"| {a} | {s['campaigns']} | {pct(s['found'])} | {pct(s['named'])} | "
            f"{pct(s['found_below_floor'])} | "
            f"{pct(s['false'])} | {pct(s['false_clean'])} | {pct(s['false_beside_other'])} | "
            f"{pct(s['path_floor'])} |"
        )
    s = summary["all"]
    lines += [
        "",
        f"Refused: {s['refusals']}; errors: {s['errors']}. Targets: found >= "
        f"{TARGETS['found']:.0%} ({'met' if summary['targets_met']['found'] else 'not met'}); "
        f"chosen where absent <= {TARGETS['false']:.0%} "
        f"({'met' if summary['targets_met']['false'] else 'not met'}). Found: a gravity "
        "deflection in the path's last model; suggested: named in a step's suggestion.",
    ]
    if summary["misses"]:
        lines += ["", "Not found (>= 5x, >= 100 poses):", ""]
        lines += [f"- {m}" for m in summary["misses"]]
    return lines


def markdown(payload: dict[str, Any]) -> str:
    lines = [
        "# lumped_compliance's choice on data its design never saw",
        "",
        f"Written by `benchmarks/lumped_heldout.py` at commit `{payload['commit']}`"
        f"{'' if payload['clean'] else ' (with local changes)'} on {payload['machine']}, "
        f"{payload['cpu_s'] / 60:.1f} min of CPU for the real folds"
        + (
            f" and {payload['drawn_cpu_s'] / 60:.1f} in the campaigns' workers (records "
            f"`runs/{payload['records']}`)"
            if "drawn_cpu_s" in payload
            else ""
        )
        + ". How the folds are made and judged: the script's docstring.",
        "",
        HELD_OUT,
    ]
    if payload.get("real"):
        lines += [
            "",
            "## Real folds",
            "",
            "Scored 3-D RMS, mm; the lab's models on the arm without masses, `compliance` with "
            "the URDF's; choice's twin: the diagnosis's choice without `lumped_compliance` where "
            "it holds it, with it where it does not. rest: what the rule did with the base set "
            "beyond the first group, judged against the better of its two options on the scored "
            f"rows (within {MARGIN:.0%}). lumped alone: the rule's `lumped_compliance` against "
            f"geometric (helps: {MARGIN:.0%} lower). in the choice: the diagnosis's decision on "
            "it, judged by its choice against the twin (right, wrong, missed, right (declined), "
            "or alike within the margin).",
            "",
            *real_lines(payload["real"]),
        ]
    if payload.get("rokae_note"):
        lines += ["", f"Rokae: {payload['rokae_note']}"]
    if payload.get("drawn"):
        lines += ["", "## Drawn campaigns", "", *drawn_lines(payload["drawn"])]
    return "\n".join(lines) + "\n"


def real_rows(parts: list[str], rokae_dir: Path | None) -> dict[str, Any]:
    t0 = time.process_time()
    folds = (ur10_across() if "real" in parts else []) + (
        ur10_regions() if "regions" in parts else []
    )
    if "real" in parts:
        folds.insert(0, ur5_reversed())
    out: dict[str, Any] = {"real": [run_fold(f) for f in folds]}
    if "rokae" in parts:
        row = rokae(_rokae_dir(rokae_dir))
        if row is None:
            out["rokae_note"] = "not run: give --rokae DIR or set SIXAXIS_REAL_DATA"
        else:
            out["real"].append(row)
    out["real_cpu_s"] = time.process_time() - t0
    return out


def earlier_rows(path: Path, payload: dict[str, Any]) -> dict[str, Any]:
    """The real rows of an earlier run of this same clean commit (a report redrawn, not refit)."""
    earlier = json.loads(path.read_text())
    if earlier.get("commit") != payload["commit"] or not earlier.get("clean"):
        raise SystemExit(f"error: {path.name} was not written by this clean commit")
    keys = ("real", "rokae_note", "real_cpu_s")
    return {k: earlier[k] for k in keys if k in earlier}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--parts", nargs="*", default=["real", "regions", "rokae", "drawn"])
    ap.add_argument("--count", type=int, default=COUNT, help="drawn campaigns")
    ap.add_argument("--workers", type=int, default=ld.WORKERS)
    ap.add_argument(
        "--rokae", type=Path, help="the converted Rokae folder (else $SIXAXIS_REAL_DATA)"
    )
    ap.add_argument(
        "--records", type=Path, help="default runs/lumped_heldout-<commit>/records.jsonl"
    )
    ap.add_argument(
        "--real-json",
        type=Path,
        help="take the real folds' rows from this run's .json (of this very commit), not refitted",
    )
    ap.add_argument("--out", type=Path, default=OUT, help="results stem (.md and .json)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    logging.getLogger("lab").setLevel(logging.WARNING)
    warnings.simplefilter("ignore")  # the lab's cautions; the figures are the result
    t0 = time.process_time()
    payload: dict[str, Any] = {**code_state(ROOT), "machine": machine()}
    if args.real_json:
        payload |= earlier_rows(args.real_json, payload)
    else:
        payload |= real_rows(args.parts, args.rokae)
    if "drawn" in args.parts and args.count:
        commit = ld._commit()
        path = args.records or ld.RUNS / f"lumped_heldout-{commit}" / "records.jsonl"
        records = ld.run(list(range(args.count)), path, args.workers, run_campaign, every=100)
        payload["drawn"] = summarise(records)
        payload["drawn_cpu_s"] = sum(r.get("cpu_seconds", 0.0) for r in records)
        payload["records"] = f"{path.parent.name}/{path.name}"
    payload["cpu_s"] = time.process_time() - t0 + payload.get("real_cpu_s", 0.0)
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(payload, indent=1) + "\n")
    atomic_write_text(args.out.with_suffix(".md"), markdown(payload))
    print(markdown(payload))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
