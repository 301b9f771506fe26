"""Discovery: the form of an effect that the catalogue lacks, found by sparse regression.

    d = discover(data, robot, "geometric", noise_mm=0.015)
    d.verdict           # "discovered", "none" or "unexplained"
    print(d.formulas)   # {2: "theta2 = q2 + 2.01e-4*sin(2*q2) - 1.0e-4*cos(2*q2)"}
    d.write_module("discovered.py")   # an effect class; fit with d.suggestion
    d.to_dict()         # the JSON of ``sixaxis lab discover --json``

Method.

1. **The model E** (default geometric) is fitted; its identifiable Jacobian columns span what it
   explains, and its residual (with that span projected out) is what is left to explain.
2. **A library of candidate terms**, each a joint-angle term ``theta_j = q_j + k * f(variables)``
   for one joint j and one function f of the measured variables (:func:`library_terms`):
   harmonics ``sin(m*q_j)``, ``cos(m*q_j)`` for m = 1..``order`` (default 64 per turn, fewer on
   a joint whose sampling resolves fewer: :func:`lab.spectral.resolvable_order`), ``q_j``; powers and
   the sign of the joint's gravity torque ``tau_j``, ``tau_j^2``, ``tau_j^3``, ``sign(tau_j)``;
   with a temperature column ``(temperature - 20)`` and its products with ``tau_j``,
   ``sin(q_j)``, ``cos(q_j)``; ``t``; ``payload``; ``dir_j`` and ``dir_j*tau_j``. A term's
   regressor is the joint-angle column of joint j of the identification Jacobian (d point /
   d theta_j, at the fitted parameters) times f, with E's span projected out; a term that E
   already explains (the column lies in E's span) or that moves no point is not a candidate.
   The sine and cosine of one harmonic are one candidate (the phase is unknown), every other
   term is one on its own.
3. **Orthogonal matching pursuit** over the candidates (:mod:`lab.spectral`: every joint's
   harmonics scanned at once as Fourier sums, the other terms beside them, no loop over
   candidates), by the F-test of nested linear models and leave-one-pose-out prediction: each
   step adds the candidate with the smallest p-value, if it is significant at ``alpha_t / M``
   (Bonferroni over the M candidates, at every step), lowers the held-out RMS and leaves every
   harmonic's amplitude within the cyclic effect's plausible bound (as :func:`lab.fit` judges
   it); the candidates the data cannot tell from it (ties within the chi-square quantile, a
   grid's aliases) are named. With the instrument's noise known, the residual is also tested
   against it by the chi-square test at ``alpha_c = alpha / 2``, the same test at the same level
   as the diagnosis's (so the two agree on whether anything is missing), and the terms get
   ``alpha_t = alpha / 4`` (:data:`TERMS_SHARE`, :data:`CHI2_SHARE`); without the noise the terms
   get both shares, ``3 alpha / 4``. The quarter left unspent is a margin: a method exactly at level ``alpha``
   measures at ``alpha`` on finite samples half the time (measured: 2.00 % over 1,200 fresh clean
   campaigns with ``alpha_t = alpha / 2``), this one at about three quarters of it.

   **The false-discovery rate, derived.** On data that E explains (Gaussian noise), the residual
   with E's span projected out is ``(I - P0) eps`` to first order, and a candidate's column is
   fixed given the poses: its F statistic follows F(k, dof - k) exactly and the residual's
   chi-square statistic chi2(dof) exactly (beyond first order, on the seed arm with 15 um of
   noise the residual differs from ``(I - P0) eps`` by 0.1-0.2 um RMS). Nothing is selected unless a first step is
   significant, so by Bonferroni P(some term) <= M * alpha_t / M = alpha_t, and by the union
   bound P(verdict != ``none``) <= alpha_t + alpha_c = 3 alpha / 4 <= alpha. Bonferroni is nearly tight here
   (the candidates are nearly independent in their upper tail), the held-out condition only
   removes selections. Measured on fresh campaigns, never used to choose anything:
   ``benchmarks/discovery_false_rate.py`` (results/benchmarks.md) and the slow test in
   ``tests/test_lab_discover.py``.

   Why not a library: scikit-learn's LassoLarsIC (AIC/BIC) and OrthogonalMatchingPursuitCV and
   pysindy's STLSQ choose sparsity by prediction error or an information criterion, which
   admits a chance term in most clean data sets once the library holds a hundred candidates;
   their measurement against this selection is ``benchmarks/discovery_selectors.py``.
4. The selected terms become an effect class (:meth:`Discovery.module_source`), and E plus that
   effect is **refitted with the lab's own non-linear least squares** (:func:`lab.fit`): the
   coefficients and their standard errors are that fit's.

The noise: the one stated (``noise_mm``), else the scatter of repeated poses
(:mod:`lab.repeatability`, tested by F since it is estimated itself), else none.

Verdict: ``discovered`` when terms were selected and, with the noise known, the refitted
residual is consistent with it, or is above it with nothing of the library left and no gross
miss (then ``implied_noise_mm`` says how much noise the residual implies); ``noise`` when nothing
was selected in that case; ``unexplained`` when the residual stays above the noise with structure
left (the terms found, if any, explaining part); ``none`` when nothing was selected and the
residual is noise (or the noise is not known).

It is one module, longer than most, because the steps above are one method: the library, the
selection, the refit and the effect module written from it read top to bottom.
"""

