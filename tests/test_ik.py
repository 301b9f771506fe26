"""Inverse kinematics: the closed form returns every solution within the limits (the original q
among them) and each reproduces the pose; damped least squares reaches poses and points on any
arm and on a calibrated error model."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from arm.description import Joint, RobotDescription
from arm.errormodel import ErrorModel
from arm.ik import (
    POSE_TOL,
    IKError,
    InverseKinematics,
    forward_pose,
    solve_model_pose,
    solve_point,
    solve_pose,
    solve_position,
    wrist_structure,
)
from arm.kinematics import Chain, link_frames, tool_points
from arm.sampling import sample_parameters
from tests.conftest import random_q


def _nearest_distance(q: np.ndarray, sols: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """Per pose, the max-norm distance from q to the nearest returned solution (inf if none)."""
    d = np.full(len(q), np.inf)
    np.minimum.at(d, owner, np.max(np.abs(sols - q[owner]), axis=1))
    return d


def _away_from_wrist_singularity(robot, q: np.ndarray, margin: float = 1e-4) -> np.ndarray:
    """At sin(theta_5) = 0 only q4 +- q6 is determined: q itself is not recoverable there."""
    th5 = q[:, 4] + robot.to_modified().column("theta_offset")[4]
    return np.abs(np.sin(th5)) > margin


@pytest.mark.parametrize("arm", ["seed", "rokae", "puma"])
def test_closed_form_returns_q_and_only_exact_solutions(arm, request):
    robot = request.getfixturevalue(arm)
    ik = InverseKinematics(robot)
    assert ik.method == "closed_form", ik.reason
    q = random_q(robot, 400, seed=11)
    q = q[_away_from_wrist_singularity(robot, q)]
    T = forward_pose(robot, q)
    sols, owner = ik.solve_flat(T)
    # the original configuration is among the solutions of its pose
    assert np.all(_nearest_distance(q, sols, owner) < 1e-7)
    # every solution is within the limits and reproduces the pose
    assert np.all(robot.within_limits(sols))
    err = np.abs(forward_pose(robot, sols) - T[owner]).max(axis=(1, 2))
    assert err.max() < POSE_TOL
    # solutions of one pose are distinct
    for k in range(len(q)):
        s = sols[owner == k]
        d = np.max(np.abs(s[:, None] - s[None]), axis=-1) + np.eye(len(s))
        assert d.min() > 1e-6


def test_standard_dh_arm_with_a_flange_row(puma):
    """A standard-DH last row TransX(a6) RotX(alpha6) is the flange: poses are the flange's."""
    joints = list(puma.joints)
    joints[5] = replace(joints[5], a=0.05, alpha=math.radians(90), theta_offset=0.3)
    arm = replace(puma, joints=tuple(joints))
    ik = InverseKinematics(arm)
    assert ik.method == "closed_form"
    q = random_q(arm, 100, seed=14)
    q = q[_away_from_wrist_singularity(arm, q)]
    T = forward_pose(arm, q)
    sols, owner = ik.solve_flat(T)
    assert np.all(_nearest_distance(q, sols, owner) < 1e-7)
    np.testing.assert_allclose(forward_pose(arm, sols), T[owner], atol=1e-9)


def test_wrist_angles_are_aliased_by_two_pi(seed):
    """q6 spans +-6.28 rad on the seed arm: both q6 and q6 - 2 pi reach the pose; the wrist flip
    (q4 + pi, -q5, q6 + pi) is there too, with its own aliases."""
    q = np.array([0.3, -1.2, 0.4, 0.5, 0.8, 0.2])
    sols = InverseKinematics(seed).solve(forward_pose(seed, q))
    same_arm = sols[np.max(np.abs(sols[:, :5] - q[:5]), axis=1) < 1e-9]
    np.testing.assert_allclose(np.sort(same_arm[:, 5]), [0.2 - 2 * math.pi, 0.2], atol=1e-9)
    flip = np.array([0.3, -1.2, 0.4, 0.5 - math.pi, -0.8, 0.2 + math.pi])
    assert np.min(np.max(np.abs(sols - flip), axis=1)) < 1e-9
    assert np.min(np.max(np.abs(sols - (flip - [0, 0, 0, 0, 0, 2 * math.pi])), axis=1)) < 1e-9


