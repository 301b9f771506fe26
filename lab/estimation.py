"""Estimation: the fit of an error model's parameters to every row it is given.

    result = fit_rows(data, robot, "geometric,compliance", LabOptions(noise_mm=0.015))

The steps, each a pure function of arrays:

1. **Registration** (:mod:`lab.registration`): a large unknown base transform and tool offsets
   are placed in closed form before any iteration.
2. **Identifiability** (:mod:`lab.identifiability`) on the column-scaled Jacobian at the start:
   parameters that the poses cannot separate are fixed at nominal, not fitted into noise.
3. **Levenberg-Marquardt** (:mod:`lab.solver`) on the identifiable parameters, scaled so that
   every Jacobian column has an RMS of 1 m per pose, with the error model's analytic Jacobian.
   A robust loss (``huber``, ``soft_l1``) then runs scipy's trust-region reflective method from
   the linear solution, with ``f_scale`` set to 1.345 robust standard deviations of the residual
   (Huber's 95 %-efficiency constant) from the median absolute deviation, re-estimated once.
4. A second identifiability pass at the solution with the noise now known (``noise_mm``, else the
   residual's): a parameter whose typical-size error moves the points by less than the noise is
   fixed too, and a parameter only nearly dependent at the start is restored if the data determine
   it beyond the noise and beyond what the model leaves (its residual, where larger: systematic
   error takes up a near-null direction); then a short refit. Repeated poses count once here (:func:`distinct_poses`): repeating a
   pose averages the instrument's noise, not the model's own error, so 8,000 measurements of 60
   poses determine what 60 poses do.
5. **Standard errors** from the scaled Jacobian at the solution: ``cov = s^2 (J^T J)^-1`` with
   ``s^2 = sum r^2 / (3N - rank)`` (robust fits: IRLS weights in both).

Which rows are fitted is not decided here: :mod:`lab.screening` counts repeated rows once and
leaves gross outliers out, calling :func:`fit_rows` on the rows that count;
:func:`check_plausible` refuses identified values beyond the plausible bound of their kind
(:mod:`lab.plausibility`).
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np

from arm.description import RobotDescription, as_robot
from arm.effect_api import EffectError, ModelInputs
from arm.effects import EFFECTS, Effect, missing_inputs
from arm.errormodel import ErrorModel
from arm.errors import warn
from arm.measurements import COMPONENTS, MeasurementSet, as_measurements
from arm.noise import InstrumentNoise
from lab.blocks import Blocks
from lab.errors import (
    FitError,
    ImplausibleAcceptedWarning,
    LabWarning,
    OrientationNotFittedWarning,
)
from lab.identifiability import Identifiability, analyse_jacobian
from lab.observations import Observations, observations_of, uses_orientation
from lab.options import LabOptions
from lab.plausibility import Implausible, implausible, likely_cause
from lab.registration import (
    reading_hint,
    register_base,
    register_tool_rotation,
    tool_indices,
)
from lab.repeatability import stated_noise_of
from lab.result import FitResult, inputs_of, rms
from lab.sanity import check_stated_noise
from lab.solver import (
    HUBER_K,
    irls_weights,
    robust_sigma,
    solve,
    standard_errors,
    weighted_gram,
)

__all__ = ["fit_rows", "identifiability_of"]

log = logging.getLogger(__name__)

# The first pass fits only parameters at least 1 % independent of those before them: nearly
# dependent ones (a tool a fraction of a millimetre off joint 6's axis makes dalpha6 and dd5 so)
# would drift along the near-null space. The second pass, at the solution with the noise known,
# restores every one that the data determine (RANK_TOL and the noise criterion) and refits.
START_TOL = 1e-2
IMPLAUSIBLE_RMS = 0.1  # m: after a fit, no real arm's model is this far from most measurements
#: a residual this many times the noise is the model's own (systematic) error: a parameter nearly
#: dependent at the start is restored only where the data determine it beyond it
SYSTEMATIC = 1.5


def distinct_poses(data: MeasurementSet) -> int:
    """How many distinct poses the rows hold: distinct joint readings (with the target and the
    station, where the data name them). Repeated poses average the instrument's noise but not
    the model's own error: what the poses determine is judged per distinct pose, as if each were
    measured once (480,000 rows of 60 poses made nearly dependent parameters "identifiable" by
    the row count alone; a missing effect then drove them to centimetres and the fit was refused
    as another robot's file)."""
    keys = [data.q] + [data.columns[c][:, None] for c in ("target", "station") if c in data.columns]
    return max(1, len(np.unique(np.hstack(keys), axis=0)))


def rehomed_stations(data: MeasurementSet) -> bool:
    """Whether each station of ``data`` is a session of its own (files joined by
    :func:`arm.sessions.join_sessions`, each measured from one station no other file shares),
    two at least: each was re-homed, and a fit gives each its own zero offsets
    (:class:`arm.effects.chain.Geometric`). Stations of one file are one session (the tracker
    moved, the arm not re-homed); a station two files share holds two sessions, which the
    model cannot tell apart: no offsets of their own then."""
    stations = data.stations
    if len(stations) < 2 or len(data.sessions) < 2:
        return False
    owner: dict[int, int] = {}
    for k, s in enumerate(data.sessions):
        for sid in s.stations:
            if sid in owner or len(s.stations) != 1:
                return False
            owner[sid] = k
    return all(s in owner for s in stations)


def model_of(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: str | Sequence[str | Effect],
    measured: tuple[str, ...] | None = None,
    noise: InstrumentNoise | None = None,
) -> tuple[ErrorModel, ModelInputs]:
    """The error model for these data (one tool offset per target, one base per tracker
    station, the tool frame's rotation where orientations are fitted: ``measured``, and by
    default where ``noise`` or the data state their uncertainty) and its inputs."""
    turn = uses_orientation(data, measured, noise)
    try:
        model = ErrorModel(
            robot,
            effects,
            targets=data.targets,
            stations=data.stations,
            orientation=turn,
            rehomed=rehomed_stations(data),
        )
    except EffectError as exc:
        raise FitError(str(exc)) from None
    for e in model.effects:
        why = missing_inputs(e, model.robot, list(data.columns))
        if why:
            twin = [n for n, cls in EFFECTS.items() if cls.stands_in_for == e.name]
            instead = (
                f" (or fit {twin[0]}, which needs no mass model)"
                if twin and e.needs_masses and not model.robot.has_mass_model
                else ""
            )
            raise FitError(f"{data.source}: {e.label} cannot be fitted without {why}{instead}")
    return model, inputs_of(model, data)


def build_model(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: str | Sequence[str | Effect],
    measured: tuple[str, ...] | None = None,
    noise: InstrumentNoise | None = None,
) -> tuple[ErrorModel, ModelInputs]:
    """:func:`model_of`, refused where the data give no more equations than it has parameters."""
    model, inputs = model_of(data, robot, effects, measured, noise)
    turn = model.orientation
    n, P = len(data), len(model.layout)
    equations = 3 * n
    if turn:
        mask = data.measured
        if measured is not None:
            mask = mask & np.array([c in measured for c in COMPONENTS])
        equations = int(mask.sum())
    if equations <= P:
        need = P // 3 + 1
        raise FitError(
            f"{data.source}: {n} poses give {equations} equations, not more than the {P} "
            f"parameters of {','.join(model.effect_names)}; at least {need} poses are needed"
        )
    return model, inputs


def _registered(
    model: ErrorModel,
    inputs: ModelInputs,
    xyz: np.ndarray,
    p: np.ndarray,
    held: np.ndarray,
    obs: Observations,
) -> np.ndarray:
    """Step 1: the start ``p`` with the base and tool offsets placed in closed form (where that
    lowers the RMS; parameters ``held`` keep their values), and the tool frame's rotation where
    orientations are fitted."""
    before = rms(model.predict(inputs, p) - xyz)
    p_reg = register_base(model, inputs, xyz, p, tools=not held[tool_indices(model)].any())
    p_reg[held] = p[held]  # a held base keeps the value given: registration is a start only
    after = rms(model.predict(inputs, p_reg) - xyz)
    if after < before:
        log.debug("registration: RMS %.4g mm -> %.4g mm", before * 1e3, after * 1e3)
        p = p_reg
    if obs.rotation is not None:
        turn = model.layout.indices(["trx", "try", "trz"])
        if not held[turn].any():
            seen = np.asarray(obs.measured[:, 3:].any(axis=1))
            p = register_tool_rotation(model, inputs, p, obs.rotation, seen)
    return p


def _restored_beyond_residual(
    ident: Identifiability,
    first: np.ndarray,
    judge: Callable[..., Identifiability],
    left: float,
    noise: float,
    repeats: float,
) -> Identifiability:
    """``ident`` without the parameters it restores (nearly dependent at the start: not in
    ``first``) that the data do not determine beyond what the model leaves (``left``, m per
    axis, where :data:`SYSTEMATIC` times the ``noise`` or more; ``judge(noise=...)`` the
    identifiability at the solution): held and named with their combination, as weak.
    The residual is systematic, and a near-null direction determined against the instrument's
    noise alone takes it up: the UR10's tool 0.3 mm off joint 6's axis made dalpha6 and da6
    separable at 0.015 mm, and the 0.26 mm the geometric model leaves on its three series drove
    them, with dtheta5 and dd5, to 296 mrad, 27 mm, 148 mrad and 56 mm (refused as
    implausible)."""
    if not (left > SYSTEMATIC * noise and (ident.identifiable & ~first).any()):
        return ident
    strict = judge(noise=left * math.sqrt(repeats))
    drop = ident.identifiable & ~first & ~strict.identifiable
    if not drop.any():
        return ident
    names = [str(n) for n, d in zip(ident.names, drop, strict=True) if d]
    log.info("held, not determined beyond the model's residual: %s", ", ".join(names))
    return replace(
        ident,
        identifiable=ident.identifiable & ~drop,
        weak=(*ident.weak, *names),
        combinations=ident.combinations | {n: strict.combinations.get(n, {}) for n in names},
        labels=ident.labels | {n: strict.labels.get(n, n) for n in names},
    )


def _noise_of(
    noise_mm: float | None, obs: Observations, residuals: np.ndarray, sigma: float
) -> float:
    """The noise the second identifiability pass judges by (m): the one stated, else the
    weighted rows' reference, else the residual's (``sigma``) unless a few gross errors inflate
    it (then its robust scale)."""
    if noise_mm is not None and obs.plain:
        return noise_mm * 1e-3
    if obs.sigma_ref is not None:  # the weighted rows' noise, as the instrument states it
        return obs.sigma_ref
    rs = robust_sigma(residuals)
    return sigma if sigma <= 3.0 * rs else rs


def _warn_positions_alone(source: str) -> None:
    text = (
        f"{source}: the rows measure orientations, but their uncertainty is stated "
        "nowhere (--noise-mrad, std_rx..std_rz): the positions alone are fitted"
    )
    log.warning("%s", text)
    warn(text, OrientationNotFittedWarning)


def _check_follows(miss: np.ndarray, data: MeasurementSet, model: ErrorModel) -> None:
    """Refuse a fit whose median pose misses by more than :data:`IMPLAUSIBLE_RMS` (the median,
    not the RMS: a few gross outliers must not condemn the model), naming a joint coupling or
    DH convention that would explain it (:func:`lab.registration.reading_hint`)."""
    typical_miss = float(np.median(np.linalg.norm(miss, axis=1)))
    if typical_miss > IMPLAUSIBLE_RMS:
        hint = reading_hint(model.described, data.q, data.xyz, data.columns)
        raise FitError(
            f"{data.source}: the model cannot follow these measurements (RMS "
            f"{rms(miss) * 1e3:.4g} mm, median {typical_miss * 1e3:.4g} mm after fitting "
            f"{', '.join(model.layout.effects)}); "
            + (
                hint
                if hint
                else "are they in other units (length in mm, angles in deg: say so when "
                "reading) or of another robot?"
            )
        )


def _standard_errors(blocks: Blocks, sol, free: np.ndarray, w: np.ndarray | None, n_eq):
    """Step 5: the standard errors and the residual's sigma, from the Gram matrix of the columns
    as scaled in the solve (with a robust fit's IRLS weights ``w``)."""
    gram, scale = sol.gram, sol.scale
    if w is not None:  # the robust fit's IRLS weights in the Gram matrix
        gram = weighted_gram(blocks, sol.params, free, scale, w)
    return standard_errors(gram, sol.residuals, free, scale, w, n_eq)


def _robust(solved, sol, free, scale, loss: str, f_scale_mm, sigma: float, obs: Observations):
    """Step 3's robust loss: scipy's trust-region fit from the linear solution ``sol``, with
    ``f_scale`` the one given (mm) or 1.345 robust sigmas, re-estimated once. Returns the
    solution, the scale, and the iterations and evaluations it took."""
    f_scale = f_scale_mm * 1e-3 if f_scale_mm else HUBER_K * sigma
    iterations = evaluations = 0
    for _ in range(1 if f_scale_mm else 2):  # re-estimate the scale once, robustly
        sol = solved(sol.params, free, scale, loss, f_scale)
        iterations, evaluations = iterations + sol.iterations, evaluations + sol.evaluations
        if not f_scale_mm:
            f_scale = HUBER_K * robust_sigma(sol.residuals[obs.measured])
    return sol, f_scale, iterations, evaluations


def fit_rows(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: str | Sequence[str | Effect],
    options: LabOptions,
    *,
    start: Mapping[str, float] | None = None,
    fixed: Iterable[str] = (),
    judge_noise: bool = False,
) -> FitResult:
    """The fit of every pose of ``data``: registration, identifiability, Levenberg-Marquardt,
    identifiability again with the noise known, standard errors (the module docstring). Nothing
    is left out here: :mod:`lab.screening` decides which rows count. ``judge_noise``: refuse a
    stated noise that the residual refutes before it is used (:func:`lab.sanity.
    check_stated_noise`; the screen's first fit, of every distinct row, judges it: a fit of
    fewer rows, a trimmed start, would not be a fair judge)."""
    loss, noise_mm, f_scale_mm = options.loss, options.noise_mm, options.f_scale_mm
    model, inputs = build_model(data, robot, effects, options.measured, options.instrument)
    obs = observations_of(data, options.instrument, options.measured)
    if data.has_orientation and obs.rotation is None and options.measured is None:
        _warn_positions_alone(data.source)
    lay, xyz, target = model.layout, data.xyz, obs.target  # target: the points, plain
    p = model.nominal() if not start else lay.vector(start, default=model.nominal())
    held = np.zeros(len(lay), dtype=bool)
    held[[lay.index(n) for n in fixed]] = True
    if options.register and "geometric" in lay.effects:
        p = _registered(model, inputs, xyz, p, held, obs)
    blocks, n_eq = Blocks(model, inputs, observations=obs), obs.n_equations

    def solved(p, free, scale, loss="linear", f_scale=1.0):
        return solve(
            blocks, target, p, free, scale, loss, f_scale, options.max_evaluations, options.solver
        )

    def points(sol) -> np.ndarray:
        """The fit's position residuals (N, 3), m: the rows themselves in the plain case."""
        return sol.residuals if obs.plain else model.predict(inputs, sol.params) - xyz

    def identifiability(p, J, **kw):
        """At ``p``: from the whole Jacobian ``J`` when there is one block, else from the R of
        its QR decomposition (the same inner products, :mod:`lab.blocks`); held parameters'
        columns zeroed."""
        if J is None:
            R = _without(blocks.r_factor(p), held)
            return analyse_jacobian(model, R, n_poses=blocks.n, **kw)
        return analyse_jacobian(model, _without(J, held), **kw)

    # identifiability at the start (the structure), fit, again with the noise known, refit
    initial_rms, J = _at_start(blocks, model, inputs, p, xyz, obs)
    # held parameters are known: the others' identifiability is judged without their columns
    # (with the base held, row 1 is identifiable; with it free, the base absorbs row 1)
    ident = identifiability(p, J, tol=START_TOL, warn=False)
    del J
    _check_effects_identifiable(model, ident, held, data.source)
    check_campaign(ident, held, data, options.min_identified)
    free = ident.identifiable & ~held
    sol = solved(p, free, ident.scale)
    iterations, evaluations = sol.iterations, sol.evaluations
    if loss == "linear":
        sigma = float(np.sqrt(np.sum(sol.residuals**2) / max(n_eq - free.sum(), 1)))
    else:
        sigma = robust_sigma(sol.residuals[obs.measured])
    _check_follows(points(sol), data, model)
    # the residual no noise has touched yet: what judges a stated one (lab.sanity)
    stated = stated_noise_of(sol.residuals, obs.measured, obs.sigma_ref, int(free.sum()))
    if judge_noise:
        check_stated_noise(stated, options, data)
    noise = _noise_of(noise_mm, obs, sol.residuals, sigma)
    repeats = len(xyz) / distinct_poses(data)  # judged per distinct pose (distinct_poses)
    ident = identifiability(sol.params, sol.jacobian, noise=noise * math.sqrt(repeats), warn=True)
    left = float(np.sqrt(np.mean(points(sol) ** 2)))  # m per axis: what the model leaves
    judge = partial(identifiability, sol.params, sol.jacobian, warn=False)
    ident = _restored_beyond_residual(ident, free | held, judge, left, noise, repeats)
    if held.any():
        ident = replace(ident, held=tuple(np.asarray(lay.names)[held]))
    free2 = ident.identifiable & ~held
    _check_any_identifiable(free2, lay.effects, data.source, len(xyz), noise)
    if not np.array_equal(free2, free):
        free = free2
        sol = solved(np.where(free | held, sol.params, p), free, ident.scale)
        iterations, evaluations = iterations + sol.iterations, evaluations + sol.evaluations
    f_scale = None
    if loss != "linear":
        sol, f_scale, its, evs = _robust(
            solved, sol, free, ident.scale, loss, f_scale_mm, sigma, obs
        )
        iterations, evaluations = iterations + its, evaluations + evs

    r = sol.residuals
    w = irls_weights(r, loss, f_scale) if f_scale is not None else None
    std, sigma = _standard_errors(blocks, sol, free, w, None if obs.plain else n_eq)
    return FitResult(
        model=model,
        params=sol.params,
        std=std,
        identifiable=free,
        residuals=points(sol),
        weighted_rows=None if obs.plain else r,
        observations=obs,
        identifiability=ident,
        loss=loss,
        iterations=iterations,
        evaluations=evaluations,
        sigma=sigma,
        initial_rms=initial_rms,
        inputs=inputs,
        weights=w,
        source=data.source,
        stated_noise=stated,
        refit=partial(
            _refit_without,
            data,
            robot,
            list(model.effects),  # the instances: a user's module may be unregistered by then
            options,
            dict(zip(lay.names, sol.params, strict=True)),
            _loose_tool(model, free, held),
        ),
    )


def _at_start(
    blocks: Blocks,
    model: ErrorModel,
    inputs: ModelInputs,
    p: np.ndarray,
    xyz: np.ndarray,
    obs: Observations,
) -> tuple[float, np.ndarray | None]:
    """The RMS of the points at the start ``p``, and the whole Jacobian there when the rows are
    one block (None otherwise: the identifiability pass then works from the blocks' R)."""
    if blocks.single:
        pred, J = next(blocks.jacobians(p))[1:]
    else:
        pred, J = blocks.predict(p), None
    return (rms(pred - xyz) if obs.plain else rms(model.predict(inputs, p) - xyz)), J


def _check_any_identifiable(
    free: np.ndarray, effects: Sequence[str], source: str, n_rows: int, noise: float
) -> None:
    """Refuse a fit of which the poses identify no parameter at the noise found."""
    if not free.any():
        raise FitError(
            f"{source}: no parameter of {', '.join(effects)} can be identified from these"
            f" {n_rows} poses at a noise of {noise * 1e3:.3g} mm"
        )


def _loose_tool(model: ErrorModel, free: np.ndarray, held: np.ndarray) -> tuple[str, ...]:
    """The tool-point parameters the fit could not identify (nor was told): a refit without
    some terms holds them at this fit's values, so that the two predict from the same tool."""
    if "geometric" not in model.layout.effects:
        return ()
    idx = tool_indices(model)
    return tuple(str(model.layout.names[i]) for i in idx if not free[i] and not held[i])


def _refit_without(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: str | Sequence[str | Effect],
    options: LabOptions,
    values: Mapping[str, float],
    loose: Sequence[str],
    names: Sequence[str],
) -> np.ndarray:
    """The parameters of the same fit with ``names`` held at zero: the model without those
    terms, fitted to the same rows (what validation outside a model's domain falls back to,
    lab.domain). The rows are those given; none is left out again. The tool parameters the fit
    could not identify (``loose``) are held at its values: placed anew they would take whatever
    the registration gives them, and the two models would predict from different tools."""
    start = dict(values) | {n: 0.0 for n in names}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LabWarning)
        opts = replace(options, outliers="keep", accept_large=True)
        return fit_rows(data, robot, effects, opts, start=start, fixed=[*names, *loose]).params


