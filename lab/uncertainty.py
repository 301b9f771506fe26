"""What a calibration knows of its own parameters: their covariance and the spread between the
sessions it was fitted on (docs/format.md, ``[uncertainty]``).

    u = uncertainty_of(result)          # a fit: its covariance, and per-session fits' spread
    u.prior_covariance()                # covariance + spread**2 on the diagonal: what an update
                                        # (lab.update) takes as its prior

**Covariance.** ``s^2 (J^T J)^-1`` of the fit's rows at its solution (:attr:`FitResult.jacobian`,
weighted as the fit weighted them; a robust fit's IRLS weights in both), over the parameters it
identified, marginalised over the stations' bases (each session's own: an update frees its base).
On thousands of poses it is tiny: the scatter of the statistical estimate, not how much the arm
changes between sessions.

**Spread.** Where the fit's rows come from several sessions (a ``session`` column, else the
``station`` column, :func:`lab.transfer.block_column`), the same model is fitted to each session
alone and the spread of a parameter is the standard deviation of its values over the sessions
that identify it about the calibration's value (their scatter, and their mean's distance from
the calibration's value: a calibration of sessions that differ is a compromise none of them
holds), less the part each session's own standard error explains, from two sessions at least that determine it (its standard error in the session's
fit under its typical size; where fewer do, its typical size: nothing measured how it changes,
named in :attr:`Uncertainty.unmeasured`), and at
most its typical size (the effect's ``typical`` table: the spread of a term no session pins
down is what any arm's may be). It
holds what changes between sessions (a re-homed joint, a re-mounted tool, a region that
determines a term differently) and each session's own estimation noise. A calibration of one
session states that it has none (``sessions = 1``, no ``spread``).
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from arm.measurements import MeasurementSet
from arm.params import parse_parameter_name
from lab.errors import FitError, LabWarning, UncertaintyError
from lab.identifiability import typical_magnitudes
from lab.options import LabOptions
from lab.result import FitResult

__all__ = [
    "Prediction",
    "Rehoming",
    "Uncertainty",
    "UncertaintyError",
    "covariance_of",
    "draw_band",
    "is_session_own",
    "least_spread",
    "predicted_rms",
    "rehoming_of",
    "session_spread",
    "uncertainty_of",
]

log = logging.getLogger(__name__)


def least_spread(
    names: Sequence[str], rehome_mrad: float | None = None, remount_mm: float | None = None
) -> dict[str, float]:
    """The least spread between sessions (SI, by name) of the parameters of ``names`` that move
    between sessions whatever the calibration measured: each joint's zero offset (``dtheta``
    re-homed, ``rehome_mrad``) and the tool's offset (``tx``..., re-mounted, ``remount_mm``);
    the defaults are :class:`~lab.options.UpdateOptions`' (docs/lab.md, updating)."""
    from lab.options import UpdateOptions

    d = UpdateOptions()
    rehome = 1e-3 * (d.rehome_mrad if rehome_mrad is None else rehome_mrad)
    remount = 1e-3 * (d.remount_mm if remount_mm is None else remount_mm)
    out = {}
    for n in names:
        parsed = parse_parameter_name(n)
        if parsed is None:
            continue
        if parsed.kind == "row" and parsed.family == "dtheta":
            out[n] = rehome
        elif parsed.kind == "tool":
            out[n] = remount
    return out


def conditioned_refit(
    layout: Sequence[str], params: np.ndarray, names: Sequence[str], covariance: np.ndarray
) -> Callable[[Sequence[str]], np.ndarray]:
    """A :attr:`FitResult.refit <lab.result.FitResult.refit>` where the rows fitted are not at
    hand (an update, a calibration read from its file): the parameters ``params`` (over
    ``layout``) with the terms left out held at zero and the others moved as the fit's
    ``covariance`` (of ``names``) says they move with them. For a least-squares fit this is
    the refit itself to first order: the conditional mean of a Gaussian, ``p_r - C_rd C_dd^-1
    p_d``."""
    index = {str(n): i for i, n in enumerate(layout)}
    where = {str(n): j for j, n in enumerate(names)}
    cov = np.asarray(covariance, dtype=float)

    def refit(left_out: Sequence[str]) -> np.ndarray:
        p = np.array(params, dtype=float)
        d = [where[n] for n in left_out if n in where]
        r = [j for j in range(len(names)) if j not in set(d)]
        if d and r:
            at_d = [index[str(names[j])] for j in d]
            at_r = [index[str(names[j])] for j in r]
            solve = np.linalg.lstsq(cov[np.ix_(d, d)], p[at_d], rcond=1e-12)[0]
            p[at_r] -= cov[np.ix_(r, d)] @ solve
        p[[index[n] for n in left_out if n in index]] = 0.0
        return p

    return refit