@pytest.mark.parametrize("arm", ["seed", "rokae"])
def test_closed_form_misses_no_solution_that_a_search_finds(arm, request):
    """Completeness against an independent search: damped least squares from 600 random starts
    within the limits finds no solution that the closed form lacks."""
    robot = request.getfixturevalue(arm)
    ik = InverseKinematics(robot)
    rng = np.random.default_rng(12)
    for q in random_q(robot, 3, seed=13):
        T = forward_pose(robot, q)
        sols = ik.solve(T)
        starts = rng.uniform(robot.lower, robot.upper, (600, 6))
        res = solve_pose(robot, np.broadcast_to(T, (600, 4, 4)), starts, max_iter=60)
        found = res.q[res.converged]
        assert len(found) > 0
        dist = np.max(np.abs(found[:, None, :] - sols[None]), axis=-1).min(axis=1)
        assert dist.max() < 1e-6, found[np.argmax(dist)]


def test_wrist_singularity_solutions_reproduce_the_pose(seed):
    q = np.array([[0.4, -1.0, 0.3, 0.7, 0.0, -0.5]])  # q5 = 0: axes 4 and 6 aligned
    T = forward_pose(seed, q)
    ik = InverseKinematics(seed)
    sols = ik.solve(T[0])
    assert len(sols) > 0
    np.testing.assert_allclose(
        forward_pose(seed, sols), np.broadcast_to(T, (len(sols), 4, 4)), atol=1e-9
    )
    # only q4 + q6 is fixed there; with q4 taken from a reference, q comes back
    near = ik.nearest(T[0], q[0])
    assert near.converged
    np.testing.assert_allclose(near.q, q[0], atol=1e-9)


def test_unreachable_pose_has_no_solution(seed):
    T = np.eye(4)
    T[:3, 3] = (3.0, 0.0, 0.5)  # far beyond the 1.2 m reach
    assert InverseKinematics(seed).solve(T).shape == (0, 6)
    res = InverseKinematics(seed).nearest(T[None], np.zeros((1, 6)))
    assert not res.converged[0]