from __future__ import annotations

import keyword
import logging
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Unpack

import numpy as np

from arm.description import RobotDescription
from arm.effects import (
    FAST_PARTS,
    REFERENCE_TEMPERATURE,
    Effect,
    order_reading,
)
from arm.files import atomic_write_text, is_dir
from arm.measurements import MeasurementSet
from lab.errors import FitError
from lab.identifiability import orthonormal_basis
from lab.options import ORDER, LabOptions, OptionFields, check_alpha, resolve
from lab.repeatability import (
    NoiseFloor,
    Repeatability,
    implied_noise_text,
    noise_floor,
    noise_like,
    noise_p_value,
)
from lab.result import SCHEMA_VERSION, FitResult, held_out
from lab.screening import Screen, screened
from lab.spectral import DEFAULT_ORDER as SCAN_ORDER
from lab.spectral import MAX_TERMS, CyclicScan, ExtraColumns, cyclic_scan, problem_of_fit
from lab.terms import Expr, Fn, Mul, Pow, Scaled, TermEffect, Var, term_effect, term_variables
from lab.transfer import block_column, blocked_text, confirm_groups, use_blocks

__all__ = [
    "Discovery",
    "LibraryProblem",
    "LibraryTerm",
    "Term",
    "check_module_path",
    "discover",
    "library_problem",
    "library_terms",
]

log = logging.getLogger(__name__)

DEFAULT_ORDER = SCAN_ORDER  # harmonics sin/cos(m q_j), m = 1..64 (fewer where unresolved)
# Shares of alpha (see the module docstring): the term tests (Bonferroni over the candidates) and,
# with the noise known, the chi-square test of the residual; the union bound keeps the family-wise
# false-discovery rate at most 3/4 alpha (a margin below alpha). The chi-square share is the
# diagnosis's, so both call the same residual consistent with the noise.
TERMS_SHARE = 0.25
CHI2_SHARE = 0.5
MAX_STEPS = MAX_TERMS  # at most this many candidates (a harmonic pair counts once) are selected
_MOVES_NOTHING = 1e-12  # m RMS per pose: a term on a joint whose angle moves no measured point


@dataclass(frozen=True)
class LibraryTerm:
    """One candidate function ``f`` on joint ``joint``: ``theta_joint += k * f``.

    ``key`` is the parameter's prefix (the parameter is ``key + str(joint)``, e.g. ``k_sin3q1``);
    ``expression`` reads f in the CSV's variable names (``sin(3*q1)``); ``form`` is f as data
    (:mod:`lab.terms`: an expression tree of the joint's variables ``q``, ``tau``, ``dT``
    (temperature - 20 degC), ``t``, ``payload``, ``direction``), evaluated on arrays and written
    as the effect module's ``basis``; ``group`` joins the sine and cosine of one harmonic into one
    candidate."""

    joint: int
    key: str
    expression: str
    form: Expr
    variables: tuple[str, ...]
    group: str
    reading: str

    @property
    def name(self) -> str:
        return f"{self.key}{self.joint}"

    @property
    def code(self) -> str:
        """f as the Python text of the effect module's ``basis`` (``np.sin(3 * q)``)."""
        return self.form.code()

    def values(self, q: np.ndarray, tau: np.ndarray, columns: dict) -> np.ndarray:
        """f on every pose (N,), from the joint readings, gravity torques and columns."""
        out = self.form.value(term_variables(q, tau, columns, self.joint))
        return np.broadcast_to(np.asarray(out, dtype=float), (len(q),))


@dataclass(frozen=True)
class Term:
    """A discovered term: ``theta_joint += coefficient * expression``, with its standard error."""

    joint: int
    name: str
    expression: str
    coefficient: float
    std: float | None
    variables: tuple[str, ...]
    reading: str
    alternatives: tuple[str, ...] = ()  # the terms the data cannot tell from this one

    def to_dict(self) -> dict:
        return {
            "joint": self.joint,
            "expression": self.expression,
            "coefficient": self.coefficient,
            "std": self.std,
            "variables": list(self.variables),
            "parameter": self.name,
            "reading": self.reading,
            "alternatives": list(self.alternatives),
        }


def _ordinal(m: int) -> str:
    if 10 <= m % 100 <= 20:
        return f"{m}th"
    return f"{m}" + {1: "st", 2: "nd", 3: "rd"}.get(m % 10, "th")


def harmonic_terms(joint: int, m: int) -> list[LibraryTerm]:
    """The sine and cosine of order ``m`` of joint ``joint`` as library terms (``k_sin3q1``)."""
    q = f"q{joint}"
    if m <= 3:
        reading = f"{_ordinal(m)} harmonic of joint {joint}: {order_reading(m)}"
    else:  # one reading for the higher orders of a joint: the CLI and the module group by it
        reading = f"a harmonic of order 4 or more of joint {joint}: {FAST_PARTS}"
    mq = q if m == 1 else f"{m}*{q}"
    angle = Var("q") if m == 1 else Scaled(m, Var("q"))
    return [
        LibraryTerm(joint, f"k_{fn}{m}q", f"{fn}({mq})", Fn(fn, angle), (q,), f"h{m}{q}", reading)
        for fn in ("sin", "cos")
    ]


