"""Extra joints before the arm's base (issue 41): a prismatic lifting column held at a value per
row. Checked against the same arm built by hand with its base moved by the column's value
(the shipped UR5 URDF), against finite differences, and on a simulated campaign whose column
scale error the extra_joints effect recovers."""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from arm.description import DescriptionError, RobotDescription, load_robot
from arm.errormodel import ErrorModel
from arm.errors import ModelError, SixAxisError
from arm.extra_joints import ExtraJoint, parse_joint_values
from arm.ik import solve_position
from arm.measurements import MeasurementSet, write_measurements
from arm.so3 import rotation_matrix
from lab import diagnose, fit
from lab.errors import OutOfDomainWarning
from lab.export import TargetSet, compensate, export_robot
from lab.urdf_export import export_urdf, read_calibrated_urdf
from tests._cli import lab, one_error_line

COLUMN_URDF = str(Path(__file__).parent / "data" / "ur_on_column.urdf")
ON_COLUMN = f"{COLUMN_URDF}#tip=ee_link"
# tests/data/ur_on_column.urdf: the column's origin, its turn about z, the carriage to the arm
COLUMN_AT, COLUMN_TURN, CARRIAGE = np.array([0.2, 0.0, 0.5]), 0.3, 0.05
SIGMA = 20e-6


def _rows(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.5, 2.5, (n, 6))
    q[:, 1] = rng.uniform(-2.8, -0.3, n)
    return q, rng.uniform(0.0, 0.8, n)


