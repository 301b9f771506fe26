"""A robot as industry gives its URDF (issue 41): an arm on a rotary table, a table that tilts it,
extra joints declared with a default. The chain's tip is found without naming it; the points
equal yourdfpy's forward kinematics of the same file, and the gravity torques (``compliance``'s
and ``lumped_compliance``'s) equal Pinocchio's of it, the table tilting the arm included, and a
tilted [mount] equals the plain arm whose gravity is turned by hand."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from arm.description import DescriptionError, RobotDescription, load_robot
from arm.effects.lumped import LumpedCompliance, first_moments, gravity_columns
from arm.errormodel import ErrorModel
from arm.errors import ModelError
from arm.extra_joints import ExtraJoint
from arm.kinematics import gravity_torques
from arm.measurements import MeasurementSet, write_measurements
from arm.so3 import rotation_matrix
from tests._cli import lab, one_error_line

TABLE_URDF = Path(__file__).parent / "data" / "ur_on_table.urdf"
ARM = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]


def _text(tilting: bool = False, declare: str = "") -> str:
    """The table's URDF; ``tilting``: its axis horizontal (x), a table that tilts the arm;
    ``declare``: elements added under <robot>."""
    text = TABLE_URDF.read_text()
    if tilting:
        text = text.replace(
            '<axis xyz="0 0 1"/>\n    <limit lower="-3.1416" upper="3.1416" effort="2000"',
            '<axis xyz="1 0 0"/>\n    <limit lower="-3.1416" upper="3.1416" effort="2000"',
        )
        assert text != TABLE_URDF.read_text()
    return text.replace("</robot>", declare + "</robot>")


def _write(tmp_path: Path, text: str, name: str = "arm.urdf") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _rows(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-2.5, 2.5, (n, 6)), rng.uniform(-1.2, 1.2, n)


def _yourdfpy_points(path: str, q: np.ndarray, table: np.ndarray) -> np.ndarray:
    """The tip link's origin in the root link's frame, by yourdfpy's own forward kinematics."""
    import yourdfpy

    urdf = yourdfpy.URDF.load(path, build_scene_graph=True, load_meshes=False)
    out = []
    for qi, ti in zip(q, table, strict=True):
        urdf.update_cfg({"table": ti} | dict(zip(ARM, qi, strict=True)))
        out.append(urdf.get_transform("wrist_3_link", "world")[:3, 3])
    return np.array(out)


def _points(robot: RobotDescription, q: np.ndarray, columns: dict) -> np.ndarray:
    m = ErrorModel(robot, "geometric")
    return m.predict(m.inputs(q, columns), m.nominal())


# -- the chain's tip, found ----------------------------------------------------------------------
def test_an_arm_on_a_rotary_table_is_read_without_naming_its_tip(tmp_path):
    arm = load_robot(str(TABLE_URDF))
    assert arm.urdf is not None and arm.urdf.tip_link == "wrist_3_link"
    assert [(j.name, j.kind) for j in arm.extra_joints] == [("table", "revolute")]
    q, table = _rows(10, 1)
    np.testing.assert_allclose(
        _points(arm, q, {"table": table}),
        _yourdfpy_points(str(TABLE_URDF), q, table),
        atol=1e-9,
    )
    # the URDF the lab writes of it declares the table, and reads back to the same points
    again = load_robot(_write(tmp_path, arm.to_urdf()))
    assert '<extra_joint joint="table"/>' in arm.to_urdf()
    at_root = replace(arm, base_translation=(0.0, 0.0, 0.0), base_rotation=(0.0, 0.0, 0.0))
    np.testing.assert_allclose(
        _points(again, q, {"table": table}), _points(at_root, q, {"table": table}), atol=1e-9
    )


def test_a_table_that_tilts_the_arm_is_ambiguous_until_declared(tmp_path):
    """A horizontal table axis crosses the arm's joint 1 as a 6R arm's joints 1 and 2 do: the
    seventh joint may be the table's or a tool's, and the file must say which."""
    with pytest.raises(DescriptionError, match="several chains") as refused:
        load_robot(_write(tmp_path, _text(tilting=True)))
    message = str(refused.value)
    assert "wrist_2_link, wrist_3_link" in message
    assert '<extra_joint joint="NAME"/>' in message and "tip=" in message
    declared = load_robot(_write(tmp_path, _text(True, '<extra_joint joint="table"/>\n')))
    assert declared.urdf is not None and declared.urdf.tip_link == "wrist_3_link"
    q, table = _rows(8, 2)
    path = _write(tmp_path, _text(True, '<extra_joint joint="table"/>\n'), "declared.urdf")
    np.testing.assert_allclose(
        _points(declared, q, {"table": table}), _yourdfpy_points(path, q, table), atol=1e-9
    )
    for bad, words in (
        ('<extra_joint joint="elbow_joint"/>', "'elbow_joint'> is not a joint before the arm"),
        ('<extra_joint joint="nowhere"/>', "'nowhere'> is not a joint before the arm"),
        ('<extra_joint joint="table" default="high"/>', "default 'high' is not a finite"),
        ('<extra_joint joint="table"/><extra_joint joint="table"/>', "declared twice"),
    ):
        with pytest.raises(DescriptionError, match=re.escape(words)):
            load_robot(_write(tmp_path, _text(False, bad)), tip="wrist_3_link")


