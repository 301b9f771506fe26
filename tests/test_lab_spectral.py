"""The spectral scan (lab.spectral) against an independent reference: every candidate's columns
built explicitly and tested by ordinary least squares (numpy's lstsq, a refit per left-out pose);
grid-sampled joints and what they cannot resolve; rows that are not three per pose."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from lab.spectral import CyclicProblem, ExtraColumns, cyclic_scan, joint_sampling


def _problem(n=60, rows=3, seed=0, hidden=((2, 5, 0.8),), q=None, weights=False):
    """A random linear problem: model columns, joint derivatives, and a residual holding the
    ``hidden`` harmonics (joint, order, size) plus noise. ``rows``: rows per pose (an int, or a
    per-pose array)."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-3.0, 3.0, (n, 6)) if q is None else q
    per = np.full(n, rows) if np.isscalar(rows) else np.asarray(rows)
    pose = np.repeat(np.arange(n), per)
    m = len(pose)
    D = rng.normal(size=(m, 6))
    J = rng.normal(size=(m, 4))
    e = rng.normal(scale=0.1, size=m) + J @ rng.normal(size=4)
    for j, k, a in hidden:
        e += a * D[:, j - 1] * np.cos(k * q[pose, j - 1] + 0.3)
    if weights:  # a weighted problem is the same problem, every row scaled
        w = rng.uniform(0.5, 2.0, m)
        D, J, e = D * w[:, None], J * w[:, None], e * w
    return CyclicProblem(e, J, D, pose, q)


def _columns(prob, j, k):
    f = k * prob.q[prob.pose, j - 1]
    return prob.joint[:, j - 1 : j] * np.column_stack([np.cos(f), np.sin(f)])


def _reference(prob, order, given=()):
    """Every candidate (j, k) not in ``given``: its F-test p-value and explained sum of squares
    given the model's columns and the ``given`` candidates, by explicit least squares."""
    base = np.hstack([prob.model, *(_columns(prob, j, k) for j, k in given)])
    r0 = prob.residual - base @ np.linalg.lstsq(base, prob.residual, rcond=None)[0]
    rank0 = np.linalg.matrix_rank(base)
    out = {}
    for j in range(1, 7):
        for k in range(1, order + 1):
            if (j, k) in given:
                continue
            A = np.hstack([base, _columns(prob, j, k)])
            r = prob.residual - A @ np.linalg.lstsq(A, prob.residual, rcond=None)[0]
            dk = np.linalg.matrix_rank(A) - rank0
            dof = len(r) - rank0 - dk
            ss = r0 @ r0 - r @ r
            F = (ss / dk) / ((r @ r) / dof)
            out[j, k] = (float(stats.f.sf(F, dk, dof)), float(ss), A, r)
    return out


def _loo_rms(prob, A):
    """Leave-one-pose-out RMS per pose by refitting without each pose."""
    total = 0.0
    for i in range(prob.n_poses):
        out = prob.pose == i
        c = np.linalg.lstsq(A[~out], prob.residual[~out], rcond=None)[0]
        total += float(np.sum((prob.residual[out] - A[out] @ c) ** 2))
    return math.sqrt(total / prob.n_poses)


@pytest.mark.parametrize(
    "rows, weights",
    [(3, False), (np.r_[np.full(30, 3), np.full(30, 6)], True), (np.tile([2, 3, 6], 20), False)],
)
def test_each_step_is_the_least_squares_test_of_the_best_candidate(rows, weights):
    """Two steps of the scan: the term chosen, its p-value, what it explains and the held-out
    RMS after it equal those of explicit least squares; rows need not be three per pose."""
    prob = _problem(rows=rows, weights=weights, hidden=((2, 5, 0.8), (4, 7, 0.5)))
    scan = cyclic_scan(prob, order=8, level=1.0, max_terms=2)
    given: list[tuple[int, int]] = []
    for t in scan.terms:
        ref = _reference(prob, 8, given)
        best = min(ref, key=lambda c: (ref[c][0], -ref[c][1]))
        assert (t.joint, t.order) == best
        p, ss, A, r = ref[best]
        assert t.p_value == pytest.approx(p, rel=1e-6, abs=1e-300)
        assert t.explained == pytest.approx(ss, rel=1e-9)
        assert t.rms_after == pytest.approx(math.sqrt(r @ r / prob.n_poses), rel=1e-9)
        assert t.cv_after == pytest.approx(_loo_rms(prob, A), rel=1e-8)
        given.append(best)
    assert given == [(2, 5), (4, 7)]


