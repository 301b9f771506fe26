"""Bootstraps written out as loops, one resample at a time, from the same draws as
:mod:`experiments.statistics` makes (``numpy.random.default_rng(BOOTSTRAP_SEED)``): the
independent reference the leaderboard's intervals are checked against. Nothing here is
vectorised: each resample is built element by element from its indices, so that no reshape can
mix resamples with episodes or scenarios."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy.special import ndtr, ndtri

from experiments.statistics import BLOCK, BOOTSTRAP_SEED, CONFIDENCE, RESAMPLES

Stat = Callable[[list[float]], float]


def mean(xs: Sequence[float]) -> float:
    """numpy's mean of one resample's values: its rounding, so that a BCa count of the resamples
    below the estimate is the same as scipy's."""
    return float(np.mean(xs))


def mean_difference(xs: Sequence[float], ys: Sequence[float]) -> float:
    """The mean of the pairs' differences (of logs: the log of the geometric mean ratio)."""
    return mean([x - y for x, y in zip(xs, ys, strict=True)])


def iqm(xs: Sequence[float]) -> float:
    """The 25 % trimmed mean by its definition (scipy's trim_mean: ``int(0.25 n)`` cut from each
    end of the sorted values)."""
    s = sorted(xs)
    cut = int(0.25 * len(s))
    return mean(s[cut : len(s) - cut])


def _percentile(dist: Sequence[float], q: float) -> float:
    """numpy's default (linear) percentile, written out."""
    s = sorted(dist)
    pos = q / 100 * (len(s) - 1)
    lo = math.floor(pos)
    hi = min(lo + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (pos - lo)


def bca(samples: Sequence[Sequence[float]], stat: Callable[..., float]) -> tuple[float, float]:
    """The BCa interval of ``stat(*samples)`` with the samples resampled together (paired: one
    index list per resample for all of them), from scipy's draws: ``integers(0, n, (RESAMPLES,
    n))``; bias from the resamples, acceleration from the jackknife (Efron & Tibshirani 14.3)."""
    n = len(samples[0])
    idx = np.random.default_rng(BOOTSTRAP_SEED).integers(0, n, (RESAMPLES, n))
    theta = stat(*samples)
    dist = []
    for row in idx:
        dist.append(stat(*([s[int(i)] for i in row] for s in samples)))
    below = sum(d < theta for d in dist) + sum(d <= theta for d in dist)
    z0 = float(ndtri(below / 2 / len(dist)))
    jack = [stat(*([s[j] for j in range(n) if j != i] for s in samples)) for i in range(n)]
    jbar = mean(jack)
    u = [(n - 1) * (jbar - t) for t in jack]
    a = (sum(x**3 for x in u) / n**3) / (6 * (sum(x**2 for x in u) / n**2) ** 1.5)
    alpha = (1 - CONFIDENCE) / 2
    out = []
    for z in (ndtri(alpha), ndtri(1 - alpha)):
        out.append(_percentile(dist, 100 * float(ndtr(z0 + (z0 + z) / (1 - a * (z0 + z))))))
    return out[0], out[1]


def stratified(values: Sequence[Sequence[Sequence[float]]], stat: Stat) -> tuple[float, float]:
    """The percentile interval of ``stat`` over the values ``[seed][stratum][episode]``: each
    resample takes as many seeds as there are, drawn with replacement, and within each drawn seed
    and each stratum as many episodes, drawn with replacement; ``stat`` gets every resampled
    value in one list. Draws per block: the seeds ``(b, m)``, then the episodes ``(b, m, S, n)``."""
    m, S, n = len(values), len(values[0]), len(values[0][0])
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    dist = []
    for start in range(0, RESAMPLES, BLOCK):
        b = min(BLOCK, RESAMPLES - start)
        seeds = rng.integers(0, m, (b, m))
        episodes = rng.integers(0, n, (b, m, S, n))
        for r in range(b):
            picked = []
            for j in range(m):
                seed = values[int(seeds[r, j])]
                for s in range(S):
                    for e in range(n):
                        picked.append(seed[s][int(episodes[r, j, s, e])])
            dist.append(stat(picked))
    tail = 100 * (1 - CONFIDENCE) / 2
    return _percentile(dist, tail), _percentile(dist, 100 - tail)


def seeded_pair(a: Sequence[Sequence[float]], b: Sequence[Sequence[float]]) -> tuple[float, float]:
    """The percentile interval of ``exp(mean log a - mean log b)`` over two agents' values
    ``[seed][episode]``: per resample each agent's seeds drawn with replacement, then one list of
    episodes for both. Draws per block: a's seeds, b's seeds, the episodes."""
    ma, mb, n = len(a), len(b), len(a[0])
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    dist = []
    for start in range(0, RESAMPLES, BLOCK):
        size = min(BLOCK, RESAMPLES - start)
        sa = rng.integers(0, ma, (size, ma))
        sb = rng.integers(0, mb, (size, mb))
        ep = rng.integers(0, n, (size, n))
        for r in range(size):
            ks = [int(k) for k in ep[r]]
            la = [math.log(a[int(i)][k]) for i in sa[r] for k in ks]
            lb = [math.log(b[int(i)][k]) for i in sb[r] for k in ks]
            dist.append(mean(la) - mean(lb))
    tail = 100 * (1 - CONFIDENCE) / 2
    return math.exp(_percentile(dist, tail)), math.exp(_percentile(dist, 100 - tail))