def _varies(v: np.ndarray) -> bool:
    v = np.asarray(v, dtype=float)
    return bool(np.ptp(v) > 1e-12 * max(1.0, float(np.max(np.abs(v)))))


# The library's terms other than the harmonics, per joint, in order: (what the data must have,
# key, expression, form, variables, group, reading). The conditions: ``tau`` the joint's gravity
# torque varies; ``temperature``, ``t``, ``payload``, ``dir`` that column is measured and varies.
# In the texts, {j} is the joint, {q} q_j, {t} tau_j, {d} dir_j, {T0} the reference temperature.
_TAU, _DT, _DIR = Var("tau"), Var("dT"), Var("direction")
_FORMS: tuple[tuple[str, str, str, Expr, tuple[str, ...], str, str], ...] = (
    ("", "k_q", "{q}", Var("q"), ("{q}",), "{q}",
     "proportional to {q}: a gear-ratio error (the catalogue's joint_scale)"),
    ("tau", "k_tau", "{t}", _TAU, ("{t}",), "k_tau{j}",
     "deflection proportional to {t}: joint elasticity (the catalogue's compliance)"),
    ("tau", "k_tausq_", "{t}^2", Pow(_TAU, 2), ("{t}",), "k_tausq_{j}",
     "deflection growing with {t}^2: a stiffness that differs with the load's direction"),
    ("tau", "k_taucube_", "{t}^3", Pow(_TAU, 3), ("{t}",), "k_taucube_{j}",
     "deflection growing with {t}^3: a non-linear (hardening) gear-mesh stiffness"),
    ("tau", "k_sign_tau", "sign({t})", Fn("sign", _TAU), ("{t}",), "k_sign_tau{j}",
     "deflection growing with sign({t}): gravity-loaded backlash (the catalogue's load_backlash)"),
    ("tau temperature", "k_temp_tau", "(temperature - {T0})*{t}", Mul(_DT, _TAU),
     ("temperature", "{t}"), "temp_tau{j}", "a stiffness of joint {j} that changes with temperature"),
    ("temperature", "k_temp_q", "(temperature - {T0})", _DT, ("temperature",), "temp_q{j}",
     "an encoder zero of joint {j} drifting with temperature"),
    ("temperature", "k_temp_sinq", "(temperature - {T0})*sin({q})", Mul(_DT, Fn("sin", Var("q"))),
     ("temperature", "{q}"), "temp_h1{q}",
     "an eccentricity of joint {j} that changes with temperature"),
    ("temperature", "k_temp_cosq", "(temperature - {T0})*cos({q})", Mul(_DT, Fn("cos", Var("q"))),
     ("temperature", "{q}"), "temp_h1{q}",
     "an eccentricity of joint {j} that changes with temperature"),
    ("t", "k_t_q", "t", Var("t"), ("t",), "t_q{j}",
     "joint {j}'s zero drifting with time (encoder or mounting creep)"),
    ("payload", "k_payload_q", "payload", Var("payload"), ("payload",), "payload_q{j}",
     "joint {j} deflecting with the payload beyond its gravity torque"),
    ("dir", "k_dir", "{d}", _DIR, ("{d}",), "dir{j}",
     "joint {j} lagging its last motion: friction-held backlash (the catalogue's backlash)"),
    ("dir tau", "k_dir_tau", "{d}*tau{j}", Mul(_DIR, _TAU), ("{d}", "tau{j}"), "dir_tau{j}",
     "a compliance of joint {j} that depends on the last motion's direction: friction "
     "hysteresis in the gear"),
)  # fmt: skip


def library_terms(
    data: MeasurementSet, tau: np.ndarray, order: int = DEFAULT_ORDER
) -> list[LibraryTerm]:
    """The candidate terms for these data: those whose variables are measured and vary."""
    cols = data.columns
    measured = {c for c in ("temperature", "t", "payload") if c in cols and _varies(cols[c])}
    out: list[LibraryTerm] = []
    for j in range(1, 7):
        names = {"j": j, "q": f"q{j}", "t": f"tau{j}", "d": f"dir{j}"}
        names["T0"] = f"{REFERENCE_TEMPERATURE:g}"
        have: set[str] = set(measured)
        if _varies(tau[:, j - 1]):
            have.add("tau")
        if f"dir{j}" in cols and _varies(cols[f"dir{j}"]):
            have.add("dir")
        for m in range(1, order + 1):
            out += harmonic_terms(j, m)
        for need, key, expr, form, variables, group, reading in _FORMS:
            if set(need.split()) <= have:
                out.append(
                    LibraryTerm(
                        j,
                        key,
                        expr.format(**names),
                        form,
                        tuple(v.format(**names) for v in variables),
                        group.format(**names),
                        reading.format(**names),
                    )
                )
    return out