def _check_effects_identifiable(
    model: ErrorModel, ident: Identifiability, held: np.ndarray, source: str
) -> None:
    """An effect asked for whose every parameter the data cannot identify (a constant column,
    a joint that gravity never loads) is an error, not parameters quietly held at nominal."""
    lay = model.layout
    for e in model.effects:
        if e.name == "geometric":
            continue
        sl = lay.slice(e.name)
        if (ident.identifiable[sl] | held[sl]).any():
            continue
        names = lay.names[sl]
        moves = [n for n in names if ident.combinations.get(n)]
        why = (
            "they move no measured point with these data"
            if not moves
            else "they move the points only as other parameters do ("
            + "; ".join(ident.labels[n] for n in moves[:4])
            + ")"
        )
        raise FitError(
            f"{source}: {e.label} cannot be fitted from these data: none of its parameters "
            f"({', '.join(names)}) is identifiable; {why}"
        )


def check_campaign(
    ident: Identifiability, held: np.ndarray, data: MeasurementSet, share: float = 1 / 3
) -> None:
    """A campaign that cannot identify most of the model is refused, saying what to measure:
    one distinct pose, or poses that identify fewer than ``share`` (``min_identified``, a third
    by default) of the parameters fitted (a full campaign identifies about three quarters: 25
    of 33 on the seed arm and the UR10, the rest combinations that no poses tell apart).
    Without this, 60 rows of one pose were "fitted" with 3 of 33 parameters and called a
    calibration. ``share`` 0 fits whatever the poses determine (an agent's calibration phase
    along a short path: 30 poses, 4 parameters)."""
    n = int((~held).sum())
    poses = distinct_poses(data)
    if n == 0 or share == 0 or (poses > 1 and ident.rank >= share * n):
        return
    need = max(30, 3 * math.ceil(n / 3))
    raise FitError(
        f"{data.source}: {poses} distinct pose{'s' if poses != 1 else ''} identify "
        f"{ident.rank} of the model's {n} parameters; measure at least {need} poses spread "
        "over every joint's range (sixaxis lab plan --n "
        f"{need} chooses them), not the same pose again"
    )


