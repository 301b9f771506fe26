"""Identifiability: the lab names exactly the parameters that the poses cannot identify, checked
against a singular value decomposition of a finite-difference Jacobian computed here."""

from __future__ import annotations

import logging
import math
import re

import numpy as np
import pytest

from arm.description import RobotDescription
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from arm.sampling import sample_parameters, sample_poses
from lab import fit, identifiability_of
from lab.identifiability import analyse, gram_factor, orthonormal_basis

NAME = re.compile(r"[a-z]+[0-9]*")


def fd_jacobian(model: ErrorModel, inputs, p: np.ndarray, h: float = 1e-7) -> np.ndarray:
    """Central differences of the predicted points by every parameter: (3N, P)."""
    cols = []
    for k in range(len(p)):
        dp = np.zeros_like(p)
        dp[k] = h
        cols.append(
            ((model.predict(inputs, p + dp) - model.predict(inputs, p - dp)) / (2 * h)).ravel()
        )
    return np.column_stack(cols)


def svd_structure(J: np.ndarray, names) -> tuple[int, set[str], set[str]]:
    """Rank, parameters that move nothing, and parameters taking part in a null-space direction,
    from the SVD of the unit-column Jacobian (finite-difference round-off ~1e-9 relative)."""
    n = J.shape[0] // 3
    norms = np.linalg.norm(J, axis=0) / math.sqrt(n)
    zero = norms < 1e-7
    A = J[:, ~zero] / norms[~zero]
    _, s, Vt = np.linalg.svd(A, full_matrices=True)
    rank = int(np.sum(s > 1e-6 * s[0]))
    null = Vt[rank:]  # rows span the null space
    involved = np.linalg.norm(null, axis=0) > 1e-3
    kept = [nm for nm, z in zip(names, zero, strict=True) if not z]
    return (
        rank,
        {nm for nm, z in zip(names, zero, strict=True) if z},
        {nm for nm, inv in zip(kept, involved, strict=True) if inv},
    )


def named(labels: list[str]) -> set[str]:
    return {t for lab in labels for t in NAME.findall(lab) if not t.isdigit()}


@pytest.mark.parametrize("effects", ["geometric", "geometric,compliance"])
def test_seed_arm_unidentifiable_parameters_match_an_independent_svd(seed, effects):
    model = ErrorModel(seed, effects)
    q = sample_poses(seed, 200, np.random.default_rng(3))
    inputs = model.inputs(q)
    ident = identifiability_of(q, seed, effects)
    J = fd_jacobian(model, inputs, model.nominal())
    rank, zero, involved = svd_structure(J, model.layout.names)

    assert ident.rank == rank
    # the fixed parameters: one per null-space direction, named with the directions they span
    fixed = set(ident.fixed_names)
    assert len(fixed) == len(model.layout) - rank
    assert named(ident.unidentifiable) == involved | zero
    assert {n for n, c in ident.combinations.items() if not c} == zero
    # what docs/format.md (geometric) says of the seed arm with one target on joint 6's axis:
    # dtheta6 moves nothing, the base absorbs row 1, the tool dd6, and the spherical wrist pairs
    # dalpha6 with dd5 and da6 with dtheta5; 25 of the 33 geometric parameters remain
    geo_fixed = {"dtheta6", "dalpha1", "da1", "dtheta1", "dd1", "dd6", "dalpha6", "da6"}
    assert fixed & set(model.layout.names[model.layout.slice("geometric")]) == geo_fixed
    assert "dtheta6" in ident.unidentifiable
    assert "dd1 - bz" in ident.unidentifiable and "dd6 - tz" in ident.unidentifiable
    if "compliance" in effects:  # tau1 and tau6 are always zero on the seed arm
        assert {"c1", "c6"} <= zero and {"c1", "c6"} <= fixed
        assert rank == 25 + 4
    else:
        assert rank == 25


