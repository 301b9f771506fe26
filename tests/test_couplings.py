"""Coupled joints as industry states them (issue 41): a robot file's linear coupling (FANUC's J3
measured from the horizon), the data's rows in the controller's angles. Checked against the same
arm without the coupling, with the coupling applied by hand to the angles, and against finite
differences."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from arm.description import DescriptionError, RobotDescription, load_robot
from arm.errormodel import ErrorModel
from arm.ik import InverseKinematics, forward_pose, solve_point
from arm.kinematics import Chain, gravity_torques, tool_points
from arm.measurements import MeasurementSet
from arm.sampling import sample_parameters, sample_poses
from lab import FitError, fit
from tests._lab_data import SIGMA

FANUC = "r2000ic_like"  # the shipped heavy arm (arm/robots/)
J3_FROM_HORIZON = ((3, 2, -1.0),)  # theta_3 = q_3 - q_2


def _coupled() -> RobotDescription:
    return replace(load_robot(FANUC), couplings=J3_FROM_HORIZON)


def _by_hand(q: np.ndarray) -> np.ndarray:
    """The controller's angles as the DH table's, by hand: J3 minus J2."""
    out = np.array(q, dtype=float, copy=True)
    out[..., 2] -= out[..., 1]
    return out


def _q(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (n, 6))


def test_the_coupled_arm_is_the_plain_arm_at_the_angles_coupled_by_hand():
    plain, coupled = load_robot(FANUC), _coupled()
    q = _q(50, 1)
    tool = coupled.tool_points[0]
    np.testing.assert_allclose(
        tool_points(Chain.from_description(coupled), q, tool),
        tool_points(Chain.from_description(plain), _by_hand(q), tool),
        atol=1e-12,
    )
    np.testing.assert_allclose(
        gravity_torques(coupled, q), gravity_torques(plain, _by_hand(q)), atol=1e-9
    )
    # a wrist coupling too, as some arms state it: theta_6 = q_6 + 0.5 q_5
    wrist = replace(plain, couplings=((6, 5, 0.5),))
    moved = np.array(q, copy=True)
    moved[:, 5] += 0.5 * q[:, 4]
    np.testing.assert_allclose(
        tool_points(Chain.from_description(wrist), q, tool),
        tool_points(Chain.from_description(plain), moved, tool),
        atol=1e-12,
    )


def test_the_robot_file_keeps_its_couplings(tmp_path):
    coupled = _coupled()
    assert coupled.coupling_matrix[2, 1] == -1.0
    path = tmp_path / "fanuc.toml"
    coupled.save(path)
    assert "couplings" in path.read_text()
    back = load_robot(path)
    assert back.couplings == J3_FROM_HORIZON
    assert back.to_modified().couplings == J3_FROM_HORIZON


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ("joint = 3\non = 3\nfactor = -1.0", "not coupled on itself"),
        ("joint = 7\non = 2\nfactor = -1.0", "'joint' must be a joint 1..6"),
        ("joint = 3\non = 2\nfactor = 0.0", "finite non-zero"),
        ("joint = 3\non = 2\nfactr = -1.0", "unknown key"),
    ],
)
def test_a_bad_coupling_is_refused_naming_it(tmp_path, table, match):
    text = load_robot(FANUC).to_toml() + f"\n[[couplings]]\n{table}\n"
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(DescriptionError, match=match):
        load_robot(path)


def test_dependent_couplings_are_refused():
    with pytest.raises(DescriptionError, match="leave the joints dependent"):
        replace(load_robot(FANUC), couplings=((3, 2, 1.0), (2, 3, 1.0)))


@pytest.mark.parametrize(
    "effects", ["geometric,compliance,transmission", "geometric,lumped_compliance[2,3]"]
)
def test_the_identification_jacobian_equals_finite_differences(effects):
    robot = _coupled()
    model = ErrorModel(robot, effects)
    p = sample_parameters(model, np.random.default_rng(3), scale=3.0)
    if "compliance," in effects:
        p[model.layout.slice("compliance")] = 2e-7  # a heavy arm's joints are stiff
    inputs = model.inputs(_q(7, 3))
    _, J = model.predict(inputs, p, jacobian=True)
    for k, name in enumerate(model.layout.names):
        h = 1e-9 if name.startswith("c") and name[1:].isdigit() else 1e-6
        pp, pm = p.copy(), p.copy()
        pp[k] += h
        pm[k] -= h
        fd = (model.predict(inputs, pp) - model.predict(inputs, pm)) / (2 * h)
        np.testing.assert_allclose(
            J[:, :, k], fd, atol=2e-7 * max(1.0, np.abs(fd).max()), err_msg=name
        )


def test_the_joint_jacobian_is_by_the_controllers_angles():
    model = ErrorModel(_coupled(), "geometric")
    p = model.nominal()
    q = _q(5, 4)
    _, J = model.joint_jacobian(model.inputs(q), p)
    h = 1e-6
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        fd = (model.predict(model.inputs(q + dq), p) - model.predict(model.inputs(q - dq), p)) / (
            2 * h
        )
        np.testing.assert_allclose(J[:, :, i], fd, atol=1e-7)


def test_inverse_kinematics_gives_the_controllers_angles():
    robot, plain = _coupled(), load_robot(FANUC)
    q = sample_poses(robot, 6, np.random.default_rng(5))
    target = tool_points(Chain.from_description(robot), q, robot.tool_points[0])
    res = solve_point(robot, target, q + 0.05)
    assert res.converged.all()
    got = tool_points(Chain.from_description(plain), _by_hand(res.q), plain.tool_points[0])
    np.testing.assert_allclose(got, target, atol=1e-9)
    # the closed form, its DH angles turned back into the controller's
    ik = InverseKinematics(robot)
    near = ik.nearest(forward_pose(robot, q), q)
    assert near.converged.all()
    np.testing.assert_allclose(near.q, q, atol=1e-7)


def _campaign(robot: RobotDescription, n: int, seed: int) -> MeasurementSet:
    """Measured in the controller's angles: the coupled arm with typical geometric errors."""
    model = ErrorModel(robot, "geometric")
    rng = np.random.default_rng(seed)
    p = sample_parameters(model, rng)
    q = sample_poses(robot, n, rng)
    xyz = model.predict(model.inputs(q), p) + rng.normal(0.0, SIGMA, (n, 3))
    return MeasurementSet(q, xyz, {}, "fanuc.csv")


