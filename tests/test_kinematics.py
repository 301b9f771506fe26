"""Forward kinematics, the joint Jacobian and gravity torques against independent references:
Pinocchio built from its own joint placements, poses derived by hand, finite differences, the
potential energy."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from arm.kinematics import Chain, geometric_jacobian, gravity_torques, link_frames, tool_points
from tests.conftest import puma_arm, random_q, rokae_arm

SETTINGS = settings(max_examples=25, derandomize=True, deadline=None)
angles = arrays(np.float64, (5, 6), elements=st.floats(-math.pi, math.pi))


# -- by hand --------------------------------------------------------------------------------------
# The seed arm of docs/format.md. At q = (0, -pi/2, 0, 0, 0, 0) frame 2 has x2 = +z (upper arm up),
# z2 = +y; o3 = (a1, 0, d1 + a2) = (0.132, 0, 0.70); the elbow offset a3 = 0.1634 goes up along
# x3 = x2 and d4 = 0.35 forward along z4 = +x; the wrist keeps z6 = +x, so the tool sits
# d6 + 0.05 = 0.2856 further along +x.
#  * home: (0.132 + 0.35 + 0.2856, 0, 0.08 + 0.62 + 0.1634) = (0.7676, 0, 0.8634) (docs/format.md).
#  * q3 = +pi/2 turns the forearm about z2 = +y: up -> +x, +x -> -z, so the elbow offset points
#    forward and the rest down: (0.132 + 0.1634, 0, 0.70 - 0.35 - 0.2856) = (0.2954, 0, 0.0644).
#  * q5 = +pi/2: z5 = -y4 = +y, turning +x into -z about the wrist centre (0.482, 0, 0.8634):
#    (0.482, 0, 0.8634 - 0.2856) = (0.482, 0, 0.5778).
#  * q1 = +pi/2 turns the home pose about the vertical: (0, 0.7676, 0.8634).
HAND = [
    ((0, -math.pi / 2, 0, 0, 0, 0), (0.7676, 0.0, 0.8634), (1, 0, 0)),
    ((0, -math.pi / 2, math.pi / 2, 0, 0, 0), (0.2954, 0.0, 0.0644), (0, 0, -1)),
    ((0, -math.pi / 2, 0, 0, math.pi / 2, 0), (0.482, 0.0, 0.5778), (0, 0, -1)),
    ((math.pi / 2, -math.pi / 2, 0, 0, 0, 0), (0.0, 0.7676, 0.8634), (0, 1, 0)),
]


@pytest.mark.parametrize(("q", "tool", "z6"), HAND)
def test_seed_arm_at_hand_derived_poses(seed, q, tool, z6):
    chain = Chain.from_description(seed)
    np.testing.assert_allclose(
        tool_points(chain, np.array(q), seed.tool_points[0]), tool, atol=1e-12
    )
    f = link_frames(chain, np.array(q))
    np.testing.assert_allclose(f.R[0, 6, :, 2], z6, atol=1e-12)
    assert np.allclose(f.R[0, 6] @ f.R[0, 6].T, np.eye(3), atol=1e-14)


def test_rokae_arm_zero_pose_by_hand():
    """The rokae table at q = 0 (theta offsets -90 and 180 deg): x2 = +z, so the arm stands up,
    the elbow offset 0.205 goes up, d4 = 0.72 forward along +x, and the 180 deg at joint 6 turns
    the flange about z6 = +x: flange at (0.085 + 0.72 + 0.075, 0, 0.487 + 0.64 + 0.205)."""
    arm = replace(rokae_arm(), tools=((0.0, 0.0, 0.0),))
    f = link_frames(Chain.from_description(arm), np.zeros(6))
    np.testing.assert_allclose(f.o[0, 6], (0.88, 0.0, 1.332), atol=1e-12)
    # Without the offset frame 6 would be x = +z, y = -y, z = +x (as on the seed arm at home);
    # RotZ(180) at joint 6 flips x6 and y6: x6 = -z, y6 = +y, z6 = +x.
    np.testing.assert_allclose(f.R[0, 6], [[0, 0, 1], [0, 1, 0], [-1, 0, 0]], atol=1e-12)


# -- standard DH ----------------------------------------------------------------------------------
def _standard_product(robot, q):
    """Frame 6 of a standard-DH arm, RotZ(theta) TransZ(d) TransX(a) RotX(alpha) per row."""
    T = np.eye(4)
    for j, qi in zip(robot.joints, q, strict=True):
        th = qi + j.theta_offset
        ct, st_, ca, sa = math.cos(th), math.sin(th), math.cos(j.alpha), math.sin(j.alpha)
        T = T @ np.array(
            [
                [ct, -st_ * ca, st_ * sa, j.a * ct],
                [st_, ct * ca, -ct * sa, j.a * st_],
                [0, sa, ca, j.d],
                [0, 0, 0, 1],
            ]
        )
    return T


def _with_flange(robot):
    """The same standard-DH arm with a last row that is not the identity (a6, alpha6 != 0)."""
    joints = list(robot.joints)
    joints[5] = replace(joints[5], a=0.05, alpha=math.radians(90), theta_offset=0.3)
    return replace(robot, joints=tuple(joints), name=robot.name + "-flange")


def test_standard_dh_to_modified_matches_the_standard_product(ur5):
    from arm.ik import forward_pose

    for robot in (ur5, puma_arm(), _with_flange(ur5), _with_flange(puma_arm())):
        m = robot.to_modified()
        chain = Chain.from_description(m)
        q = random_q(robot, 20, seed=1)
        tool = np.array(robot.tools[0])
        direct = np.array([_standard_product(robot, qi) for qi in q])
        np.testing.assert_allclose(forward_pose(robot, q), direct, atol=1e-12)
        expected = direct[:, :3, :3] @ tool + direct[:, :3, 3]
        np.testing.assert_allclose(tool_points(chain, q, m.tool_points[0]), expected, atol=1e-12)


# -- Pinocchio --------------------------------------------------------------------------------------
def _pinocchio_model(robot, payload_at_tool: float = 0.0):
    """A Pinocchio model of a modified-DH arm from its own joint placements: joint i is a revolute
    about its z, placed at RotX(alpha) RotY(beta) TransX(a) RotZ(theta_offset) TransZ(d) in i-1;
    links are point masses at their centres of mass; the tool is an operational frame."""
    pin = pytest.importorskip("pinocchio")
    m = robot.to_modified()

    def rot(axis, angle):
        return pin.AngleAxis(angle, np.eye(3)[axis]).toRotationMatrix()

    model = pin.Model()
    parent = 0
    for i, j in enumerate(m.joints, start=1):
        M = (
            pin.SE3(rot(0, j.alpha) @ rot(1, j.beta), np.zeros(3))
            * pin.SE3(np.eye(3), np.array([j.a, 0.0, 0.0]))
            * pin.SE3(rot(2, j.theta_offset), np.array([0.0, 0.0, j.d]))
        )
        parent = model.addJoint(parent, pin.JointModelRZ(), M, f"joint{i}")
        model.appendBodyToJoint(
            parent, pin.Inertia(j.mass, np.array(j.com), np.zeros((3, 3))), pin.SE3.Identity()
        )
    tool = pin.SE3(np.eye(3), m.tool_points[0])
    if payload_at_tool:
        model.appendBodyToJoint(
            parent,
            pin.Inertia(payload_at_tool, m.tool_points[0], np.zeros((3, 3))),
            pin.SE3.Identity(),
        )
    fid = model.addFrame(pin.Frame("tool", parent, 0, tool, pin.FrameType.OP_FRAME))
    model.gravity.linear = np.array(m.gravity)
    return pin, model, fid


@pytest.mark.parametrize("arm", ["seed", "rokae", "puma"])
def test_fk_equals_pinocchio(arm, request):
    robot = request.getfixturevalue(arm)
    pin, model, fid = _pinocchio_model(robot)
    data = model.createData()
    m = robot.to_modified()
    chain = Chain.from_description(m)
    q = random_q(robot, 200, seed=2)
    f = link_frames(chain, q)
    pts = tool_points(chain, q, m.tool_points[0])
    for k, qk in enumerate(q):
        pin.framesForwardKinematics(model, data, qk)
        np.testing.assert_allclose(pts[k], data.oMf[fid].translation, rtol=0, atol=1e-12)
        for i in range(1, 7):
            np.testing.assert_allclose(f.R[k, i], data.oMi[i].rotation, rtol=0, atol=1e-12)
            np.testing.assert_allclose(f.o[k, i], data.oMi[i].translation, rtol=0, atol=1e-12)


def test_gravity_torques_equal_pinocchio(seed):
    """The sign of docs/format.md (compliance): tau is minus the torque that holds the arm, i.e.
    minus Pinocchio's g(q)."""
    payload = 3.0
    pin, model, _ = _pinocchio_model(seed, payload_at_tool=payload)
    data = model.createData()
    q = random_q(seed, 50, seed=3)
    tau = gravity_torques(seed, q, payload=payload)
    ref = np.array([-pin.computeGeneralizedGravity(model, data, qk) for qk in q])
    np.testing.assert_allclose(tau, ref, rtol=0, atol=1e-10)