def test_combinations_are_null_directions_of_the_jacobian(seed):
    model = ErrorModel(seed, "geometric")
    q = sample_poses(seed, 100, np.random.default_rng(4))
    inputs = model.inputs(q)
    ident = identifiability_of(q, seed)
    J = fd_jacobian(model, inputs, model.nominal())
    typical = np.linalg.norm(J, axis=0).max()
    for name, combo in ident.combinations.items():
        v = model.layout.vector(combo)
        if not combo:
            v[model.layout.index(name)] = 1.0
        moved = np.linalg.norm(J @ v)
        assert moved < 1e-6 * typical * np.linalg.norm(v), name


def test_another_arm_with_two_targets_matches_the_svd(rokae):
    arm = RobotDescription(
        "two-targets",
        rokae.joints,
        tools=((0.05, 0.0, 0.2), (-0.03, 0.04, 0.18)),
    )
    model = ErrorModel(arm, "geometric,transmission", targets=(0, 1))
    rng = np.random.default_rng(5)
    q = sample_poses(arm, 150, rng)
    cols = {"target": rng.choice([0.0, 1.0], len(q))}
    inputs = model.inputs(q, cols)
    _, Ja = model.predict(inputs, model.nominal(), jacobian=True)
    from lab.identifiability import analyse_jacobian

    ident = analyse_jacobian(model, Ja)
    J = fd_jacobian(model, inputs, model.nominal())
    rank, zero, involved = svd_structure(J, model.layout.names)
    assert ident.rank == rank
    assert named(ident.unidentifiable) == involved | zero
    # with the targets off joint 6's axis, dtheta6 moves them, but both tool offsets absorb it
    assert "dtheta6" in ident.fixed_names and "dtheta6" not in zero


def test_observability_indices_and_condition_number_from_the_singular_values(seed):
    model = ErrorModel(seed, "geometric")
    q = sample_poses(seed, 60, np.random.default_rng(6))
    _, J = model.predict(model.inputs(q), model.nominal(), jacobian=True)
    ident = analyse(J, model.layout.names)
    A = J.reshape(-1, J.shape[2])[:, ident.identifiable]
    A = A / np.linalg.norm(A, axis=0) * math.sqrt(len(q))
    s = np.linalg.svd(A, compute_uv=False)
    assert ident.condition_number == pytest.approx(s[0] / s[-1], rel=1e-6)
    assert ident.o1 == pytest.approx(np.prod(s) ** (1 / len(s)) / math.sqrt(len(q)), rel=1e-6)
    assert ident.o4 == pytest.approx(s[-1] ** 2 / s[0], rel=1e-6)


def test_a_poor_pose_set_is_warned_about(seed, caplog):
    rng = np.random.default_rng(7)
    q0 = sample_poses(seed, 1, rng)
    q = q0 + rng.uniform(-0.05, 0.05, (40, 6))  # every pose near one configuration
    with caplog.at_level(logging.WARNING, logger="lab.identifiability"):
        ident = identifiability_of(q, seed)
    assert ident.condition_number > 100
    assert any("condition number" in r.message for r in caplog.records)


def test_the_noise_criterion_fixes_parameters_that_move_points_less_than_the_noise(seed):
    q = sample_poses(seed, 200, np.random.default_rng(8))
    plain = identifiability_of(q, seed, "geometric,compliance")
    # compliance of the wrist joints: tau4, tau5 of a few N m move the tool by microns
    noisy = identifiability_of(q, seed, "geometric,compliance", noise_mm=0.2)
    assert set(noisy.weak) and set(noisy.weak) <= set(plain.identifiable_names)
    assert noisy.rank == plain.rank - len(noisy.weak)
    assert {"c2", "c3"} <= set(noisy.identifiable_names)


def test_orthonormal_basis_spans_the_independent_columns():
    rng = np.random.default_rng(9)
    A = rng.normal(size=(300, 8))
    A[:, 3] = 2 * A[:, 1] - A[:, 2]
    A[:, 6] = 0.0
    Q = orthonormal_basis(A)
    assert Q.shape == (300, 6)
    assert np.allclose(Q.T @ Q, np.eye(6), atol=1e-12)
    assert np.allclose(Q @ (Q.T @ A), A, atol=1e-10)
    idx, L = gram_factor(A.T @ A)
    assert len(idx) == 6 and np.allclose(L @ L.T, (A.T @ A)[np.ix_(idx, idx)])