def test_a_fit_in_the_controllers_angles_needs_the_coupling_stated():
    """The issue's FANUC: its rows in the controller's angles fit to the noise once the robot
    file states the coupling; without it the same rows miss by millimetres."""
    robot = _coupled()
    d = _campaign(robot, 150, 6)
    res = fit(d, robot, "geometric", noise_mm=SIGMA * 1e3)
    assert res.rms_mm < 1.2 * SIGMA * np.sqrt(3) * 1e3
    # without it, the refusal names the coupling that explains the rows
    with pytest.raises(FitError, match="cannot follow these measurements") as refused:
        fit(d, load_robot(FANUC), "geometric", noise_mm=SIGMA * 1e3)
    assert "coupled joints 2 and 3 (theta_3 = q_3 - q_2" in str(refused.value)
    assert "[[couplings]] joint = 3, on = 2, factor = -1)" in str(refused.value)


def _near_one_pose(robot: RobotDescription, n: int, seed: int) -> MeasurementSet:
    """The issue's campaign: 60 poses about one configuration (J2 within a few degrees), the
    rows the coupled arm's controller angles with typical geometric errors."""
    model = ErrorModel(robot, "geometric")
    rng = np.random.default_rng(seed)
    p = sample_parameters(model, rng)
    q = rng.uniform(-0.3, 0.3, (n, 6)) + np.array([0.0, 0.2, 0.3, 0.0, 0.0, 0.0])
    xyz = model.predict(model.inputs(q), p) + rng.normal(0.0, SIGMA, (n, 3))
    return MeasurementSet(q, xyz, {}, "fanuc.csv")


def test_the_cli_names_the_coupling_of_the_issues_fanuc(tmp_path):
    """Rows in the controller's angles about one configuration, the robot file uncoupled: the
    fit does not fail to follow them, it reaches link lengths metres off; the refusal (one line,
    exit 2) names the coupling; stated, the rows fit to the noise."""
    from arm.measurements import write_measurements
    from tests._cli import lab, one_error_line

    rows = tmp_path / "fanuc.csv"
    write_measurements(_near_one_pose(_coupled(), 60, 2), rows)
    line = one_error_line(
        lab("fit", rows, "--robot", FANUC, "--noise-mm", SIGMA * 1e3), "not a plausible model"
    )
    assert "coupled joints 2 and 3 (theta_3 = q_3 - q_2" in line
    assert "[[couplings]] joint = 3, on = 2, factor = -1" in line
    coupled = tmp_path / "coupled.toml"
    _coupled().save(coupled)
    res = lab("fit", rows, "--robot", coupled, "--noise-mm", SIGMA * 1e3)
    assert res.exit_code == 0, res.output


