"""Diagnosis: which physical effect does the model miss?

    d = diagnose(data, robot, "geometric", noise_mm=0.015)
    d.verdict        # "compliance", "none" or "unexplained"
    d.candidates     # every catalogued effect (per joint) tested, best first
    d.hints          # which measured variables the residual still depends on
    d.to_dict()      # the JSON of docs/format.md

Method. The model is fitted; its identifiable Jacobian columns ``J0`` span what it can explain.
Every effect of the catalogue (and any the user registered) that is not in the model becomes
candidates: one per joint for a per-joint effect, plus one with all its joints, one for a
global effect (thermal). Their Jacobian columns at the fitted parameters, with the current
model's columns projected out, are tested by the **F-test of nested linear models** (equivalent,
to first order, to the score / Lagrange-multiplier test of the added parameters: one
Gauss-Newton step from the fitted model): ``F = (SS_added / k) / (RSS_after / (3N - r - k))``.
Columns that the current model already explains, or whose typical-size effect beyond it stays
under the noise, are not testable (unidentifiable given the model) and are skipped.
One family-wise significance level ``alpha`` holds over all candidates (Holm's step-down
correction). A significant candidate must also **predict held-out poses** better than the model
alone: leave-one-pose-out residuals of the linearised model, from the (3 x 3) diagonal blocks of
the hat matrix, no refits. Significant, confirmed candidates rank by that held-out RMS.

**Cyclic errors** (the ``cyclic`` effect) are not tested whole: every joint's orders up to 64 per
turn are scanned (:mod:`lab.spectral`) and compete with the catalogued effects in the forward
selection below, term by term, at their own level (the candidates' share of ``alpha`` is split
equally between the catalogue's tests and the scan's); the orders a joint's sampling cannot
resolve, and those the data cannot tell from a chosen one, are named (``notes``).

**Plausibility**: a candidate whose parameters (or the explanation's, with it) would go beyond
the plausible bound of their kind at the linearised estimate is passed over (``implausible``),
as :func:`lab.fit` would refuse that model: what the diagnosis suggests, fit accepts.

The **explanation** is built by effect-level forward selection from that ranking: the best
effect, on the joints that each add significantly (given the ones before), then the next effect
given the first, while one is significant (Bonferroni over all candidates at every step) and
predicts held-out poses better. The verdict names the first effect chosen, unless ``noise_mm``
is known and even the whole explanation leaves a residual above the noise (chi-square, below):
then it is ``unexplained``, the catalogue explains part only. ``suggestion`` is the model to fit
next (``geometric,compliance[2,3]``); ``candidates`` lists the explanation first
(each entry tested given those before it), then every other candidate.

**The noise**: ``noise_mm`` as stated, else the scatter of the poses the data repeat
(:mod:`lab.repeatability`; then an F-test takes the chi-square test's place, that noise being
estimated too). When the explanation leaves a residual above the noise but nothing in it is
structure (no hint significant, no pose beyond the outlier radius of its own scale), the verdict
says so: the explanation's first effect, or ``noise`` when there is none, with the per-axis noise
the residual implies (``implied_noise_mm``), instead of ``unexplained``.

Otherwise, with the instrument's per-axis noise ``noise_mm`` known, a **chi-square test** of the
residual sum of squares with 3N minus the identifiable parameters as degrees of freedom says
whether the residual is noise (``none``) or not (``unexplained``); ``alpha`` is then split
equally between the candidates and this test, so that the false-alarm rate on a correct model
stays under ``alpha`` (Bonferroni). The default, 2 %, keeps it well inside 5 % (measured: 2 %
over 200 simulated campaigns); the catalogue's effects at the low end of their typical magnitude
(docs/format.md, parameter names) come out at p-values below 1e-50 with 200 poses, so the
stricter level costs them nothing. Without ``noise_mm`` the verdict comes from the candidate tests
alone.

**Outliers** (``outliers="auto"``): the fit leaves out those of its own residual, and the tests
those that stay beyond the rule of :mod:`lab.screening` once the model and every candidate may
explain the residual; both are named by row. A candidate the data or the arm cannot support (a
missing column, no mass model) is listed in ``skipped`` with the reason. The candidates' columns
are held once and tested in turn; none is kept between trials (:class:`lab.selection.
ForwardSelection`), so the memory stays a few KB per pose for the whole catalogue.

**Hints** score every measured variable (q1..q6, gravity torques tau1..tau6, t, temperature,
payload, dir1..dir6, target, and any other column) by how much of the remaining residual smooth
functions of it explain (adjusted R^2, with the F-test's p-value): harmonics 1-3 of an angle,
linear and quadratic terms of other variables, the sign of a direction; each function enters
times a fixed direction in the measurement frame and times the sensitivity of the point to each
joint angle, so both a Cartesian and a joint-angle error that depend on the variable show up.

It is one module, longer than most, because the method above is one test: its candidates, hints and
result types are built in the order it runs.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Unpack

import numpy as np
from scipy.optimize import brentq
from scipy.stats import chi2, ncx2

from arm.description import RobotDescription
from arm.effect_api import ArmSize
from arm.effects import Cyclic, Effect, cyclic_readings, plausible_bound_of, union_of
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from lab import blocks as _blocks
from lab.blocks import Blocks
from lab.candidates import (
    candidate_columns,
    candidate_groups,
    candidate_indices,
    compact,
    group_label,
    project_out,
)
from lab.identifiability import gram_factor, lower_inverse, orthonormal_basis, typical_magnitudes
from lab.options import LabOptions, OptionFields, check_alpha, resolve
from lab.repeatability import (
    NoiseFloor,
    Repeatability,
    implied_noise_text,
    noise_floor,
    noise_like,
    noise_p_value,
)
from lab.result import SCHEMA_VERSION, FitResult, Outlier
from lab.screening import Screen, annotate, screened
from lab.selection import DEPENDENT, ForwardSelection, f_test, hat_blocks, holm, press_rms
from lab.spectral import CyclicProblem, CyclicScan, CyclicScanner
from lab.transfer import block_column, blocked_text, confirm_groups, use_blocks

__all__ = ["Candidate", "Diagnosis", "Hint", "diagnose"]

log = logging.getLogger(__name__)

HARMONICS = 3  # sin/cos(k q), k = 1..HARMONICS, for the angle hints
MAX_EFFECT_STEPS = 6  # forward selection adds at most this many candidates
TIE = 1e-6  # held-out RMS within this share of each other: the same explanation


@dataclass(frozen=True)
class Candidate:
    """One tested effect: its name, joints (None for a global effect), the parameters tested,
    the training RMS after adding it (linearised), its held-out RMS and the F-test."""

    effect: str
    joints: tuple[int, ...] | None
    parameters: tuple[str, ...]
    rms_mm: float
    cv_rms_mm: float
    statistic: float
    p_value: float
    significant: bool = False
    confirmed: bool = False
    orders: tuple[int, ...] | None = None  # a cyclic error's orders (of its one joint)

    @property
    def label(self) -> str:
        if self.joints is None:
            return self.effect
        if self.orders is not None:
            return f"{self.effect}[{self.joints[0]}:{','.join(map(str, self.orders))}]"
        return f"{self.effect}[{','.join(map(str, self.joints))}]"

    def to_dict(self) -> dict:
        return {
            "effect": self.effect,
            "joints": None if self.joints is None else list(self.joints),
            "rms_mm": self.rms_mm,
            "p_value": self.p_value,
            "significant": self.significant,
            "cv_rms_mm": self.cv_rms_mm,
            "confirmed": self.confirmed,
            "parameters": list(self.parameters),
            "orders": None if self.orders is None else list(self.orders),
        }


@dataclass(frozen=True)
class Hint:
    """How much of the remaining residual depends on one measured variable."""

    variable: str
    score: float
    p_value: float

    def to_dict(self) -> dict:
        return {"variable": self.variable, "score": self.score, "p_value": self.p_value}


@dataclass
class Diagnosis:
    """The verdict on a model, with every candidate tested and the hints; see the module doc."""

    fit: FitResult
    verdict: str
    candidates: list[Candidate]
    hints: list[Hint]
    noise_mm: float | None
    alpha: float
    cv_rms_mm: float
    chi2_p_value: float | None
    chi2_p_value_after: float | None
    suggestion: str | None
    explanation: list[Candidate] = field(default_factory=list)
    outliers: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=int))
    n_tested: int = 0
    skipped: dict[str, str] = field(default_factory=dict)
    # every pose left out: by the fit (its own residual) and by the tests (the residual beyond
    # what the model and every candidate explain); ``outliers`` are their indices in the data
    outlier_list: list[Outlier] = field(default_factory=list)
    outliers_mode: str = "keep"
    outlier_rule: str | None = None
    # what the cyclic scan could not resolve: grid aliases, orders the data cannot tell apart
    notes: list[str] = field(default_factory=list)
    # parameters of the catalogue's candidates left out of the explanation: beyond the plausible
    # bound of their kind (lab.plausibility) given the others, as lab.fit would refuse them
    implausible: list[str] = field(default_factory=list)
    # where noise_mm came from ("stated", "repeated poses" or None), the scatter of repeated
    # poses where the data have them, and, when no structure is left but the residual is above
    # noise_mm, the per-axis noise the residual implies (mm)
    noise_source: str | None = None
    repeatability: Repeatability | None = None
    implied_noise_mm: float | None = None
    # with a session or station column: the chosen effects confirmed by blocked
    # cross-validation (lab.transfer): {"column", "models": [{"without", "blocked_rms_mm"}],
    # "dropped": effects that did not help on a block they were not fitted on}
    blocked_cv: dict | None = None
    # the smallest effect (its RMS beyond what the model absorbs, over the noise floor) that the
    # tests of these poses find nine times in ten (:func:`resolution`); None without a noise
    resolution: float | None = None

    @property
    def resolution_note(self) -> str | None:
        """Where the verdict names no effect, what it cannot have seen: ``an effect under 0.8x
        the floor is not resolved from 60 poses; measure more to resolve smaller ones``."""
        if self.resolution is None or self.verdict != "none":
            return None
        return (
            f"not resolved: an effect under {self.resolution:.2g}x the noise floor (its RMS "
            f"beyond the model) is not resolved from {self.fit.n_points} poses at this noise; "
            "measure more poses to resolve smaller ones"
        )

    @property
    def noise_note(self) -> str | None:
        """``no structure is left: the residual is noise of ..., 6 % above ...``, or None."""
        if self.implied_noise_mm is None or self.noise_mm is None:
            return None
        return implied_noise_text(self.implied_noise_mm, self.noise_mm, self.noise_source)

    @property
    def cyclic_orders(self) -> dict[int, list[int]]:
        """The cyclic errors of the explanation: joint -> orders per turn, ascending."""
        out: dict[int, list[int]] = {}
        for c in self.explanation:
            if c.orders is not None and c.joints is not None:
                out.setdefault(c.joints[0], []).extend(c.orders)
        return {j: sorted(ks) for j, ks in sorted(out.items())}

    @property
    def readings(self) -> list[str]:
        """What the explanation's cyclic errors usually are (one line per kind of order)."""
        return cyclic_readings(self.cyclic_orders)

    @property
    def effects(self) -> list[str]:
        return self.fit.effects

    @property
    def rms_mm(self) -> float:
        return self.fit.rms_mm

    @property
    def noise_floor_mm(self) -> float | None:
        """The 3-D RMS of a perfect model on held-out points: noise_mm * sqrt(3)."""
        return None if self.noise_mm is None else self.noise_mm * math.sqrt(3.0)

    @property
    def best(self) -> Candidate | None:
        return self.candidates[0] if self.candidates else None

    def to_dict(self) -> dict:
        """The JSON object of ``sixaxis lab diagnose --json`` (docs/format.md, diagnose)."""
        return {
            "schema_version": SCHEMA_VERSION,
            "effects": self.effects,
            "n_points": self.fit.n_points,
            "rms_mm": self.rms_mm,
            "noise_floor_mm": self.noise_floor_mm,
            "verdict": self.verdict,
            "candidates": [c.to_dict() for c in self.candidates],
            "hints": [h.to_dict() for h in self.hints],
            "cv_rms_mm": self.cv_rms_mm,
            "noise_mm": self.noise_mm,
            "chi2_p_value": self.chi2_p_value,
            "chi2_p_value_after": self.chi2_p_value_after,
            "alpha": self.alpha,
            "suggestion": self.suggestion,
            "skipped": dict(self.skipped),
            "outliers": [o.to_dict() for o in self.outlier_list],
            "outliers_mode": self.outliers_mode,
            "outlier_rule": self.outlier_rule,
            "duplicates": [d.to_dict() for d in self.fit.duplicates],
            "n_rows": self.fit.to_dict()["n_rows"],
            "n_tested": self.n_tested,
            "notes": list(self.notes),
            "implausible": list(self.implausible),
            "noise_source": self.noise_source,
            "repeatability": None if self.repeatability is None else self.repeatability.to_dict(),
            "implied_noise_mm": self.implied_noise_mm,
            "blocked_cv": self.blocked_cv,
            "resolution": self.resolution,
        }

    def summary(self) -> str:
        floor = f", noise floor {self.noise_floor_mm:.4f} mm" if self.noise_floor_mm else ""
        left = ""
        if self.outlier_list:
            shown = ", ".join(o.where for o in self.outlier_list[:10])
            more = ", ..." if len(self.outlier_list) > 10 else ""
            left = f" ({len(self.outlier_list)} outlier(s) left out: {shown}{more})"
        lines = [
            f"model {', '.join(self.effects)}: RMS {self.rms_mm:.4f} mm, held-out "
            f"{self.cv_rms_mm:.4f} mm{floor}{left}",
            f"verdict: {self.verdict}" + (f" (fit {self.suggestion})" if self.suggestion else ""),
        ]
        for c in self.candidates[:5]:
            flag = "significant" if c.significant else "not significant"
            lines.append(
                f"  {c.label:<22} RMS {c.rms_mm:.4f} mm, held-out {c.cv_rms_mm:.4f} mm, "
                f"p = {c.p_value:.3g} ({flag})"
            )
        lines.append("hints: " + ", ".join(f"{h.variable} {h.score:.2f}" for h in self.hints[:5]))
        lines += self.readings
        if self.blocked_cv is not None:
            lines.append(blocked_text(self.blocked_cv))
        if self.noise_note:
            lines.append(self.noise_note)
        if self.resolution_note:
            lines.append(self.resolution_note)
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------------
def diagnose(
    data: Screen | MeasurementSet | str | Path,
    robot: RobotDescription | str | Path | None = None,
    effects: str | Sequence[str | Effect] | None = None,
    *,
    options: LabOptions | None = None,
    alpha: float = 0.02,
    candidates: Sequence[str] | None = None,
    across_blocks: bool | None = None,
    **keywords: Unpack[OptionFields],
) -> Diagnosis:
    """Fit ``effects`` (default geometric) and test what they miss; see the module docstring.

    ``data``: a measurement set (or its file), screened once (:func:`lab.screen`: duplicates,
    the fit's outliers, and the poses beyond the model and every candidate, which the tests
    leave out), or a :class:`lab.Screen` made before (nothing screened again). The options
    (``noise_mm`` ... ``register``, or ``options=``) are :class:`lab.LabOptions`; ``noise_mm``
    (:data:`arm.noise.NOISE_MM`) also decides ``none`` against
    ``unexplained``. ``alpha``: the family-wise false-alarm rate. ``candidates``: effect names
    to test (default: every registered effect). ``across_blocks``: confirm the chosen effects by
    leaving each session (or station) out in turn, dropping those that do not help where they
    were not fitted (:mod:`lab.transfer`); None: where the data have at least
    :data:`lab.transfer.MIN_BLOCKS` of them.
    """
    check_alpha(alpha)
    opts = resolve(options, **keywords)
    s = screened(data, robot, effects, opts, candidates=candidates, tests=True)
    # the noise the tests use: the stated one, else the scatter of repeated poses
    floor = noise_floor(s.options.noise_mm, s.kept)
    res, data = s.fit, s.kept
    assert s.untested_rows is not None  # screened(tests=True) judged them
    if res.weighted and res.noise_ref is not None:  # stated by the rows' uncertainties
        floor = NoiseFloor(1e3 * res.noise_ref, "stated", floor.repeatability)
    noise_mm = floor.noise_mm
    cat, Q0 = _catalogue_problem(s)
    H0 = hat_blocks(Q0, cat.k_pose)
    cv0 = press_rms(cat.e0, H0)
    sel = ForwardSelection(cat.e0, cat.rss0, cat.dof0, H0, cv0)
    sigma = noise_mm * 1e-3 if noise_mm is not None else math.sqrt(cat.rss0 / max(cat.dof0, 1))
    alpha_c = alpha / 2 if noise_mm is not None else alpha
    # the cyclic errors' orders are scanned (lab.spectral) unless the candidates leave them out;
    # the catalogue's tests and the scan then share alpha_c equally (a union bound)
    scanning = _scans(s.candidates)
    alpha_cat = alpha_c / 2 if scanning else alpha_c
    Jq = _joint_jacobian(res, cat.inlier)
    hints = _hints(res, data, Q0, cat.e0, cat.rss0, cat.dof0, cat.inlier, Jq)
    cands, bases, keys = _tested_candidates(cat, sel, sigma, alpha_cat)
    n_tested = len(cands)
    scanner = _scanner(s, cat, Q0, Jq, alpha_c / 2, scanning)
    rejected: list[str] = []
    explanation = _forward(
        cands, bases, keys, sel, alpha_cat, scanner, cat.columns_of(s.options), rejected
    )
    chosen = [c for c in explanation if c.effect != Cyclic.name]
    scan = scanner.result()
    rejected += scan.implausible
    # the explanation first (each given the ones before it), then every other candidate
    picked = {(c.effect, c.joints) for c in chosen}
    cands = explanation + [c for c in cands if (c.effect, c.joints) not in picked]
    chi2_p = chi2_after = None
    if noise_mm is not None:  # chi-square against a stated noise, F against a measured one
        chi2_p = noise_p_value(cat.rss0, cat.dof0, floor)
        chi2_after = noise_p_value(sel.rss, sel.dof, floor)
    # above the noise after the explanation: is any structure left? The selection found no
    # more; the hints say whether the residual still depends on a measured variable
    implied = None
    if chi2_after is not None and chi2_after < alpha / 2:
        implied = _implied_noise(res, data, Q0, sel, cat.inlier, Jq, alpha / 2)
    del Q0
    blocked = None
    if explanation and use_blocks(s.kept, across_blocks):
        explanation, blocked = _confirm_across_blocks(s, res.model, explanation)
        cands = explanation + [c for c in cands if c not in explanation]
    verdict, suggestion = _verdict(res.model, explanation, chi2_p, chi2_after, implied, alpha)
    # every pose left out (by the screen: of the fit, and of the tests), by its index in the data
    # a candidate's note is said only of the model fitted or the one suggested
    speaking = {e.name for e in res.model.effects} | {c.effect for c in chosen}
    left_out = annotate(s.left_out, cat.full, s.data, effects=speaking)
    d = Diagnosis(
        fit=res,
        verdict=verdict,
        candidates=cands,
        hints=hints,
        noise_mm=noise_mm,
        alpha=alpha,
        cv_rms_mm=1e3 * cv0,
        chi2_p_value=chi2_p,
        chi2_p_value_after=chi2_after,
        suggestion=suggestion,
        explanation=explanation,
        outliers=np.array(sorted(o.index for o in left_out), dtype=int),
        n_tested=n_tested,
        skipped=cat.skipped,
        outlier_list=left_out,
        outliers_mode=s.options.outliers,
        outlier_rule=s.test_rule,
        notes=scan.notes() + _alternative_notes(scan),
        implausible=rejected,
        noise_source=floor.source,
        repeatability=floor.repeatability,
        implied_noise_mm=implied,
        blocked_cv=blocked,
        resolution=None
        if noise_mm is None
        else resolution(res.n_points, alpha_cat / max(n_tested, 1)),
    )
    log.info("%s", d.summary())
    return d