# --------------------------------------------------------------------------------------------------
@dataclass
class Discovery:
    """What :func:`discover` found; see the module docstring."""

    base: FitResult
    verdict: str
    terms: list[Term]
    noise_mm: float | None
    alpha: float
    order: int
    n_candidates: int
    effect_name: str
    refit: FitResult | None = None
    chi2_p_value: float | None = None
    chi2_p_value_after: float | None = None
    p_value: float = 1.0  # the best first term's p-value, Bonferroni-adjusted (times M)
    selected: list[LibraryTerm] = field(default_factory=list)
    effect_module: str | None = None
    source: str = "<memory>"
    # what the sampling of the joints cannot resolve (grid-sampled joints alias high orders)
    notes: list[str] = field(default_factory=list)
    scan: CyclicScan | None = field(default=None, repr=False)
    # where noise_mm came from ("stated", "repeated poses" or None), the scatter of repeated
    # poses, and, when nothing the library holds is left but the residual is above noise_mm,
    # the per-axis noise the residual implies (mm)
    noise_source: str | None = None
    repeatability: Repeatability | None = None
    implied_noise_mm: float | None = None
    # with a session or station column: the discovered effect confirmed by blocked
    # cross-validation (lab.transfer), as the diagnosis's blocked_cv; dropped when it does not
    # help on a block it was not fitted on
    blocked_cv: dict | None = None
    # the terms the data cannot tell from each selected one, by parameter name
    alternatives: dict[str, tuple[str, ...]] = field(default_factory=dict, repr=False)

    @property
    def noise_note(self) -> str | None:
        """``no structure is left: the residual is noise of ..., 6 % above ...``, or None."""
        if self.implied_noise_mm is None or self.noise_mm is None:
            return None
        return implied_noise_text(self.implied_noise_mm, self.noise_mm, self.noise_source)

    @property
    def effects(self) -> list[str]:
        return self.base.effects

    @property
    def rms_mm(self) -> float:
        return self.base.rms_mm

    @property
    def noise_floor_mm(self) -> float | None:
        return None if self.noise_mm is None else self.noise_mm * math.sqrt(3.0)

    @property
    def rms_after_mm(self) -> float:
        return self.refit.rms_mm if self.refit is not None else self.base.rms_mm

    @property
    def validation_rms_mm(self) -> float | None:
        res = self.refit if self.refit is not None else self.base
        return res.validation_rms_mm

    @property
    def suggestion(self) -> str | None:
        """The ``--effects`` string that fits E plus the discovered effect."""
        if not self.terms:
            return None
        return ",".join([*self.effects, self.effect_name])

    @property
    def formulas(self) -> dict[int, str]:
        """One line per joint with terms: ``theta2 = q2 + 2.01e-4*sin(2*q2) - ...``."""
        out: dict[int, str] = {}
        for j in sorted({t.joint for t in self.terms}):
            line = f"theta{j} = q{j}"
            for t in (t for t in self.terms if t.joint == j):
                sign = "-" if t.coefficient < 0 else "+"
                line += f" {sign} {_number(abs(t.coefficient), t.std)}*{_wrap(t.expression)}"
            out[j] = line
        return out

    def module_source(self) -> str:
        """The Python text of the discovered effect class (empty without terms)."""
        if not self.selected:
            return ""
        return _module_source(self)

    def effect_class(self) -> type[TermEffect]:
        """The effect class that :meth:`module_source` defines, built from the same terms as
        data (the lab's refit uses it; nothing is executed)."""
        if not self.selected:
            raise FitError("nothing was discovered: there is no effect class")
        return _effect_class(self)

    def write_module(self, path: str | Path) -> Path:
        """Write :meth:`module_source` atomically to ``path``; refuses when nothing was found."""
        if not self.selected:
            raise FitError("nothing was discovered: there is no effect module to write")
        path = check_module_path(path)
        atomic_write_text(path, self.module_source())
        self.effect_module = str(path)
        return path

    def to_dict(self) -> dict:
        """The JSON object of ``sixaxis lab discover --json``."""
        return {
            "schema_version": SCHEMA_VERSION,
            "effects": self.effects,
            "rms_mm": self.rms_mm,
            "noise_floor_mm": self.noise_floor_mm,
            "verdict": self.verdict,
            "terms": [t.to_dict() for t in self.terms],
            "formulas": {str(j): f for j, f in self.formulas.items()},
            "effect_name": self.effect_name if self.terms else None,
            "suggestion": self.suggestion,
            "effect_module": self.effect_module,
            "rms_after_mm": self.rms_after_mm,
            "validation_rms_mm": self.validation_rms_mm,
            "noise_mm": self.noise_mm,
            "alpha": self.alpha,
            "order": self.order,
            "n_candidates": self.n_candidates,
            "chi2_p_value": self.chi2_p_value,
            "chi2_p_value_after": self.chi2_p_value_after,
            "p_value": self.p_value,
            "n_points": self.base.n_points,
            "source": self.source,
            "notes": list(self.notes),
            "noise_source": self.noise_source,
            "repeatability": None if self.repeatability is None else self.repeatability.to_dict(),
            "implied_noise_mm": self.implied_noise_mm,
            "blocked_cv": self.blocked_cv,
        }

    def summary(self) -> str:
        floor = f", noise floor {self.noise_floor_mm:.4f} mm" if self.noise_floor_mm else ""
        lines = [
            f"model {', '.join(self.effects)}: RMS {self.rms_mm:.4f} mm{floor}; "
            f"{self.n_candidates} candidate terms (harmonics to order {self.order} per turn)",
            f"verdict: {self.verdict}",
        ]
        for f in self.formulas.values():
            lines.append(f"  {f}")
        for t in self.terms:
            std = "-" if t.std is None else f"{t.std:.2g}"
            lines.append(f"  {t.name} = {t.coefficient:.4g} +- {std}: {t.reading}")
        if self.terms:
            lines.append(f"with the terms: RMS {self.rms_after_mm:.4f} mm; fit {self.suggestion}")
        if self.noise_note:
            lines.append(self.noise_note)
        lines += self.notes
        if self.blocked_cv is not None:
            lines.append(blocked_text(self.blocked_cv))
        return "\n".join(lines)