def _without(J: np.ndarray, held: np.ndarray) -> np.ndarray:
    """``J`` with the columns of held (known) parameters zeroed (the last axis: a Jacobian
    (N, 3, P) or the R factor (P, P) of one, whose inner products are the same)."""
    if not held.any():
        return J
    J = J.copy()
    J[..., held] = 0.0
    return J


def check_plausible(
    result: FitResult, accept: bool, data: MeasurementSet | None = None
) -> tuple[Implausible, ...]:
    """The identified parameters beyond the plausible bound of their kind: an error naming them
    and the likely cause (a joint coupling or DH convention of the robot file's, where ``data``
    show one),
    unless ``accept`` (then logged and returned)."""
    bad = tuple(implausible(result.model, result.params, result.identifiable))
    if not bad:
        return bad
    shown = "; ".join(b.text() for b in bad[:4])
    if len(bad) > 4:
        shown += f"; and {len(bad) - 4} more"
    cause = likely_cause(result.model, list(bad))
    by_weights = weights_conditioning(result)
    if by_weights and not accept:
        raise FitError(f"{result.source}: {by_weights}; it gives {shown}")
    if by_weights:
        cause = by_weights
    if not accept and data is not None:
        cause = reading_hint(result.model.described, data.q, data.xyz, data.columns) or cause
    if not accept:
        raise FitError(
            f"{result.source}: not a plausible model of {result.model.robot.name!r}: {shown}, "
            f"beyond the bound of its kind; likely cause: {cause}. Check the data and the "
            "arm's file, or keep it anyway with --accept-large (accept_large=True)"
        )
    log.warning("%s: accepted beyond the plausible bound: %s (%s)", result.source, shown, cause)
    warn(
        f"{result.source}: accepted beyond the plausible bound: {shown} ({cause})",
        ImplausibleAcceptedWarning,
    )
    return bad


