"""Sequential model selection: which effect set predicts the tracker's next point best.

A controller that tracks with the geometric model can ask, point by point, whether a wider model
would have predicted its measurements better. :class:`SequentialSelection` runs *shadow
estimators* beside it on the same tracker points: one of the current model (the null) and one per
candidate effect family of the catalogue (the current model plus that effect on every joint the
identifiability analysis keeps). Each is the recursive least-squares estimator of
:mod:`agents.online_calibration` without forgetting: starting from the prior (the effects'
typical sizes), before it takes a point it predicts it, with the innovation's covariance ``S = H
info^-1 H' + sigma^2 I``; the log of that Gaussian density, summed over the points, is the
model's *prequential* log-likelihood (Dawid), each point predicted from the points before it
only, so a model with more parameters gains nothing for fitting noise: it must predict better.

The difference of two such sums is the log **Bayes factor** of the two models (exactly, for a
model linear in its parameters with a Gaussian prior; to first order here). Under the null, the
Bayes factor of any alternative is a nonnegative martingale of mean one, so by Ville's inequality
it ever reaches ``1 / a`` with probability at most ``a``, however long one watches; with ``K``
candidates, a threshold of ``log(K / alpha)`` on each log Bayes factor keeps the chance of any
false selection, over the whole episode, below ``alpha`` (Bonferroni). The same bound between two
alternatives makes the choice among candidates: a family is selected when its log Bayes factor
against the null *and* against every other candidate reaches the threshold (a sequential
multi-hypothesis test). Compared with a batch test repeated on growing data, it needs no schedule:
a backlash shows its evidence at each reversal of a joint, within a few points of it.

A richer model also predicts better while the arm *changes* (a payload that the operator has not
declared yet): its extra parameters adapt faster. So one more competitor runs, the **drift**: the
current model with a short memory (forgetting ``drift``, 0.95 by default: about 20 points). It is
never selected, but while it leads, nothing is: an effect must explain the data better than a
change of the arm's parameters does.

Two guards keep the test honest on a real controller's data. The first ``burn_in`` points train
the shadows but do not count (the start of an episode, where the controller pulls the arm onto
the path, is where a prior that is too narrow would show; the Bayes factor conditional on those
points keeps the bound). A point that every model finds beyond the chi-square gate
(``gate``; an outlier, or a motion that no candidate can express) counts for none of them and
trains none, up to ``max_skip`` in a row (then the next one is taken: the data have changed).

The record: :meth:`SequentialSelection.evidence` (the log Bayes factors by family) and the point
at which a family was selected. Costs: one compiled call per shadow and point (about 40 us for a
30-parameter model).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from agents.base import refuse_settings
from agents.online_calibration import (
    CHI2_3_GATE,
    ESTIMATOR_SETTINGS,
    cached_identifiable,
    compiled_update,
    merge_effects,
    prior_scales,
)
from agents.tool_model import ToolModel, cached_tool_model
from arm.constraints import Constraint, Interval
from arm.effects import EFFECTS, Effect, candidate_effects, make_effect, missing_inputs
from arm.errormodel import ErrorModel

__all__ = ["DRIFT", "SequentialSelection", "ShadowEstimator", "candidate_families"]

log = logging.getLogger(__name__)

#: the name of the drifting null among the shadows (the current model with a short memory)
DRIFT = "drift"
#: what the selection's settings may be (:mod:`arm.constraints`): the test's level, and the
#: points a shadow takes before it is scored
SELECTION_SETTINGS: dict[str, Constraint] = {
    "alpha": Interval(float, 0.0, 1.0, closed="neither"),
    "burn_in": Interval(int, 0, None),
}


class ShadowEstimator:
    """Recursive least squares over ``model``'s identifiable parameters, without forgetting or
    gating, that scores each point by its predictive density before taking it
    (:meth:`step`). The prior is :class:`~agents.online_calibration.RecursiveLeastSquares`'s:
    nominal values, standard deviations ``prior_factor`` times the effects' typical sizes."""

    def __init__(
        self,
        model: ErrorModel,
        sigma: float,
        free: Sequence[str] | None = None,
        prior_factor: float = 2.0,
        tool_model: ToolModel | None = None,
        forgetting: float = 1.0,
    ) -> None:
        refuse_settings(ESTIMATOR_SETTINGS, sigma=sigma, forgetting=forgetting)
        self.model = model
        self.sigma = float(sigma)
        self.free = list(cached_identifiable(model) if free is None else free)
        self.idx = model.layout.indices(self.free)
        self.tm = cached_tool_model(model) if tool_model is None else tool_model
        self.p0 = model.nominal()
        self.scale = prior_factor * prior_scales(model)[self.idx]
        self._f = compiled_update(
            self.tm,
            self.idx,
            self.scale,
            self.p0[self.idx],
            self.sigma,
            forgetting,
            predictive=True,
        )
        n = len(self.idx)
        self.n = n
        self._p = self.p0.copy()
        self._z = np.zeros(n)
        self._info = np.eye(n)
        self.n_points = 0

    @property
    def params(self) -> np.ndarray:
        return self._p.copy()

    def score(self, q: np.ndarray, y: np.ndarray, columns: Mapping[str, float]):
        """The point's normalised innovation ``e' S^-1 e`` and ``log det S`` under the estimate
        before it, and the compiled call's output (for :meth:`take`)."""
        zq = self.tm.pack(q, self._p, columns)
        out = self._f(np.concatenate([zq, y, self._z, self._info.reshape(-1)]))
        return float(out[-2]), float(out[-1]), out

    def take(self, out: np.ndarray) -> None:
        """Keep the update that :meth:`score` computed."""
        n = self.n
        self._z = out[3 : 3 + n].copy()
        self._p = self.p0.copy()
        self._p[self.idx] = out[3 + n : 3 + 2 * n]
        self._info = out[3 + 2 * n : 3 + 2 * n + n * n].reshape(n, n).copy()
        self.n_points += 1

    def step(self, q: np.ndarray, y: np.ndarray, columns: Mapping[str, float]) -> float:
        """Take one point; returns its log predictive density (without the constant
        ``-3/2 log 2 pi``, the same for every model)."""
        nis, logdet, out = self.score(q, y, columns)
        self.take(out)
        return -0.5 * (nis + logdet)