def _wrap(expr: str) -> str:
    """An expression as a factor: ``(temperature - 20)`` stays, ``a - b`` gets brackets."""
    if expr.startswith("(") and expr.endswith(")") and expr.count("(") == 1:
        return expr
    return f"({expr})" if (" - " in expr or " + " in expr) else expr


def _number(x: float, std: float | None) -> str:
    """A coefficient with as many digits as its standard error supports (2 to 4)."""
    if x == 0 or not math.isfinite(x):
        return f"{x:.3g}"
    digits = 3
    if std is not None and std > 0 and math.isfinite(std):
        digits = int(
            np.clip(math.floor(math.log10(abs(x))) - math.floor(math.log10(std)) + 2, 2, 4)
        )
    return f"{x:.{digits - 1}e}".replace("e-0", "e-").replace("e+0", "e")


# --------------------------------------------------------------------------------------------------
def _q(text: str) -> str:
    """A string literal in double quotes (the style ruff formats to)."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _class_name(name: str) -> str:
    return "".join(p.capitalize() for p in name.split("_")) or "Discovered"


def _forms(
    d: Discovery,
) -> tuple[dict[int, list[LibraryTerm]], list[str], dict[str, tuple[float, float]]]:
    """The discovered effect's terms per joint, its term keys in order, and each key's typical
    range: the size found, so that sample_parameters draws it and the fit keeps it (a
    harmonic's sine and cosine share the pair's amplitude: one of them may be near zero)."""
    forms: dict[int, list[LibraryTerm]] = {}
    for t in d.selected:
        forms.setdefault(t.joint, []).append(t)
    coef = {t.name: t for t in d.terms}
    keys = list(dict.fromkeys(t.key for t in d.selected))
    amp: dict[str, float] = {}
    for t in d.selected:
        amp[t.group] = max(amp.get(t.group, 0.0), abs(coef[t.name].coefficient))
    typical = {}
    for k in keys:
        mags = [amp[t.group] for t in d.selected if t.key == k]
        typical[k] = (0.5 * min(mags), 2.0 * max(mags))
    return forms, keys, typical


def _data_columns(d: Discovery) -> tuple[str, ...]:
    """The measured columns the discovered terms read (beyond q and tau), sorted."""
    return tuple(
        sorted({v for t in d.selected for v in t.variables if not re.fullmatch(r"(q|tau)\d", v)})
    )


def _module_source(d: Discovery) -> str:
    name = d.effect_name
    forms, keys, typical = _forms(d)
    codes = {t.key: t.code for t in d.selected}
    formula_lines = "\n".join(f"    {f}" for f in d.formulas.values())
    readings = "\n".join(f"    {t.name}: {t.expression} -- {t.reading}" for t in d.terms)
    data_cols = _data_columns(d)
    forms_text = ",\n".join(
        f"        {j}: ({', '.join(_q(t.key) for t in ts)},)" for j, ts in sorted(forms.items())
    )
    typical_text = ",\n".join(
        f"        {_q(k)}: ({lo:.3g}, {hi:.3g})" for k, (lo, hi) in typical.items()
    )
    branches = "\n".join(
        f"        {'if' if i == 0 else 'elif'} term == {_q(k)}:\n            return {codes[k]}"
        for i, k in enumerate(keys)
    )
    needs_dT = any("dT" in codes[k] for k in keys)
    needs_dir = any("direction" in codes[k] for k in keys)
    needs_t = any(re.search(r"\bt\b", codes[k]) for k in keys)
    needs_payload = any("payload" in codes[k] for k in keys)
    used = " ".join(codes[k] for k in keys)
    locals_ = []
    if re.search(r"\bq\b", used):
        locals_.append("        q = inputs.q[:, joint - 1]")
    if re.search(r"\btau\b", used):
        locals_.append("        tau = inputs.tau[:, joint - 1]")
    if needs_dT:
        locals_.append('        dT = inputs.column("temperature") - REFERENCE_TEMPERATURE')
    if needs_t:
        locals_.append('        t = inputs.column("t")')
    if needs_payload:
        locals_.append('        payload = inputs.column("payload")')
    if needs_dir:
        locals_.append('        direction = inputs.column(f"dir{joint}")')
    locals_text = "\n".join(locals_)
    effects = ",".join(d.effects)
    suggestion = d.suggestion
    header = (
        f'"""An effect discovered by ``sixaxis lab discover`` on top of {effects}\n'
        f"({d.base.n_points} poses of {d.source}; harmonics to order {d.order}, "
        f"alpha {d.alpha:g}):\n\n"
        f"{formula_lines}\n\n"
        "Each term, with the physical reading the lab knows for its form:\n\n"
        f"{readings}\n\n"
        "Edit it like any effect: ``forms`` says which terms act on which joint, ``basis`` what\n"
        "each term is. Fit it with\n\n"
        f"    sixaxis lab fit DATA.csv --effect-module THIS_FILE.py --effects {suggestion}\n"
        '"""'
    )
    dT_import = (
        "from arm.effects import REFERENCE_TEMPERATURE, JointAngleEffect"
        if needs_dT
        else "from arm.effects import JointAngleEffect"
    )
    return f'''{header}

import numpy as np

{dT_import}


class {_class_name(name)}(JointAngleEffect):
    """theta_j = q_j + sum over the joint's terms of k_term_j * term(variables)."""

    name = {_q(name)}
    description = {_q("discovered: " + "; ".join(d.formulas.values()))}
    columns = ({"".join(_q(c) + ", " for c in data_cols).rstrip()})
    # the terms of each joint; a parameter is named term + joint (k_sin2q2)
    forms = {{
{forms_text},
    }}
    terms = ({"".join(_q(k) + ", " for k in keys).rstrip()})
    # the size found: the lab fixes a parameter whose typical error moves no point above the noise
    typical = {{
{typical_text},
    }}

    def parameter_names(self, robot, targets):
        return [f"{{t}}{{j}}" for j in self.active_joints() for t in self.forms.get(j, ())]

    def regressor(self, inputs):
        """(N, 6, k) d theta / d parameters, in the order of parameter_names."""
        cols = [
            (j, self.basis(inputs, j, t)) for j in self.active_joints() for t in self.forms.get(j, ())
        ]
        out = np.zeros((inputs.n, 6, len(cols)))
        for k, (j, b) in enumerate(cols):
            out[:, j - 1, k] = b
        return out

    def basis(self, inputs, joint, term):
{locals_text}
{branches}
        raise ValueError(f"unknown term {{term!r}}")
'''