def is_base(name: str) -> bool:
    """Whether ``name`` is a station's base parameter (``bx``, ``brz3``...): each session's own."""
    parsed = parse_parameter_name(name)
    return parsed is not None and parsed.kind == "base"


def is_session_own(name: str) -> bool:
    """Whether ``name`` is one session's own: a station's base, or its session's zero offset of
    a joint (``dtheta2_s3``). A calibration states neither (an unseen session has its own)."""
    parsed = parse_parameter_name(name)
    return parsed is not None and parsed.kind in ("base", "rehome")


@dataclass(frozen=True)
class Uncertainty:
    """A calibration's parameters: ``values``, every one's but the bases' (relative to its nominal
    arm, SI, by name); ``names``, those it identified, whose covariance (P, P) it states; the per-axis residual ``sigma`` (m) of its fit, how many ``sessions`` it
    was fitted on and the ``spread`` (P,) of the values between them (standard deviations; None:
    one session, no spread); ``unmeasured``: the names that fewer than two sessions identified
    (their spread is their typical size: nothing measured how they change)."""

    names: tuple[str, ...]
    values: Mapping[str, float]
    covariance: np.ndarray
    sigma: float
    sessions: int = 1
    spread: np.ndarray | None = None
    unmeasured: tuple[str, ...] = ()
    source: str = field(default="<memory>", compare=False)

    def __post_init__(self) -> None:
        n = len(self.names)
        where = f"{self.source}: [uncertainty]"
        if len(set(self.names)) != n:
            raise UncertaintyError(f"{where} names a parameter twice")
        values = {str(k): float(v) for k, v in dict(self.values).items()}
        cov = np.asarray(self.covariance, dtype=float)
        if cov.shape != (n, n):
            raise UncertaintyError(
                f"{where}: {n} parameters, but a covariance of shape {cov.shape}"
            )
        if missing := [k for k in self.names if k not in values]:
            raise UncertaintyError(f"{where}: no value of {', '.join(missing)}")
        if not (all(map(math.isfinite, values.values())) and np.isfinite(cov).all()):
            raise UncertaintyError(f"{where}: values and covariance must be finite")
        if n and not np.allclose(cov, cov.T, rtol=1e-6, atol=1e-30):
            raise UncertaintyError(f"{where}: the covariance is not symmetric")
        if n and np.linalg.eigvalsh(cov).min() < -1e-9 * max(float(np.abs(cov).max()), 1e-300):
            raise UncertaintyError(f"{where}: the covariance is not positive semi-definite")
        if not (math.isfinite(self.sigma) and self.sigma > 0):
            raise UncertaintyError(f"{where}: sigma must be a positive number, got {self.sigma}")
        if self.sessions < 1:
            raise UncertaintyError(f"{where}: sessions must be 1 or more, got {self.sessions}")
        spread = None
        if self.spread is not None:
            spread = np.asarray(self.spread, dtype=float).reshape(-1)
            if spread.shape != (n,) or not (np.isfinite(spread).all() and (spread >= 0).all()):
                raise UncertaintyError(
                    f"{where}: spread must be {n} finite numbers >= 0, one a parameter"
                )
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "spread", spread)

    @property
    def std(self) -> np.ndarray:
        """The standard errors of the fit (sqrt of the covariance's diagonal)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def prior_covariance(self, least: Mapping[str, float] | None = None) -> np.ndarray:
        """The covariance widened by the spread between sessions (added on the diagonal): what
        the parameters may be in a session the calibration has not seen. ``least``: the
        smallest spread of some parameters (by name, SI; :func:`least_spread`), used where the
        measured one is smaller or absent (one session)."""
        spread = np.zeros(len(self.names)) if self.spread is None else self.spread
        if least:
            floor = np.array([least.get(n, 0.0) for n in self.names])
            spread = np.maximum(spread, floor)
        return self.covariance + np.diag(spread**2)

    def to_dict(self) -> dict[str, Any]:
        """The ``[uncertainty]`` table of a calibration file (SI units)."""
        doc: dict[str, Any] = {
            "parameters": list(self.names),
            "values": dict(self.values),
            "covariance": [[float(v) for v in row] for row in self.covariance],
            "sigma": float(self.sigma),
            "sessions": int(self.sessions),
        }
        if self.spread is not None:
            doc["spread"] = [float(v) for v in self.spread]
            if self.unmeasured:
                doc["unmeasured"] = list(self.unmeasured)
        return doc

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any], source: str = "<memory>") -> Uncertainty:
        where = f"{source}: [uncertainty]"
        try:
            names = tuple(str(n) for n in doc["parameters"])
            return cls(
                names,
                dict(doc["values"]),
                np.asarray(doc["covariance"], dtype=float).reshape(len(names), len(names)),
                float(doc["sigma"]),
                int(doc.get("sessions", 1)),
                None if doc.get("spread") is None else np.asarray(doc["spread"], dtype=float),
                tuple(str(n) for n in doc.get("unmeasured", ())),
                source,
            )
        except KeyError as exc:
            raise UncertaintyError(f"{where}: missing key {exc}") from None
        except (TypeError, ValueError) as exc:
            raise UncertaintyError(f"{where}: {exc}") from None

    def summary(self) -> str:
        if self.spread is None:
            return f"one session ({len(self.names)} parameters' covariance; no spread between sessions)"
        return (
            f"{self.sessions} sessions: the spread between them widens the covariance of "
            f"{len(self.names)} parameters"
        )


# -- measured from a fit -------------------------------------------------------------------------
def covariance_of(result: FitResult) -> tuple[tuple[str, ...], np.ndarray]:
    """The covariance (module docstring) of the parameters ``result`` identified but each
    session's own (the bases, the sessions' zero offsets): (names, (P, P))."""
    names, cov = full_covariance(result)
    keep = np.array([not is_session_own(n) for n in names], dtype=bool)
    return tuple(n for n, k in zip(names, keep, strict=True) if k), cov[np.ix_(keep, keep)]


def full_covariance(result: FitResult) -> tuple[tuple[str, ...], np.ndarray]:
    """The covariance of every parameter ``result`` identified (the sessions' own included):
    (names, (P, P))."""
    free = np.flatnonzero(result.identifiable)
    names = np.asarray(result.names)[free]
    if free.size == 0:
        return (), np.zeros((0, 0))
    J = result.jacobian
    A = J.reshape(-1, J.shape[-1])[:, free]
    if result.weights is not None:
        A = A * np.sqrt(np.asarray(result.weights).reshape(-1))[:, None]
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    G = (A / scale).T @ (A / scale)
    cov = np.linalg.pinv(G, hermitian=True) / np.outer(scale, scale) * result.sigma**2
    return tuple(str(n) for n in names), cov


def _blocks_of(data: MeasurementSet) -> tuple[str | None, list[float]]:
    from lab.transfer import block_column

    col = block_column(data)
    return col, ([] if col is None else [float(b) for b in np.unique(data.columns[col])])


def fitted_rows(result: FitResult) -> MeasurementSet:
    """The rows ``result`` fitted, as measurements (the points: prediction minus residual)."""
    xyz = result.model.predict(result.inputs, result.params) - result.residuals
    return MeasurementSet(result.inputs.q, xyz, dict(result.inputs.columns), result.source)


@dataclass(frozen=True)
class Spread:
    """What per-session fits measured: how many ``sessions``, the ``spread`` of each parameter
    (None: one session), the names fewer than two sessions identified (``unmeasured``) and the
    per-axis residual ``sigma`` of a session fitted alone (m; None: one session)."""

    sessions: int = 1
    spread: np.ndarray | None = None
    unmeasured: tuple[str, ...] = ()
    sigma: float | None = None


def session_spread(
    result: FitResult, names: Sequence[str], data: MeasurementSet | None = None
) -> Spread:
    """The model of ``result`` fitted to each session of its rows (``data``: those rows,
    default rebuilt from the result) alone (module docstring): the :class:`Spread` of
    ``names``."""
    rows = fitted_rows(result) if data is None else data
    col, blocks = _blocks_of(rows)
    if col is None:
        return Spread()
    values: dict[str, list[float]] = {n: [] for n in names}
    sigmas: list[float] = []
    typical = dict(zip(result.names, typical_magnitudes(result.model), strict=True))
    noise: dict[str, list[float]] = {n: [] for n in names}
    opts = LabOptions(outliers="keep", accept_large=True, noise_mm=1e3 * result.sigma)
    from lab.estimation import fit_rows

    for b in blocks:
        part = rows.subset(np.flatnonzero(rows.columns[col] == b))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", LabWarning)
                fit = fit_rows(part, result.model.robot, list(result.model.effects), opts)
        except FitError as exc:
            log.info("%s: session %s=%g not fitted alone: %s", result.source, col, b, exc)
            continue
        got, std = fit.parameters(), fit.standard_errors()
        sigmas.append(fit.sigma)
        for n, ok in zip(fit.names, fit.identifiable, strict=True):
            # a value the session determines (its standard error under the parameter's
            # typical size): a joint's harmonic over the few degrees one session turned it
            # is not a measurement of how the arm changed
            if ok and n in values and (std[n] or 0.0) < typical[n]:
                values[n].append(got[n])
                noise[n].append(std[n] or 0.0)
    own = result.parameters()
    spread = np.array(
        [
            min(_deviation(v, own[n], noise[n]), typical[n]) if len(v) >= 2 else typical[n]
            for n, v in values.items()
        ]
    )
    unmeasured = tuple(n for n, v in values.items() if len(v) < 2)
    sigma = float(np.sqrt(np.mean(np.square(sigmas)))) if sigmas else None
    return Spread(len(blocks), spread, unmeasured, sigma)


def _deviation(values: Sequence[float], calibrated: float, std: Sequence[float]) -> float:
    """The RMS of the sessions' values about the calibration's (their scatter, with the sample's
    degree of freedom, and the calibration's bias), less what each session's own estimation
    noise (``std``, its standard errors) explains of it: how much the parameter changed."""
    v = np.asarray(values, dtype=float)
    scatter = float(np.var(v, ddof=1))
    bias = float(np.mean(v) - calibrated) ** 2
    own = float(np.mean(np.square(std)))
    return float(np.sqrt(max(scatter + bias - own, 0.0)))


@dataclass(frozen=True)
class Rehoming:
    """The sessions' own zero offsets of a fit of several stations (``dtheta{i}_s{s}``):
    ``offsets`` (S, 6), rad, of every station's session (the last's minus the others' sum; 0
    where not identified), ``joints`` the joints (1..6) whose offsets the fit told apart from
    the bases, ``spread`` (6,) each joint's re-homing standard deviation (rad) measured from
    them (:func:`rehoming_of`; NaN where not told apart) and ``expected`` (6,) the spread of an
    unseen session's offset about the calibration's ``dtheta{i}`` (``spread * sqrt(1 + 1/S)``:
    the sessions' mean is itself a draw)."""

    stations: tuple[int, ...]
    offsets: np.ndarray
    joints: tuple[int, ...]
    spread: np.ndarray
    expected: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        def mrad(v: np.ndarray) -> list[float | None]:
            return [None if not math.isfinite(x) else 1e3 * float(x) for x in v]

        return {
            "stations": list(self.stations),
            "offsets_mrad": [mrad(row) for row in self.offsets],
            "joints": list(self.joints),
            "spread_mrad": mrad(self.spread),
            "expected_mrad": mrad(self.expected),
        }


def rehoming_of(result: FitResult) -> Rehoming | None:
    """The :class:`Rehoming` of a fit of several stations whose sessions have their own zero
    offsets, None otherwise. A joint's spread is the RMS of the stations' offsets with S - 1
    degrees of freedom, less the part their standard errors explain (their covariance)."""
    from arm.effects.chain import session_offsets

    stations = tuple(result.model.stations)
    S = len(stations)
    names = result.names
    if S < 2 or f"dtheta1_s{stations[0]}" not in names:
        return None
    got = result.parameters()
    values = np.array([[got[f"dtheta{i}_s{s}"] or 0.0 for i in range(1, 7)] for s in stations[:-1]])
    offsets = session_offsets(values)
    ident = dict(zip(names, result.identifiable, strict=True))
    joints = tuple(i for i in range(1, 7) if all(ident[f"dtheta{i}_s{s}"] for s in stations[:-1]))
    spread = np.full(6, np.nan)
    if joints:
        full, cov = full_covariance(result)
        at = {n: k for k, n in enumerate(full)}
        # the stations' offsets are T v, v the S - 1 named, T = [I; -1...-1]
        T = np.vstack([np.eye(S - 1), -np.ones((1, S - 1))])
        for i in joints:
            idx = [at[f"dtheta{i}_s{s}"] for s in stations[:-1]]
            noise = float(np.trace(T @ cov[np.ix_(idx, idx)] @ T.T))
            square = float(np.sum(offsets[:, i - 1] ** 2))
            spread[i - 1] = math.sqrt(max(square - noise, 0.0) / (S - 1))
    return Rehoming(stations, offsets, joints, spread, spread * math.sqrt(1.0 + 1.0 / S))


def uncertainty_of(result: FitResult, data: MeasurementSet | None = None) -> Uncertainty:
    """The :class:`Uncertainty` of a fit: its own where it states one (an update's posterior),
    else its covariance and the spread of per-session fits (module docstring); the zero offsets
    of the joints whose sessions' own offsets the fit identified spread as those offsets do
    (:func:`rehoming_of`)."""
    if result.uncertainty is not None:
        return Uncertainty.from_dict(result.uncertainty, result.source)
    names, cov = covariance_of(result)
    s = session_spread(result, names, data)
    values = {n: v for n, v in result.parameters().items() if not is_session_own(n)}
    sigma = result.sigma if s.sigma is None else s.sigma
    spread, unmeasured = s.spread, s.unmeasured
    rehome = rehoming_of(result)
    if spread is not None and rehome is not None and rehome.joints:
        measured = {f"dtheta{i}": float(rehome.expected[i - 1]) for i in rehome.joints}
        spread = np.array([measured.get(n, v) for n, v in zip(names, spread, strict=True)])
        unmeasured = tuple(n for n in unmeasured if n not in measured)
    return Uncertainty(names, values, cov, sigma, s.sessions, spread, unmeasured, result.source)


def with_uncertainty(result: FitResult, u: Uncertainty) -> FitResult:
    """``result`` stating ``u`` as its own (what an export writes)."""
    return replace(result, uncertainty=u.to_dict())


# -- the accuracy it predicts ------------------------------------------------------------------------
@dataclass(frozen=True)
class Prediction:
    """The RMS (mm, 3-D) a calibration expects on some poses, before they are measured: from its
    parameters' covariance (``parameters_mm``: the RMS of J C J^T over the poses) and the
    discrepancy a session fitted alone leaves (``discrepancy_mm``, sqrt(3) sigma), added in
    quadrature (``rms_mm``); ``unseen``: whether the poses are of a session the parameters were
    not fitted on (then the covariance is widened by the spread between sessions)."""

    rms_mm: float
    parameters_mm: float
    discrepancy_mm: float
    unseen: bool
    poses: int
    low_mm: float = math.nan
    high_mm: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        return {
            "rms_mm": self.rms_mm,
            "low_mm": self.low_mm,
            "high_mm": self.high_mm,
            "parameters_mm": self.parameters_mm,
            "discrepancy_mm": self.discrepancy_mm,
            "unseen": self.unseen,
            "poses": self.poses,
        }

    def text(self) -> str:
        where = "a session it has not seen" if self.unseen else "the session it was fitted on"
        return (
            f"predicted RMS {self.rms_mm:.4f} mm (5-95 %: {self.low_mm:.4f}-{self.high_mm:.4f}) "
            f"on {self.poses} poses of {where} (parameters {self.parameters_mm:.4f} mm, the "
            f"model's discrepancy {self.discrepancy_mm:.4f} mm)"
        )


def predicted_rms(
    result: FitResult,
    data: MeasurementSet | np.ndarray,
    *,
    unseen: bool,
    u: Uncertainty | None = None,
    references: MeasurementSet | np.ndarray | None = None,
) -> Prediction:
    """The 3-D RMS ``result`` expects on the poses of ``data`` (measurements, or a program's
    joint angles (N, 6): nothing measured is read) (:class:`Prediction`): the
    covariance of its parameters (``u``, default its own, :func:`uncertainty_of`), widened by the
    spread where the poses are ``unseen`` (for a calibration of one session, which measured
    none, the least spread, :func:`least_spread`), through the Jacobian at those poses, and the discrepancy of one session fitted alone. The
    base is placed on ``references`` (the reference poses that register a new station: joint
    angles or measurements, their measured points unread), their noise carried to the target;
    without them on the poses themselves (what a change of the parameters moves as a base
    does, it takes up). Nothing is added for poses outside the fitted domain."""
    u = uncertainty_of(result) if u is None else u
    model = result.model
    names = [n for n in u.names if n in model.layout]
    keep = [u.names.index(n) for n in names]
    # the least spread where nothing was measured between sessions (one session): sessions that
    # were measured say how much this shop's sessions differ
    least = least_spread(u.names) if u.spread is None else None
    cov = (u.prior_covariance(least) if unseen else u.covariance)[np.ix_(keep, keep)]
    A, B = _columns_at(result, data, names)
    n = len(A) // 3
    discrepancy = math.sqrt(3.0) * u.sigma
    if B is not None and references is not None:
        Ar, Br = _columns_at(result, references, names)
        assert Br is not None
        P = B @ np.linalg.pinv(Br)  # the base placed on the references moves the target so
        A = A - P @ Ar
        # each reference's own error (the discrepancy) moves the base with it
        discrepancy = math.hypot(discrepancy, u.sigma * float(np.linalg.norm(P)) / math.sqrt(n))
    elif B is not None:  # what the base placed on these poses takes up, it does not err by
        A = A - B @ np.linalg.lstsq(B, A, rcond=None)[0]
    params = float(np.sqrt(np.einsum("ia,ab,ib->", A, cov, A) / n))
    low, high = draw_band(A, cov, n, discrepancy)
    return Prediction(
        1e3 * math.hypot(params, discrepancy),
        1e3 * params,
        1e3 * discrepancy,
        unseen,
        n,
        1e3 * low,
        1e3 * high,
    )


def _columns_at(
    result: FitResult, data: MeasurementSet | np.ndarray, names: Sequence[str]
) -> tuple[np.ndarray, np.ndarray | None]:
    """The Jacobian columns (3N, P) of ``names`` at the poses of ``data`` (as measured from the
    fit's first station), and those of the base (None without one)."""
    from lab.result import inputs_of

    if not isinstance(data, MeasurementSet):
        q = np.atleast_2d(np.asarray(data, dtype=float))
        data = MeasurementSet(q, np.zeros((len(q), 3)), source="program")
    model = result.model
    cols = {k: v for k, v in data.columns.items() if k != "station"}
    if "station" in result.inputs.columns:  # each station's base is placed: the first one's
        cols["station"] = np.full(len(data), float(model.stations[0]))
    inputs = inputs_of(model, MeasurementSet(data.q, data.xyz, cols, data.source))
    _, J = model.predict(inputs, result.params, jacobian=True)
    A = J[:, :, model.layout.indices(names)].reshape(-1, len(names))
    base = [n for n in model.layout.names if is_base(n)]
    if not base:
        return A, None
    return A, J[:, :, model.layout.indices(base)].reshape(-1, len(base))


#: draws of the parameters for the band of a prediction (seeded: the same band every time)
BAND_DRAWS = 400


def draw_band(A: np.ndarray, cov: np.ndarray, n: int, discrepancy: float) -> tuple[float, float]:
    """The 5-95 % range of the RMS over the poses of one draw of the parameters from ``cov``
    (the RMS of ``A delta``, delta ~ N(0, cov)), the discrepancy added in quadrature: the
    squared RMS is a weighted sum of chi-squares, the weights the eigenvalues of
    ``L^T A^T A L / n`` (``cov = L L^T``)."""
    if cov.size == 0:
        return discrepancy, discrepancy
    w, V = np.linalg.eigh(cov)
    L = V * np.sqrt(np.clip(w, 0.0, None))
    B = A @ L
    lam = np.clip(np.linalg.eigvalsh(B.T @ B / n), 0.0, None)
    z = np.random.default_rng(0).standard_normal((BAND_DRAWS, lam.size))
    r2 = (z**2) @ lam + discrepancy**2
    lo, hi = np.quantile(np.sqrt(r2), [0.05, 0.95])
    return float(lo), float(hi)