#: weights under which the poses count as fewer than this share of them (Kish's effective number)
#: concentrate a fit on a few poses: a refused fit then says so
EFFECTIVE_SHARE = 0.25


def weights_conditioning(result: FitResult) -> str:
    """Why a weighted fit went astray, where its weights are the reason: the poses count as
    fewer than :data:`EFFECTIVE_SHARE` of them (Kish's effective number, (sum w)^2 / sum w^2 of
    the poses' squared weights), a few rows' tiny stated sigmas deciding it; else ``""``."""
    obs = result.observations
    if obs is None or obs.scale is None or obs.sigma_ref is None:
        return ""
    w2 = np.sum(obs.scale[:, :3] ** 2, axis=1)
    n_eff = float(w2.sum() ** 2 / np.sum(w2**2))
    if not n_eff < EFFECTIVE_SHARE * len(w2):
        return ""
    w = np.sqrt(w2 / 3.0)
    return (
        f"the rows' weights make the fit ill-conditioned: weighted by their stated sigmas, its "
        f"{len(w2)} poses count as {n_eff:.0f} (the largest weight is "
        f"{w.max() / np.median(w):.3g} times the median, sigma {1e3 * obs.sigma_ref / w.max():.2g}"
        f" mm), and the {result.rank} parameters they identify have condition number "
        f"{result.condition_number:.3g}: a few rows' std_* cells decide the fit. State the "
        "instrument's noise (--noise-mm, --noise-ppm): no row then weighs more than it allows "
        "(docs/format.md); or leave the std_* columns out"
    )