# --------------------------------------------------------------------------------------------------
_NAME = re.compile(r"[a-z][a-z0-9_]*")


def check_module_path(path: str | Path) -> Path:
    """``path`` if an effect module can be written there (a ``.py`` file: ``--effect-module``
    imports it), else a :class:`FitError`."""
    path = Path(path)
    if path.suffix != ".py" and not is_dir(path):
        raise FitError(f"{path}: the effect module must be a .py file")
    return path


def discover(
    data: Screen | MeasurementSet | str | Path,
    robot: RobotDescription | str | Path | None = None,
    effects: str | Sequence[str | Effect] | None = None,
    *,
    options: LabOptions | None = None,
    alpha: float = 0.02,
    validate: MeasurementSet | str | Path | None = None,
    references: MeasurementSet | str | Path | None = None,
    order: int = DEFAULT_ORDER,
    name: str = "discovered",
    across_blocks: bool | None = None,
    **keywords: Unpack[OptionFields],
) -> Discovery:
    """Search the library of :func:`library_terms` for what ``effects`` (default geometric)
    miss; see the module docstring. ``data``: a measurement set (or its file), screened once
    (:func:`lab.screen`), or a :class:`lab.Screen` made before (its fit is the start; nothing
    screened again). The options (``noise_mm`` ... ``register``, or ``options=``) are
    :class:`lab.LabOptions`; ``noise_mm`` (:data:`arm.noise.NOISE_MM`) also
    decides the verdict ``none`` against ``unexplained``. ``alpha``: the family-wise
    false-discovery rate; ``validate``: held-out data for the refitted model (``references``:
    reference points that register a station of it the fit has not seen,
    :meth:`lab.FitResult.validate`); ``order``: the
    highest harmonic; ``name``: the discovered effect's name; ``across_blocks``: keep the
    discovered effect only if it helps on a session (or station) it was not fitted on
    (:mod:`lab.transfer`; None: where the data have at least :data:`lab.transfer.MIN_BLOCKS`)."""
    check_alpha(alpha)
    opts = resolve(options, **keywords)
    held = held_out(validate, references)
    if not ORDER.constraint.holds(order):
        raise FitError(
            f"order (the highest harmonic) must {ORDER.constraint.predicate}, got {order!r}"
        )
    if not _NAME.fullmatch(name) or keyword.iskeyword(name):
        raise FitError(f"effect name {name!r} must be lower-case letters, digits and _")
    s = screened(data, robot, effects, opts, tests=False)
    # the noise the tests use: the stated one, else the scatter of repeated poses
    floor = noise_floor(s.options.noise_mm, s.kept)
    res = s.fit
    if res.weighted and res.noise_ref is not None:  # stated by the rows' uncertainties
        floor = NoiseFloor(1e3 * res.noise_ref, "stated", floor.repeatability)
    if name in res.model.layout.effects:
        raise FitError(f"the model already has an effect named {name!r}; choose another name")
    disc = _selection(res, s.kept, floor, alpha, order, name)
    if not disc.selected:
        return _nothing_kept(disc, held)
    cls = disc.effect_class()
    if use_blocks(s.kept, across_blocks) and not _helps_across_blocks(disc, s, cls):
        disc.selected, disc.terms = [], []
        return _nothing_kept(disc, held)
    # the discovered model is a new model of the rows that count: the rule judges its own misses
    # (poses where a discovered term cannot say its sign are gross misses of it, not of the base)
    refit = screened(s.kept, s.robot, [*res.model.effects, cls()], s.options, tests=False).fit
    if held is not None:
        refit = refit.validate(held[0], references=held[1])
    _judge_refit(disc, refit, floor)
    log.info("%s", disc.summary())
    return disc


