"""URDF in: the serial chain of a URDF becomes the lab's modified-DH arm exactly. Forward kinematics
and gravity torques equal Pinocchio's (an independent URDF reader) on the shipped UR3/UR5/UR10/Z1
and on random arms with skew, intersecting, parallel and nearly parallel axes; UR's published DH
table comes out of ur5_robot.urdf; the tip is found or named; bad files are refused by name."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from arm.description import DescriptionError, RobotDescription, load_robot
from arm.ik import forward_pose
from arm.kinematics import Chain, gravity_torques, tool_points
from tests.test_architecture import _loaded_after

pin = pytest.importorskip("pinocchio")

SHIPPED = [
    ("ur3_robot", {}),
    ("ur5_robot", {}),
    ("ur5_robot", {"base": "base", "tip": "tool0"}),
    ("ur10_robot", {"tip": "ee_link"}),
    ("z1", {}),
    ("z1", {"tip": "gripperStator"}),
]


# -- Pinocchio, the independent reader ------------------------------------------------------------
def _pin_setup(robot: RobotDescription):
    model = pin.buildModelFromXML(robot.urdf.text)
    data = model.createData()
    base = model.getFrameId(robot.urdf.base_link, pin.BODY)
    tip = model.getFrameId(robot.urdf.tip_link, pin.BODY)
    assert base < model.nframes and tip < model.nframes
    return model, data, base, tip


def _pin_q(model, robot, q6):
    """Pinocchio's configuration with the arm's joints at q6 (URDF joint order by name), other
    joints (a gripper) at zero."""
    q = pin.neutral(model)
    arm_joints = _arm_joint_names(robot)
    for k, name in enumerate(arm_joints):
        jm = model.joints[model.getJointId(name)]
        if jm.nq == 2:  # continuous: (cos, sin)
            q[jm.idx_q : jm.idx_q + 2] = (math.cos(q6[k]), math.sin(q6[k]))
        else:
            q[jm.idx_q] = q6[k]
    return q


def _arm_joint_names(robot):
    from arm.urdf import read_urdf

    u = robot.urdf
    return read_urdf(u.path, tip=u.tip_link, base=u.base_link, text=u.text).joint_names


def _pin_tip(robot, q6):
    """(N, 4, 4) tip link in the base link's frame, by Pinocchio."""
    model, data, base, tip = _pin_setup(robot)
    out = []
    for q in q6:
        pin.framesForwardKinematics(model, data, _pin_q(model, robot, q))
        out.append((data.oMf[base].inverse() * data.oMf[tip]).homogeneous)
    return np.array(out)


def _lab_tip(robot, q6):
    """(N, 4, 4) tip link in the base link's frame by the lab's kinematics: the base transform,
    the chain (arm.kinematics) and the flange (arm.ik.forward_pose)."""
    return robot.base_matrix @ forward_pose(robot, q6)


def _random_q(robot, n, seed):
    lo, hi = np.maximum(robot.lower, -4.0), np.minimum(robot.upper, 4.0)
    return np.random.default_rng(seed).uniform(lo, hi, (n, 6))