# -- finite differences ------------------------------------------------------------------------------
def _so3_vee(S: np.ndarray) -> np.ndarray:
    return (
        np.stack(
            [S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0], S[..., 1, 0] - S[..., 0, 1]],
            -1,
        )
        / 2
    )


@SETTINGS
@given(q=angles, arm=st.sampled_from(["seed", "rokae", "puma"]))
def test_geometric_jacobian_equals_finite_differences(q, arm):
    robot = {"seed": None, "rokae": rokae_arm(), "puma": puma_arm()}[arm]
    if robot is None:
        from arm.description import seed_robot

        robot = seed_robot()
    m = robot.to_modified()
    chain = Chain.from_description(m)
    point = m.tool_points[0]
    J = geometric_jacobian(chain, q, point)
    h = 1e-6
    R = link_frames(chain, q).R[:, 6]
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        dp = (tool_points(chain, q + dq, point) - tool_points(chain, q - dq, point)) / (2 * h)
        np.testing.assert_allclose(J[:, :3, i], dp, rtol=0, atol=1e-8)
        dR = (link_frames(chain, q + dq).R[:, 6] - link_frames(chain, q - dq).R[:, 6]) / (2 * h)
        omega = _so3_vee(dR @ np.swapaxes(R, 1, 2))  # dR/dq R^T = [omega]x
        np.testing.assert_allclose(J[:, 3:, i], omega, rtol=0, atol=1e-8)


