"""A fitted model's domain: where it was identified, and what it does outside it.

    dom = result.domain                       # the ranges of the fitted poses
    dom.ranges["temperature"]                 # (21.6, 22.2) degC
    dom.excursions(inputs_of(result.model, other))   # what lies outside, and how far
    result.validate(other)                    # warns out of domain, terms not extrapolated

**The domain** is the range of every variable the model reads over the poses it was fitted on:
the joint readings ``q1..q6`` (rad), the nominal gravity torques ``tau1..tau6`` (N·m), and where
the data have them ``temperature`` (degC), ``payload`` (kg) and ``t`` (s, the time span), each
widened by :data:`MARGIN` (10 %) of its span on either side. A fit
records it (``FitResult.domain``, the JSON's ``domain``), an exported arm carries it
(``[domain]`` of the robot TOML), and validation, compensation and the exported model's users
are told where data lie outside it: which variable, how far, how many rows.

**Outside the domain an effect term is not extrapolated beyond what its form justifies.** A
parameter's term is a function of some of those variables (found from the effect itself: a
joint-angle effect's basis is evaluated with each variable moved, :func:`term_dependence`):

* a term periodic in a joint angle (a harmonic ``sin(k q_j)``, the catalogue's ``transmission``
  and ``cyclic``) holds at every reading whose phase the fit has seen: everywhere where the fit
  covered a whole period of it, and a whole number of periods from a fitted reading otherwise
  (a joint that turned once more, :func:`unseen_phase`);
* except a first harmonic alone (``sin q_j``, ``cos q_j``: once per turn, the eccentricity of
  a gear or an encoder on the joint's output, the catalogue's ``transmission``): a circle off
  its centre errs by that sinusoid over the whole turn, so where the fit covered at least half
  a turn of the joint (:data:`ECCENTRICITY_ARC`, over which its sine and cosine are told apart
  from the joint's zero) it holds everywhere (the UR10's A and B, q1 over 3.6 rad, predicted
  D's q1 beyond it: 0.291 -> 0.239 mm with the diagnosis's choice);
* any other dependence (a line in temperature fitted over 0.4 degC, a polynomial in a joint
  angle or a gravity torque, a gear-ratio error ``g q`` fitted over part of the joint's range,
  a term in time or payload) holds only over the fitted range;
* effects whose form is a law of the arm's structure over its whole range (the geometry, joint
  compliance, backlash) declare ``extrapolates = True``
  (:class:`arm.effects.Effect`) and are never dropped.

Rows outside the range a term holds over are predicted by the model without that term: the
fit again on the same rows with the term's parameters held at zero
(:meth:`lab.result.FitResult.without`; an arm read from a file, which has no rows, zeroes them), with a :class:`OutOfDomainWarning` naming the variable, how far,
and the terms left out; ``extrapolate=True`` (``--extrapolate``) keeps every term everywhere,
and still warns.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from arm.effect_api import ModelInputs
from arm.effects import JointAngleEffect
from arm.errormodel import ErrorModel
from arm.errors import warn
from lab.errors import OutOfDomainWarning, ToolPlacedWarning

__all__ = [
    "DOMAIN_COLUMNS",
    "Domain",
    "Excursion",
    "OutOfDomainWarning",
    "Terms",
    "ToolPlacedWarning",
    "out_of_domain",
    "term_dependence",
    "unseen_phase",
]

log = logging.getLogger(__name__)

#: the measured columns a domain records, beside the joints and their gravity torques
DOMAIN_COLUMNS = ("temperature", "payload", "t")
_UNITS = {"q": "rad", "tau": "N·m", "temperature": "degC", "payload": "kg", "t": "s"}
#: the share of a variable's fitted span by which data may lie beyond either end and still be
#: inside the domain (a held-out pose of the same campaign a little beyond the fitted ones)
MARGIN = 0.1
#: poses on which a term's dependence is probed
PROBE_POSES = 16
#: the arc of its joint (rad) over which a once-per-turn term must have been fitted to hold over
#: the whole turn: half a turn, where its sine and cosine are told apart from the joint's zero
ECCENTRICITY_ARC = math.pi


def _unit(variable: str) -> str:
    return _UNITS.get(variable.rstrip("0123456789"), "")


def _number(v: float, unit: str) -> str:
    text = f"{v:.4g} {unit}".strip()
    if unit == "rad":
        text += f" ({math.degrees(v):.3g} deg)"
    return text


@dataclass(frozen=True)
class Excursion:
    """Rows of a data set outside the domain's range ``lo..hi`` of ``variable``: ``below`` and
    ``above``, how far the farthest lies beyond each end (0 on a side none crosses); ``rows``
    which rows (a boolean mask over the data)."""

    variable: str
    lo: float
    hi: float
    below: float
    above: float
    rows: np.ndarray = field(repr=False, compare=False)

    @property
    def beyond(self) -> float:
        return max(self.below, self.above)

    def text(self) -> str:
        u = _unit(self.variable)
        sides = []
        if self.below > 0:
            sides.append(f"{_number(self.below, u)} below")
        if self.above > 0:
            sides.append(f"{_number(self.above, u)} above")
        n = int(self.rows.sum())
        return (
            f"{self.variable} up to {' and '.join(sides)} the fitted "
            f"{self.lo:.4g}..{self.hi:.4g} {u} ({n} of {self.rows.size} rows)"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "variable": self.variable,
            "lo": self.lo,
            "hi": self.hi,
            "below": self.below,
            "above": self.above,
            "rows": int(self.rows.sum()),
        }


def _variables(inputs: ModelInputs) -> dict[str, np.ndarray]:
    out = {f"q{j + 1}": inputs.q[:, j] for j in range(6)}
    out |= {f"tau{j + 1}": inputs.tau[:, j] for j in range(6)}
    out |= {c: inputs.columns[c] for c in DOMAIN_COLUMNS if c in inputs.columns}
    return out


@dataclass(frozen=True)
class Domain:
    """Where a model was identified: ``ranges`` {variable: (lo, hi)} over ``n_poses`` poses
    (SI units, temperature in degC)."""

    ranges: Mapping[str, tuple[float, float]]
    n_poses: int

    @classmethod
    def of(cls, inputs: ModelInputs) -> Domain:
        return cls(
            {k: (float(v.min()), float(v.max())) for k, v in _variables(inputs).items()},
            inputs.n,
        )

    def to_dict(self) -> dict[str, Any]:
        return {"n_poses": self.n_poses, "ranges": {k: list(v) for k, v in self.ranges.items()}}

    def union(self, other: Domain) -> Domain:
        """Where either was identified: each variable's range over both (a variable that one
        of them does not record is not judged, so it is left out)."""
        ranges = {
            k: (min(lo, other.ranges[k][0]), max(hi, other.ranges[k][1]))
            for k, (lo, hi) in self.ranges.items()
            if k in other.ranges
        }
        return Domain(ranges, self.n_poses + other.n_poses)

    @classmethod
    def of_description(cls, d: Mapping[str, Any]) -> Domain | None:
        """The domain a calibrated arm's ``[domain]`` carries (``RobotDescription.domain``),
        None for an arm without one."""
        if not d:
            return None
        ranges = {k: (float(v[0]), float(v[1])) for k, v in d.items() if k != "n_poses"}
        return cls(ranges, int(d.get("n_poses", 0)))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Domain:
        ranges = {str(k): (float(v[0]), float(v[1])) for k, v in d["ranges"].items()}
        return cls(ranges, int(d.get("n_poses", 0)))

    def text(self) -> str:
        parts = []
        for k, (lo, hi) in self.ranges.items():
            if k.startswith("tau"):
                continue
            parts.append(f"{k} {lo:.4g}..{hi:.4g} {_unit(k)}".strip())
        return ", ".join(parts)

    def excursions(self, inputs: ModelInputs) -> list[Excursion]:
        """The variables of ``inputs`` outside this domain (beyond either end of a fitted range
        by more than :data:`MARGIN` of its span), farthest first relative to the span. A
        variable the domain does not record (a column the fit had not) is not judged."""
        out = []
        for k, v in _variables(inputs).items():
            if k not in self.ranges or not v.size:
                continue
            lo, hi = self.ranges[k]
            tol = MARGIN * (hi - lo) + 1e-9 * max(1.0, abs(lo), abs(hi))
            rows = (v < lo - tol) | (v > hi + tol)
            if not rows.any():
                continue
            below = float(max(0.0, lo - v.min()))
            above = float(max(0.0, v.max() - hi))
            out.append(Excursion(k, lo, hi, below if below > tol else 0.0, above, rows))
        return sorted(out, key=lambda e: -e.beyond / max(e.hi - e.lo, 1e-12))


# -- which terms depend on what -------------------------------------------------------------------
@dataclass(frozen=True)
class Terms:
    """What a parameter's term depends on: (variable, period) pairs, the period (rad) of a term
    periodic in a joint angle, else None."""

    by_parameter: Mapping[str, tuple[tuple[str, float | None], ...]]
    #: the parameters whose term is a first harmonic of its joint alone (``sin q``, ``cos q``:
    #: once per turn, an eccentricity), whatever effect carries it
    once_per_turn: frozenset[str] = frozenset()


def _moved(inputs: ModelInputs, **kw) -> ModelInputs:
    return replace(inputs, _cache={}, **kw)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.allclose(a, b, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(a).max()))))


def _regressor(effect: JointAngleEffect, inputs: ModelInputs) -> np.ndarray:
    """(N, k): d theta / d parameter, each parameter on its own joint's row, summed over joints."""
    return effect.regressor(inputs).sum(axis=1)