def test_the_level_stops_the_scan_and_counts_the_candidates():
    prob = _problem(hidden=())
    scan = cyclic_scan(prob, order=8, alpha=0.05)
    assert scan.n_candidates == 6 * 8 and scan.level == pytest.approx(0.05 / 48)
    assert scan.terms == [] and scan.stop == "not significant" and scan.exhausted
    ref = _reference(prob, 8)
    assert scan.first_p == pytest.approx(min(v[0] for v in ref.values()), rel=1e-6)


def test_extra_columns_compete_with_the_harmonics():
    """A library function of a pose (here q4^2) on joint 4 is found as itself."""
    prob = _problem(hidden=())
    f = prob.q[:, 3] ** 2
    e = prob.residual + 0.5 * prob.joint[:, 3] * f[prob.pose]
    prob = CyclicProblem(e, prob.model, prob.joint, prob.pose, prob.q)
    extra = ExtraColumns(4, f[:, None], ((0,),), ("q4^2",))
    scan = cyclic_scan(prob, order=8, alpha=0.05, extras=[extra])
    assert [(t.joint, t.order, t.key) for t in scan.terms] == [(4, None, "q4^2")]


def test_a_grid_sampled_joint_resolves_up_to_its_nyquist_order_and_names_the_aliases():
    """Joint 2 on a grid of 12 deg (30 steps a turn): order 25 is order 5 there (30 - 25); the
    scan goes to order 14 on that joint, finds 5 and says it cannot tell it from 25 and 35."""
    rng = np.random.default_rng(3)
    n = 300
    q = rng.uniform(-3.0, 3.0, (n, 6))
    h = 2 * math.pi / 30
    q[:, 1] = 0.1 + h * rng.integers(-14, 15, n)
    samp = joint_sampling(q, 2, 64)
    assert samp.grid == pytest.approx(h, rel=1e-6) and samp.resolvable == 14
    assert samp.aliases(5, 64) == [25, 35, 55, 65][:3]
    assert joint_sampling(q, 1, 64).grid is None and joint_sampling(q, 1, 64).resolvable == 64
    prob = _problem(n=n, q=q, hidden=((2, 25, 0.8),))
    scan = cyclic_scan(prob, order=64, alpha=0.05)
    assert scan.orders[2] == 14 and scan.orders[1] == 64
    (t,) = scan.terms
    assert (t.joint, t.order) == (2, 5)
    assert {(2, 25), (2, 35), (2, 55)} <= set(t.alternatives)
    assert any("grid of 12 deg" in note for note in scan.notes())


def test_a_joint_with_few_angles_resolves_few_orders_and_one_that_never_moved_none():
    q = np.random.default_rng(4).uniform(-3.0, 3.0, (50, 6))
    q[:, 2] = np.resize([0.1, 0.5, 1.3, 2.0, -1.1], 50)  # five angles, not a grid
    q[:, 4] = 0.7
    assert joint_sampling(q, 3, 64).resolvable == 2
    assert joint_sampling(q, 5, 64).resolvable == 0
    scan = cyclic_scan(_problem(n=50, q=q, hidden=()), order=64)
    # 50 distinct angles: at most 24 orders (49 functions besides the constant)
    assert scan.orders[3] == 2 and scan.orders[5] == 0 and scan.orders[1] == 24
    assert any("joint 5 did not move" in n for n in scan.notes())
