"""The accuracy a calibration expects on a target (a program's joints, or held-out measurements)
before anything is measured there, and the model it expects to be best there (the fallback).

    e = expect(result, data, program_q, unseen=True)
    print(e.text())           # "expected RMS 0.41 mm (5-95 %: 0.22-0.63) ... with the geometric
                              #  model: the lab's terms did not help on a session left out"
    e.chosen                  # "model" or "geometric"

**The blocked check.** The training rows are split into blocks: their sessions (a ``session``,
else ``station`` column of two ids or more, :func:`lab.transfer.block_column`), else, for one
session, :data:`JOINT_BLOCKS` blocks of the joint that the poses turn over the widest range
(its lowest third, middle third, highest third: the model is fitted on two and checked on the
third, which lies beyond what it was fitted on). Each block is left out in turn, the model
fitted to the others and its 3-D RMS measured on it (:func:`lab.transfer.blocked_rms`), for
the calibration's model and for the geometric one. A fold that cannot be fitted, or only to
parameters the lab would refuse as a result (beyond the plausible bound of their kind), says
nothing about a session: the models are compared on the blocks both could be fitted for. Fitted
on one session, terms that two sessions identify can take values that cancel in that session and
not in the next: with the UR10's series A left out, the lab's model fitted on series B alone had
3374 mrad in a transmission term and erred 772 mm on series D, while fitted on both it erred
0.19 mm on A.

**The fallback.** Where the calibration's model does not err less than the geometric one by
:data:`MARGIN` on the blocks left out (the log-mean over the blocks), its terms are not
expected to help on rows it was not fitted on: the geometric model is used (fitted on the same
rows), and the output says so. This is decided from the training rows alone, never from the
target's measurements.

**The prediction** (:class:`lab.uncertainty.Prediction`, of the model chosen) adds in
quadrature: the parameters' covariance through the Jacobian at the target's poses (widened by
the spread between sessions and the least spread, :func:`lab.uncertainty.least_spread`, where
the target is a session it has not seen), the discrepancy of a session fitted alone, and, for
the target's poses outside the fitted domain (:mod:`lab.domain`), what the blocked check
measured beyond the covariance's own prediction for the blocks left out (the model's
extrapolation error). For a session not seen, where the blocks are sessions, the blocks left
out are such sessions: the prediction (and its band) is scaled by what they erred against what
the fit of the other sessions would have predicted for them, its covariance and the
calibration's spread (:attr:`Expectation.scale`, the square root
of the ratio of their mean squares; at least down to the discrepancy). A spread measured from
two or three sessions has one or two degrees of freedom a joint; the sessions' own errors say
how large a new session's is. Its band (5-95 %) is that of the RMS of one session's draw of the
parameters from their covariance: with few directions that matter (a re-homing of six
joints), one session's error may lie well away from the expected one.
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from arm.measurements import MeasurementSet
from lab.errors import FitError, LabWarning
from lab.folds import Fold
from lab.options import LabOptions
from lab.result import FitResult
from lab.uncertainty import Prediction, Uncertainty, predicted_rms, uncertainty_of

__all__ = [
    "JOINT_BLOCKS",
    "MARGIN",
    "Expectation",
    "blocked_check",
    "blocked_folds_check",
    "expect",
    "expect_update",
    "joint_blocks",
]

log = logging.getLogger(__name__)

JOINT_BLOCKS = 3
#: the calibration's model is kept where its blocked RMS is under this fraction of the geometric
#: one's: a smaller gain on two or three blocks is within what one draw of a session varies by
MARGIN = 0.95


def joint_blocks(data: MeasurementSet, blocks: int = JOINT_BLOCKS) -> MeasurementSet:
    """``data`` with a ``session`` column that splits its rows into ``blocks`` ranges of the joint
    its poses turn over the widest range (module docstring)."""
    j = int(np.argmax(np.ptp(data.q, axis=0)))
    edges = np.quantile(data.q[:, j], np.linspace(0.0, 1.0, blocks + 1)[1:-1])
    cols = dict(data.columns) | {"session": np.searchsorted(edges, data.q[:, j]).astype(float)}
    return replace(data, columns=cols)


def blocked_check(
    data: MeasurementSet, result: FitResult, options: LabOptions | None = None
) -> tuple[str, dict[str, dict[float, float]]]:
    """The blocks (``"sessions"`` or ``"joint qN"``) and {model: {block: RMS (m)}} of ``result``'s
    model and the geometric one, each block left out in turn (module docstring)."""
    from lab.transfer import rms_of

    how, folds = blocked_folds_check(data, result, options)
    return how, {m: rms_of(f) for m, f in folds.items()}


def blocked_folds_check(
    data: MeasurementSet, result: FitResult, options: LabOptions | None = None
) -> tuple[str, dict[str, dict[float, Fold | None]]]:
    """:func:`blocked_check` with each block's fold (the fit of the other blocks and its
    residuals on the block; None where it could not be fitted to a plausible model)."""
    from lab.transfer import block_column, blocked_folds

    col = block_column(data)
    if col is not None and len(np.unique(data.columns[col])) >= 2:
        rows, how = data, "sessions"
    else:
        rows = joint_blocks(data)
        how = f"joint q{int(np.argmax(np.ptp(data.q, axis=0))) + 1}"
    opts = options or LabOptions(noise_mm=1e3 * result.sigma)
    robot = result.model.robot
    out = {"model": blocked_folds(rows, robot, list(result.model.effects), opts, plausible=True)}
    if result.model.effect_names != ["geometric"]:
        out["geometric"] = blocked_folds(rows, robot, "geometric", opts, plausible=True)
    return how, out


def _log_mean(rms: dict[float, float], blocks: set[float] | None = None) -> float:
    v = [x for b, x in rms.items() if (blocks is None or b in blocks) and 0 < x < math.inf]
    return math.exp(float(np.mean(np.log(v)))) if v else math.inf


def _log_means(blocked: dict[str, dict[float, float]]) -> dict[str, float]:
    """Each model's log-mean RMS over the blocks every model could be fitted for (a fold that
    cannot be fitted, or only to an implausible model, says nothing about the others' blocks);
    the model's alone, infinite, where it could be fitted for none of them."""
    common = set.intersection(
        *({b for b, x in rms.items() if 0 < x < math.inf} for rms in blocked.values())
    )
    if not common:
        return {m: _log_mean(rms) if m != "model" else math.inf for m, rms in blocked.items()}
    return {m: _log_mean(rms, common) for m, rms in blocked.items()}