def test_the_z1s_gripper_joint_is_still_not_the_arms():
    """The Z1's seventh revolute joint is its gripper's: joints 2 and 3 of the other reading
    are parallel, so it is not the arm."""
    z1 = load_robot("z1")
    assert z1.urdf is not None and z1.urdf.tip_link == "link06" and not z1.extra_joints


# -- a default for rows without a value ---------------------------------------------------------
def test_a_declared_default_holds_rows_without_a_value(tmp_path):
    path = _write(tmp_path, _text(False, '<extra_joint joint="table" default="0.4"/>\n'))
    arm = load_robot(path)
    assert arm.extra_joints[0].default == 0.4
    q, table = _rows(6, 3)
    np.testing.assert_allclose(
        _points(arm, q, {}), _yourdfpy_points(path, q, np.full(6, 0.4)), atol=1e-9
    )
    np.testing.assert_allclose(  # a row's own value wins
        _points(arm, q, {"table": table}), _yourdfpy_points(path, q, table), atol=1e-9
    )
    # kept by the robot TOML (in its angle unit) and by the URDF the lab writes
    toml = RobotDescription.from_toml(arm.to_toml(angle_unit="deg"))
    assert toml.extra_joints[0].default == pytest.approx(0.4, abs=1e-15)
    assert "default = 22.918" in arm.to_toml(angle_unit="deg")
    assert '<extra_joint joint="table" default="0.4"/>' in arm.to_urdf()
    assert load_robot(_write(tmp_path, arm.to_urdf(), "again.urdf")).extra_joints[0].default == 0.4


def test_without_a_value_or_a_default_the_refusal_says_how_to_give_one(tmp_path):
    q, _ = _rows(40, 4)
    with pytest.raises(ModelError) as refused:
        ErrorModel(load_robot(str(TABLE_URDF)), "geometric").inputs(q, source="rows.csv")
    message = str(refused.value)
    for words in (
        "rows.csv: no value for extra joint 'table' (revolute)",
        f"of {TABLE_URDF}",
        "a column 'table'",
        "--joint-value table=VALUE",
        '<extra_joint joint="table" default="VALUE"/> under <robot> (in rad)',
    ):
        assert words in message, message
    toml = tmp_path / "arm.toml"
    load_robot(str(TABLE_URDF)).save(toml)
    with pytest.raises(ModelError, match=re.escape("default = VALUE under its [[extra_joints]]")):
        ErrorModel(load_robot(toml), "geometric").inputs(q, source="rows.csv")
    # the CLI: one line, and the value on the command line fits
    arm = load_robot(str(TABLE_URDF))
    rows = tmp_path / "rows.csv"
    write_measurements(MeasurementSet(q, _points(arm, q, {"table": np.full(40, 0.3)})), rows)
    one_error_line(lab("fit", rows, "--robot", TABLE_URDF), "'table'", "--joint-value table=")
    res = lab("fit", rows, "--robot", TABLE_URDF, "--joint-value", "table=0.3")
    assert res.exit_code == 0, res.output