@dataclass
class _Catalogue:
    """The diagnosis's problem: the fit's residual rows ``e0`` (the poses the tests keep,
    ``inlier``) with the model's span projected out, its sum of squares and degrees of freedom;
    the model with every candidate (``full``) and the candidates' groups; every candidate's
    columns ``Jc`` (the model's span projected out; ``norms``, ``norms_p`` their norms before
    and after), ``cand`` their indices in ``full``'s layout and ``column`` the reverse; the
    candidates skipped, with why."""

    full: ErrorModel
    groups: list
    skipped: dict[str, str]
    cand: np.ndarray
    column: dict[int, int]
    Jc: np.ndarray
    norms: np.ndarray
    norms_p: np.ndarray
    e0: np.ndarray
    rss0: float
    dof0: int
    inlier: np.ndarray
    n: int
    k_pose: int

    def columns_of(self, options: LabOptions):
        """A function of a candidate's parameter names: its columns (the model's span
        projected out), nominal values and plausible bounds (none with ``accept_large``)."""
        full, p_full = self.full, self.full.nominal()
        size = ArmSize.of(full.robot)

        def columns_of(names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            idx = full.layout.indices(names)
            bounds = [
                None
                if options.accept_large
                else plausible_bound_of(full.effects[_effect_index(full, nm)], nm, size)
                for nm in names
            ]
            return (
                self.Jc[:, [self.column[int(i)] for i in idx]],
                p_full[idx],
                np.array([np.nan if b is None else b for b in bounds], dtype=float),
            )

        return columns_of


def _catalogue_problem(s: Screen) -> tuple[_Catalogue, np.ndarray]:
    """The diagnosis's problem for the screen ``s`` (:class:`_Catalogue`) and the orthonormal
    basis ``Q0`` of the model's identifiable columns (kept apart: the largest array, freed as
    soon as the tests are done)."""
    res, data = s.fit, s.kept
    assert s.untested_rows is not None
    model = res.model
    N = res.n_points
    full, groups, skipped = candidate_groups(model, data, s.candidates)
    inputs = full.inputs(data.q, data.columns, source=data.source)
    p = full.nominal()
    p[full.layout.indices(model.layout.names)] = res.params
    # the model's identifiable columns (scaled) and every candidate's, block by block: the
    # whole catalogue's Jacobian of 200k poses is 340 MB, and no copy of it is made
    cand = candidate_indices(full, groups)
    column = {int(j): k for k, j in enumerate(cand)}
    J0, Jc = candidate_columns(res, full, inputs, p, cand)
    # the fit's rows: the points, or the weighted rows (orientations too) of lab.observations,
    # whose common noise is the instrument's reference sigma
    rows_of = res.row_residuals
    k_pose = rows_of.shape[1]
    e = rows_of.reshape(-1).copy()
    # the poses the screen left out of the tests: they would look like a missing effect
    far = s.untested_rows
    inlier = np.ones(N, dtype=bool)
    inlier[far] = False
    n = int(inlier.sum())
    if far.size:
        keep3 = np.repeat(inlier, k_pose)
        J0, Jc, e = compact(J0, keep3), compact(Jc, keep3), e[keep3]
    Q0 = orthonormal_basis(J0, overwrite=True)
    del J0
    e0 = e - Q0 @ (Q0.T @ e)
    n_rows = 3 * n
    if res.weighted and res.observations is not None:
        n_rows = int(res.observations.measured[inlier].sum())  # rows not measured weigh 0
    norms = np.sqrt(np.einsum("ij,ij->j", Jc, Jc))
    project_out(Jc, Q0)  # every candidate column with the model's span projected out
    norms_p = np.sqrt(np.einsum("ij,ij->j", Jc, Jc))
    cat = _Catalogue(
        full, groups, skipped, cand, column, Jc, norms, norms_p, e0, float(e0 @ e0),
        n_rows - Q0.shape[1], inlier, n, k_pose,
    )  # fmt: skip
    return cat, Q0


def _tested_candidates(
    cat: _Catalogue, sel: ForwardSelection, sigma: float, alpha: float
) -> tuple[list[Candidate], list, list[int]]:
    """Every candidate group the model does not explain already, tested alone (F-test and
    held-out RMS given the model), judged by Holm's procedure at ``alpha``, best first; with
    each one's basis (a function: computed when tried) and key in the selection's remembered
    first trials. A group whose columns lie in the model's span, or move no point above the
    noise ``sigma`` at their typical size, is skipped."""
    typ = typical_magnitudes(cat.full)
    Jc, rss0, dof0 = cat.Jc, cat.rss0, cat.dof0
    tested: list[np.ndarray] = []  # each candidate's columns (of Jc) that were tested
    rows: list[Candidate] = []
    for g in cat.groups:
        idx = np.array([cat.column[int(i)] for i in cat.full.layout.indices(g.names)], dtype=int)
        nx, nxp = cat.norms[idx], cat.norms_p[idx]
        keep = (nxp > DEPENDENT * nx) & (nxp * typ[cat.cand[idx]] > sigma)
        if not keep.any():
            cat.skipped[group_label(g)] = "unidentifiable given the model"
            continue
        cols = idx[keep]

        def basis(cols: np.ndarray = cols) -> np.ndarray:
            return orthonormal_basis(Jc[:, cols], overwrite=True)

        t = sel.trial(basis, key=len(rows))
        if t is None:
            cat.skipped[group_label(g)] = "unidentifiable given the model"
            continue
        cv, pv, (Qc, _, ss, _) = t
        k = Qc.shape[1]
        F, _ = f_test(ss, k, rss0 - ss, dof0 - k)
        joints = g.joints
        if joints is not None and len(joints) > 1:  # the joints that were testable
            kept = {nm for nm, ok in zip(g.names, keep, strict=True) if ok}
            joints = tuple(j for j in joints if any(nm.endswith(str(j)) for nm in kept))
        names = tuple(nm for nm, ok in zip(g.names, keep, strict=True) if ok)
        tested.append(cols)
        rows.append(
            Candidate(
                effect=g.effect,
                joints=joints,
                parameters=names,
                rms_mm=1e3 * math.sqrt(max(rss0 - ss, 0.0) / cat.n),
                cv_rms_mm=1e3 * cv,
                statistic=F,
                p_value=pv,
            )
        )
    pvals = np.array([c.p_value for c in rows])
    sig = holm(pvals, alpha) if rows else np.zeros(0, dtype=bool)
    cv0 = sel.cv
    cands = [
        Candidate(**{**c.__dict__, "significant": bool(s), "confirmed": c.cv_rms_mm < 1e3 * cv0})
        for c, s in zip(rows, sig, strict=True)
    ]
    order = sorted(
        range(len(cands)),
        key=lambda i: (
            not (cands[i].significant and cands[i].confirmed),
            cands[i].cv_rms_mm if cands[i].significant and cands[i].confirmed else 0.0,
            cands[i].p_value,
        ),
    )
    bases = [lambda cols=tested[i]: orthonormal_basis(Jc[:, cols], overwrite=True) for i in order]
    return [cands[i] for i in order], bases, list(order)


def _scanner(
    s: Screen, cat: _Catalogue, Q0: np.ndarray, Jq: np.ndarray, alpha: float, scanning: bool
) -> CyclicScanner:
    """The cyclic errors' scan (lab.spectral) at ``alpha``, kept in step with the selection: it
    also judges the plausibility of every parameter of the explanation, catalogued or cyclic
    (without the scan, joints=(): no cyclic candidate, the same judge)."""
    data, n = s.kept, cat.n
    return CyclicScanner(
        CyclicProblem(
            residual=cat.e0,
            model=Q0,
            joint=Jq.reshape(-1, 6),
            pose=np.repeat(np.arange(n), Jq.shape[1]),
            q=data.q[cat.inlier] if n < s.fit.n_points else data.q,
            orthonormal=True,
        ),
        alpha=alpha,
        joints=(1, 2, 3, 4, 5, 6) if scanning else (),
        # accept_large: the user keeps large values, so nothing is passed over for them
        bound=None if s.options.accept_large else Cyclic({1: [1]}).plausible_bound("cs1_1"),
    )


def _verdict(
    model: ErrorModel,
    explanation: list[Candidate],
    chi2_p: float | None,
    chi2_after: float | None,
    implied: float | None,
    alpha: float,
) -> tuple[str, str | None]:
    """The verdict and the suggested model (the module docstring)."""
    if explanation:
        suggestion = _suggestion(model, explanation)
        # what the catalogue offers must bring the residual down to the noise, or leave noise
        # alone (then the noise is above the one stated)
        ok = chi2_after is None or chi2_after >= alpha / 2 or implied is not None
        return (explanation[0].effect if ok else "unexplained"), suggestion
    if chi2_p is not None and chi2_p < alpha / 2:
        return ("noise" if implied is not None else "unexplained"), None
    return "none", None


def _confirm_across_blocks(
    s: Screen, model: ErrorModel, explanation: list[Candidate]
) -> tuple[list[Candidate], dict]:
    """The explanation's effects (a cyclic effect's orders together) that help on a session or
    station they were not fitted on (lab.transfer); the others are dropped from it."""
    names = list(dict.fromkeys(c.effect for c in explanation))

    def build(keep: list[int]) -> str:
        return _suggestion(model, [c for c in explanation if names.index(c.effect) in keep])

    kept, table = confirm_groups(s.kept, s.robot, build, names, s.options)
    dropped = [n for i, n in enumerate(names) if i not in kept]
    return [c for c in explanation if names.index(c.effect) in kept], {
        "column": block_column(s.kept),
        "models": table,
        "dropped": dropped,
    }


RESOLUTION_POWER = 0.9  # the share of campaigns in which an effect at the resolution is found
RESOLUTION_PARAMETERS = 2  # a typical candidate's columns (one joint's sine and cosine, ...)


def resolution(n_poses: int, level: float, power: float = RESOLUTION_POWER) -> float:
    """The smallest effect, as the RMS of its 3-D displacement beyond what the model absorbs
    over the noise floor (``sigma sqrt(3)``), that a candidate's test at ``level`` (the
    catalogue's share of alpha over the candidates tested) finds with probability ``power`` from
    ``n_poses`` poses: with per-axis noise sigma, an effect of that RMS ``a`` adds a
    non-centrality ``n a^2 / sigma^2`` to a chi-square of :data:`RESOLUTION_PARAMETERS` degrees of
    freedom. The diagnosis's ``none`` means *not resolved* below it (measured against the
    verdicts of thousands of campaigns in ``results/lab_decisions.md``)."""
    k = RESOLUTION_PARAMETERS
    crit = float(chi2.isf(level, k))
    lam = brentq(lambda x: float(ncx2.sf(crit, k, x)) - power, 1e-6, 1e4)
    return math.sqrt(lam / max(int(n_poses), 1) / 3.0)


def _implied_noise(res, data, Q0, sel: ForwardSelection, inlier, Jq, alpha) -> float | None:
    """The per-axis noise (mm) that the residual left after the explanation implies, when it
    looks like noise: no measured variable explains any of it (the hints, Bonferroni at
    ``alpha``) and no pose lies beyond the outlier radius of that noise (a gross error is not
    noise); None when it does not."""
    left = _hints(res, data, [Q0, sel.Q], sel.e, sel.rss, sel.dof, inlier, Jq)
    if any(h.p_value <= alpha / max(len(left), 1) for h in left):
        return None
    if not noise_like(sel.e):
        return None
    return 1e3 * math.sqrt(sel.rss / max(sel.dof, 1))


def _scans(candidates: Sequence[str] | None) -> bool:
    """Whether the cyclic errors are among the candidates (all of them by default)."""
    if candidates is None:
        return True
    return any(str(c).strip().split("[")[0] == Cyclic.name for c in candidates)


def _effect_index(model: ErrorModel, name: str) -> int:
    return model.layout.effects.index(model.layout.effect_of(name))


def _forward(
    cands, bases, keys, sel: ForwardSelection, alpha, scanner: CyclicScanner, columns_of, rejected
) -> list[Candidate]:
    """Forward selection over the catalogue's effects and the cyclic errors' orders. Each step
    tries every candidate of the effects not yet chosen given those chosen, and the scan's next
    cyclic term; it takes the one that predicts held-out poses best among those significant at
    their level (an effect: ``alpha`` over all the catalogue's candidates, Bonferroni, at every
    step, so that a chance addition stays rare however many steps there are; a cyclic term: the
    scan's own, :mod:`lab.spectral`), that lower the held-out RMS and whose parameters stay
    plausible with those chosen (as :func:`lab.fit` judges them: ``scanner.implausible``; each
    one passed over is described in ``rejected``). An effect's joints are then settled by
    forward selection over its single joints (the same rule). Returns the explanation in the
    order chosen (an effect's joints merged), each with the F-test of its columns given those
    chosen before it and the training and held-out RMS after it."""
    chosen: list[Candidate] = []
    done: set[str] = set()
    level = alpha / max(len(cands), 1)
    n_effects = 0

    def fails(c: Candidate) -> bool:
        X, nominal, bounds = columns_of(c.parameters)
        bad = scanner.implausible(X, list(c.parameters), nominal, bounds)
        if bad and not any(r.startswith(c.label + ":") for r in rejected):
            rejected.append(f"{c.label}: {', '.join(bad)}")
        return bool(bad)

    def joins(c: Candidate) -> None:  # the scan learns the columns the selection took
        X, nominal, bounds = columns_of(c.parameters)
        scanner.add_columns(X, list(c.parameters), nominal, bounds)

    def best_of(live: list[int]):
        tried = []
        for i in live:
            t = sel.trial(bases[i], keys[i])
            if t is not None and t[1] <= level and t[0] < sel.cv:
                tried.append((t[0], t, i))
        tried.sort(key=lambda x: x[0])
        return next(((t, i) for _, t, i in tried if not fails(cands[i])), None)

    while True:
        live = [i for i, c in enumerate(cands) if c.effect not in done]
        best = best_of(live) if live and n_effects < MAX_EFFECT_STEPS else None
        term = scanner.propose()
        if best is None and term is None:
            break
        rss_before, dof_before = sel.rss, sel.dof
        # an effect tested whole (the catalogue's, a user's) wins a tie with a cyclic term
        if term is not None and (best is None or term.cv < best[0][0] * (1.0 - TIE)):
            chosen.append(_cyclic_step(sel, scanner, term))
            continue
        assert best is not None
        c = cands[best[1]]
        done.add(c.effect)
        n_effects += 1
        singles = [
            i
            for i in live
            if cands[i].effect == c.effect
            and cands[i].joints is not None
            and len(cands[i].joints) == 1
        ]
        joints: list[int] = []
        names: list[str] = []
        while singles:
            pick = _best_single(singles, bases, keys, sel, level)
            if pick is None:
                break
            singles.remove(pick[1])
            if fails(cands[pick[1]]):
                continue
            sel.add(pick[0][0], pick[0][2], bases[pick[1]])
            joins(cands[pick[1]])
            joints.append(cands[pick[1]].joints[0])
            names += cands[pick[1]].parameters
        if not joints:  # no single joint carries it alone: take the whole group
            sel.add(best[0][0], best[0][2], bases[best[1]])
            joins(c)
            names = list(c.parameters)
        F, pv = f_test(rss_before - sel.rss, dof_before - sel.dof, sel.rss, sel.dof)
        chosen.append(
            Candidate(
                effect=c.effect,
                joints=tuple(sorted(joints)) if joints else c.joints,
                parameters=tuple(sorted(names, key=names.index)),
                rms_mm=1e3 * math.sqrt(max(sel.rss, 0.0) / (sel.e.size // sel.H.shape[1])),
                cv_rms_mm=1e3 * sel.cv,
                statistic=F,
                p_value=pv,
                significant=True,
                confirmed=True,
            )
        )
    return chosen


def _cyclic_step(sel: ForwardSelection, scanner: CyclicScanner, term) -> Candidate:
    """The scan's cyclic ``term`` taken into the selection: the candidate it makes, with the
    F-test of its columns given those chosen before it."""
    rss_before, dof_before = sel.rss, sel.dof
    t = scanner.accept(term)
    proj = term.basis.T @ sel.e
    sel.add(
        term.cv,
        (
            term.basis,
            proj,
            float(proj @ proj),
            sel.H + hat_blocks(term.basis, sel.H.shape[1]),
        ),
    )
    F, pv = f_test(rss_before - sel.rss, dof_before - sel.dof, sel.rss, sel.dof)
    j, k = t.joint, int(t.order or 0)
    return Candidate(
        effect=Cyclic.name,
        joints=(j,),
        parameters=(f"cs{j}_{k}", f"cc{j}_{k}"),
        rms_mm=1e3 * math.sqrt(max(sel.rss, 0.0) / (sel.e.size // 3)),
        cv_rms_mm=1e3 * sel.cv,
        statistic=F,
        p_value=pv,
        significant=True,
        confirmed=True,
        orders=(k,),
    )


def _best_single(singles: list[int], bases, keys, sel: ForwardSelection, level: float):
    """The single joint (of ``singles``) that predicts held-out poses best among those
    significant at ``level`` that lower the held-out RMS: (its trial, its index), or None."""
    pick = None
    for i in singles:
        t = sel.trial(bases[i], keys[i])
        if t is not None and t[1] <= level and t[0] < sel.cv:
            if pick is None or t[0] < pick[0][0]:
                pick = (t, i)
    return pick


def _alternative_notes(scan: CyclicScan) -> list[str]:
    """``cyclic[1:27]: the data cannot tell it from order 26 of the same joint`` for each term
    with ties (those of other joints counted)."""
    out = []
    for t in scan.terms:
        if t.order is None or not t.alternatives:
            continue
        same = [o for jj, o in t.alternatives if jj == t.joint and isinstance(o, int)]
        others = len(t.alternatives) - len(same)
        text = f"orders {', '.join(map(str, same))} of the same joint" if same else ""
        if others:
            text += (" and " if text else "") + f"{others} candidate(s) of other joints"
        out.append(f"cyclic[{t.joint}:{t.order}]: the data cannot tell it from {text}")
    return out


def _suggestion(model: ErrorModel, chosen: list[Candidate]) -> str:
    """The model to fit next: the fitted effects plus the chosen candidates, joints merged (a
    cyclic error's orders merged per joint)."""
    return ",".join(e.label for e in union_of([*model.effects, *(c.label for c in chosen)]))


# --------------------------------------------------------------------------------------------------
def _standardise(v: np.ndarray) -> np.ndarray | None:
    sd = float(np.std(v))
    if not np.isfinite(sd) or sd < 1e-12 * max(1.0, float(np.max(np.abs(v)))):
        return None
    return (v - np.mean(v)) / sd


def hint_variables(res: FitResult, data: MeasurementSet) -> dict[str, np.ndarray]:
    """The measured variables and their smooth functions (N, K) that the hints regress on."""
    return dict(_hint_variables(res, data))


def _hint_variables(res: FitResult, data: MeasurementSet) -> Iterator[tuple[str, np.ndarray]]:
    q = data.q
    for j in range(6):
        kq = np.outer(q[:, j], np.arange(1, HARMONICS + 1))  # sin q, cos q, sin 2q, cos 2q...
        yield f"q{j + 1}", np.stack([np.sin(kq), np.cos(kq)], axis=2).reshape(len(q), -1)
    tau = res.inputs.tau
    for j in range(6):
        z = _standardise(tau[:, j])
        if z is not None:
            yield f"tau{j + 1}", np.column_stack([z, z**2])
    for name, v in data.columns.items():
        if name == "target":
            ids = np.unique(v)
            if len(ids) > 1:
                yield name, np.column_stack([(v == t).astype(float) for t in ids[1:]])
            continue
        if name.startswith("dir") and name[3:].isdigit():
            if np.std(v) > 0:
                yield name, (v - np.mean(v))[:, None]
            continue
        z = _standardise(v)
        if z is not None:
            yield name, np.column_stack([z, z**2])


def _max_hint_width(data: MeasurementSet) -> int:
    """An upper bound of the number of hint functions of ``data``'s variables."""
    width = 6 * 2 * HARMONICS + 6 * 2  # harmonics of q, tau and tau^2
    for name, v in data.columns.items():
        width += len(np.unique(v)) - 1 if name == "target" else 2
    return width


def _joint_jacobian(res: FitResult, inlier: np.ndarray) -> np.ndarray:
    """d point / d theta (N, 3, 6) at the fit, of the poses ``inlier``, block by block; of the
    fit's weighted rows (N, k, 6) where it has them (:mod:`lab.observations`)."""
    obs = res.observations if res.weighted else None
    Jq = np.empty((res.n_points, 3 if obs is None else obs.per_pose, 6))
    for sl, part in Blocks(res.model, res.inputs):
        if obs is None:
            Jq[sl] = res.model.joint_jacobian(part, res.params)[1]
        else:
            Jq[sl] = obs.joint_rows(res.model, part, res.params, sl)
    return Jq[inlier] if inlier.sum() < res.n_points else Jq


def _hints(res, data, Q0, e0, rss0, dof0, inlier, Jq) -> list[Hint]:
    """(``Q0``: the model's orthonormal columns, one array or a list of blocks of columns.)"""
    """Score each variable's block ``phi_k(v) * direction_d`` by the F-test of adding it to the
    fitted model. The block's Gram matrices come from the Kronecker structure (per pose
    ``D^T D``, ``Q0^T D``, ``e^T D``), so no (3N, K * 9) matrix is formed, and all variables go
    through three matrix products together, summed over blocks of poses (many small
    multithreaded BLAS calls stall on a busy machine; one product of 200k poses holds GBs)."""
    n = int(inlier.sum())
    obs = res.observations if res.weighted else None
    kp = Jq.shape[1]  # rows per pose: 3, or the weighted rows of lab.observations
    scale = None
    if obs is not None:  # each measured row's own direction, weighted as the rows are
        scale = np.ones((res.n_points, kp)) if obs.scale is None else obs.scale
        if n < res.n_points:
            scale = scale[inlier]
    rms = np.sqrt(np.mean(np.sum(Jq**2, axis=1), axis=0))
    js = [j for j in range(6) if rms[j] > 0]
    nd = kp + len(js)
    Qs = [Q0] if isinstance(Q0, np.ndarray) else [Q for Q in Q0 if Q.shape[1]]
    r0 = sum(Q.shape[1] for Q in Qs)

    names, spans = [], []
    width = 0
    Phi = np.empty((n, _max_hint_width(data)))  # the functions of every variable, side by side
    for name, phi in _hint_variables(res, data):
        # few poses: the lowest-order functions only, at most half the degrees of freedom
        K = min(phi.shape[1], max(1, dof0 // (2 * nd)))
        names.append(name)
        spans.append((width, K))
        Phi[:, width : width + K] = phi[inlier][:, :K] if n < res.n_points else phi[:, :K]
        width += K
    if not names:
        return []
    Phi = Phi[:, :width]
    n_pairs = sum(K * K for _, K in spans)
    Gall = np.zeros((n_pairs, nd * nd))
    Call = np.zeros((width, r0 * nd))
    ball = np.zeros((width, nd))
    size = _blocks.BLOCK
    for blk in (slice(a, min(a + size, n)) for a in range(0, n, size)):
        m = blk.stop - blk.start
        if scale is None:
            dirs = [np.broadcast_to(np.eye(3)[a], (m, 3)) for a in range(3)]
        else:  # each measured row's own direction, weighted as the rows are
            dirs = [np.eye(kp)[a] * scale[blk, a : a + 1] for a in range(kp)]
        dirs += [Jq[blk, :, j] / rms[j] for j in js]
        D = np.stack(dirs, axis=-1)  # (m, k, nd)
        Dt = D.transpose(0, 2, 1)
        M = np.matmul(Dt, D).reshape(m, nd * nd)
        rows = slice(kp * blk.start, kp * blk.stop)
        Qr = Qs[0][rows] if len(Qs) == 1 else np.hstack([Q[rows] for Q in Qs])
        Qb = Qr.reshape(m, kp, r0).transpose(0, 2, 1)
        Q0D = np.matmul(Qb, D).reshape(m, r0 * nd)
        eb = e0[kp * blk.start : kp * blk.stop].reshape(m, kp, 1)
        eD = np.matmul(Dt, eb)[:, :, 0]  # (m, nd)
        P = Phi[blk]
        pairs = np.hstack(
            [(P[:, c : c + K, None] * P[:, None, c : c + K]).reshape(m, -1) for c, K in spans]
        )
        Gall += pairs.T @ M  # (sum K^2, nd^2)
        Call += P.T @ Q0D
        ball += P.T @ eD  # (sum K, nd)
    Call = Call.reshape(-1, r0, nd)  # (sum K, r0, nd)
    out = []
    c = g = 0
    for name, (_, K) in zip(names, spans, strict=True):
        Gbb = Gall[g : g + K * K].reshape(K, K, nd, nd).transpose(0, 2, 1, 3).reshape(K * nd, -1)
        G0b = Call[c : c + K].transpose(1, 0, 2).reshape(r0, K * nd)
        b = ball[c : c + K].reshape(K * nd)
        c, g = c + K, g + K * K
        idx, L = gram_factor(Gbb - G0b.T @ G0b, DEPENDENT)
        k = idx.size
        if k == 0 or dof0 - k <= 0:
            continue
        z = lower_inverse(L) @ b[idx]
        ss = min(float(z @ z), rss0)
        _, pv = f_test(ss, k, rss0 - ss, dof0 - k)
        adj = 1.0 - ((rss0 - ss) / (dof0 - k)) / (rss0 / dof0)
        out.append(Hint(name, max(float(adj), 0.0), pv))
    out.sort(key=lambda h: (-h.score, h.p_value))
    return out