def _potential(robot, q, payload):
    """V(q) = -sum_k m_k g . c_k(q) - m_p g . tool(q), the gravity potential of the mass model."""
    chain = Chain.from_description(robot)
    f = link_frames(chain, q)
    g = np.array(robot.gravity)
    V = np.zeros(f.o.shape[0])
    for k, j in enumerate(robot.joints, start=1):
        c = f.o[:, k] + f.R[:, k] @ np.array(j.com)
        V -= j.mass * c @ g
    return V - payload * (f.point(robot.tool_points[0]) @ g)


@SETTINGS
@given(q=angles, payload=st.floats(0.0, 20.0))
def test_gravity_torques_are_minus_the_potential_gradient(seed, q, payload):
    """tau = -dV/dq: the generalised force of gravity, i.e. minus the holding torque
    (docs/format.md, compliance)."""
    tau = gravity_torques(seed, q, payload=payload)
    h = 1e-6
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        dV = (_potential(seed, q + dq, payload) - _potential(seed, q - dq, payload)) / (2 * h)
        np.testing.assert_allclose(tau[:, i], -dV, rtol=0, atol=1e-6)
    # on the seed arm axis 1 is vertical and every mass of link 6 and the payload lie on axis 6
    np.testing.assert_allclose(tau[:, [0, 5]], 0.0, atol=1e-10)


def test_gravity_torques_at_home_by_hand(seed):
    """At home z2 = z3 = +y, z4 = z6 = +x, z5 = +y; a mass forward (+x) of an axis along +y
    pulls it the positive way (x turns towards -z about +y). Horizontal levers from o3
    (x = 0.132): link 3 com 0.10 (y3 = +x), link 4 com 0.35 - 0.10, link 5 com 0.35, link 6 com
    0.35 + 0.2356 + 0.02; link 2's com is straight above o2, so tau2 = tau3. About axis 5 (at the
    wrist centre) only link 6 pulls, lever 0.2556; axes 1, 4 and 6 carry nothing."""
    tau = gravity_torques(seed, np.array([0, -math.pi / 2, 0, 0, 0, 0]))
    t3 = 9.81 * (8.0 * 0.10 + 3.0 * 0.25 + 2.0 * 0.35 + 0.5 * 0.6056)
    np.testing.assert_allclose(tau, [0.0, t3, t3, 0.0, 9.81 * 0.5 * 0.2556, 0.0], atol=1e-12)
    # a 2 kg payload at the tool point (0.2856 beyond the wrist centre) adds to 2, 3 and 5
    tau_p = gravity_torques(seed, np.array([0, -math.pi / 2, 0, 0, 0, 0]), payload=2.0)
    np.testing.assert_allclose(
        tau_p - tau, [0, 2 * 9.81 * 0.6356, 2 * 9.81 * 0.6356, 0, 2 * 9.81 * 0.2856, 0], atol=1e-12
    )


def test_batched_shapes_and_per_pose_chain(seed):
    chain = Chain.from_description(seed)
    q = random_q(seed, 7, seed=4)
    pts = tool_points(chain, q, seed.tool_points[0])
    assert pts.shape == (7, 3)
    np.testing.assert_allclose(tool_points(chain, q[3], seed.tool_points[0]), pts[3], atol=0)
    assert geometric_jacobian(chain, q[0], seed.tool_points[0]).shape == (6, 6)
    # per-pose lengths (thermal growth): each pose equals the chain scaled alone
    scale = np.linspace(1.0, 1.001, 7)
    per_pose = chain.replace(a=chain.a[None] * scale[:, None], d=chain.d[None] * scale[:, None])
    got = tool_points(per_pose, q, seed.tool_points[0])
    frames = link_frames(per_pose, q).point(seed.tool_points[0])
    for k in range(7):
        one = chain.replace(a=chain.a * scale[k], d=chain.d * scale[k])
        ref = tool_points(one, q[k], seed.tool_points[0])
        np.testing.assert_allclose(got[k], ref, atol=1e-15)
        np.testing.assert_allclose(frames[k], ref, atol=1e-15)