# -- gravity as the extra joints turn the arm ---------------------------------------------------
def _pinocchio_torques(text: str, q: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Minus Pinocchio's generalized gravity of the arm's joints (the lab's sign)."""
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromXML(text)
    data = model.createData()
    names = ["table", *ARM]
    out = []
    for qi, ti in zip(q, table, strict=True):
        x = pin.neutral(model)
        for name, v in zip(names, [ti, *qi], strict=True):
            x[model.joints[model.getJointId(name)].idx_q] = v
        g = pin.computeGeneralizedGravity(model, data, x)
        out.append([-g[model.joints[model.getJointId(n)].idx_v] for n in ARM])
    return np.array(out)


@pytest.mark.parametrize("tilting", [False, True])
def test_gravity_torques_follow_the_table_as_pinocchio_computes_them(tmp_path, tilting):
    text = _text(tilting, '<extra_joint joint="table"/>\n')
    arm = load_robot(_write(tmp_path, text))
    q, table = _rows(12, 5)
    inputs = ErrorModel(arm, "geometric,compliance").inputs(q, {"table": table})
    expected = _pinocchio_torques(text, q, table)
    np.testing.assert_allclose(inputs.tau, expected, atol=1e-9)
    if tilting:  # joint 1 of a tilted arm carries a torque
        assert np.abs(expected[:, 0]).max() > 1.0
    # lumped_compliance's regressor: the links' first moments give the same torques ...
    Y = gravity_columns(arm, q, inputs.gravity)
    U = first_moments(arm)
    g = float(np.linalg.norm(arm.gravity))
    np.testing.assert_allclose(g * np.einsum("njkc,kc->nj", Y, U), expected, atol=1e-9)
    # ... and its base set spans compliance's deflection on these rows (constants aside)
    c = np.array([4e-6, 6e-6, 8e-6, 1e-5, 1e-5, 1e-5])
    X = LumpedCompliance().regressor(inputs)
    for j in range(6):
        A = np.column_stack([X[:, j, :], np.ones(len(q))])
        dq = c[j] * expected[:, j]
        fit = A @ np.linalg.lstsq(A, dq, rcond=None)[0]
        assert np.max(np.abs(fit - dq)) < 1e-9 * max(1.0, np.abs(dq).max() * 1e6), j


def test_a_tilted_mount_is_the_plain_arm_with_gravity_turned_by_hand():
    """A UR5 on a linear track whose mount leans 30 degrees about x: its gravity torques are the
    plain UR5's (no extra joint) with gravity turned into its tilted frame 0 by hand."""
    plain = load_robot("ur5")
    track = ExtraJoint("track", "prismatic", (1.0, 0.0, 0.0), default=0.5)
    lean = math.radians(30.0)
    arm = replace(plain, extra_joints=(track,), mount_rotation=(lean, 0.0, 0.0))
    arm = replace(arm, joints=tuple(replace(j, mass=2.0 + i) for i, j in enumerate(arm.joints)))
    by_hand = replace(
        arm,
        extra_joints=(),
        mount_rotation=(0.0, 0.0, 0.0),
        gravity=tuple(rotation_matrix(np.array([lean, 0.0, 0.0])).T @ np.array(arm.gravity)),
    )
    q = np.random.default_rng(6).uniform(-2.5, 2.5, (15, 6))
    at = np.random.default_rng(7).uniform(0.0, 2.0, 15)
    tau = ErrorModel(arm, "compliance").inputs(q, {"track": at}).tau
    np.testing.assert_allclose(tau, gravity_torques(by_hand, q), atol=1e-10)
    assert np.abs(tau[:, 0]).max() > 0.5  # the leaning arm's joint 1 is loaded
    # and the robot file keeps it: gravity stays in the frame the extra joints start from
    again = RobotDescription.from_toml(arm.to_toml())
    np.testing.assert_allclose(again.frame0_gravity(), by_hand.gravity, atol=1e-12)


def test_a_fit_finds_joint_1s_compliance_on_a_table_that_tilts_the_arm(tmp_path):
    """Joint 1 of an upright arm carries no gravity torque; tilted by its table it does, and a
    fit of rows drawn so recovers its compliance (held at its standard error)."""
    from lab import fit

    arm = load_robot(_write(tmp_path, _text(True, '<extra_joint joint="table"/>\n')))
    truth = ErrorModel(arm, "geometric,compliance")
    names = truth.layout.names
    p = truth.nominal()
    c = dict(zip([f"c{i}" for i in range(1, 7)], [3e-5, 2e-5, 2e-5, 4e-5, 4e-5, 4e-5], strict=True))
    for k, v in c.items():
        p[names.index(k)] = v
    q, table = _rows(150, 8)
    rng = np.random.default_rng(9)
    xyz = truth.predict(truth.inputs(q, {"table": table}), p) + rng.normal(0.0, 20e-6, (150, 3))
    res = fit(MeasurementSet(q, xyz, {"table": table}), arm, "geometric,compliance", noise_mm=0.02)
    k = res.identifiability.names.index("c1")
    assert abs(res.params[k] - c["c1"]) < max(4 * res.std[k], 2e-6), (res.params[k], res.std[k])
    assert res.std[k] < c["c1"] / 5  # measured, not a prior
