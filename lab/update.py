"""A calibration updated with a few poses of a new session or region: a MAP fit.

    u = lab.update.update("calibrated.toml", read_measurements("new.csv"))
    u.result                     # a FitResult like any other: export, compensate, validate
    print(u.summary())

**The prior** is the calibration's parameters (``[uncertainty]`` of its file, or a fit's,
:mod:`lab.uncertainty`) relative to the nominal arm it calibrated, with their covariance widened
by the spread measured between the sessions it was fitted on, and at least by the least spread
declared for what moves between any two sessions (the joints' zero offsets re-homed, 2 mrad;
the tool re-mounted, 0.5 mm: :class:`~lab.options.UpdateOptions`), so that a calibration of one
session, which measured no spread, can still learn them. **Free** (no prior): the new
session's base (each station's), and the tool where it was re-mounted (``remount=True``). The
parameters the calibration did not identify are held at its values.

**The fit** minimises ``|(f(p) - y) / sigma|^2 + (p - p0)^T C^-1 (p - p0)`` over the free and
the prior's parameters by Gauss-Newton (``sigma``: the calibration's per-axis residual, or the
stated noise), the base placed in closed form first. With ``k`` poses it frees at most
``3k - 3`` parameters, in the order base translation, base rotation, tool; the others are held
at the calibration's values and named (a :class:`UpdateWarning`).

**Terms the prior holds** are re-estimated by the fit, within their prior. Each effect beside
the geometry is then kept as the prior holds it, released (fitted on the new poses alone, where
they can carry it) or dropped (held at zero), whichever predicts the new poses best when each is
left out in turn (the leave-one-pose-out error of the linearised fit, from its hat matrix).

**The calibration as it is, or moved.** The update is kept only where its leave-one-pose-out
error is below :data:`CHANGE` times that of the calibration as it is (its base placed on the new
poses, every other term held): else ``result`` is the calibration as it is
(:attr:`Update.moved` False). Twenty poses of a region the calibration fits well move its many
terms to fit their own noise (the UR10's series left out, ``results/ur10_sessions.md``).

**The discrepancy** the result states (its uncertainty's ``sigma``, which the prediction adds,
:func:`lab.uncertainty.predicted_rms`) is the larger of the calibration's and what the new
poses measured: their leave-one-pose-out RMS less what the covariance explains at them.

**The result** is a :class:`~lab.result.FitResult` of the update's model (the nominal arm and
the calibration's effects), its residuals on the new poses, its standard errors and covariance
the posterior's (:attr:`FitResult.uncertainty`, which an export writes), its domain the
calibration's and the new poses' together (the calibration's alone where it is kept as it is:
the new poses fitted none of its terms). Outside it, the terms that do not hold are left out
and the others moved as the covariance says a refit would move them
(:func:`lab.uncertainty.conditioned_refit`: the rows fitted are not at hand).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from arm.constraints import check, constraints_of
from arm.description import RobotDescription, as_robot
from arm.effect_api import EffectError
from arm.effects import EFFECTS, Effect
from arm.errormodel import ErrorModel
from arm.errors import warn
from arm.measurements import MeasurementSet, as_measurements
from arm.params import BASE_NAMES, parse_parameter_name
from lab.domain import Domain
from lab.errors import FitError, UpdateWarning
from lab.estimation import model_of
from lab.identifiability import Identifiability
from lab.options import UpdateOptions
from lab.registration import register_base, tool_indices
from lab.result import FitResult, RowsCounted, rms
from lab.uncertainty import (
    Uncertainty,
    UncertaintyError,
    conditioned_refit,
    is_base,
    least_spread,
    uncertainty_of,
)

__all__ = ["Prior", "Update", "UpdateWarning", "geometric_prior", "prior_of", "update"]

log = logging.getLogger(__name__)

ITERATIONS = 30
#: an effect is dropped or released only where that lowers the leave-one-pose-out error by 10 %
#: at least: with tens of poses, smaller differences are the draw's (the UR10's folds)
CHANGE = 0.9
STEP_TOL = 1e-10  # m or rad, scaled: Gauss-Newton stops when no parameter moves more
#: the smallest variance of a prior's direction, relative to its largest (correlations scaled)
PRIOR_RCOND = 1e-12


@dataclass(frozen=True)
class Prior:
    """What an update starts from: the ``nominal`` arm calibrated, the calibration's
    ``effects`` (instances) and its :class:`~lab.uncertainty.Uncertainty`; ``domain``: where it
    was identified (None: not recorded)."""

    nominal: RobotDescription
    effects: tuple[Effect, ...]
    uncertainty: Uncertainty
    domain: Domain | None = None
    source: str = "<memory>"


def prior_of(calibration: Prior | FitResult | RobotDescription | str | Path) -> Prior:
    """The prior of a calibration: a fit (its uncertainty measured, :mod:`lab.uncertainty`), or
    a calibrated arm (a robot TOML that ``lab export`` wrote, or its description) with its
    ``[nominal]`` and ``[uncertainty]``."""
    if isinstance(calibration, Prior):
        return calibration
    if isinstance(calibration, FitResult):
        u = uncertainty_of(calibration)
        return Prior(
            calibration.model.robot,
            tuple(calibration.model.effects),
            u,
            calibration.domain,
            calibration.source,
        )
    desc = as_robot(calibration)
    source = str(calibration) if isinstance(calibration, str | Path) else desc.name
    if desc.nominal is None or not desc.uncertainty:
        missing = "[nominal]" if desc.nominal is None else "[uncertainty]"
        raise UncertaintyError(
            f"{source}: not a calibration an update can start from: it has no {missing} (the "
            "arm calibrated, the parameters' covariance); export it again with sixaxis lab export"
        )
    unknown = [e for e in desc.effects if e != "geometric" and e not in EFFECTS]
    if unknown:
        raise FitError(
            f"{source}: carries values of effect(s) {', '.join(unknown)} that are not "
            "registered: load the module that defines them (--effect-module FILE.py)"
        )
    try:
        effects = [EFFECTS["geometric"]()] + [
            EFFECTS[n].from_parameters(list(v)) for n, v in desc.effects.items() if n != "geometric"
        ]
    except EffectError as exc:
        raise FitError(f"{source}: {exc}") from None
    u = Uncertainty.from_dict(desc.uncertainty, source)
    return Prior(desc.nominal, tuple(effects), u, Domain.of_description(desc.domain), source)


@dataclass(frozen=True)
class Update:
    """An updated calibration (``result``) and how it was made: the ``prior``, the new
    ``poses``; ``free``, the parameters no prior held (fitted on the new poses alone);
    ``held``, those it would have freed but the poses were too few for (held at the
    calibration's values); ``dropped``, ``released``: the effects the new poses dropped (held at
    zero) or fitted alone (their prior released); ``prior_rms_mm``: the calibration's own 3-D
    RMS on the new poses, its base placed on them (the prior alone)."""

    result: FitResult
    prior: Prior
    poses: int
    free: tuple[str, ...]
    held: tuple[str, ...] = ()
    dropped: tuple[str, ...] = ()
    released: tuple[str, ...] = ()
    prior_rms_mm: float = float("nan")
    remount: bool = False
    choices: dict[str, dict[str, float]] = field(default_factory=dict)
    # the calibration alone, its free parameters (the base) fitted on the new poses: what it
    # predicts without the update (validate it as any fit)
    prior_result: FitResult | None = field(default=None, repr=False, compare=False)
    # the leave-one-pose-out 3-D RMS (mm) of the update on its poses (its hat matrix)
    loo_rms_mm: float = float("nan")
    # whether the new poses moved the calibration's terms (False: ``result`` is the calibration
    # as it is, its base placed: updated, its terms predicted the poses left out no better)
    moved: bool = True

    def to_dict(self) -> dict[str, Any]:
        return {
            "poses": self.poses,
            "calibration": self.prior.source,
            "sessions": self.prior.uncertainty.sessions,
            "remount": self.remount,
            "free": list(self.free),
            "held": list(self.held),
            "dropped": list(self.dropped),
            "released": list(self.released),
            "prior_rms_mm": self.prior_rms_mm,
            "rms_mm": self.result.rms_mm,
            "moved": self.moved,
            "loo_rms_mm": self.choices,
            "update_loo_rms_mm": self.loo_rms_mm,
        }

    def summary(self) -> str:
        u = self.prior.uncertainty
        lines = [
            f"update of {self.prior.source} ({u.summary()}) with {self.poses} poses of "
            f"{self.result.source}: RMS {self.prior_rms_mm:.4f} mm (the calibration, its base "
            f"placed) -> {self.result.rms_mm:.4f} mm",
            f"free (no prior): {', '.join(self.free) or 'none'}",
        ]
        if not self.moved:
            c = self.choices.get("calibration", {})
            lines.append(
                "the calibration's terms kept as they are: moved by these poses they predict "
                f"each pose left out no better ({c.get('updated', math.nan):.4f} mm, as they "
                f"are {c.get('placed', math.nan):.4f} mm)"
            )
        if self.held:
            lines.append(
                f"held at the calibration's values (too few poses): {', '.join(self.held)}"
            )
        if self.dropped:
            lines.append(
                f"dropped (the new poses predict better without): {', '.join(self.dropped)}"
            )
        if self.released:
            lines.append(f"fitted on the new poses alone: {', '.join(self.released)}")
        return "\n".join(lines)


# -- the MAP fit --------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Problem:
    """One update problem: the model and its inputs, the measured points, the noise, the prior
    (its names' indices, mean and the square root of its precision)."""

    model: ErrorModel
    inputs: Any
    xyz: np.ndarray
    sigma: float
    prior_idx: np.ndarray
    mean: np.ndarray
    covariance: np.ndarray  # the prior's (widened by the spread)
    roots: dict[tuple[int, ...], np.ndarray] = field(default_factory=dict, repr=False)

    def root(self, prior: np.ndarray) -> np.ndarray:
        """R with R^T R the inverse of the marginal prior of the parameters ``prior`` (once
        per set: the Gauss-Newton steps and the effects' choices reuse it)."""
        key = tuple(int(j) for j in prior)
        if key not in self.roots:
            self.roots[key] = _precision_root(self.covariance[np.ix_(prior, prior)])
        return self.roots[key]


@dataclass(frozen=True)
class _Solution:
    params: np.ndarray
    active: np.ndarray  # indices fitted: free, then prior
    A: np.ndarray  # the scaled augmented Jacobian at the solution (data rows, then prior rows)
    scale: np.ndarray
    residual: np.ndarray  # data rows (k, 3), m
    iterations: int
    loo_rms: float  # the leave-one-pose-out 3-D RMS, m
    inverse: np.ndarray  # (A^T A)^+: the covariance in the scaled parameters

    @cached_property
    def covariance(self) -> np.ndarray:
        return self.inverse / np.outer(self.scale, self.scale)


def _precision_root(cov: np.ndarray) -> np.ndarray:
    """R with R^T R the (pseudo-)inverse of ``cov``."""
    if cov.size == 0:
        return np.zeros((0, 0))
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    d[d == 0] = 1.0
    w, V = np.linalg.eigh(cov / np.outer(d, d))
    # a direction of (numerically) no variance is one the prior fixes: floored, never dropped
    # (a pseudo-inverse would leave it free)
    w = np.maximum(w, PRIOR_RCOND * max(float(w.max()), 1e-300))
    return (V / np.sqrt(w)).T / d


def _augmented(pb: _Problem, p: np.ndarray, free: np.ndarray, prior: np.ndarray):
    """The rows of the MAP objective at ``p``: (A (rows, a), r (rows,)), data rows in units of
    sigma, over the parameters ``free`` then ``prior`` (indices into ``pb.prior_idx``)."""
    pred, J = pb.model.predict(pb.inputs, p, jacobian=True)
    r_data = ((pred - pb.xyz) / pb.sigma).reshape(-1)
    active = np.concatenate([free, pb.prior_idx[prior]])
    A_data = J.reshape(-1, J.shape[-1])[:, active] / pb.sigma
    # the prior rows: R (p - mean) over the prior parameters kept (their marginal prior)
    if prior.size:
        R = pb.root(prior)
        r_prior = R @ (p[pb.prior_idx[prior]] - pb.mean[prior])
        A_prior = np.hstack([np.zeros((len(R), free.size)), R])
    else:
        r_prior, A_prior = np.zeros(0), np.zeros((0, active.size))
    return active, np.vstack([A_data, A_prior]), np.concatenate([r_data, r_prior]), pred


def _solve(pb: _Problem, p: np.ndarray, free: np.ndarray, prior: np.ndarray) -> _Solution:
    """Gauss-Newton on the MAP objective from ``p``; the leave-one-pose-out error at the end."""
    p = p.copy()
    k = len(pb.xyz)
    it = 0
    for it in range(1, ITERATIONS + 1):  # noqa: B007  (the count is reported)
        active, A, r, _ = _augmented(pb, p, free, prior)
        scale = np.linalg.norm(A, axis=0)
        scale[scale == 0] = 1.0
        step = np.linalg.lstsq(A / scale, -r, rcond=None)[0] / scale
        p[active] += step
        if np.max(np.abs(step)) < STEP_TOL:
            break
    active, A, r, pred = _augmented(pb, p, free, prior)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    M = np.linalg.pinv(As.T @ As, hermitian=True)
    Ad = As[: 3 * k].reshape(k, 3, -1)
    H = np.einsum("kia,kja->kij", Ad @ M, Ad)  # each pose's 3x3 block of the hat matrix
    rd = r[: 3 * k].reshape(k, 3)
    loo = np.linalg.solve(np.eye(3)[None] - H, rd[..., None])[..., 0] * pb.sigma
    return _Solution(p, active, As, scale, pred - pb.xyz, it, rms(loo), M)


# -- the update ---------------------------------------------------------------------------------
def _check_robot(prior: Prior, robot: RobotDescription | str | Path | None, source: str) -> None:
    if robot is None:
        return
    name = as_robot(robot).name
    if name != prior.nominal.name:
        raise FitError(
            f"{source}: measured on {name!r}, but the calibration {prior.source} is of "
            f"{prior.nominal.name!r}: an update joins poses of the arm it calibrated"
        )


def _free_order(model: ErrorModel, remount: bool) -> list[str]:
    """The parameters an update frees, in the order it frees them when the poses are few: each
    station's base translation, its rotation, then (re-mounted) the tool."""
    names = model.layout.names
    out = []
    for part in (BASE_NAMES[:3], BASE_NAMES[3:]):
        for s in model.stations:
            suffix = "" if len(model.stations) == 1 else str(s)
            out += [f"{c}{suffix}" for c in part if f"{c}{suffix}" in names]
    if remount:
        out += [str(names[i]) for i in tool_indices(model)]
    return out


def _start(pb: _Problem, prior: Prior, free: list[str]) -> np.ndarray:
    """The calibration's values, the base placed on the new poses in closed form (with the
    tool where it is free), or shifted alone where the poses are too few to turn it."""
    model, lay = pb.model, pb.model.layout
    p = model.nominal()
    for n, v in prior.uncertainty.values.items():
        if n in lay:
            p[lay.index(n)] = v
    if all(n in free for n in BASE_NAMES if n in lay) and len(pb.xyz) >= 3:
        tools = bool(free) and all(str(lay.names[i]) in free for i in tool_indices(model))
        return register_base(model, pb.inputs, pb.xyz, p, tools=tools)
    if any(n in free for n in ("bx", "by", "bz")):
        shift = np.mean(pb.xyz - model.predict(pb.inputs, p), axis=0)
        p[lay.indices(["bx", "by", "bz"])] += shift
    return p


def _choose_effects(pb: _Problem, p0, free, prior, effect_of, k) -> tuple[Any, dict]:
    """Each effect beside the geometry: kept (its prior), released (no prior) or dropped (at
    zero), whichever has the least leave-one-pose-out error, given the others' choice."""
    choices: dict[str, dict[str, float]] = {}
    best = _solve(pb, p0, free, prior)
    decided: dict[str, list[str]] = {"dropped": [], "released": []}
    for eff in dict.fromkeys(effect_of):
        if eff == "geometric":
            continue
        mine = np.flatnonzero([effect_of[j] == eff for j in prior])
        if not mine.size:
            continue
        rest = np.delete(prior, mine)
        own = pb.prior_idx[prior[mine]]
        options = {"kept": best}
        p_drop = best.params.copy()
        p_drop[own] = 0.0
        options["dropped"] = _solve(pb, p_drop, free, rest)
        if free.size + own.size <= 3 * k - 3:
            options["released"] = _solve(pb, best.params, np.concatenate([free, own]), rest)
        choices[eff] = {c: 1e3 * s.loo_rms for c, s in options.items()}
        pick = min(options, key=lambda c: (options[c].loo_rms, c != "kept"))
        if pick == "kept" or options[pick].loo_rms > CHANGE * best.loo_rms:
            continue
        decided[pick].append(eff)
        best, prior = options[pick], rest
        if pick == "released":
            free = np.concatenate([free, own])
    return (best, free, prior, decided), choices


def update(
    calibration: Prior | FitResult | RobotDescription | str | Path,
    data: MeasurementSet | str | Path,
    *,
    remount: bool = False,
    noise_mm: float | None = None,
    robot: RobotDescription | str | Path | None = None,
    rehome_mrad: float = UpdateOptions.rehome_mrad,
    remount_mm: float = UpdateOptions.remount_mm,
) -> Update:
    """The calibration updated with the poses of ``data`` (the module docstring). ``remount``:
    the tool was re-mounted (its offset is free); ``noise_mm``: the per-axis noise the new
    poses are weighted by (default the calibration's residual); ``robot``: the arm the poses
    were measured on, refused unless it is the one calibrated (by name); ``rehome_mrad``,
    ``remount_mm``: the least spread between sessions of the joints' zero offsets and of the
    tool's offset (:func:`lab.uncertainty.least_spread`), which the prior allows whatever the
    calibration measured."""
    given = {
        "remount": remount,
        "noise_mm": noise_mm,
        "rehome_mrad": rehome_mrad,
        "remount_mm": remount_mm,
    }
    bad = check(given, constraints_of(UpdateOptions))
    if bad:
        raise FitError("; ".join(bad))
    prior = prior_of(calibration)
    data = as_measurements(data)
    _check_robot(prior, robot, data.source)
    if data.has_orientation:
        log.info("%s: the update fits the positions alone", data.source)
    plain = MeasurementSet(data.q, data.xyz, dict(data.columns), data.source)
    model, inputs = model_of(plain, prior.nominal, list(prior.effects))
    lay, u = model.layout, prior.uncertainty
    k = len(data)
    order = _free_order(model, remount)
    n_free = max(0, min(len(order), 3 * k - 3))
    free_names, held = order[:n_free], tuple(order[n_free:])
    if held:
        text = (
            f"{data.source}: {k} pose(s) free {n_free} of the {len(order)} parameters an update "
            f"frees; held at the calibration's values: {', '.join(held)}"
        )
        log.warning("%s", text)
        warn(text, UpdateWarning)
    keep = [j for j, n in enumerate(u.names) if n in lay and n not in order]
    least = least_spread(u.names, rehome_mrad, remount_mm)
    cov = u.prior_covariance(least)[np.ix_(keep, keep)]
    names_p = [u.names[j] for j in keep]
    pb = _Problem(
        model,
        inputs,
        data.xyz,
        1e-3 * noise_mm if noise_mm is not None else u.sigma,
        lay.indices(names_p),
        np.array([u.values[n] for n in names_p]),
        cov,
    )
    p0 = _start(pb, prior, free_names)
    free = lay.indices(free_names)
    alone = _solve(pb, p0, free, np.zeros(0, dtype=int))
    prior_rms = rms(alone.residual)
    effect_of = [lay.effect_of(n) for n in names_p]
    (sol, free, _, decided), choices = _choose_effects(
        pb, p0, free, np.arange(len(names_p)), effect_of, k
    )
    # the prior alone counts the calibration's parameters as identified, as the update does:
    # outside the domain both leave out the same terms (lab.domain)
    prior_result = _result(
        pb, alone, prior, data, len(free_names), prior_rms, pb.prior_idx, _discrepancy(pb, alone)
    )
    # the calibration's terms moved by the new poses, or the calibration as it is (its base
    # placed): the first only where it predicts the poses left out in turn better by CHANGE
    moved = sol.loo_rms < CHANGE * alone.loo_rms
    choices["calibration"] = {"placed": 1e3 * alone.loo_rms, "updated": 1e3 * sol.loo_rms}
    if moved:
        result = _result(pb, sol, prior, data, free.size, prior_rms, None, _discrepancy(pb, sol))
    else:
        result, sol = prior_result, alone
        free = lay.indices(free_names)
        decided = {"dropped": [], "released": []}
        log.info(
            "%s: the calibration's terms are kept as they are (its base placed): updated on "
            "%d poses they predict the poses left out no better (%.4f mm, placed %.4f mm)",
            data.source,
            k,
            choices["calibration"]["updated"],
            choices["calibration"]["placed"],
        )
    return Update(
        result,
        prior,
        k,
        tuple(free_names),
        held,
        tuple(decided["dropped"]),
        tuple(decided["released"]),
        1e3 * prior_rms,
        remount,
        choices,
        prior_result,
        1e3 * sol.loo_rms,
        moved,
    )


def geometric_prior(prior: Prior) -> Prior:
    """``prior`` without its effects beside the geometry (their values at zero): what an update
    falls back to where the calibration's terms are not expected to help
    (:func:`lab.prediction.expect_update`)."""
    geo = [e for e in prior.effects if e.name == "geometric"]
    u = prior.uncertainty
    kinds = ("row", "beta", "base", "tool", "tool_rotation")
    names = {n for n in u.values if (p := parse_parameter_name(n)) and p.kind in kinds}
    keep = [j for j, n in enumerate(u.names) if n in names]
    spread = None if u.spread is None else u.spread[keep]
    sub = Uncertainty(
        tuple(u.names[j] for j in keep),
        {n: v for n, v in u.values.items() if n in names},
        u.covariance[np.ix_(keep, keep)],
        u.sigma,
        u.sessions,
        spread,
        tuple(n for n in u.unmeasured if n in names),
        u.source,
    )
    return replace(prior, effects=tuple(geo), uncertainty=sub)


def _result(
    pb: _Problem,
    sol: _Solution,
    prior: Prior,
    data: MeasurementSet,
    n_free: int,
    prior_rms: float,
    identified: np.ndarray | None = None,
    discrepancy: float | None = None,
) -> FitResult:
    """The update as a FitResult (the module docstring); ``identified``: parameters it counts
    as identified beside those it fitted (the calibration's, for the prior alone);
    ``discrepancy``: the per-axis residual its uncertainty states (:func:`_discrepancy`;
    default the calibration's)."""
    model = pb.model
    lay = model.layout
    P = len(lay)
    active = np.zeros(P, dtype=bool)
    active[sol.active] = True
    if identified is not None:
        active[identified] = True
    std = np.full(P, np.nan)
    std[sol.active] = np.sqrt(np.clip(np.diag(sol.covariance), 0.0, None))
    if identified is not None:  # the prior's own
        std[pb.prior_idx] = np.sqrt(np.clip(np.diag(pb.covariance), 0.0, None))
    k = len(data)
    sv = np.linalg.svd(sol.A, compute_uv=False)
    ident = Identifiability(
        names=lay.names,
        identifiable=active,
        scale=np.ones(P),
        singular_values=sv,
        combinations={},
        labels={},
        n_poses=k,
        noise=pb.sigma,
        held=tuple(n for n, a in zip(lay.names, active, strict=True) if not a),
    )
    posterior = prior.uncertainty if identified is not None else _posterior(pb, sol, prior, data)
    if discrepancy is not None and discrepancy > posterior.sigma:
        posterior = replace(posterior, sigma=discrepancy)
    if identified is not None:
        # the calibration as it is: the new poses placed its base, nothing of its terms was
        # fitted on them, so where they hold is where the calibration found them
        domain = prior.domain if prior.domain is not None else Domain.of(pb.inputs)
        names, cov = list(prior.uncertainty.names), prior.uncertainty.covariance
    else:
        domain = Domain.of(pb.inputs)
        if prior.domain is not None:
            domain = prior.domain.union(domain)
        names, cov = [str(lay.names[i]) for i in sol.active], sol.covariance
    return FitResult(
        model=model,
        params=sol.params,
        std=std,
        identifiable=active,
        residuals=sol.residual,
        identifiability=ident,
        loss="linear",
        iterations=sol.iterations,
        evaluations=sol.iterations + 1,
        sigma=float(np.sqrt(np.sum(sol.residual**2) / max(3 * k - n_free, 1))),
        initial_rms=prior_rms,
        inputs=pb.inputs,
        source=data.source,
        counted=RowsCounted(n_rows=k),
        uncertainty=posterior.to_dict(),
        fitted_domain=domain,
        refit=conditioned_refit(lay.names, sol.params, names, cov),
    )


def _discrepancy(pb: _Problem, sol: _Solution) -> float:
    """The per-axis discrepancy the new poses measured (m): the leave-one-pose-out RMS of
    ``sol`` less what its parameters' covariance explains at those poses, at least the
    calibration's own. Where the poses lie in a region the calibration was not fitted on, its
    residual there says more than the sessions it was fitted on did: the prediction
    (:func:`lab.uncertainty.predicted_rms`) adds this one."""
    k = len(pb.xyz)
    Ad = sol.A[: 3 * k] * pb.sigma  # the data rows, m per scaled parameter
    params2 = float(np.einsum("ia,ab,ib->", Ad, sol.inverse, Ad)) / k
    return max(pb.sigma, math.sqrt(max(sol.loo_rms**2 - params2, 0.0) / 3.0))


def _posterior(pb: _Problem, sol: _Solution, prior: Prior, data: MeasurementSet) -> Uncertainty:
    """The update's parameters with their posterior covariance, the prior's spread and
    sessions: what an export of the update carries."""
    lay, u = pb.model.layout, prior.uncertainty
    names = [str(lay.names[i]) for i in sol.active if not is_base(str(lay.names[i]))]
    pos = [list(sol.active).index(lay.index(n)) for n in names]
    return Uncertainty(
        tuple(names),
        {n: v for n, v in lay.as_dict(sol.params).items() if not is_base(n)},
        sol.covariance[np.ix_(pos, pos)],
        u.sigma,
        u.sessions,
        None if u.spread is None else _spread_of(u, names),
        u.unmeasured,
        data.source,
    )


def _spread_of(u: Uncertainty, names: Sequence[str]) -> np.ndarray:
    """The prior's spread of ``names`` (0 for a name it did not state: a re-mounted tool's)."""
    assert u.spread is not None
    by = dict(zip(u.names, u.spread, strict=True))
    return np.array([by.get(n, 0.0) for n in names])