def _by_hand(q: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The shipped UR5, its base moved by hand to where the column puts it at each row's h."""
    ur = load_robot("ur5_robot.urdf#tip=ee_link")
    turn = rotation_matrix(np.array([0.0, 0.0, COLUMN_TURN]))
    out = []
    for qi, hi in zip(q, h, strict=True):
        at = COLUMN_AT + turn @ np.array([0.0, 0.0, hi + CARRIAGE])
        arm = replace(ur, base_translation=tuple(at), base_rotation=(0.0, 0.0, COLUMN_TURN))
        m = ErrorModel(arm, "geometric")
        out.append(m.predict(m.inputs(qi[None]), m.nominal())[0])
    return np.array(out)


def _points(robot: RobotDescription, q, columns) -> np.ndarray:
    m = ErrorModel(robot, "geometric")
    return m.predict(m.inputs(q, columns), m.nominal())


def test_the_urdf_column_is_read_as_an_extra_joint_by_name():
    arm = load_robot(ON_COLUMN)
    (column,) = arm.extra_joints
    assert (column.name, column.kind, column.axis) == ("column", "prismatic", (0.0, 0.0, 1.0))
    assert column.default is None
    assert arm.has_mass_model  # the arm's own masses; the column's are not the arm's


def test_rows_with_a_column_value_give_the_hand_built_arms_points():
    q, h = _rows(12, 1)
    arm = load_robot(ON_COLUMN)
    np.testing.assert_allclose(_points(arm, q, {"column": h}), _by_hand(q, h), atol=1e-9)
    # the same arm through its TOML, the column in mm there and in the data
    mm = RobotDescription.from_toml(arm.to_toml(length_unit="mm"))
    np.testing.assert_allclose(_points(mm, q, {"column": h * 1e3}), _by_hand(q, h), atol=1e-9)


def test_the_urdf_export_keeps_the_column(tmp_path):
    q, h = _rows(8, 2)
    arm = load_robot(ON_COLUMN)
    path = tmp_path / "exported.urdf"
    path.write_text(arm.to_urdf())
    again = load_robot(f"{path}#tip=flange")
    assert [j.name for j in again.extra_joints] == ["column"]
    np.testing.assert_allclose(_points(again, q, {"column": h}), _by_hand(q, h), atol=1e-9)


def test_a_value_held_by_default_or_on_the_command_line():
    q, h = _rows(5, 3)
    arm = load_robot(ON_COLUMN)
    with pytest.raises(ModelError, match="no value for extra joint 'column'"):
        _points(arm, q, {})
    held = arm.holding(parse_joint_values(["column=0.35"]))
    np.testing.assert_allclose(_points(held, q, {}), _by_hand(q, np.full(5, 0.35)), atol=1e-9)
    # a row's own column wins over the held value
    np.testing.assert_allclose(_points(held, q, {"column": h}), _by_hand(q, h), atol=1e-9)
    with pytest.raises(DescriptionError, match=r"no extra joint 'lift'.*column"):
        arm.holding({"lift": 0.1})
    for bad in ("column", "column=", "column=high", "=0.3", "column=nan"):
        with pytest.raises(DescriptionError, match="NAME=VALUE"):
            parse_joint_values([bad])


def test_robot_toml_extra_joints_are_checked():
    base = load_robot("ur5").to_toml()
    good = base + '\n[[extra_joints]]\nname = "track"\ntype = "prismatic"\naxis = [1, 0, 0]\n'
    arm = RobotDescription.from_toml(good, "arm.toml")
    assert arm.extra_joints == (ExtraJoint("track", "prismatic", (1.0, 0.0, 0.0)),)
    assert RobotDescription.from_toml(arm.to_toml()) == arm
    for text, words in (
        (good.replace('"prismatic"', '"helical"'), "type 'helical'"),
        (good.replace("[1, 0, 0]", "[0, 0, 0]"), "axis"),
        (good.replace('name = "track"', 'name = "q1"'), "'q1'"),
        (good + "colour = 1\n", "unknown key"),
        (base + "\n[mount]\ntranslation = [0, 0, 1]\n", "[mount] without extra joints"),
    ):
        with pytest.raises(DescriptionError, match=words.replace("[", r"\[")):
            RobotDescription.from_toml(text, "arm.toml")


def _two_axes() -> RobotDescription:
    column = ExtraJoint("column", "prismatic", (0.1, 0.0, 1.0), (0.1, 0.2, 0.3), (0.0, 0.0, 0.3))
    table = ExtraJoint("table", "revolute", (0.0, 0.2, 1.0), (0.3, 0.0, 0.1), (0.1, 0.0, 0.3))
    return replace(
        load_robot("ur5"),
        extra_joints=(column, table),
        mount_translation=(0.0, 0.1, 0.05),
        base_rotation=(0.1, 0.2, 0.3),
    )


@pytest.mark.parametrize("stations", [(0,), (1, 2)])
def test_every_jacobian_column_against_finite_differences(stations):
    model = ErrorModel(_two_axes(), "geometric,compliance,extra_joints", stations=stations)
    assert model.layout.groups[-1] == (
        "extra_joints",
        ("xs_column", "xt1_column", "xt2_column", "xs_table"),
    )
    rng = np.random.default_rng(4)
    q = rng.uniform(-2.0, 2.0, (7, 6))
    cols = {"column": rng.uniform(0.0, 1.0, 7), "table": rng.uniform(-1.0, 1.0, 7)}
    if len(stations) > 1:
        cols["station"] = np.array([1, 2, 1, 2, 1, 2, 1.0])
    inputs = model.inputs(q, cols)
    p = model.nominal() + rng.normal(0.0, 1e-3, len(model.layout))
    _, J = model.predict(inputs, p, jacobian=True)
    for k in range(len(p)):
        e = np.zeros_like(p)
        e[k] = 1e-6
        fd = (model.predict(inputs, p + e) - model.predict(inputs, p - e)) / 2e-6
        np.testing.assert_allclose(J[:, :, k], fd, atol=1e-8, err_msg=str(k))


def _campaign(
    n: int, seed: int, scale: float, height: float | None = None
) -> tuple[MeasurementSet, ErrorModel, np.ndarray]:
    """Rows (poses drawn from ``seed``) of one column arm with small geometric errors and a
    column ``scale`` error, the column at random heights or at ``height``."""
    arm = load_robot(ON_COLUMN)
    truth = ErrorModel(arm, "geometric,extra_joints")
    rng = np.random.default_rng(5)
    p = truth.nominal()
    names = [name for _, group in truth.layout.groups for name in group]
    for k, name in enumerate(names):
        if name.startswith(("dalpha", "da", "dd", "dtheta")):
            p[k] += rng.normal(0.0, 2e-4)
    p[names.index("xs_column")] = scale
    q, h = _rows(n, seed)
    if height is not None:
        h = np.full(n, height)
    xyz = truth.predict(truth.inputs(q, {"column": h}), p) + rng.normal(0.0, SIGMA, (n, 3))
    return MeasurementSet(q, xyz, {"column": h}), truth, p


def test_a_planted_column_scale_error_is_recovered(tmp_path):
    data, _, _ = _campaign(120, 5, 3e-3)
    held, _, _ = _campaign(60, 6, 3e-3)
    plain = fit(data, load_robot(ON_COLUMN), "geometric", noise_mm=SIGMA * 1e3, validate=held)
    res = fit(
        data, load_robot(ON_COLUMN), "geometric,extra_joints", noise_mm=SIGMA * 1e3, validate=held
    )
    k = res.identifiability.names.index("xs_column")
    assert abs(res.params[k] - 3e-3) < max(4 * res.std[k], 1e-4)
    floor = SIGMA * np.sqrt(3) * 1e3
    assert res.validation_rms_mm < 1.3 * floor < plain.validation_rms_mm
    # exported as a TOML and into the URDF: the column and its scale kept, the same points
    fitted = res.model.predict(res.inputs, res.params)
    toml = export_robot(res, tmp_path / "cal.toml")
    export_urdf(res, tmp_path / "cal.urdf")
    for arm in (toml, read_calibrated_urdf(tmp_path / "cal.urdf")):
        assert [j.name for j in arm.extra_joints] == ["column"]
        assert arm.effects["extra_joints"]["xs_column"] == res.params[k]
        m = ErrorModel(arm, "geometric,extra_joints")
        np.testing.assert_allclose(
            m.predict(m.inputs(data.q, data.columns), m.nominal()), fitted, atol=1e-9
        )


def test_ik_holds_the_column_at_the_rows_value():
    data, truth, p = _campaign(6, 7, 2e-3)
    h = data.columns["column"]
    q0 = data.q + 0.05
    q, ok = solve_position(truth, {"column": h}, p, data.xyz, q0)[:2]
    assert np.all(ok)
    np.testing.assert_allclose(
        truth.predict(truth.inputs(q, {"column": h}), p), data.xyz, atol=1e-8
    )


def test_the_cli_fits_with_the_column_or_a_held_value(tmp_path):
    data, _, _ = _campaign(80, 8, 0.0, height=0.35)
    with_column = tmp_path / "column.csv"
    write_measurements(data, with_column)
    res = lab("fit", with_column, "--robot", ON_COLUMN, "--noise-mm", SIGMA * 1e3)
    assert res.exit_code == 0, res.output
    fixed = MeasurementSet(data.q, data.xyz)
    without = tmp_path / "without.csv"
    write_measurements(fixed, without)
    one_error_line(lab("fit", without, "--robot", ON_COLUMN), "extra joint 'column'")
    one_error_line(
        lab("fit", without, "--robot", ON_COLUMN, "--joint-value", "lift=0.3"), "'lift'", "column"
    )
    res = lab("fit", without, "--robot", ON_COLUMN, "--joint-value", "column=0.35")
    assert res.exit_code == 0, res.output


def test_a_column_and_a_rotary_table_round_trip_through_the_urdf(tmp_path):
    arm = _two_axes()
    path = tmp_path / "two_axes.urdf"
    path.write_text(arm.to_urdf())
    again = load_robot(f"{path}#tip=flange")  # a revolute extra joint: the arm's tip is named
    assert [(j.name, j.kind) for j in again.extra_joints] == [
        ("column", "prismatic"),
        ("table", "revolute"),
    ]
    rng = np.random.default_rng(9)
    q = rng.uniform(-2.0, 2.0, (6, 6))
    cols = {"column": rng.uniform(0.0, 1.0, 6), "table": rng.uniform(-1.0, 1.0, 6)}
    at_root = replace(arm, base_translation=(0.0, 0.0, 0.0), base_rotation=(0.0, 0.0, 0.0))
    np.testing.assert_allclose(_points(again, q, cols), _points(at_root, q, cols), atol=1e-9)


def test_the_simulator_and_the_mpc_refuse_an_arm_on_a_column_rather_than_ignore_it():
    from agents.tool_model import ToolModel, UnsupportedEffectError
    from envs.plant import Plant, PlantError

    arm = load_robot(ON_COLUMN)
    with pytest.raises(PlantError, match="extra joints \\(column\\)"):
        Plant(arm)
    with pytest.raises(UnsupportedEffectError, match="extra joints"):
        ToolModel(ErrorModel(arm, "geometric"))


def test_compensation_holds_each_targets_column_value(tmp_path):
    data, truth, p = _campaign(120, 5, 3e-3)
    res = fit(data, load_robot(ON_COLUMN), "geometric,extra_joints", noise_mm=SIGMA * 1e3)
    cal = export_robot(res, tmp_path / "cal.toml")
    q, h = _rows(8, 11)  # new poses at new heights: the truth's points are the targets
    goal = truth.predict(truth.inputs(q, {"column": h}), p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfDomainWarning)  # joint 1's torque: zero when fitted
        comp = compensate(cal, TargetSet(goal, q + 1e-3, {"column": h}))
    assert comp.converged.all()
    reached = truth.predict(truth.inputs(comp.q, {"column": h}), p)
    assert np.sqrt(np.mean(np.sum((reached - goal) ** 2, axis=1))) < 3 * SIGMA
    without = TargetSet(goal, q + 1e-3)
    with pytest.raises(SixAxisError, match="extra joint 'column'"):
        compensate(cal, without)


def test_diagnose_names_a_column_scale_error():
    data, _, _ = _campaign(200, 5, 3e-3)
    d = diagnose(data, load_robot(ON_COLUMN), "geometric", noise_mm=SIGMA * 1e3)
    assert d.verdict == "extra_joints"


def test_the_closed_form_base_registration_places_the_arm_through_its_column():
    """The measurement frame is anywhere: the closed-form registration (the fit's start, and the
    coupling hint's registered miss) finds it through the column's per-row values."""
    from lab.registration import register_base

    data, _, _ = _campaign(60, 12, 0.0)
    R = rotation_matrix(np.array([0.1, -0.2, 2.0]))
    t = np.array([1.5, -0.7, 0.3])
    model = ErrorModel(load_robot(ON_COLUMN), "geometric")
    inputs = model.inputs(data.q, data.columns)
    found = register_base(model, inputs, data.xyz @ R.T + t, model.nominal())
    miss = model.predict(inputs, found) - (data.xyz @ R.T + t)
    assert np.median(np.linalg.norm(miss, axis=1)) < 2e-3  # the geometric errors' size
    names = model.layout.names
    np.testing.assert_allclose([found[names.index(k)] for k in ("bx", "by", "bz")], t, atol=5e-3)