@dataclass(frozen=True)
class Expectation:
    """What a calibration expects on a target: the ``prediction`` of the model ``chosen``
    (``"model"``: the calibration's, or ``"geometric"``: the fallback), the ``blocked`` RMS of each
    (mm, the log-mean over the blocks left out, by ``blocks``), the share of the target's poses
    ``outside`` the fitted domain and the ``extrapolation_mm`` added for them."""

    prediction: Prediction
    chosen: str
    blocked: dict[str, float]
    blocks: str
    outside: float
    extrapolation_mm: float
    result: FitResult
    # the sessions left out in turn erred this many times what the covariance and the spread
    # predicted for them: an unseen target's prediction is scaled by it (1: not scaled)
    scale: float = 1.0
    # blocks left out whose fold of the model could not be fitted, or only to an implausible
    # model: not counted (the module docstring), and said
    unfitted: int = 0

    @property
    def reason(self) -> str:
        unfit = (
            f" ({self.unfitted} fold{'s' if self.unfitted != 1 else ''} of the model, fitted "
            "without a block, could not be fitted, or only to an implausible model, and "
            f"{'are' if self.unfitted != 1 else 'is'} not counted)"
            if self.unfitted
            else ""
        )
        if self.chosen == "model":
            return f"the model's terms helped on the blocks left out{unfit}"
        return (
            f"the lab's terms are not expected to help there: on the {self.blocks} left out in "
            f"turn the model erred {self.blocked['model']:.4f} mm, the geometric one "
            f"{self.blocked.get('geometric', math.nan):.4f} mm{unfit}; the geometric model is "
            "used"
        )

    def to_dict(self) -> dict[str, Any]:
        return self.prediction.to_dict() | {
            "chosen": self.chosen,
            "reason": self.reason,
            "blocked_mm": self.blocked,
            "blocks": self.blocks,
            "outside_share": self.outside,
            "extrapolation_mm": self.extrapolation_mm,
            "scale": self.scale,
            "unfitted_blocks": self.unfitted,
        }

    def text(self) -> str:
        return f"{self.prediction.text()}; {self.reason}"