def _selection(
    res: FitResult, data: MeasurementSet, floor: NoiseFloor, alpha: float, order: int, name: str
) -> Discovery:
    """Steps 1-3 of the module docstring: the library's candidates scanned on the residual of
    ``res`` (a fit of ``data``); the discovery with the terms selected (their sizes from the
    scan's linearised fit, the first pass of the effect module's typical ranges) and the
    residual's chi-square test against the noise ``floor``."""
    noise_mm = floor.noise_mm
    # the library's other terms (torques, temperature, ...) join the scan of every joint's
    # harmonics as candidates of their own (lab.spectral: one vectorised selection)
    tau = res.inputs.tau
    others = library_terms(data, tau, order=0)
    extras = _extra_columns(others, data, tau)
    # without the noise there is no chi-square test: the terms get both shares
    share = TERMS_SHARE if noise_mm is not None else TERMS_SHARE + CHI2_SHARE
    scan = cyclic_scan(
        problem_of_fit(res), order, alpha=share * alpha, extras=extras, max_terms=MAX_STEPS
    )
    M = scan.n_candidates
    # in the library's order (harmonics by order, then tau2 before tau2^3; joints in turn)
    rank = {t.group: k for k, t in enumerate(others)}
    selected: list[LibraryTerm] = []
    alternatives: dict[str, tuple[str, ...]] = {}
    size: dict[str, float] = {}  # each term's coefficient in the scan's linearised fit
    for st in sorted(scan.terms, key=lambda t: (t.joint, t.order or 0, rank.get(t.key or "", -1))):
        if st.order is not None:
            found = harmonic_terms(st.joint, st.order)  # sine, cosine: the cyclic cs, cc
            scan_names = [f"cs{st.joint}_{st.order}", f"cc{st.joint}_{st.order}"]
        else:
            found = [t for t in others if t.group == st.key]
            scan_names = [f"{st.key}:{c}" for c in range(len(found))]
        selected += found
        alts = tuple(_alternative(a) for a in st.alternatives)
        for t, sn in zip(found, scan_names, strict=True):
            alternatives[t.name] = alts
            size[t.name] = scan.estimates.get(sn, 0.0)
    for st in scan.terms:
        log.debug("discovery: %s (p = %.3g)", st.label, st.p_value)
    return Discovery(
        base=res,
        verdict="none",
        terms=[
            Term(
                t.joint,
                t.name,
                t.expression,
                size[t.name],
                None,
                t.variables,
                t.reading,
                alternatives[t.name],
            )
            for t in selected
        ],
        noise_mm=noise_mm,
        alpha=alpha,
        order=order,
        n_candidates=M,
        effect_name=name,
        chi2_p_value=noise_p_value(scan.rss0, scan.dof0, floor),
        p_value=min(1.0, scan.first_p * max(M, 1)),
        selected=selected,
        source=data.source,
        notes=scan.notes() + list(scan.implausible),
        scan=scan,
        noise_source=floor.source,
        repeatability=floor.repeatability,
        alternatives=alternatives,
    )


def _nothing_kept(
    disc: Discovery, held: tuple[MeasurementSet, MeasurementSet | None] | None
) -> Discovery:
    """The discovery without terms: ``none``, ``noise`` or ``unexplained`` by the residual's
    chi-square test (the module docstring's verdict)."""
    disc.terms = []
    scan, chi2_p = disc.scan, disc.chi2_p_value
    assert scan is not None
    if chi2_p is not None and chi2_p < CHI2_SHARE * disc.alpha:
        # above the noise: structure the library does not hold, or only noise (more of it
        # than stated) when no candidate is left that the residual depends on
        if scan.exhausted and noise_like(scan.residual):
            disc.verdict = "noise"
            disc.implied_noise_mm = 1e3 * math.sqrt(scan.rss0 / max(scan.dof0, 1))
        else:
            disc.verdict = "unexplained"
    if held is not None:
        disc.base = disc.base.validate(held[0], references=held[1])
    log.info("%s", disc.summary())
    return disc


def _helps_across_blocks(disc: Discovery, s: Screen, cls: type[TermEffect]) -> bool:
    """Whether the discovered effect helps on a session or station it was not fitted on
    (:mod:`lab.transfer`); the table goes to ``disc.blocked_cv``."""
    name = disc.effect_name
    base_effects = list(s.fit.model.effects)
    kept, table = confirm_groups(
        s.kept,
        s.robot,
        lambda keep: [*base_effects, cls()] if keep else base_effects,
        [name],
        s.options,
    )
    disc.blocked_cv = {
        "column": block_column(s.kept),
        "models": table,
        "dropped": [] if kept else [name],
    }
    return bool(kept)


def _judge_refit(disc: Discovery, refit: FitResult, floor: NoiseFloor) -> None:
    """Step 4: the terms' coefficients and standard errors from the refit of the model with
    the discovered effect, and the verdict by the refit's residual against the noise."""
    std = refit.standard_errors()
    disc.refit = refit
    disc.terms = [
        Term(
            t.joint,
            t.name,
            t.expression,
            refit[t.name],
            std[t.name],
            t.variables,
            t.reading,
            disc.alternatives[t.name],
        )
        for t in disc.selected
    ]
    if disc.noise_mm is None:
        disc.verdict = "discovered"
        return
    scan = disc.scan
    assert scan is not None
    rows = refit.row_residuals  # the points, or the weighted rows (lab.observations)
    rss = float(np.sum(rows**2))
    dof = max(refit.n_equations - refit.rank, 1)
    disc.chi2_p_value_after = noise_p_value(rss, dof, floor)
    ok = (disc.chi2_p_value_after or 0.0) >= CHI2_SHARE * disc.alpha
    # the rest is noise (more of it than stated) where nothing of the library is left and
    # no pose misses grossly
    noise = not ok and scan.exhausted and noise_like(rows[rows != 0].reshape(-1))
    if noise:
        disc.implied_noise_mm = 1e3 * math.sqrt(rss / dof)
    disc.verdict = "discovered" if ok or noise else "unexplained"