#: samples over one turn of a joint when a term's period is found (above twice MAX_ORDER)
TURN_SAMPLES = 2048


def _periods(effect: JointAngleEffect, probe: ModelInputs, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Each parameter's fundamental period (rad) in joint angle ``k`` (0-based), NaN where its
    term does not repeat every turn: the term sampled over one turn (the other variables those of
    one pose), its harmonics by FFT, the period 2 pi / (their greatest common divisor); and
    whether its only harmonic is the first (once per turn)."""
    n = TURN_SAMPLES
    one = probe.subset(np.zeros(n, dtype=int))
    q = one.q.copy()
    q[:, k] += np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    turn = _regressor(effect, _moved(one, q=q))
    q2 = q.copy()
    q2[:, k] += 2 * math.pi
    again = _regressor(effect, _moved(one, q=q2))
    spectrum = np.abs(np.fft.rfft(turn - turn.mean(axis=0), axis=0))[1:]
    out = np.full(turn.shape[1], np.nan)
    once = np.zeros(turn.shape[1], dtype=bool)
    for c in range(turn.shape[1]):
        if not _same(again[:, c], turn[:, c]):
            continue  # not periodic over a turn
        top = spectrum[:, c].max()
        orders = np.flatnonzero(spectrum[:, c] > 1e-8 * top) + 1
        if top > 0 and orders.size and orders.max() < n // 2:
            out[c] = 2 * math.pi / int(np.gcd.reduce(orders))
            once[c] = orders.tolist() == [1]
    return out, once


def term_dependence(model: ErrorModel, inputs: ModelInputs) -> Terms:
    """The variables each parameter's term depends on, probed on a few of ``inputs``' poses:
    a joint-angle effect's regressor evaluated with each variable moved (a joint angle by 0.1
    rad, a gravity torque by 1 N·m, a column by 1 unit), and the period of its dependence on a
    joint angle from its harmonics over a turn; any other effect's by the columns it reads.
    Effects with ``extrapolates`` (and the geometry) depend on nothing here."""
    idx = np.linspace(0, inputs.n - 1, min(PROBE_POSES, inputs.n)).astype(int)
    probe = inputs.subset(idx)
    out: dict[str, tuple[tuple[str, float | None], ...]] = {}
    once_per_turn: set[str] = set()
    lay = model.layout
    for e in model.effects:
        if getattr(e, "extrapolates", False) or e.name == "geometric":
            continue
        names = list(lay.names[lay.slice(e.name)])
        if not isinstance(e, JointAngleEffect):
            reads = tuple((c, None) for c in e.columns if c in DOMAIN_COLUMNS)
            for n in names:
                out[n] = reads
            continue
        base = _regressor(e, probe)
        deps: list[list[tuple[str, float | None]]] = [[] for _ in names]

        def moved(inp: ModelInputs) -> np.ndarray:
            r = _regressor(e, inp)  # noqa: B023  (used within the loop iteration)
            return np.array(
                [not _same(r[:, c], base[:, c]) for c in range(len(names))]  # noqa: B023
            )

        for c in DOMAIN_COLUMNS:
            if c in probe.columns:
                cols = dict(probe.columns)
                cols[c] = cols[c] + 1.0
                for i in np.flatnonzero(moved(_moved(probe, columns=cols))):
                    deps[i].append((c, None))
        for k in range(6):
            q = probe.q.copy()
            q[:, k] += 0.1
            on_q = np.flatnonzero(moved(_moved(probe, q=q)))
            if on_q.size:
                periods, once = _periods(e, probe, k)
                for i in on_q:
                    p = periods[i]
                    deps[i].append((f"q{k + 1}", None if np.isnan(p) else float(p)))
                    if once[i]:
                        once_per_turn.add(names[i])
            tau = probe.tau.copy()
            tau[:, k] += 1.0
            for i in np.flatnonzero(moved(_moved(probe, tau=tau))):
                deps[i].append((f"tau{k + 1}", None))
        for n, d in zip(names, deps, strict=True):
            out[n] = tuple(d)
    return Terms(out, frozenset(once_per_turn))


def unseen_phase(v: np.ndarray, lo: float, hi: float, period: float) -> np.ndarray:
    """Which readings ``v`` of a joint put a term of period ``period`` (rad) at a phase the fit
    did not see over ``lo..hi`` (widened by :data:`MARGIN`): a reading a whole number of periods
    from a fitted one is that reading to the term (a joint that turned once more, q1 5.6 rad
    against a fitted -0.7). None where the fit covered a whole period."""
    tol = MARGIN * (hi - lo) + 1e-9 * max(1.0, abs(lo), abs(hi))
    if hi - lo + 2 * tol >= period * (1 - 1e-9):
        return np.zeros(v.shape, dtype=bool)
    return np.mod(v - (lo - tol), period) > (hi - lo) + 2 * tol


def out_of_domain(
    model: ErrorModel,
    params: np.ndarray,
    identifiable: np.ndarray,
    domain: Domain,
    fitted: ModelInputs,
    inputs: ModelInputs,
) -> tuple[list[Excursion], dict[str, np.ndarray]]:
    """The excursions of ``inputs`` from ``domain``, and for each identified parameter whose
    term does not hold there (the module docstring) the rows it must be left out of. The terms'
    dependence is probed on ``fitted``, the inputs of the fit."""
    exc = domain.excursions(inputs)
    if not exc:
        return exc, {}
    by_var = {e.variable: e for e in exc}
    lay = model.layout
    candidates = [n for k, n in enumerate(lay.names) if identifiable[k] and params[k] != 0.0]
    if not candidates:
        return exc, {}
    dependence = term_dependence(model, fitted)
    terms = dependence.by_parameter
    values = _variables(inputs)
    drop: dict[str, np.ndarray] = {}
    for n in candidates:
        rows = np.zeros(inputs.n, dtype=bool)
        for var, period in terms.get(n, ()):
            e = by_var.get(var)
            if e is None:
                continue
            if period is not None:
                if n in dependence.once_per_turn and e.hi - e.lo >= ECCENTRICITY_ARC:
                    continue  # an eccentricity, identified over half a turn: the whole turn
                rows |= e.rows & unseen_phase(values[var], e.lo, e.hi, period)
                continue
            rows |= e.rows
        if rows.any():
            drop[n] = rows
    return exc, drop


def fallback_text(
    source: str, exc: Sequence[Excursion], drop: Mapping[str, np.ndarray], kept: bool
) -> str:
    """The warning of data outside a model's domain."""
    # the gravity torques follow from the joints: named only where no joint is out
    shown = [e for e in exc if not e.variable.startswith("tau")] or list(exc)
    text = f"{source}: outside the fitted domain: " + "; ".join(e.text() for e in shown[:4])
    if len(shown) > 4:
        text += f"; and {', '.join(e.variable for e in shown[4:])}"
    if drop:
        names = ", ".join(list(drop)[:8]) + (f" and {len(drop) - 8} more" if len(drop) > 8 else "")
        rows = int(np.logical_or.reduce(list(drop.values())).sum())
        if kept:
            text += f". The terms {names} are extrapolated there (as asked)"
        else:
            text += (
                f". The terms {names} do not hold there (their form is not periodic over what "
                f"the fit covered): those {rows} rows are predicted by the model without them "
                "(extrapolate=True, --extrapolate, keeps them)"
            )
    return text


def warn_out_of_domain(
    source: str, exc: Sequence[Excursion], drop: Mapping[str, np.ndarray], kept: bool
) -> None:
    if not exc:
        return
    text = fallback_text(source, exc, drop, kept)
    log.warning("%s", text)
    warn(text, OutOfDomainWarning)


# -- what the fit did not identify ----------------------------------------------------------------
def tool_placed_text(stations: Sequence[int], shift: Mapping[str, float]) -> str:
    """The line that says which unidentified tool parameters were placed with new bases."""
    ids = ", ".join(map(str, stations))
    moved = ", ".join(f"{k} {1e3 * v:+.3f} mm" for k, v in shift.items())
    return (
        f"validation: {', '.join(shift)} not identified by the fit (its poses hardly turned the "
        f"flange: the base took it); placed with the base of station(s) {ids} on the reference "
        f"points ({moved} from the fit's value): the prediction does not rest on a tool offset "
        "the calibration never determined"
    )


def warn_tool_placed(source: str, stations: Sequence[int], shift: Mapping[str, float]) -> None:
    if not shift:
        return
    text = f"{source}: {tool_placed_text(stations, shift)}"
    log.warning("%s", text)
    warn(text, ToolPlacedWarning)