def _targets(target: MeasurementSet | np.ndarray) -> MeasurementSet:
    if isinstance(target, MeasurementSet):
        return target
    q = np.atleast_2d(np.asarray(target, dtype=float))
    return MeasurementSet(q, np.zeros((len(q), 3)), source="program")


def expect(
    result: FitResult,
    data: MeasurementSet,
    target: MeasurementSet | np.ndarray,
    *,
    unseen: bool,
    options: LabOptions | None = None,
    geometric: FitResult | None = None,
    u: Uncertainty | None = None,
    references: MeasurementSet | np.ndarray | None = None,
) -> Expectation:
    """The :class:`Expectation` of ``result`` (fitted on ``data``) on ``target`` (module
    docstring). ``geometric``: the geometric model fitted on the same rows, where it is at hand
    (else it is fitted when the fallback chooses it); ``u``: the calibration's uncertainty
    (default measured from ``result`` and ``data``); ``references``: the poses that register the
    target's station (:func:`lab.uncertainty.predicted_rms`; default the target's own)."""
    from lab.transfer import rms_of

    target = _targets(target)
    how, folds = blocked_folds_check(data, result, options)
    blocked = {m: rms_of(f) for m, f in folds.items()}
    means = _log_means(blocked)
    chosen = "model"
    if "geometric" in means and not means["model"] < MARGIN * means["geometric"]:
        chosen = "geometric"
    use = result
    if chosen == "geometric":
        use = geometric or _geometric(data, result, options)
        u = None
    u = u or uncertainty_of(use, data)
    base = predicted_rms(use, target, unseen=unseen, u=u, references=references)
    measured, predicted = _blocks_measured(
        use,
        data,
        folds["model" if use is result else "geometric"],
        u,
        fold_covariance=how == "sessions" and unseen,
    )
    outside = _outside_share(use, target)
    scale, extra = 1.0, 0.0
    if unseen and how == "sessions" and predicted:
        # a session left out is what an unseen target is: what the blocks erred, against what
        # the covariance and the spread predicted for them, scales the prediction
        scale = math.sqrt(sum(m * m for m in measured) / sum(p * p for p in predicted))
        scale = max(scale, base.discrepancy_mm / max(base.rms_mm, 1e-300))
    else:
        excess = [max(0.0, m * m - p * p) for m, p in zip(measured, predicted, strict=True)]
        extra = math.sqrt(outside) * (math.sqrt(float(np.mean(excess))) if excess else 0.0)
    pred = replace(
        base,
        rms_mm=math.hypot(scale * base.rms_mm, extra),
        low_mm=math.hypot(scale * base.low_mm, extra),
        high_mm=math.hypot(scale * base.high_mm, extra),
    )
    return Expectation(
        pred,
        chosen,
        {m: 1e3 * v for m, v in means.items()},
        how,
        outside,
        extra,
        use,
        scale,
        sum(1 for v in blocked["model"].values() if not math.isfinite(v)),
    )


def _geometric(data: MeasurementSet, result: FitResult, options: LabOptions | None) -> FitResult:
    from lab.identification import fit

    opts = options or LabOptions(noise_mm=1e3 * result.sigma)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LabWarning)
        return fit(data, result.model.robot, "geometric", options=opts)


