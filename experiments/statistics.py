"""Statistics over episodes that resolve orderings: bootstrap confidence intervals of a mean, of
the ratio of two agents on the same episodes (paired), of aggregates across scenarios,
and which orderings those intervals resolve.

    mean, lo, hi = mean_interval(x)                    # 95 % BCa bootstrap interval of the mean
    r = paired_ratio(a, b)                             # a / b, episode by episode (geometric mean)
    r.resolved                                         # the interval excludes 1

Every interval is a bootstrap interval of 10,000 resamples from a fixed generator seed, so that a
table is the same every time it is made: BCa (``scipy.stats.bootstrap``) over the episodes of one
scenario, percentile intervals of the stratified bootstrap across scenarios or training seeds. For a positive quantity
the interval of its mean lies between the smallest and the largest resampled mean, so it never
reaches below zero, where a Student-t interval of 20 skewed values can.

Pairing. The leaderboard's episodes are the same for every agent and scenario (the sweep draws
one list of seeds), so two agents on a scenario are compared episode by episode: the bootstrap
resamples episodes, the same ones for both, which removes what the episode itself decides (the
path, the arm's errors, the noise).

Ratios are taken episode by episode and summarised by their geometric mean (the mean of the
log-ratios): scale-free, symmetric (A/B is 1/(B/A)), and not hostage to one hard episode. A cell
of the ranking is the geometric mean over its episodes for the same reason: every agent runs the
same episodes, so the ratio of two cells is exactly their paired ratio, and a table's order and
its orderings agree (with arithmetic means they need not).

Aggregates, as rliable recommends for few runs over many tasks: the interquartile mean (IQM) of
the per-episode ratios of an agent's settled RMS to a reference agent's on the same episode, over
every scenario and episode, and their geometric mean. Their intervals come from rliable's
*stratified* bootstrap (:func:`stratified_distribution`, percentile intervals): each resample
draws the episodes anew within each scenario, the reference's value going with its episode.

Training seeds. A learned agent is a training recipe, not one network: trained with several
seeds it is ranked over all of them (``{seed: ...}`` inputs of the ``seeded_*`` functions and
:func:`aggregate_over_seeds`), and its intervals come from the stratified bootstrap over seeds
and episodes: each resample draws the seeds with replacement, then the episodes within each
drawn seed (and scenario). An agent of one seed (every agent that is not learned) is exactly the
single-seed case: BCa over episodes for a scenario or a pair, the stratified episode bootstrap
for the aggregate.

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
    "aggregate_over_seeds",
    "aggregate_to_reference",
    "geometric_mean_interval",
    "iqm",
    "mean_interval",
    "paired_ratio",
    "seeded_geometric_mean_interval",
    "seeded_mean_interval",
    "seeded_paired_ratio",
    "stratified_distribution",
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


# -- training seeds: the agent, not one network ------------------------------------------------
#: resamples drawn at a time by the stratified bootstrap (seeds, then episodes): a block's
#: draws are made together, the blocks one after another, so that memory stays small
BLOCK = 1_000


def _percentile_interval(dist: np.ndarray) -> tuple[float, float]:
    """The percentile interval (rliable's) of a bootstrap distribution."""
    tail = 100 * (1 - CONFIDENCE) / 2
    lo, hi = np.percentile(dist, [tail, 100 - tail])
    return float(lo), float(hi)


def stratified_distribution(
    values: np.ndarray,
    statistic: Callable[[np.ndarray], np.ndarray],
    resamples: int = RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> np.ndarray:
    """The bootstrap distribution of ``statistic`` over ``values`` shaped ``(m, S, n)``
    (training seeds, strata such as scenarios, episodes): each resample draws ``m`` seeds with
    replacement, then, within each drawn seed and each stratum, ``n`` episodes with replacement
    (rliable's stratified bootstrap; with one seed, episodes within each scenario).

    ``statistic`` takes the resamples ``(b, m, S, n)`` and returns ``(b,)``. The draws are made
    in blocks of :data:`BLOCK` resamples from ``numpy.random.default_rng(seed)``: in each block
    first the seeds ``integers(0, m, (b, m))``, then the episodes ``integers(0, n, (b, m, S, n))``.
    """
    m, S, n = values.shape
    rng = np.random.default_rng(seed)
    out = np.empty(resamples)
    strata = np.arange(S)[:, None]
    for start in range(0, resamples, BLOCK):
        b = min(BLOCK, resamples - start)
        seeds = rng.integers(0, m, (b, m))
        episodes = rng.integers(0, n, (b, m, S, n))
        out[start : start + b] = statistic(values[seeds[:, :, None, None], strata, episodes])
    return out


def _flat(x: np.ndarray) -> np.ndarray:
    """A resample ``(b, m, S, n)`` as ``(b, m * S * n)``."""
    return x.reshape(x.shape[0], -1)


def _seeded_exp_mean(logs: np.ndarray) -> Interval:
    """``exp(mean(logs))`` of ``logs`` shaped ``(m, n)`` (seeds, episodes) with the interval of
    the stratified bootstrap over seeds and episodes (percentile), exponentiated; one seed: the
    BCa interval over episodes (:func:`_exp_mean_interval`)."""
    m, n = logs.shape
    if m == 1:
        return _exp_mean_interval(logs[0])
    g = float(np.exp(np.mean(logs)))
    if np.ptp(logs) == 0:
        return Interval(g, g, g, m * n)
    dist = stratified_distribution(logs[:, None, :], lambda x: np.mean(_flat(x), axis=-1))
    lo, hi = _percentile_interval(dist)
    return Interval(g, float(np.exp(lo)), float(np.exp(hi)), m * n)


def _common_episodes(series: Sequence[Mapping[int, float]]) -> list[int]:
    """The episodes every series has a finite positive value of."""
    keys = [{k for k, v in s.items() if v is not None and np.isfinite(v) and v > 0} for s in series]
    return sorted(set.intersection(*keys)) if keys else []


def seeded_geometric_mean_interval(by_seed: Mapping[Any, Mapping[int, float]]) -> Interval:
    """The geometric mean of an agent's values over its training seeds and episodes
    (``{seed: {episode: value}}``, the episodes every seed has) and its interval: with one seed,
    :func:`geometric_mean_interval`; with several, the stratified bootstrap (seeds, then episodes
    within each seed)."""
    if len(by_seed) == 1:  # in the episodes' order, whatever order the records were read in
        only = next(iter(by_seed.values()))
        return geometric_mean_interval([only[k] for k in sorted(only)])
    keys = _common_episodes(list(by_seed.values()))
    if not keys:
        return NAN
    logs = np.log([[s[k] for k in keys] for s in by_seed.values()])
    return _seeded_exp_mean(logs)


def seeded_mean_interval(by_seed: Mapping[Any, Mapping[int, float]]) -> Interval:
    """The arithmetic mean of an agent's values over its training seeds and episodes (the
    episodes every seed has) and its interval: one seed, :func:`mean_interval`; several, the
    percentile interval of the stratified bootstrap (seeds, then episodes within each seed)."""
    if len(by_seed) == 1:
        only = next(iter(by_seed.values()))
        return mean_interval([only[k] for k in sorted(only)])
    keys = sorted(
        set.intersection(
            *(
                {k for k, v in s.items() if v is not None and np.isfinite(v)}
                for s in by_seed.values()
            )
        )
    )
    if not keys:
        return NAN
    x = np.array([[s[k] for k in keys] for s in by_seed.values()], dtype=float)
    m = float(np.mean(x))
    if np.ptp(x) == 0:
        return Interval(m, m, m, x.size)
    dist = stratified_distribution(x[:, None, :], lambda r: np.mean(_flat(r), axis=-1))
    lo, hi = _percentile_interval(dist)
    return Interval(m, lo, hi, x.size)


def seeded_paired_ratio(
    a: Mapping[Any, Mapping[int, float]], b: Mapping[Any, Mapping[int, float]]
) -> Interval:
    """:func:`paired_ratio` of two agents over their training seeds (``{seed: {episode:
    value}}`` each): the geometric mean over a's seeds and the episodes of ``a`` over that of
    ``b`` on the same episodes. One seed each: :func:`paired_ratio` (BCa). Otherwise each
    resample draws each agent's seeds with replacement, then one set of episodes for both (the
    pairing), and the interval is the percentile interval."""
    if len(a) == 1 and len(b) == 1:
        return paired_ratio(next(iter(a.values())), next(iter(b.values())))
    keys = _common_episodes([*a.values(), *b.values()])
    if not keys:
        return NAN
    la = np.log([[s[k] for k in keys] for s in a.values()])  # (ma, n)
    lb = np.log([[s[k] for k in keys] for s in b.values()])  # (mb, n)
    diff = float(np.mean(la) - np.mean(lb))
    n = len(keys)
    if n < 2:
        return Interval(float(np.exp(diff)), math.nan, math.nan, n)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    dist = np.empty(RESAMPLES)
    for start in range(0, RESAMPLES, BLOCK):
        bb = min(BLOCK, RESAMPLES - start)
        sa = rng.integers(0, la.shape[0], (bb, la.shape[0]))
        sb = rng.integers(0, lb.shape[0], (bb, lb.shape[0]))
        ep = rng.integers(0, n, (bb, n))
        ra = la[sa[:, :, None], ep[:, None, :]].reshape(bb, -1)
        rb = lb[sb[:, :, None], ep[:, None, :]].reshape(bb, -1)
        dist[start : start + bb] = ra.mean(axis=-1) - rb.mean(axis=-1)
    lo, hi = _percentile_interval(dist)
    return Interval(float(np.exp(diff)), float(np.exp(lo)), float(np.exp(hi)), n)


def aggregate_to_reference(
    agent: Mapping[str, Mapping[int, float]], reference: Mapping[str, Mapping[int, float]]
) -> dict[str, Interval]:
    """An agent (one network) against a reference across scenarios (``{scenario: {episode:
    value}}`` each): :func:`aggregate_over_seeds` with one seed."""
    return aggregate_over_seeds({None: agent}, reference)


def aggregate_over_seeds(
    agent: Mapping[Any, Mapping[str, Mapping[int, float]]],
    reference: Mapping[str, Mapping[int, float]],
) -> dict[str, Interval]:
    """An agent over its training seeds (``{seed: {scenario: {episode: value}}}``) against a
    reference across scenarios (``{scenario: {episode: value}}``), over the scenarios every seed
    has and the episodes every scenario of every seed and of the reference has: ``iqm``, the
    interquartile mean of the per-episode ratios agent / reference over every seed, scenario and
    episode, and ``geomean``, their geometric mean. The intervals are percentile intervals of
    the stratified bootstrap (:func:`stratified_distribution`): seeds drawn, then episodes
    within each seed and scenario, the reference's value going with its episode. ``n`` is the
    number of episodes per scenario."""
    seeds = list(agent)
    scenarios = sorted(set.intersection(*(set(agent[k]) for k in seeds)) & set(reference))
    if not scenarios:
        return {"iqm": NAN, "geomean": NAN}
    finite = [
        {k for k, v in agent[sd][s].items() if v is not None and np.isfinite(v)}
        for sd in seeds
        for s in scenarios
    ]
    finite += [set(_common_episodes([reference[s]])) for s in scenarios]
    keys = sorted(set.intersection(*finite))
    n = len(keys)
    if n == 0:
        return {"iqm": NAN, "geomean": NAN}
    ref = np.array([[reference[s][k] for k in keys] for s in scenarios], dtype=float)  # (S, n)
    a = np.array([[[agent[sd][s][k] for k in keys] for s in scenarios] for sd in seeds])
    ratios = a / ref  # (m, S, n)
    stats_ = {
        "iqm": lambda x: iqm(_flat(x), axis=-1),
        "geomean": lambda x: np.exp(np.mean(np.log(_flat(x)), axis=-1)),
    }
    out = {}
    for name, stat in stats_.items():
        value = float(stat(ratios[None])[0])
        if n < 2 and len(seeds) < 2:
            out[name] = Interval(value, math.nan, math.nan, n)
            continue
        lo, hi = _percentile_interval(stratified_distribution(ratios, stat))
        out[name] = Interval(value, lo, hi, n)
    return out