def test_tool_pose_and_batched_list(seed):
    tool = np.eye(4)
    tool[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    tool[:3, 3] = (0.01, 0.02, 0.15)
    q = random_q(seed, 20, seed=3)
    T = forward_pose(seed, q, tool)
    out = InverseKinematics(seed, tool=tool).solve(T)
    assert isinstance(out, list) and len(out) == 20
    for qk, s in zip(q, out, strict=True):
        assert np.min(np.max(np.abs(s - qk), axis=1)) < 1e-7 or abs(math.sin(qk[4])) < 1e-4
        np.testing.assert_allclose(
            forward_pose(seed, s, tool),
            np.broadcast_to(forward_pose(seed, qk, tool), (len(s), 4, 4)),
            atol=1e-9,
        )


def test_nearest_follows_a_trajectory(seed):
    """The nearest solution of a smooth path stays on the path's branch."""
    t = np.linspace(0.0, 1.0, 50)[:, None]
    q = np.array([0.2, -1.3, 0.5, -0.4, 0.9, 1.0]) + t * np.array([0.5, 0.3, -0.4, 0.6, -0.3, 2.0])
    res = InverseKinematics(seed).nearest(forward_pose(seed, q), q + 0.01)
    assert res.converged.all()
    np.testing.assert_allclose(res.q, q, atol=1e-8)


def test_structure_check_names_what_breaks_it(seed, ur5):
    ok, reason = wrist_structure(seed)
    assert ok and reason == ""
    ok, reason = wrist_structure(ur5)
    assert not ok and "d_5" in reason
    ik = InverseKinematics(ur5)
    assert ik.method == "dls" and not ik.closed_form


def test_calibrated_arm_uses_closed_form_then_refines(seed):
    """Small geometric errors break the exact structure (beta2, a_4...); the closed form of the
    nearest structured arm seeds a refinement on the true chain, still finding q."""
    model = ErrorModel(seed, "geometric")
    p = sample_parameters(model, np.random.default_rng(4))
    cal = model.description(p)
    ik = InverseKinematics(cal)
    assert ik.method == "closed_form+dls"
    q = random_q(seed, 150, seed=5)
    q = q[_away_from_wrist_singularity(seed, q, 1e-2)]
    T = forward_pose(cal, q)
    sols, owner = ik.solve_flat(T)
    assert np.all(_nearest_distance(q, sols, owner) < 1e-7)
    err = np.abs(forward_pose(cal, sols) - T[owner]).max()
    assert err < POSE_TOL


def test_dls_pose_converges_on_a_non_spherical_wrist(ur5):
    rng = np.random.default_rng(6)
    q = rng.uniform(-2.5, 2.5, (200, 6))
    T = forward_pose(ur5, q)
    q0 = q + rng.normal(0.0, 0.2, q.shape)
    res = solve_pose(ur5, T, q0)
    assert res.converged.mean() > 0.97  # a few starts near a singularity may stall
    ok = res.converged
    np.testing.assert_allclose(forward_pose(ur5, res.q[ok]), T[ok], atol=1e-9)


def test_ik_fallback_solutions_reproduce_the_pose(ur5):
    q = random_q(ur5, 10, seed=7) * 0.6
    T = forward_pose(ur5, q)
    sols, owner = InverseKinematics(ur5, n_starts=12).solve_flat(T)
    assert set(owner.tolist()) == set(range(10))  # at least one solution per reachable pose
    np.testing.assert_allclose(forward_pose(ur5, sols), T[owner], atol=1e-9)


def test_solve_point_reaches_tool_points_within_limits(seed):
    rng = np.random.default_rng(8)
    q = random_q(seed, 200, seed=8)
    chain = Chain.from_description(seed)
    target = tool_points(chain, q, seed.tool_points[0])
    res = solve_point(
        seed, target, np.clip(q + rng.normal(0, 0.1, q.shape), seed.lower, seed.upper)
    )
    assert res.converged.all()
    assert np.all(seed.within_limits(res.q))
    np.testing.assert_allclose(tool_points(chain, res.q, seed.tool_points[0]), target, atol=1e-11)


def test_solve_position_inverts_a_calibrated_model(seed):
    """What the lab's compensation needs: encoder readings for which the calibrated model (all
    effects, base, thermal, payload, backlash directions, two targets) predicts the wanted points."""
    robot = replace(seed, tools=((0.0, 0.0, 0.05), (0.03, 0.0, 0.04)))
    model = ErrorModel(
        robot,
        "geometric,compliance,transmission,joint_scale,backlash,load_backlash,thermal",
        targets=(0, 1),
    )
    rng = np.random.default_rng(9)
    p = sample_parameters(model, rng)
    p[model.layout.index("brz")] = 1.3  # a real tracker sits far from the base, turned
    p[model.layout.index("bx")] = 2.5
    n = 120
    q = random_q(seed, n, seed=9)
    cols = {
        "temperature": rng.uniform(15, 35, n),
        "payload": rng.uniform(0, 5, n),
        "target": rng.integers(0, 2, n).astype(float),
        **{f"dir{j}": rng.choice((-1.0, 1.0), n) for j in range(1, 7)},
    }
    target = model.predict(model.inputs(q, cols), p)
    q0 = np.clip(q + rng.normal(0, 0.05, q.shape), seed.lower, seed.upper)
    res = solve_position(model, cols, p, target, q0)
    assert res.converged.all(), res.error.max()
    reached = model.predict(model.inputs(res.q, cols), p)
    np.testing.assert_allclose(reached, target, atol=1e-9)
    assert np.all(seed.within_limits(res.q))


def test_solve_model_pose_returns_the_pose_of_the_start_branch(seed):
    """Six equations on a calibrated model (geometric errors, a base 1.5 m away): from a start a
    few hundredths of a radian off, the solve returns the joints that made the pose, reproducing
    it by the plain kinematics of the model's description (frames and tool point)."""
    model = ErrorModel(seed, "geometric")
    rng = np.random.default_rng(4)
    p = sample_parameters(model, rng)
    p[model.layout.index("bx")] = 1.5
    arm = model.description(p)  # the calibrated arm as a description, read by plain kinematics
    q = random_q(seed, 60, seed=4)
    chain = Chain.from_description(arm)
    B = arm.base_matrix
    f = link_frames(chain, q)
    xyz = tool_points(chain, q, arm.tool_points[0]) @ B[:3, :3].T + B[:3, 3]
    R = B[:3, :3] @ f.R[:, 6]
    keep = np.abs(np.sin(q[:, 4])) > 0.2  # away from the wrist singularity
    q0 = np.clip(q + rng.normal(0, 0.02, q.shape), seed.lower, seed.upper)
    own = ErrorModel(arm, "geometric")
    res = solve_model_pose(own, {}, own.nominal(), xyz[keep], R[keep], q0[keep])
    assert res.converged.all(), res.error.max()
    np.testing.assert_allclose(res.q, q[keep], atol=1e-8)


def test_bad_shapes_are_refused(seed):
    with pytest.raises(IKError, match="q0"):
        solve_pose(seed, np.eye(4)[None].repeat(3, 0), np.zeros((2, 6)))
    with pytest.raises(IKError, match="tool"):
        InverseKinematics(seed, tool=np.zeros(2))


@settings(max_examples=25, derandomize=True, deadline=None)
@given(
    lengths=arrays(np.float64, 9, elements=st.floats(-0.6, 0.6)),
    offsets=arrays(np.float64, 6, elements=st.floats(-math.pi, math.pi)),
    alpha0=st.floats(-math.pi, math.pi),
    alpha3=st.floats(-math.pi, math.pi),
    alpha4=st.sampled_from([90.0, -90.0, 60.0, -120.0]),
    alpha5=st.sampled_from([90.0, -90.0, 45.0]),
    alpha1=st.sampled_from([90.0, -90.0]),
    alpha2=st.sampled_from([0.0, 180.0]),
)
def test_closed_form_on_any_arm_of_the_supported_structure(
    lengths, offsets, alpha0, alpha3, alpha4, alpha5, alpha1, alpha2
):
    """The derivation's generality: any alpha_0, a_0, d_1, shoulder offset a_1, lateral offsets
    d_2, d_3, elbow offsets a_3, d_4 and alpha_3, either sign of alpha_1, alpha_2 = 0 or 180 deg,
    non-orthogonal wrists, any theta offsets."""
    a0, a1, a2, a3, d1, d2, d3, d4, d6 = lengths
    a2 = math.copysign(max(abs(a2), 0.2), a2)  # joints 2, 3 need a link between them
    d4 = math.copysign(max(abs(d4), 0.2), d4)  # and the wrist centre must be off axis 3
    alpha3 = math.copysign(max(abs(alpha3), 0.3), alpha3)
    rows = [
        (math.degrees(alpha0), a0, d1),
        (alpha1, a1, d2),
        (alpha2, a2, d3),
        (math.degrees(alpha3), a3, d4),
        (alpha4, 0.0, 0.0),
        (alpha5, 0.0, d6),
    ]
    arm = RobotDescription(
        "random",
        tuple(
            Joint(alpha=math.radians(al), a=a, d=d, theta_offset=off)
            for (al, a, d), off in zip(rows, offsets, strict=True)
        ),
    )
    ik = InverseKinematics(arm)
    assert ik.method == "closed_form", ik.reason
    q = random_q(arm, 40, seed=15)
    T = forward_pose(arm, q)
    sols, owner = ik.solve_flat(T)
    W = np.cross(
        link_frames(Chain.from_description(arm), q).R[:, 4, :, 2],
        link_frames(Chain.from_description(arm), q).R[:, 6, :, 2],
    )
    regular = np.linalg.norm(W, axis=1) > 1e-3  # axes 4 and 6 not aligned
    assert np.all(_nearest_distance(q, sols, owner)[regular] < 1e-6)
    np.testing.assert_allclose(forward_pose(arm, sols), T[owner], atol=1e-9)