def _blocks_measured(
    result: FitResult,
    data: MeasurementSet,
    folds: dict[float, Fold | None],
    u: Uncertainty,
    *,
    fold_covariance: bool = False,
) -> tuple[list[float], list[float]]:
    """Each block left out: the RMS (mm) its fold erred, and what ``result``'s covariance
    predicts for it as a session not seen (the blocks that could be fitted and predicted). With
    ``fold_covariance`` (sessions left out), each block is predicted as its fold knew it: with
    the covariance of the fold's own fit of the other blocks (fewer poses, a narrower region) and
    the calibration's spread, so that what the folds erred is set against what a calibration of
    their poses would have predicted, not what the calibration of every session predicts."""
    from lab.transfer import block_column

    col = block_column(data)
    rows = data if col is not None else joint_blocks(data)
    col = col or "session"
    measured, predicted = [], []
    for b, f in folds.items():
        if f is None:
            continue
        part = rows.subset(np.flatnonzero(rows.columns[col] == b))
        try:
            fold_u = _with_fold_covariance(u, f.result) if fold_covariance else u
            pred = predicted_rms(result, part, unseen=True, u=fold_u).rms_mm
        except FitError:
            continue
        measured.append(1e3 * f.rms)
        predicted.append(pred)
    return measured, predicted


def _with_fold_covariance(u: Uncertainty, fold: FitResult) -> Uncertainty:
    """``u`` with the covariance of ``fold`` (a fit of some of the calibration's rows) where that
    fit identifies a parameter, ``u``'s own elsewhere, its spread kept."""
    from lab.uncertainty import covariance_of

    names, cov = covariance_of(fold)
    at = {n: i for i, n in enumerate(names)}
    idx = [at.get(n, -1) for n in u.names]
    new = np.array(u.covariance, dtype=float, copy=True)
    both = [i for i, j in enumerate(idx) if j >= 0]
    src = [idx[i] for i in both]
    new[np.ix_(both, both)] = cov[np.ix_(src, src)]
    # a parameter the fold identified and one it did not: no covariance known between them
    other = [i for i, j in enumerate(idx) if j < 0]
    new[np.ix_(both, other)] = 0.0
    new[np.ix_(other, both)] = 0.0
    return replace(u, covariance=new)


def _outside_share(result: FitResult, target: MeasurementSet) -> float:
    """The share of ``target``'s poses outside ``result``'s fitted joint ranges."""
    ranges = result.domain.ranges
    out = np.zeros(len(target), dtype=bool)
    for j in range(6):
        if f"q{j + 1}" in ranges:
            lo, hi = ranges[f"q{j + 1}"]
            out |= (target.q[:, j] < lo) | (target.q[:, j] > hi)
    return float(np.mean(out)) if len(out) else 0.0


def expect_update(
    u: Any, data: MeasurementSet, target: MeasurementSet | np.ndarray, **options: Any
) -> Expectation:
    """The :class:`Expectation` of an update (:class:`lab.update.Update`, made from the poses
    of ``data``) on ``target``: the new poses are too few for blocked checks, so the fallback
    is decided on them alone, each left out in turn: the update's leave-one-pose-out RMS
    against that of the same update from the calibration without its terms beside the geometry
    (:func:`lab.update.geometric_prior`); the geometric one is used unless the update's is
    under :data:`MARGIN` of it. ``options``: :func:`lab.update.update`'s (``remount``,
    ``noise_mm``...), as the update was made. Its prediction is the posterior's
    (:func:`lab.uncertainty.predicted_rms`, the session seen), with nothing added outside the
    domain (no blocked check measured the extrapolation)."""
    from lab.uncertainty import predicted_rms
    from lab.update import geometric_prior, update

    target = _targets(target)
    blocked = {"model": u.loo_rms_mm}
    chosen, use = "model", u
    if any(e.name != "geometric" for e in u.prior.effects):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LabWarning)
            geo = update(geometric_prior(u.prior), data, **options)
        blocked["geometric"] = geo.loo_rms_mm
        if not u.loo_rms_mm < MARGIN * geo.loo_rms_mm:
            chosen, use = "geometric", geo
    pred = predicted_rms(use.result, target, unseen=False)
    blocks = f"{u.poses} poses of the update"
    return Expectation(
        pred, chosen, blocked, blocks, _outside_share(use.result, target), 0.0, use.result
    )