def candidate_families(
    model: ErrorModel, candidates: Iterable[str] | None = None, columns: Iterable[str] = ()
) -> list[str]:
    """The effect families a selection tests beside ``model``: ``candidates`` (default the
    catalogue) without the geometric errors, those the model has (on any joint), those that
    need a column the data lack (``columns``; empty: no check), those the arm cannot carry (a
    mass model, extra joints: :func:`arm.effects.missing_inputs`, as the lab's diagnosis skips
    them) and a stand-in where the effect it stands in for is tested (``lumped_compliance``
    beside ``compliance``)."""
    have = {e.name for e in model.effects}
    cols = set(columns)
    found: list[Effect] = []
    for spec in candidate_effects() if candidates is None else candidates:
        if isinstance(spec, str) and spec.strip() in EFFECTS and EFFECTS[spec.strip()].scan_only:
            continue  # needs its joints and orders: not a family tested whole
        e = make_effect(spec)
        if e.name == "geometric" or e.name in have or e.name in [f.name for f in found]:
            continue
        if cols and any(c not in cols for c in e.columns):
            continue
        if missing_inputs(e, model.robot, e.columns):  # the arm's own lack, not the data's
            continue
        found.append(e)
    tested = {e.name for e in found} | have
    return [e.name for e in found if not e.stands_in_for or e.stands_in_for not in tested]