@pytest.mark.parametrize(("name", "kw"), SHIPPED)
def test_forward_kinematics_equals_pinocchio_on_the_shipped_urdfs(name, kw):
    robot = load_robot(name, **kw)
    q = _random_q(robot, 200, seed=1)
    expected = _pin_tip(robot, q)
    got = _lab_tip(robot, q)
    np.testing.assert_allclose(got[:, :3, 3], expected[:, :3, 3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[:, :3, :3], expected[:, :3, :3], rtol=0, atol=1e-12)
    # the tool point the lab fits (the tip link's origin) through the batched point kinematics
    pts = tool_points(Chain.from_description(robot), q, robot.tool_points[0])
    pts = pts @ robot.base_matrix[:3, :3].T + robot.base_matrix[:3, 3]
    np.testing.assert_allclose(pts, expected[:, :3, 3], rtol=0, atol=1e-12)


@pytest.mark.parametrize(("name", "kw"), [("ur5_robot", {}), ("z1", {}), ("ur3_robot", {})])
def test_gravity_torques_equal_pinocchio(name, kw):
    """The masses and centres of mass come from the inertials (the Z1's gripper, beyond the arm,
    at its zero position): the lab's gravity torques are minus Pinocchio's generalized gravity."""
    robot = load_robot(name, **kw)
    model, data, _, _ = _pin_setup(robot)
    idx = [model.joints[model.getJointId(n)].idx_v for n in _arm_joint_names(robot)]
    q = _random_q(robot, 30, seed=2)
    tau = gravity_torques(robot, q)
    for k, qk in enumerate(q):
        g = pin.computeGeneralizedGravity(model, data, _pin_q(model, robot, qk))
        np.testing.assert_allclose(tau[k], -g[idx], rtol=0, atol=1e-10)
    assert robot.has_mass_model


# -- random arms ------------------------------------------------------------------------------------
def _random_urdf(seed: int) -> tuple[str, dict]:
    """A URDF of six revolute joints with random placements: skew axes, and at random an axis
    parallel, nearly parallel (1 mrad) or antiparallel to the previous one, or intersecting it;
    a fixed mount before the arm and a tool after it; continuous joints and unnormalised axes."""
    rng = np.random.default_rng(seed)

    def fmt(v):
        return " ".join(repr(float(x)) for x in v)

    links = ["world", "mount", *[f"l{i}" for i in range(1, 7)], "tool"]
    out = ['<?xml version="1.0"?>', f'<robot name="random{seed}">']
    for i, name in enumerate(links):
        m = rng.uniform(0.2, 5.0)
        c = rng.uniform(-0.1, 0.1, 3)
        out.append(
            f'  <link name="{name}"><inertial><mass value="{m!r}"/><origin xyz="{fmt(c)}"/>'
            '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>'
            if i > 0
            else f'  <link name="{name}"/>'
        )
    out.append(
        f'  <joint name="mount_joint" type="fixed"><parent link="world"/><child link="mount"/>'
        f'<origin xyz="{fmt(rng.uniform(-1, 1, 3))}" rpy="{fmt(rng.uniform(-3, 3, 3))}"/></joint>'
    )
    axis = rng.normal(size=3)
    kinds = {}
    for i in range(1, 7):
        kind = rng.choice(["skew", "parallel", "nearly", "anti", "intersect"]) if i > 1 else "skew"
        kinds[i] = kind
        xyz, rpy = rng.uniform(-0.4, 0.4, 3), rng.uniform(-math.pi, math.pi, 3)
        new_axis = rng.normal(size=3) * rng.uniform(0.5, 2.0)
        if kind in ("parallel", "nearly", "anti"):
            rpy = np.zeros(3) if kind != "nearly" else rng.normal(size=3) * 1e-3
            new_axis = axis * (-1.7 if kind == "anti" else 1.3)
        elif kind == "intersect":
            xyz = axis / np.linalg.norm(axis) * rng.uniform(-0.3, 0.3)
        jtype = "continuous" if rng.random() < 0.2 else "revolute"
        limit = '<limit lower="-3.0" upper="2.5" effort="1" velocity="1"/>'
        parent = "mount" if i == 1 else f"l{i - 1}"
        out.append(
            f'  <joint name="j{i}" type="{jtype}"><parent link="{parent}"/><child link="l{i}"/>'
            f'<origin xyz="{fmt(xyz)}" rpy="{fmt(rpy)}"/><axis xyz="{fmt(new_axis)}"/>'
            f"{limit if jtype == 'revolute' else ''}</joint>"
        )
        axis = new_axis
    out.append(
        f'  <joint name="tool_joint" type="fixed"><parent link="l6"/><child link="tool"/>'
        f'<origin xyz="{fmt(rng.uniform(-0.2, 0.2, 3))}" rpy="{fmt(rng.uniform(-3, 3, 3))}"/></joint>'
    )
    out.append("</robot>")
    return "\n".join(out) + "\n", kinds


@pytest.mark.parametrize("seed", range(24))
def test_forward_kinematics_equals_pinocchio_on_random_arms(tmp_path, seed):
    text, kinds = _random_urdf(seed)
    path = tmp_path / "random.urdf"
    path.write_text(text)
    for kw in ({"tip": "tool"}, {"base": "mount", "tip": "l6"}):
        robot = load_robot(path, **kw)
        q = _random_q(robot, 50, seed=seed)
        expected, got = _pin_tip(robot, q), _lab_tip(robot, q)
        np.testing.assert_allclose(got[:, :3, 3], expected[:, :3, 3], rtol=0, atol=1e-12)
        np.testing.assert_allclose(got[:, :3, :3], expected[:, :3, :3], rtol=0, atol=1e-12)
        # parallel and nearly parallel neighbours take Hayati's beta, never a far common normal
        for i, kind in kinds.items():
            j = robot.joints[i - 1]
            if kind in ("parallel", "anti"):
                assert abs(math.sin(j.alpha)) < 1e-9 and abs(j.beta) < 1e-9, (i, kind)
                assert i in robot.parallel_rows()
            if kind == "nearly":
                assert abs(math.sin(j.alpha)) < 0.01 and abs(j.beta) < 0.01, (i, kind)
            if kind in ("parallel", "anti", "nearly"):  # frame i-1 stays where row i-1 arrives
                assert abs(robot.joints[i - 2].d) < 1e-12, (i, kind)
        assert all(-math.pi / 2 < j.theta_offset <= math.pi / 2 + 1e-12 for j in robot.joints[:5])


# -- UR's own table -------------------------------------------------------------------------------
def test_ur5_urdf_from_base_to_tool0_is_urs_published_dh_table():
    """ur5_robot.urdf read from UR's `base` link to `tool0` is arm/robots/ur5.toml, UR's published
    standard-DH table with the URDF's masses (the URDF writes pi/2 as 1.57079632679: 5e-12 rad)."""
    urdf = load_robot("ur5_robot", base="base", tip="tool0")
    dh = load_robot("ur5").to_modified()
    for ju, jd in zip(urdf.joints, dh.joints, strict=True):
        for key in ("alpha", "a", "d", "theta_offset", "beta", "mass", "lower", "upper"):
            assert getattr(ju, key) == pytest.approx(getattr(jd, key), abs=1e-11), key
        np.testing.assert_allclose(ju.com, jd.com, atol=1e-12)
    np.testing.assert_allclose(urdf.flange_matrix, dh.flange_matrix, atol=1e-11)
    np.testing.assert_allclose(urdf.base_matrix, np.eye(4), atol=0)
    np.testing.assert_allclose(urdf.tool_points, dh.tool_points, atol=1e-15)
    assert urdf.parallel_rows() == dh.parallel_rows() == (3, 4)


def test_the_default_chain_and_the_tip_found():
    ur5 = load_robot("ur5_robot")
    assert (ur5.urdf.base_link, ur5.urdf.tip_link) == ("world", "wrist_3_link")
    z1 = load_robot("z1")  # the gripper's revolute joint is a seventh: not part of the arm
    assert (z1.urdf.base_link, z1.urdf.tip_link) == ("world", "link06")
    assert load_robot("ur5_robot.urdf") == ur5  # a bare file name: the shipped one


def test_a_urdf_description_round_trips_through_toml():
    """The equivalent DH TOML of a URDF: the flange transform survives, every float exact."""
    for name, kw in SHIPPED:
        robot = load_robot(name, **kw)
        back = RobotDescription.from_toml(robot.to_toml("m", "rad"))
        assert back == robot
        assert back.urdf is None  # the TOML knows no URDF to edit


def _edit(text: str, old: str, new: str) -> str:
    assert text.count(old) >= 1, old
    return text.replace(old, new, 1)


UR5 = load_robot("ur5_robot").urdf.text  # type: ignore[union-attr]


@pytest.mark.parametrize(
    ("text", "kw", "message"),
    [
        ("<robot name='x'><link name='a'>", {}, "not well-formed XML"),
        (UR5, {"tip": "nowhere"}, "no link 'nowhere' for the tip"),
        (UR5, {"base": "shoulder_link"}, "no chain of 6 revolute joints below base link"),
        (UR5, {"tip": "forearm_link"}, "3 revolute joints between 'world' and 'forearm_link'"),
        (UR5, {"base": "tool0", "tip": "wrist_3_link"}, "does not hang below base link 'tool0'"),
        (
            _edit(UR5, 'name="elbow_joint" type="revolute"', 'name="elbow_joint" type="prismatic"'),
            {"tip": "wrist_3_link"},
            "joint 'elbow_joint' between 'world' and 'wrist_3_link' is prismatic",
        ),
        (
            _edit(
                UR5,
                '<limit effort="150.0" lower="-3.14159265359" upper="3.14159265359" velocity="3.15"/>',
                "",
            ),
            {},
            "joint 'elbow_joint': a revolute joint needs <limit",
        ),
        (
            _edit(UR5, '<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>'),
            {},
            "<axis xyz> is zero",
        ),
        (
            _edit(UR5, '<child link="shoulder_link"/>', '<child link="shoulderlink"/>'),
            {},
            "not defined",
        ),
    ],
)
def test_bad_urdf_is_refused_by_name(tmp_path, text, kw, message):
    path = tmp_path / "arm.urdf"
    path.write_text(text)
    with pytest.raises(DescriptionError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_robot(path, **kw)


def test_several_chains_need_a_tip(tmp_path):
    """Two arms on one base: the tip must be named, and the message lists both ends."""
    text, _ = _random_urdf(3)
    twin = text.replace("</robot>", "")
    for name in ["l1", "l2", "l3", "l4", "l5", "l6", "tool"]:
        twin = twin.replace(f'"{name}"', f'"{name}b"')
    twin = twin.replace('name="j', 'name="k').replace('"tool_joint"', '"tool_jointb"')
    twin = twin.replace('<link name="world"/>', "").replace(
        '<link name="mount"', '<link name="mountb"'
    )
    twin = twin.replace('name="mount_joint"', 'name="mount_jointb"').replace(
        '<child link="mount"/>', '<child link="mountb"/>'
    )
    twin = twin.replace('<parent link="mount"/>', '<parent link="mountb"/>')
    body = twin.split(">", 2)[2]  # drop the declaration and <robot>
    path = tmp_path / "twin.urdf"
    path.write_text(text.replace("</robot>", body + "</robot>"))
    with pytest.raises(DescriptionError, match=r"several chains.*l6, l6b"):
        load_robot(path)
    assert load_robot(path, tip="l6b").urdf.tip_link == "l6b"


def test_the_chain_may_follow_the_file_in_a_robot_string(tmp_path):
    """--robot 'arm.urdf#tip=tool0,base=base' is load_robot(..., tip=, base=); bad fragments are
    named; a file whose name holds '#' is still that file."""
    a = load_robot("ur5_robot.urdf#tip=tool0,base=base")
    assert (a.urdf.base_link, a.urdf.tip_link) == ("base", "tool0")
    assert a == load_robot("ur5_robot", tip="tool0", base="base")
    assert load_robot("z1#tip=gripperStator").urdf.tip_link == "gripperStator"
    for bad, message in [
        ("ur5_robot.urdf#tool0", "give tip=LINK and/or base=LINK"),
        ("ur5_robot.urdf#tip=a,tip=b", "tip given twice"),
        ("ur5_robot.urdf#tip=nowhere", "no link 'nowhere' for the tip"),
    ]:
        with pytest.raises(DescriptionError, match=message):
            load_robot(bad)
    with pytest.raises(DescriptionError, match="tip='tool0' there, tip='ee_link' given"):
        load_robot("ur5_robot.urdf#tip=tool0", tip="ee_link")
    odd = tmp_path / "arm#1.urdf"
    odd.write_text(load_robot("ur5_robot").urdf.text)
    assert load_robot(str(odd)).urdf.tip_link == "wrist_3_link"


def test_tip_and_base_are_for_urdfs_only():
    with pytest.raises(DescriptionError, match="a tip or base link is chosen in a URDF"):
        load_robot("seed", tip="tool0")


def test_reading_a_urdf_loads_no_simulator():
    loaded = _loaded_after(
        "from arm import load_robot; load_robot('ur5_robot')",
        ["mujoco", "gymnasium", "pinocchio"],
    )
    assert loaded == []


def test_a_calibrated_description_keeps_its_urdf():
    robot = load_robot("z1")
    cal = replace(robot, name="z1-cal")
    assert cal.urdf is robot.urdf


@pytest.mark.parametrize("make", ["seed", "ur5", "puma", "rokae", "calibrated"])
def test_a_dh_arm_written_as_urdf_reads_back_as_itself(tmp_path, make):
    """RobotDescription.to_urdf: Pinocchio and load_robot read the DH table's own kinematics
    (flange included) and masses from it, to 1e-12 m."""
    from tests.conftest import puma_arm, rokae_arm

    robot = {
        "seed": lambda: load_robot("seed"),
        "ur5": lambda: load_robot("ur5"),
        "puma": puma_arm,
        "rokae": rokae_arm,
        "calibrated": lambda: replace(
            load_robot("seed"),
            joints=tuple(
                replace(j, beta=1e-3 * k, theta_offset=0.01 * k, alpha=j.alpha + 2e-4)
                for k, j in enumerate(load_robot("seed").joints)
            ),
        ),
    }[make]()
    path = tmp_path / "arm.urdf"
    path.write_text(robot.to_urdf())
    back = load_robot(path, tip="flange")
    q = _random_q(robot, 100, seed=3)
    expected = forward_pose(robot, q)  # frame 0 <- flange
    np.testing.assert_allclose(_lab_tip(back, q), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(_pin_tip(back, q), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        gravity_torques(back, q), gravity_torques(robot, q), rtol=0, atol=1e-10
    )