def test_a_coupling_stated_but_not_in_the_rows_is_named():
    """The robot file states FANUC's coupling, the rows are the DH angles (another controller, or
    converted already): the refusal says the rows fit without it."""
    d = _campaign(load_robot(FANUC), 150, 9)
    with pytest.raises(FitError) as refused:
        fit(d, _coupled(), "geometric", noise_mm=SIGMA * 1e3)
    message = str(refused.value)
    assert "joint 3 not coupled on joint 2" in message, message
    assert "remove [[couplings]] joint = 3, on = 2" in message


def test_the_coupling_is_named_on_an_arm_on_a_column():
    """The hint holds the rows' extra joint values (it registers the arm on them)."""
    from arm.extra_joints import ExtraJoint

    column = ExtraJoint("column", "prismatic", (0.0, 0.0, 1.0))
    on_column = replace(_coupled(), extra_joints=(column,))
    model = ErrorModel(on_column, "geometric")
    rng = np.random.default_rng(10)
    p = sample_parameters(model, rng)
    q = sample_poses(on_column, 150, rng)
    h = rng.uniform(0.0, 1.0, 150)
    xyz = model.predict(model.inputs(q, {"column": h}), p) + rng.normal(0.0, SIGMA, (150, 3))
    d = MeasurementSet(q, xyz, {"column": h}, "lifted.csv")
    plain = replace(on_column, couplings=())
    with pytest.raises(FitError, match=r"coupled joints 2 and 3 \(theta_3 = q_3 - q_2"):
        fit(d, plain, "geometric", noise_mm=SIGMA * 1e3)


def test_no_coupling_is_named_where_none_explains_the_rows():
    """Rows of the uncoupled arm read in the wrong unit: the refusal names no coupling."""
    robot = load_robot(FANUC)
    d = _campaign(robot, 60, 8)
    in_mm = MeasurementSet(d.q, d.xyz * 1e-3, {}, "m_as_mm.csv")
    with pytest.raises(FitError) as refused:
        fit(in_mm, robot, "geometric")
    assert "coupl" not in str(refused.value) and "convention =" not in str(refused.value)


def test_the_urdf_keeps_the_couplings(tmp_path):
    """Written as a URDF and read back, the coupled arm moves its tool as the robot file's does."""
    robot = _coupled()
    path = tmp_path / "fanuc.urdf"
    path.write_text(robot.to_urdf())
    assert '<coupling joint="joint3" on="joint2" factor="-1.0"/>' in path.read_text()
    back = load_robot(path)
    assert back.couplings == J3_FROM_HORIZON
    q = _q(20, 7)
    np.testing.assert_allclose(
        tool_points(Chain.from_description(back), q, np.zeros(3)) @ back.base_matrix[:3, :3].T
        + back.base_matrix[:3, 3],
        tool_points(Chain.from_description(robot), q, np.zeros(3)),
        atol=1e-12,
    )
    bad = tmp_path / "bad.urdf"
    bad.write_text(path.read_text().replace('on="joint2"', 'on="column_joint"'))
    with pytest.raises(DescriptionError, match=r"'column_joint' is not one of the arm's joints"):
        load_robot(bad)


def test_the_simulator_and_the_mpc_refuse_a_coupled_arm_rather_than_ignore_it():
    from agents.tool_model import ToolModel, UnsupportedEffectError
    from envs.plant import Plant, PlantError

    robot = _coupled()
    with pytest.raises(PlantError, match="coupled joints"):
        Plant(robot)
    with pytest.raises(UnsupportedEffectError, match="coupled joints"):
        ToolModel(ErrorModel(robot, "geometric"))


@pytest.mark.parametrize(("arm", "said"), [("ur5", "modified"), ("seed", "standard")])
def test_a_dh_table_read_in_the_wrong_convention_is_named(arm, said):
    """A data sheet's DH table in a robot file that reads it in the other convention (a standard
    table where `convention` was left out): the refusal names the convention that fits."""
    robot = load_robot(arm)
    d = _campaign(robot, 120, 11)
    wrong = replace(robot, convention=said)
    with pytest.raises(FitError) as refused:
        fit(d, wrong, "geometric", noise_mm=SIGMA * 1e3)
    message = str(refused.value)
    assert f'say convention = "{robot.convention}"' in message, message
    assert "coupl" not in message