BASE = ("bx", "by", "bz", "brx", "bry", "brz")


def test_a_held_base_leaves_row_1_identifiable_as_an_independent_svd_says(seed):
    """With the base known (``fit(..., fixed=base)``: the measurement frame is the robot's),
    nothing absorbs row 1: the others' identifiability is that of the finite-difference
    Jacobian without the base's columns, the row-1 errors are identified, and the base keeps the
    values given (the closed-form registration is only a start)."""
    model = ErrorModel(seed, "geometric")
    rng = np.random.default_rng(10)
    p = sample_parameters(model, rng)
    for n in ("dtheta6", "dd6", "dalpha6", "da6"):  # unidentifiable either way: no truth in them
        p[model.layout.index(n)] = 0.0
    q = sample_poses(seed, 200, rng)
    sigma = 15e-6
    data = MeasurementSet(q, model.predict(model.inputs(q), p) + rng.normal(0, sigma, (200, 3)))
    start = {b: float(p[model.layout.index(b)]) for b in BASE}
    res = fit(data, seed, "geometric", fixed=BASE, start=start, noise_mm=1e3 * sigma)
    assert all(res[b] == start[b] for b in BASE)  # held exactly

    names = model.layout.names
    others = [k for k, n in enumerate(names) if n not in BASE]
    # the structure at the starting arm, where the first-order dependencies are exact
    p0 = model.layout.vector(start, default=model.nominal())
    J = fd_jacobian(model, model.inputs(q), p0)
    rank, zero, involved = svd_structure(J[:, others], [names[k] for k in others])
    assert res.rank == rank == 23  # 25 with the base free, less its 6, plus row 1's 4
    assert {"dalpha1", "da1", "dtheta1", "dd1"} <= set(res.identifiability.identifiable_names)
    ident = res.identifiability
    assert set(ident.held) == set(BASE)
    assert not set(BASE) & (set(ident.fixed_names) | named(ident.unidentifiable))
    # the fixed ones are one per null direction, each taking part in one; the kept are independent
    assert set(ident.fixed_names) <= involved | zero
    assert len(ident.fixed_names) == len(others) - rank
    kept = [k for k, n in enumerate(names) if n in ident.identifiable_names]
    assert svd_structure(J[:, kept], kept)[0] == len(kept)
    # and the fit finds row 1 where it is, at the noise floor
    for n in ("dalpha1", "da1", "dtheta1", "dd1"):
        k = model.layout.index(n)
        assert abs(res.params[k] - p[k]) <= 4 * res.std[k], n
        assert res.std[k] < 0.05 * abs(p[k]) or res.std[k] < 2e-6, n
    assert res.sigma == pytest.approx(sigma, rel=0.1)


def test_a_free_base_absorbs_row_1(seed):
    """The same arm with the base free: the finite-difference Jacobian has row 1 in the base's
    span, and the fit names the pairs."""
    model = ErrorModel(seed, "geometric")
    rng = np.random.default_rng(10)
    p = sample_parameters(model, rng)
    q = sample_poses(seed, 200, rng)
    data = MeasurementSet(q, model.predict(model.inputs(q), p) + rng.normal(0, 15e-6, (200, 3)))
    res = fit(data, seed, "geometric", noise_mm=0.015)
    J = fd_jacobian(model, model.inputs(q), model.nominal())
    rank, _, involved = svd_structure(J, model.layout.names)
    assert res.rank == rank == 25
    assert {"dalpha1", "da1", "dtheta1", "dd1"} <= involved
    assert {"dd1 - bz", "dtheta1 - brz"} <= set(res.unidentifiable)
    assert res.identifiability.held == ()