def _extra_columns(
    terms: Sequence[LibraryTerm], data: MeasurementSet, tau: np.ndarray
) -> list[ExtraColumns]:
    """The library's terms other than the harmonics as the scan's candidates: per joint, each
    group (one term, or the sine and cosine of one product) one candidate."""
    out = []
    for j in range(1, 7):
        ts = [t for t in terms if t.joint == j]
        if not ts:
            continue
        values = np.column_stack([t.values(data.q, tau, data.columns) for t in ts])
        keys = list(dict.fromkeys(t.group for t in ts))
        groups = tuple(tuple(k for k, t in enumerate(ts) if t.group == g) for g in keys)
        out.append(ExtraColumns(j, values, groups, tuple(keys)))
    return out


def _alternative(a: tuple[int, int | str]) -> str:
    """``order 26 of joint 1``, or a library term's group."""
    joint, what = a
    return f"order {what} of joint {joint}" if isinstance(what, int) else f"{what} (joint {joint})"


@dataclass(frozen=True)
class LibraryProblem:
    """The sparse-regression problem of one fit: the residual ``residual`` (3N) and the library's
    columns ``columns`` (3N, K), both with the model's span (orthonormal ``model_basis``)
    projected out; ``terms`` (K) the library terms kept, ``groups`` their candidates (indices
    into the columns), ``joint_jacobian`` (N, 3, 6) d point / d theta at the fit."""

    residual: np.ndarray
    columns: np.ndarray
    terms: list[LibraryTerm]
    groups: dict[str, list[int]]
    model_basis: np.ndarray
    joint_jacobian: np.ndarray


def library_problem(
    data: MeasurementSet, res: FitResult, order: int = DEFAULT_ORDER
) -> LibraryProblem:
    """The library's columns and the residual of ``res`` (a fit of ``data``), the model's span
    projected out: each term's column is d point / d theta_j times f; a term the model explains
    already (its column in the span) or that moves no point is left out."""
    N = res.n_points
    k = res.row_residuals.shape[1]  # rows per pose: 3, or the weighted rows of lab.observations
    free = res.identifiable
    J0 = res.jacobian[:, :, free].reshape(k * N, -1) * res.identifiability.scale[free]
    Q0 = orthonormal_basis(J0)
    e = res.row_residuals.reshape(-1)
    e0 = e - Q0 @ (Q0.T @ e)
    Jq = _joint_rows(res)  # (N, k, 6)
    tau = res.inputs.tau
    groups: dict[str, list[int]] = {}
    cols: list[np.ndarray] = []
    kept: list[LibraryTerm] = []
    for term in library_terms(data, tau, order):
        f = term.values(data.q, tau, data.columns)
        x = (Jq[:, :, term.joint - 1] * f[:, None]).reshape(-1)
        nx = float(np.linalg.norm(x))
        if nx / math.sqrt(N) < _MOVES_NOTHING * max(1.0, float(np.max(np.abs(f)))):
            continue
        xp = x - Q0 @ (Q0.T @ x)
        if np.linalg.norm(xp) <= 1e-6 * nx:  # the model explains it already
            continue
        groups.setdefault(term.group, []).append(len(cols))
        cols.append(xp)
        kept.append(term)
    X = np.column_stack(cols) if cols else np.zeros((k * N, 0))
    return LibraryProblem(e0, X, kept, groups, Q0, Jq)


def _joint_rows(res: FitResult) -> np.ndarray:
    """d point / d theta (N, 3, 6) at the fit; of its weighted rows (N, k, 6) where the fit has
    them (:meth:`lab.observations.Observations.joint_rows`)."""
    if res.weighted and res.observations is not None:
        return res.observations.joint_rows(res.model, res.inputs, res.params)
    return res.model.joint_jacobian(res.inputs, res.params)[1]


def _effect_class(d: Discovery) -> type[TermEffect]:
    """The effect class that :meth:`Discovery.module_source` defines, built from the same data
    (:func:`lab.terms.term_effect`): the same terms, typical ranges (as the module writes them,
    to three digits) and description, the same numpy operations."""
    forms, keys, typical = _forms(d)
    expressions = {t.key: t.form for t in d.selected}
    return term_effect(
        d.effect_name,
        _class_name(d.effect_name),
        f"sixaxis_discovered_{d.effect_name}",
        "discovered: " + "; ".join(d.formulas.values()),
        _data_columns(d),
        {j: tuple(t.key for t in ts) for j, ts in forms.items()},
        {k: (float(f"{lo:.3g}"), float(f"{hi:.3g}")) for k, (lo, hi) in typical.items()},
        {k: expressions[k] for k in keys},
        _module_source(d),
    )
