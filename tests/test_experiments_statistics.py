"""The leaderboard's statistics do what they claim on data whose truth is known: the intervals of
a mean cover it about 95 % of the time and never reach below zero for positive data, a paired
ratio resolves a 3 % difference that unpaired intervals cannot, orderings between agents that
do not differ are resolved about as rarely as the level says, and the aggregates are what their
definitions give by hand."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.statistics import aggregate_to_reference, iqm, mean_interval, paired_ratio


def test_the_interval_of_a_mean_covers_it_and_stays_positive():
    rng = np.random.default_rng(7)
    true_mean = float(np.exp(0.5 * 0.8**2))  # lognormal(0, 0.8)
    hits, trials = 0, 300
    for _ in range(trials):
        x = rng.lognormal(0.0, 0.8, 20)
        ci = mean_interval(x)
        assert 0 < ci.lo <= ci.value <= ci.hi
        hits += ci.lo <= true_mean <= ci.hi
    assert 0.88 <= hits / trials <= 0.99  # BCa at n = 20 on skewed data: close to 95 %


def test_a_paired_ratio_resolves_what_unpaired_intervals_cannot():
    """Episodes differ tenfold in difficulty; agent A is 3 % better than B on every one."""
    rng = np.random.default_rng(3)
    hard = rng.lognormal(0.0, 1.0, 20)
    b = hard * (1 + rng.normal(0, 0.01, 20))
    a = 0.97 * hard * (1 + rng.normal(0, 0.01, 20))
    ia, ib = mean_interval(a), mean_interval(b)
    assert ia.hi > ib.lo  # unpaired: the intervals overlap
    r = paired_ratio(dict(enumerate(a)), dict(enumerate(b)))
    assert r.below_one and r.resolved and r.lo < 0.97 < r.hi
    # symmetric: B against A is the reciprocal
    back = paired_ratio(dict(enumerate(b)), dict(enumerate(a)))
    assert back.value == pytest.approx(1 / r.value) and back.lo > 1
    # only the episodes both ran count
    r2 = paired_ratio(dict(enumerate(a)), {k: v for k, v in enumerate(b) if k != 4})
    assert r2.n == 19


def test_agents_that_do_not_differ_are_rarely_resolved():
    rng = np.random.default_rng(11)
    resolved, trials = 0, 200
    for _ in range(trials):
        hard = rng.lognormal(0.0, 1.0, 20)
        a = hard * rng.lognormal(0.0, 0.1, 20)
        b = hard * rng.lognormal(0.0, 0.1, 20)
        resolved += paired_ratio(dict(enumerate(a)), dict(enumerate(b))).resolved
    assert resolved / trials <= 0.10  # the level is 5 %


def test_aggregates_by_hand():
    x = np.array([5.0, 1.0, 3.0, 2.0, 100.0, 4.0, 0.0, 6.0])
    assert float(iqm(x)) == pytest.approx(np.mean(np.sort(x)[2:6]))  # the middle half
    rng = np.random.default_rng(5)
    ref = {s: {k: float(rng.lognormal()) for k in range(12)} for s in ("a", "b", "c")}
    ratio = {"a": 0.5, "b": 1.0, "c": 2.0}
    agent = {s: {k: v * ratio[s] for k, v in ref[s].items()} for s in ref}
    agg = aggregate_to_reference(agent, ref)
    assert agg["geomean"].value == pytest.approx(1.0)  # (0.5 * 1 * 2) ** (1/3)
    # the middle half of the 36 ratios: 3 x 0.5, 12 x 1, 3 x 2
    assert agg["iqm"].value == pytest.approx((3 * 0.5 + 12 + 3 * 2) / 18)
    assert agg["geomean"].n == 12
    # an episode missing in one scenario leaves that episode out of every scenario
    del agent["b"][3]
    assert aggregate_to_reference(agent, ref)["iqm"].n == 11


# -- every interval against the bootstrap written as a loop (tests/_bootstrap_loops.py) ---------
def _lognormal(seed: int, *shape: int) -> np.ndarray:
    return np.random.default_rng(seed).lognormal(0.0, 0.6, shape)


def test_one_scenario_intervals_are_the_loop_written_bootstrap():
    from experiments.statistics import geometric_mean_interval
    from tests import _bootstrap_loops as loops

    x = _lognormal(1, 12)
    ci = mean_interval(x)
    assert (ci.lo, ci.hi) == pytest.approx(loops.bca([list(x)], loops.mean), rel=1e-12)
    g = geometric_mean_interval(x)
    lo, hi = loops.bca([list(np.log(x))], loops.mean)
    assert (g.lo, g.hi) == pytest.approx((np.exp(lo), np.exp(hi)), rel=1e-12)


def test_a_paired_interval_is_the_loop_written_bootstrap():
    from tests import _bootstrap_loops as loops

    a, b = _lognormal(2, 15), _lognormal(3, 15)
    r = paired_ratio(dict(enumerate(a)), dict(enumerate(b)))
    lo, hi = loops.bca([list(np.log(a)), list(np.log(b))], loops.mean_difference)
    assert (r.lo, r.hi) == pytest.approx((np.exp(lo), np.exp(hi)), rel=1e-12)


def test_the_aggregate_interval_is_the_loop_written_stratified_bootstrap():
    """Episodes resampled within each scenario; every resample's IQM over all its ratios (the
    statistic once mixed resamples with episodes, and its 'interval' was the spread of the
    per-scenario values)."""
    from tests import _bootstrap_loops as loops

    scen = ("a", "b", "c", "d")
    ref = {s: dict(enumerate(_lognormal(10 + i, 8))) for i, s in enumerate(scen)}
    agent = {
        s: {k: v * _lognormal(20 + i, 8)[k] for k, v in ref[s].items()} for i, s in enumerate(scen)
    }
    agg = aggregate_to_reference(agent, ref)
    ratios = [[[agent[s][k] / ref[s][k] for k in range(8)] for s in scen]]
    assert (agg["iqm"].lo, agg["iqm"].hi) == pytest.approx(
        loops.stratified(ratios, loops.iqm), rel=1e-12
    )
    geo = lambda xs: float(np.exp(loops.mean([np.log(x) for x in xs])))  # noqa: E731
    assert (agg["geomean"].lo, agg["geomean"].hi) == pytest.approx(
        loops.stratified(ratios, geo), rel=1e-12
    )


def test_the_aggregate_interval_is_the_episodes_not_the_spread_of_the_scenarios():
    """Ratios 0.5, 1 and 2 on three scenarios, within 1 % on every episode: the agent's
    aggregate is known to about 1 %, however far apart the scenarios are."""
    rng = np.random.default_rng(4)
    ref = {s: {k: float(rng.lognormal()) for k in range(20)} for s in ("a", "b", "c")}
    ratio = {"a": 0.5, "b": 1.0, "c": 2.0}
    agent = {
        s: {k: v * ratio[s] * float(rng.lognormal(0, 0.01)) for k, v in ref[s].items()} for s in ref
    }
    for iv in aggregate_to_reference(agent, ref).values():
        assert iv.lo < iv.value < iv.hi
        assert iv.hi / iv.lo < 1.02


def test_an_agent_over_seeds_is_the_loop_written_stratified_bootstrap():
    """Three training seeds: seeds drawn, then episodes within each seed (and scenario)."""
    from experiments.statistics import (
        aggregate_over_seeds,
        seeded_geometric_mean_interval,
        seeded_paired_ratio,
    )
    from tests import _bootstrap_loops as loops

    scen = ("a", "b", "c")
    ref = {s: dict(enumerate(_lognormal(30 + i, 6))) for i, s in enumerate(scen)}
    agent = {
        seed: {
            s: {k: v * _lognormal(40 + 7 * seed + i, 6)[k] for k, v in ref[s].items()}
            for i, s in enumerate(scen)
        }
        for seed in (1, 2, 3)
    }
    agg = aggregate_over_seeds(agent, ref)
    ratios = [[[agent[sd][s][k] / ref[s][k] for k in range(6)] for s in scen] for sd in agent]
    assert agg["iqm"].n == 6
    assert (agg["iqm"].lo, agg["iqm"].hi) == pytest.approx(
        loops.stratified(ratios, loops.iqm), rel=1e-12
    )
    # one scenario: the cell
    cell = seeded_geometric_mean_interval({sd: agent[sd]["a"] for sd in agent})
    logs = [[[float(np.log(agent[sd]["a"][k])) for k in range(6)]] for sd in agent]
    lo, hi = loops.stratified(logs, loops.mean)
    assert (cell.lo, cell.hi) == pytest.approx((np.exp(lo), np.exp(hi)), rel=1e-12)
    # a pair: three seeds against one
    pair = seeded_paired_ratio({sd: agent[sd]["b"] for sd in agent}, {0: ref["b"]})
    expect = loops.seeded_pair(
        [[agent[sd]["b"][k] for k in range(6)] for sd in agent], [[ref["b"][k] for k in range(6)]]
    )
    assert (pair.lo, pair.hi) == pytest.approx(expect, rel=1e-12)
    # one seed is the agent of one network
    one = aggregate_over_seeds({7: agent[1]}, ref)
    assert one == aggregate_to_reference(agent[1], ref)


def test_a_cells_interval_does_not_depend_on_the_order_the_records_were_read_in():
    """Run files are read in their names' order (ep0, ep1, ep10, ...): the interval is taken
    over the episodes in their own order all the same."""
    from experiments.statistics import (
        geometric_mean_interval,
        seeded_geometric_mean_interval,
        seeded_mean_interval,
    )

    x = _lognormal(8, 20)
    by_name = {k: float(x[k]) for k in sorted(range(20), key=lambda k: f"ep{k}")}
    assert list(by_name) != list(range(20))
    assert seeded_geometric_mean_interval({0: by_name}) == geometric_mean_interval(x)
    assert seeded_mean_interval({0: by_name}) == mean_interval(x)
