"""Statistics over episodes that resolve orderings: bootstrap confidence intervals of a mean, of
the ratio of two agents on the same episodes (paired), of aggregates across scenarios,
and which orderings those intervals resolve.

    mean, lo, hi = mean_interval(x)                    # 95 % BCa bootstrap interval of the mean
    r = paired_ratio(a, b)                             # a / b, episode by episode (geometric mean)
    r.resolved                                         # the interval excludes 1

Every interval is a bootstrap interval (``scipy.stats.bootstrap``, BCa, 10,000 resamples, a
fixed generator seed so that a table is the same every time it is made). For a positive quantity
the interval of its mean lies between the smallest and the largest resampled mean, so it never
reaches below zero, where a Student-t interval of 20 skewed values can.

Pairing. The leaderboard's episodes are the same for every agent and scenario (the sweep draws
one list of seeds), so two agents on a scenario are compared episode by episode: the bootstrap
resamples episodes, the same ones for both, which removes what the episode itself decides (the
path, the arm's errors, the noise). An aggregate across scenarios resamples episodes the same way
in every scenario at once (episode k has the same seed in each).

Ratios are taken episode by episode and summarised by their geometric mean (the mean of the
log-ratios): scale-free, symmetric (A/B is 1/(B/A)), and not hostage to one hard episode. A cell
of the ranking is the geometric mean over its episodes for the same reason: every agent runs the
same episodes, so the ratio of two cells is exactly their paired ratio, and a table's order and
its orderings agree (with arithmetic means they need not).

Aggregates, as rliable recommends for few runs over many tasks: the interquartile mean (IQM) of
the per-episode ratios of an agent's settled RMS to a reference agent's on the same episode, over
every scenario and episode, and their geometric mean.

An ordering "A below B" on a scenario is *resolved* when the paired interval of A / B lies
wholly below 1. Each interval is at 95 %: over many orderings some
unresolved ones may look resolved by chance (about 1 in 40 per ordering, one-sided), which is why
the tables show every interval and not only the verdict.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "BOOTSTRAP_SEED",
    "CONFIDENCE",
    "RESAMPLES",
    "Interval",
    "aggregate_to_reference",
    "geometric_mean_interval",
    "iqm",
    "mean_interval",
    "paired_ratio",
]

CONFIDENCE = 0.95
RESAMPLES = 10_000
#: the bootstrap's generator seed: the same records give the same table
BOOTSTRAP_SEED = 20_240_611


@dataclass(frozen=True)
class Interval:
    """An estimate with its bootstrap interval ``[lo, hi]`` over ``n`` episodes."""

    value: float
    lo: float
    hi: float
    n: int

    @property
    def resolved(self) -> bool:
        """For a ratio: the interval excludes 1 (the two differ)."""
        return self.n >= 2 and (self.hi < 1.0 or self.lo > 1.0)

    @property
    def below_one(self) -> bool:
        return self.n >= 2 and self.hi < 1.0

    def as_dict(self) -> dict[str, float | int]:
        return {"value": self.value, "lo": self.lo, "hi": self.hi, "n": self.n}


NAN = Interval(math.nan, math.nan, math.nan, 0)


def _bootstrap(
    samples: Sequence[np.ndarray], statistic: Callable[..., Any], paired: bool
) -> tuple[float, float]:
    """The BCa interval of ``statistic`` (vectorized, reducing the last axis, along which the
    episodes lie), or the percentile interval where BCa is undefined (tied resamples)."""
    import warnings

    from scipy import stats

    lo = hi = math.nan
    for method in ("BCa", "percentile"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # BCa's "degenerate data": the percentile then
            res = stats.bootstrap(
                tuple(samples),
                statistic,
                paired=paired,
                vectorized=True,
                axis=-1,
                n_resamples=RESAMPLES,
                confidence_level=CONFIDENCE,
                method=method,
                rng=np.random.default_rng(BOOTSTRAP_SEED),
            )
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
        if math.isfinite(lo) and math.isfinite(hi):
            break
    return lo, hi


def _finite(x: Sequence[float] | np.ndarray) -> np.ndarray:
    a = np.asarray([np.nan if v is None else v for v in x], dtype=float)
    return a[np.isfinite(a)]


def mean_interval(values: Sequence[float] | np.ndarray) -> Interval:
    """The mean of the finite ``values`` and its bootstrap interval (NaN bounds with fewer than
    two values; the value itself when they are all equal)."""
    x = _finite(values)
    n = int(x.size)
    if n == 0:
        return NAN
    m = float(np.mean(x))
    if n < 2:
        return Interval(m, math.nan, math.nan, n)
    if np.ptp(x) == 0:
        return Interval(m, m, m, n)
    lo, hi = _bootstrap((x,), lambda s, axis: np.mean(s, axis=axis), paired=False)
    return Interval(m, lo, hi, n)


def _exp_mean_interval(logs: np.ndarray) -> Interval:
    """``exp(mean(logs))`` of one or more ``logs`` and its bootstrap interval (the interval of
    the mean, exponentiated)."""
    n = int(logs.size)
    g = float(np.exp(np.mean(logs)))
    if n < 2:
        return Interval(g, math.nan, math.nan, n)
    if np.ptp(logs) == 0:
        return Interval(g, g, g, n)
    lo, hi = _bootstrap((logs,), lambda s, axis: np.mean(s, axis=axis), paired=False)
    return Interval(g, float(np.exp(lo)), float(np.exp(hi)), n)


def geometric_mean_interval(values: Sequence[float] | np.ndarray) -> Interval:
    """The geometric mean of the finite positive ``values`` (``exp(mean(log x))``) and its
    bootstrap interval (the interval of the mean log, exponentiated)."""
    x = _finite(values)
    x = x[x > 0]
    n = int(x.size)
    if n == 0:
        return NAN
    return _exp_mean_interval(np.log(x))


def _pairs(a: Mapping[int, float], b: Mapping[int, float]) -> tuple[np.ndarray, np.ndarray]:
    keys = sorted(k for k in a.keys() & b.keys() if np.isfinite(a[k]) and np.isfinite(b[k]))
    return (
        np.array([a[k] for k in keys], dtype=float),
        np.array([b[k] for k in keys], dtype=float),
    )


def paired_ratio(a: Mapping[int, float], b: Mapping[int, float]) -> Interval:
    """The typical ratio of ``a`` to ``b`` on the same episode (``{episode: value}``, over the
    episodes both have, positive values): the geometric mean of the per-episode ratios,
    ``exp(mean(log a_k - log b_k))``, with the paired bootstrap interval (episodes resampled
    together). On the log scale an episode ten times harder than the rest weighs as much as any
    other; the ratio of the two means would hang on it (its bootstrap interval covered the truth
    only 88-91 % of the time over 20 episodes whose difficulty spreads as e**N(0, 1))."""
    x, y = _pairs(a, b)
    keep = (x > 0) & (y > 0)
    x, y = x[keep], y[keep]
    n = int(x.size)
    if n == 0:
        return NAN
    return _exp_mean_interval(np.log(x) - np.log(y))


def iqm(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """The interquartile mean along ``axis``: the mean of the middle half (the 25 % trimmed mean,
    rliable's IQM)."""
    from scipy import stats

    return np.asarray(stats.trim_mean(x, 0.25, axis=axis))


def aggregate_to_reference(
    agent: Mapping[str, Mapping[int, float]], reference: Mapping[str, Mapping[int, float]]
) -> dict[str, Interval]:
    """An agent against a reference across scenarios (``{scenario: {episode: value}}`` each),
    over the episodes that every scenario of both has: ``iqm``, the interquartile mean of the
    per-episode ratios agent / reference over every scenario and episode, and ``geomean``, the
    geometric mean over scenarios of the ratio of means; both with the bootstrap interval that
    resamples episodes in every scenario at once."""
    scenarios = sorted(agent.keys() & reference.keys())
    if not scenarios:
        return {"iqm": NAN, "geomean": NAN}
    common = set.intersection(
        *(
            {k for k, v in agent[s].items() if np.isfinite(v)}
            & {k for k, v in reference[s].items() if np.isfinite(v) and v > 0}
            for s in scenarios
        )
    )
    keys = sorted(common)
    n = len(keys)
    if n == 0:
        return {"iqm": NAN, "geomean": NAN}
    a = np.array([[agent[s][k] for k in keys] for s in scenarios], dtype=float)  # (S, n)
    r = np.array([[reference[s][k] for k in keys] for s in scenarios], dtype=float)

    def iqm_stat(aa: np.ndarray, rr: np.ndarray, axis: int) -> np.ndarray:
        ratios = np.moveaxis(aa / rr, axis, -1)  # (..., S, n)
        return iqm(ratios.reshape(*ratios.shape[:-2], -1), axis=-1)

    def geo_stat(aa: np.ndarray, rr: np.ndarray, axis: int) -> np.ndarray:
        logs = np.moveaxis(np.log(aa) - np.log(rr), axis, -1)  # (..., S, n)
        return np.exp(np.mean(logs.reshape(*logs.shape[:-2], -1), axis=-1))

    out = {}
    for name, stat in (("iqm", iqm_stat), ("geomean", geo_stat)):
        value = float(stat(a, r, axis=-1))
        if n < 2:
            out[name] = Interval(value, math.nan, math.nan, n)
            continue
        # one sample per episode: the (S,) columns of both, resampled together
        lo, hi = _bootstrap((a, r), stat, paired=True)
        out[name] = Interval(value, lo, hi, n)
    return out