class SequentialSelection:
    """The sequential test of the module docstring for ``model`` against each of ``families``
    added to it. Feed it points (:meth:`feed`); :attr:`selected` is the family chosen (None
    until the evidence suffices), :attr:`selected_at` the point's number (0-based) when it was.

    ``alpha``: the chance of a false selection over the whole stream (default 2 %, the lab's
    family-wise level). ``burn_in``, ``gate`` and ``max_skip``: the guards of the module
    docstring. ``forgetting``: the shadows' (default none; the controller's own estimator's, to
    compare the models as it would run them). ``drift``: the drifting competitor's forgetting
    (None: none)."""

    def __init__(
        self,
        model: ErrorModel,
        families: Sequence[str],
        sigma: float,
        alpha: float = 0.02,
        burn_in: int = 5,
        gate: float = CHI2_3_GATE,
        max_skip: int = 5,
        forgetting: float = 1.0,
        drift: float | None = 0.95,
    ) -> None:
        refuse_settings(SELECTION_SETTINGS, alpha=alpha, burn_in=burn_in)
        self.model = model
        self.families = list(families)
        self.alpha = float(alpha)
        self.burn_in = int(burn_in)
        self.gate = float(gate)
        self.max_skip = int(max_skip)
        self.threshold = math.log(max(len(self.families), 1) / self.alpha)
        self.null = ShadowEstimator(model, sigma, forgetting=forgetting)
        self.shadows: dict[str, ShadowEstimator] = {}
        for f in self.families:
            wide = ErrorModel(model.robot, merge_effects(model, [f]), targets=model.targets)
            self.shadows[f] = ShadowEstimator(wide, sigma, forgetting=forgetting)
        if drift is not None:  # the null with a short memory: a change of the arm, not an effect
            self.shadows[DRIFT] = ShadowEstimator(model, sigma, forgetting=drift)
        self.log_bf = dict.fromkeys(self.shadows, 0.0)
        self.n_points = 0
        self.n_skipped = 0
        self._run = 0
        self.selected: str | None = None
        self.selected_at = -1
        self._held: dict[str, int] = {}  # family -> the point count before which it may not win

    def feed(
        self, q: np.ndarray, y: np.ndarray, columns: Mapping[str, float], decide: bool = True
    ) -> str | None:
        """Take one tracker point (encoder reading ``q`` when it was sampled, the point ``y``
        (m), its columns); returns the family selected by it, if any (after a selection, points
        are still taken: the evidence keeps growing for the record). ``decide=False`` adds the
        point's evidence without deciding (a replay of points already seen)."""
        q = np.asarray(q, dtype=float).reshape(6)
        y = np.asarray(y, dtype=float).reshape(3)
        k = self.n_points
        self.n_points += 1
        if not math.isfinite(float(q @ q + y @ y)):
            return None
        scores = {"": self.null.score(q, y, columns)}
        for f, sh in self.shadows.items():
            scores[f] = sh.score(q, y, columns)
        if min(s[0] for s in scores.values()) > self.gate and self._run < self.max_skip:
            self._run += 1
            self.n_skipped += 1
            return None
        self._run = 0
        self.null.take(scores[""][2])
        for f, sh in self.shadows.items():
            sh.take(scores[f][2])
        if k < self.burn_in:
            return None
        ll0 = -0.5 * (scores[""][0] + scores[""][1])
        for f in self.shadows:
            self.log_bf[f] += -0.5 * (scores[f][0] + scores[f][1]) - ll0
        if self.selected is None and decide:
            best = self._decide()
            if best is not None:
                self.selected, self.selected_at = best, k
                log.info(
                    "selection: %s at point %d (log Bayes factor %.1f, threshold %.1f)",
                    best,
                    k,
                    self.log_bf[best],
                    self.threshold,
                )
                return best
        return None

    def veto(self, family: str, until: int) -> None:
        """Undo the selection of ``family`` (a further test refused it): it may not be selected
        again before ``until`` points have been taken (nor another while it leads); its
        evidence keeps counting."""
        self._held[family] = int(until)
        if self.selected == family:
            self.selected, self.selected_at = None, -1

    def _decide(self) -> str | None:
        if not self.families:
            return None
        ranked = sorted(self.log_bf, key=lambda f: -self.log_bf[f])
        best = ranked[0]
        if best == DRIFT or self.n_points < self._held.get(best, 0):
            return None
        lead = self.log_bf[best] - (self.log_bf[ranked[1]] if len(ranked) > 1 else 0.0)
        if self.log_bf[best] >= self.threshold and lead >= self.threshold:
            return best
        return None

    def evidence(self) -> dict[str, float]:
        """The log Bayes factor of each family (and of the drift) against the null, so far."""
        return {f: float(v) for f, v in self.log_bf.items()}