def identifiability_of(
    data: MeasurementSet | str | Path | np.ndarray,
    robot: RobotDescription | str | Path | None = None,
    effects: str | Sequence[str | Effect] = "geometric",
    params: Mapping[str, float] | None = None,
    *,
    noise_mm: float | None = None,
    noise_ppm: float = 0.0,
    noise_mrad: float | None = None,
    measured: tuple[str, ...] | None = None,
) -> Identifiability:
    """Which parameters of ``effects`` the poses of ``data`` (a measurement set, or joint angles
    (N, 6) alone) can identify, at ``params`` (default nominal): rank, named unidentifiable
    combinations, condition number, O1 and O4. The rows are the fit's (:mod:`lab.observations`):
    one base per tracker station, the measured orientations where their uncertainty is stated
    (``noise_mrad``, ``std_rx..std_rz``) or ``measured`` names them, each row weighted by the
    instrument model (``noise_mm``, ``noise_ppm``, ``noise_mrad``, as :class:`lab.LabOptions`).
    With a noise known, parameters whose typical-size error moves the rows by less than the
    noise are counted unidentifiable too."""
    options = LabOptions(
        noise_mm=noise_mm, noise_ppm=noise_ppm, noise_mrad=noise_mrad, measured=measured
    )
    robot = as_robot(robot)
    if isinstance(data, np.ndarray):
        data = MeasurementSet(data, np.zeros((len(np.atleast_2d(data)), 3)), source="poses")
    data = as_measurements(data)
    model, inputs = model_of(data, robot, effects, options.measured, options.instrument)
    obs = observations_of(data, options.instrument, options.measured)
    p = model.nominal() if not params else model.layout.vector(params, default=model.nominal())
    _, J = obs.rows(model, inputs, p)
    assert J is not None  # rows(..., jacobian=True)
    noise = options.noise if obs.plain else obs.sigma_ref
    return analyse_jacobian(model, J, noise=noise)
