"""Export and compensation: the calibrated arm written as a robot TOML is the fitted model, read
back by ``load_robot`` and evaluated by the plain kinematics (not the error model that fitted it);
compensated joint angles put the true arm's tool point on the desired points, where the nominal
inverse kinematics misses by the calibration error. Bad input is refused with nothing written."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from arm.description import load_robot
from arm.effects import JointAngleEffect
from arm.ik import solve_model_pose
from arm.kinematics import Chain, gravity_torques, link_frames, tool_points
from arm.sampling import sample_poses
from arm.so3 import rotation_matrix
from lab import fit
from lab.export import (
    FAR_RAD,
    CompensationError,
    ExportError,
    TargetSet,
    calibrated_model,
    compensate,
    export_robot,
    nominal_arm,
    read_targets,
    torque_difference,
    write_joints,
)
from tests._beyond_points import pose_campaign
from tests._cli import lab, one_error_line
from tests._lab_data import campaign


def fk(robot, q, theta=None):
    """Tool point in the measurement frame by the plain kinematics of a description: its DH
    table (Hayati beta, offsets), first tool point and base transform; ``theta`` replaces the
    joint angles (to add an effect by hand)."""
    chain = Chain.from_description(robot)
    p = tool_points(chain, q if theta is None else theta, robot.tool_points[0])
    return p @ rotation_matrix(np.array(robot.base_rotation)).T + np.array(robot.base_translation)


@pytest.fixture(scope="module")
def geometric_fit(seed):
    c = campaign(seed, "geometric", seed=21)
    data = c.measure(150)
    return c, data, fit(data, seed, "geometric")


@pytest.mark.parametrize("units", [("m", "rad"), ("mm", "deg")])
def test_exported_arm_is_the_fitted_model_by_plain_kinematics(geometric_fit, tmp_path, units):
    c, data, res = geometric_fit
    path = tmp_path / "cal.toml"
    export_robot(res, path, length_unit=units[0], angle_unit=units[1])
    arm = load_robot(path)
    assert f'length_unit = "{units[0]}"' in path.read_text()
    assert arm.joints[2].beta == pytest.approx(res["beta2"], abs=1e-15)  # Hayati's beta kept
    # on the fitted poses and on poses the fit never saw
    new = sample_poses(arm, 300, np.random.default_rng(5))
    for q, fitted in ((data.q, res.predict(res.inputs)), (new, res.predict(c.measure(new)))):
        assert np.max(np.linalg.norm(fk(arm, q) - fitted, axis=1)) < 1e-12  # m: round-off
    # and it is calibrated: the measured points within the noise
    rms = np.sqrt(np.mean(np.sum((fk(arm, data.q) - data.xyz) ** 2, axis=1)))
    assert rms == pytest.approx(res.rms, rel=1e-9)


def test_exported_compliance_uses_the_fits_torques_up_to_a_second_order_term(seed, tmp_path):
    """The fit's compliance angle is ``c * tau`` with tau from the nominal table; the exported
    arm's values reproduce it exactly with those torques, and with the torques of its own
    (calibrated) table stay within a few micrometres (the term export_robot reports)."""
    c = campaign(seed, "geometric,compliance", seed=7, hidden_level="typical")
    data = c.measure(200)
    res = fit(data, seed, "geometric,compliance[2,3]")
    arm = export_robot(res, tmp_path / "cal.toml")
    assert load_robot(tmp_path / "cal.toml") == arm
    cvals = np.array([0, arm.effects["compliance"]["c2"], arm.effects["compliance"]["c3"], 0, 0, 0])
    assert cvals[1] == res["c2"] and cvals[2] == res["c3"]
    fitted = res.predict(res.inputs)
    with_fit_tau = fk(arm, data.q, data.q + cvals * gravity_torques(seed, data.q))
    assert np.max(np.linalg.norm(with_fit_tau - fitted, axis=1)) < 1e-12
    own = fk(arm, data.q, data.q + cvals * gravity_torques(arm, data.q))
    second_order = np.max(np.linalg.norm(own - fitted, axis=1))
    assert 1e-8 < second_order < 5e-6
    assert torque_difference(res, arm) == pytest.approx(second_order, rel=1e-6)


def test_exported_cyclic_errors_read_back_with_their_joints_and_orders(seed, tmp_path):
    """The file names each cyclic term (cs2_17...); the arm read back rebuilds the effect with
    the same joints and orders and predicts what the fit does."""
    c = campaign(seed, "geometric,cyclic[2:17;3:5,23]", seed=8, hidden_level="typical")
    data = c.measure(200)
    res = fit(data, seed, "geometric,cyclic[2:17;3:5,23]")
    arm = export_robot(res, tmp_path / "cal.toml")
    assert set(arm.effects["cyclic"]) == {"cs2_17", "cc2_17", "cs3_5", "cc3_5", "cs3_23", "cc3_23"}
    model = calibrated_model(arm)
    assert model.effects[1].label == "cyclic[2:17;3:5,23]"
    new = sample_poses(arm, 100, np.random.default_rng(6))
    got = model.predict(model.inputs(new), model.nominal())
    assert np.max(np.linalg.norm(got - res.predict(c.measure(new)), axis=1)) < 1e-12


class _Wobble(JointAngleEffect):
    """An effect that is never registered: a file cannot name it for load_robot."""

    name = "wobble_unregistered"
    terms = ("w",)
    typical = {"w": (1e-4, 5e-4)}

    def basis(self, inputs, joint, term):
        return np.sin(3 * inputs.q[:, joint - 1])


def test_export_refuses_bad_input_and_leaves_the_old_file(geometric_fit, seed, tmp_path):
    _, data, res = geometric_fit
    old = tmp_path / "cal.toml"
    old.write_text("old\n")
    with pytest.raises(ExportError, match="length unit must be one of m, mm, got 'inch'"):
        export_robot(res, old, length_unit="inch")
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ExportError, match=r"file/cal\.toml: cannot be written"):
        export_robot(res, blocker / "cal.toml")
    odd = fit(data, seed, ["geometric", _Wobble(joints=[2])])
    with pytest.raises(ExportError, match=r"wobble_unregistered.*not registered.*not written"):
        export_robot(odd, old)
    assert old.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.toml", "file"]  # no temp files


# -- compensation ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def true_arm(seed):
    """A true arm with geometric errors and joint compliance; its description is what a perfect
    calibration exports."""
    c = campaign(seed, "geometric,compliance", seed=3, hidden_level="typical")
    return c.truth.description(c.params, name="truth")


def true_fk(arm, q):
    """The true arm's tool point, by hand: joint angles sagged by c * tau (tau of its own table)."""
    cvals = np.array([arm.effects["compliance"].get(f"c{j}", 0.0) for j in range(1, 7)])
    return fk(arm, q, q + cvals * gravity_torques(arm, q))


def true_frame(arm, q):
    """The true arm's tool-frame rotation (measurement frame <- frame 6), by hand: the link
    frames at the sagged joint angles, turned by the base rotation."""
    cvals = np.array([arm.effects["compliance"].get(f"c{j}", 0.0) for j in range(1, 7)])
    f = link_frames(Chain.from_description(arm), q + cvals * gravity_torques(arm, q))
    return rotation_matrix(np.array(arm.base_rotation)) @ f.R[:, 6]


def angle_between(Ra, Rb):
    """Rotation angle (rad) from Rb to Ra, per pose (scipy's)."""
    return Rotation.from_matrix(Ra @ np.swapaxes(Rb, 1, 2)).magnitude()


def test_compensation_keeps_the_program(seed, true_arm):
    """A program taught on the nominal arm: its joint angles and the points they were meant to
    reach. Compensated, the true arm reaches the points with the program's tool orientation
    (both computed by hand), each joint moved by the calibration's few milliradians."""
    q_prog = sample_poses(seed, 40, np.random.default_rng(8))
    targets = TargetSet(fk(seed, q_prog), q=q_prog)
    comp = compensate(true_arm, targets, nominal=seed)
    assert comp.converged.all() and comp.start == "program" and comp.orientation == "program"
    np.testing.assert_array_equal(comp.q_start, q_prog)
    # the program's own error on the true arm, which the report states
    miss = 1e3 * np.linalg.norm(true_fk(true_arm, q_prog) - targets.xyz, axis=1)
    assert np.sqrt(np.mean(miss**2)) > 1.0
    np.testing.assert_allclose(comp.error_start_mm, miss, rtol=1e-6, atol=1e-9)
    # the compensated joints put the true arm's tool point on the targets, orientation held
    hit = 1e3 * np.linalg.norm(true_fk(true_arm, comp.q) - targets.xyz, axis=1)
    assert hit.max() < 1e-4  # mm: 0.1 um
    turn = angle_between(true_frame(true_arm, comp.q), true_frame(true_arm, q_prog))
    singular = comp.singular != ""
    assert 0 < singular.sum() < 5  # random poses near a stretched elbow or an aligned wrist
    assert turn[~singular].max() < 1e-9
    assert turn[singular].max() < 0.02  # the orientation held as near as the program's split allows
    np.testing.assert_allclose(comp.turn, turn, atol=1e-9)
    # on the program's branch: the joints move by what the model's error implies (milliradians;
    # tens near a singularity), the wrist not flipped
    change = np.abs(comp.q - q_prog).max(axis=1)
    assert np.median(change) < 0.02 and change.max() < FAR_RAD
    assert np.all(np.sign(np.sin(comp.q[:, 4])) == np.sign(np.sin(q_prog[:, 4])))
    assert np.all(true_arm.within_limits(comp.q))
    d = comp.to_dict()
    assert d["start_rms_mm"] == pytest.approx(np.sqrt(np.mean(miss**2)))
    assert d["rms_mm"] < 1e-4 and d["converged"] == 40 and d["unreachable"] == []
    assert d["max_turn_mrad"] == pytest.approx(1e3 * turn.max(), abs=1e-6)
    assert sorted(i for rows in d["singular"].values() for i in rows) == list(
        np.flatnonzero(singular)
    )
    assert d["max_joint_change_mrad"] == pytest.approx(1e3 * change.max())
    assert d["median_joint_change_mrad"] == pytest.approx(1e3 * np.median(np.abs(comp.q - q_prog)))


def test_without_a_program_the_nominal_arm_starts_with_the_calibrations_base_and_tool(
    seed, true_arm, tmp_path
):
    """Targets with an orientation and no joint angles: the nominal inverse kinematics (the
    nominal table where the calibration put the base and the tool) reaches the pose on the
    nominal arm, and the compensated joints reach it on the true one (poses away from the wrist
    singularity and the joint limits, where the nominal arm reaches them too)."""
    q_true = sample_poses(seed, 60, np.random.default_rng(3))
    inside = (q_true > seed.lower + 0.3) & (q_true < seed.upper - 0.3)
    q_true = q_true[inside.all(axis=1) & (np.abs(np.sin(q_true[:, 4])) > 0.3)][:20]
    R = true_frame(true_arm, q_true)
    targets = TargetSet(true_fk(true_arm, q_true), R=R)
    comp = compensate(true_arm, targets, nominal=seed)
    assert comp.start == "nominal_ik" and comp.orientation == "targets" and comp.converged.all()
    placed = nominal_arm(true_arm, seed)
    assert placed.tools == true_arm.tools and placed.base_rotation == true_arm.base_rotation
    assert np.max(np.linalg.norm(fk(placed, comp.q_start) - targets.xyz, axis=1)) < 1e-9
    hit = np.linalg.norm(true_fk(true_arm, comp.q) - targets.xyz, axis=1)
    assert hit.max() < 1e-7
    assert angle_between(true_frame(true_arm, comp.q), R).max() < 1e-9


def test_points_alone_are_refused_unless_the_orientation_is_free(seed, true_arm):
    q = sample_poses(seed, 10, np.random.default_rng(4))
    xyz = true_fk(true_arm, q)
    with pytest.raises(CompensationError, match=r"neither the program's joint angles.*--free-or"):
        compensate(true_arm, xyz, nominal=seed)
    comp = compensate(true_arm, xyz, nominal=seed, free_orientation=True)
    assert comp.orientation == "free" and comp.converged.all()
    assert np.linalg.norm(true_fk(true_arm, comp.q) - xyz, axis=1).max() < 1e-7
    assert comp.to_dict()["max_turn_mrad"] is None


def test_a_calibrated_arm_without_its_nominal_arm_says_so(seed, true_arm, caplog):
    """A calibrated description that records no nominal arm (made before export recorded it)
    serves as its own nominal arm where the nominal inverse kinematics is needed, with a word."""
    q = sample_poses(seed, 4, np.random.default_rng(9))
    with caplog.at_level("WARNING", logger="lab.export"):
        compensate(true_arm, TargetSet(true_fk(true_arm, q), q=q))  # a program: not needed
        assert not caplog.records
        comp = compensate(true_arm, true_fk(true_arm, q), free_orientation=True)
    assert "records no nominal arm" in caplog.text and comp.nominal_robot == "truth"


def test_compensation_from_an_exported_file_and_a_targets_csv(seed, tmp_path):
    """The user's path: an exported TOML (which records its nominal arm), a CSV of desired poses
    in mm and degrees with the program, a CSV of joints out."""
    c = campaign(seed, "geometric", seed=4)
    result = fit(c.measure(120), seed, "geometric")
    path = tmp_path / "cal.toml"
    export_robot(result, path)
    arm = load_robot(path)
    assert arm.nominal == seed and arm.nominal.name == "seed"  # what the fit started from
    q = sample_poses(arm, 5, np.random.default_rng(2))
    xyz = fk(seed, q)
    rows = [np.r_[p * 1e3, np.degrees(qq)] for p, qq in zip(xyz, q, strict=True)]
    lines = ["x,y,z,q1,q2,q3,q4,q5,q6"] + [",".join(repr(float(v)) for v in r) for r in rows]
    (tmp_path / "targets.csv").write_text("\n".join(lines) + "\n")
    targets = read_targets(tmp_path / "targets.csv", length_unit="mm", angle_unit="deg")
    np.testing.assert_allclose(targets.q, q, rtol=1e-12)
    comp = compensate(path, targets)
    assert comp.nominal_robot == "seed"
    assert np.max(np.linalg.norm(fk(arm, comp.q) - xyz, axis=1)) < 1e-9
    write_joints(comp, tmp_path / "joints.csv")
    out = np.loadtxt(tmp_path / "joints.csv", delimiter=",", skiprows=2)
    np.testing.assert_array_equal(out[:, :6], comp.q)
    # the orientation as columns, a rotation vector or roll-pitch-yaw in degrees, is read alike
    model = calibrated_model(arm)
    R = model.predict_pose(model.inputs(q), model.nominal())[1]
    rv = np.degrees(Rotation.from_matrix(R).as_rotvec())
    rpy = np.degrees(Rotation.from_matrix(R).as_euler("xyz"))
    for names, ang in (("rvx,rvy,rvz", rv), ("roll,pitch,yaw", rpy)):
        body = [
            ",".join(repr(float(v)) for v in np.r_[p, a]) for p, a in zip(xyz, ang, strict=True)
        ]
        (tmp_path / "poses.csv").write_text("\n".join([f"x,y,z,{names}", *body]) + "\n")
        poses = read_targets(tmp_path / "poses.csv", angle_unit="deg")
        np.testing.assert_allclose(poses.R, R, atol=1e-12)
        again = compensate(path, poses)
        assert again.start == "nominal_ik" and again.converged.all()
        assert np.max(np.linalg.norm(fk(arm, again.q) - xyz, axis=1)) < 1e-9


def test_bad_targets_are_named(tmp_path, true_arm):
    f = tmp_path / "t.csv"
    f.write_text("x,y\n1,2\n")
    with pytest.raises(CompensationError, match=r"t.csv, line 1: missing required column\(s\) z"):
        read_targets(f)
    f.write_text("x,y,z\n0.5,0.1,0.6\n0.5,abc,0.6\n")
    with pytest.raises(
        CompensationError, match=r"t.csv, line 3, column 'y': 'abc' is not a number"
    ):
        read_targets(f)
    # lines are the file's own, past comments and blank lines
    f.write_text("# cell 3\nx,y,z,target\n0.5,0.1,0.6,0\n\n0.5,0.2,0.6,1.5\n")
    with pytest.raises(CompensationError, match=r"t.csv, line 5, column 'target': 1.5 must be"):
        read_targets(f)
    f.write_text("x,y,z,q1,q2\n0.5,0.1,0.6,0,0\n")
    with pytest.raises(CompensationError, match=r"need all of q1\.\.q6, found only q1, q2"):
        read_targets(f)
    with pytest.raises(CompensationError, match=r"target id\(s\) \[1\] are not among"):
        two = np.array([[0.5, 0.1, 0.6], [0.5, 0.2, 0.6]])
        compensate(true_arm, two, columns={"target": np.array([0.0, 1.0])}, free_orientation=True)
    with pytest.raises(CompensationError, match="no targets"):
        compensate(true_arm, np.empty((0, 3)))
    f.write_text("x,y,z,rvx,rvy\n0.5,0.1,0.6,0,0\n")
    with pytest.raises(CompensationError, match=r"t.csv, line 1: missing column\(s\) rvz"):
        read_targets(f)
    f.write_text("x,y,z,rvx,rvy,rvz,roll,pitch,yaw\n0.5,0.1,0.6,0,0,0,0,0,0\n")
    with pytest.raises(CompensationError, match=r"t.csv, line 1: columns rvx, .*: give the orien"):
        read_targets(f)


@pytest.mark.parametrize(
    "header", ["x,y,z,rvx,rvy,rvz,roll,pitch,yaw", "x,y,z,rvx,rvy", "x,y,z,roll,yaw"]
)
def test_the_targets_and_the_measurements_check_the_orientation_columns_alike(tmp_path, header):
    """One check of the orientation's columns (arm.measurements.orientation_form) for both
    readers: the same words for the same header, each reader's own error class."""
    from arm.measurements import MeasurementError, read_measurements

    n = header.count(",") - 2
    f = tmp_path / "t.csv"
    f.write_text(f"q1,q2,q3,q4,q5,q6,{header}\n0,-1,0.5,0,0.5,0,0.5,0.1,0.6{',0' * n}\n")
    with pytest.raises(CompensationError) as target:
        read_targets(f)
    with pytest.raises(MeasurementError) as measured:
        read_measurements(f)
    assert str(target.value) == str(measured.value)
    assert str(target.value).startswith(f"{f}, line 1: ")


def test_per_station_targets_are_mapped_through_the_calibrations_registration(seed, tmp_path):
    """A calibration from two tracker stations records each station's frame; a program given
    in the second station's frame compensates as the same program given in the first's (the
    truth's own bases map one to the other), and a station the calibration never saw is refused."""
    c = pose_campaign(seed, seed=3)
    data, _ = c.measure(120, stations=(1, 2))
    result = fit(data, seed, "geometric", measured=("x", "y", "z"), noise_mm=0.015)
    path = tmp_path / "cal.toml"
    arm = export_robot(result, path)
    assert [s for s, _, _ in arm.stations] == [1, 2]
    assert arm.stations[0][1] == pytest.approx(arm.base_translation, abs=1e-12)
    assert load_robot(path).stations == arm.stations  # read back
    q = sample_poses(seed, 8, np.random.default_rng(6))
    seen = {}
    for sid in (1, 2):
        x = c.truth.predict(c.truth.inputs(q, {"station": np.full(8, float(sid))}), c.params)
        targets = TargetSet(x, q=q, columns={"station": np.full(8, float(sid))})
        seen[sid] = compensate(path, targets)
        assert seen[sid].converged.all()
    # the same program: the fitted bases map it alike, to the registration's accuracy (tens of
    # um, the second station 12 m away), and its joints alike
    shift = 1e3 * np.linalg.norm(seen[2].error_start - seen[1].error_start, axis=1)
    assert shift.max() < 0.1 and seen[1].error_start_mm.max() < 0.1
    assert np.median(np.abs(seen[2].q - seen[1].q)) < 1e-4
    # unmapped, the second station's points lie metres from the arm
    assert not compensate(path, TargetSet(x, q=q)).converged.any()
    far = TargetSet(x, q=q, columns={"station": np.full(8, 3.0)})
    with pytest.raises(CompensationError, match=r"station\(s\) \[3\] not among the calibra"):
        compensate(path, far)


# -- singular poses ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_calibration(seed):
    """A true arm whose errors are 15 % of the typical ones: a calibration that moves the points
    by tenths of a millimetre, as the UR10's does (0.47 mm RMS)."""
    c = campaign(seed, "geometric,compliance", seed=3, hidden_level="typical")
    p0 = c.truth.nominal()
    return c.truth.description(p0 + 0.15 * (c.params - p0), name="truth")


def test_singular_poses_keep_the_programs_split_and_unreachable_targets_are_named(
    seed, small_calibration
):
    """A program taught on the nominal arm with two poses at the wrist singularity (q5 = 0: axes
    4 and 6 aligned), one with the elbow stretched, and one target 2 m beyond the arm. The six
    equations of a pose have solutions there only far from the program (joints 4 and 6 turned
    in opposite senses by hundreds of mrad); compensation reaches the point, checked by the
    plain kinematics, with joint changes of the calibration's order, and names the rows."""
    arm = small_calibration
    q = sample_poses(seed, 8, np.random.default_rng(8))
    q[1:3, 4] = 0.0  # the wrist singular
    q[3, 2] = -np.arctan2(0.35, 0.1634)  # the wrist centre (a3, d4) in line with joints 2 and 3
    xyz = fk(seed, q)
    xyz[7] += [2.0, 0.0, 0.0]
    comp = compensate(arm, TargetSet(xyz, q=q), nominal=seed)
    kinds = comp.singular
    assert "wrist" in kinds[1] and "wrist" in kinds[2] and "elbow" in kinds[3]
    assert kinds[7] == ""  # 2 m from its program: a target elsewhere, not a singular pose
    assert list(comp.converged) == [True] * 7 + [False]
    hit = np.linalg.norm(true_fk(arm, comp.q[:7]) - xyz[:7], axis=1)
    assert hit.max() < 1e-7
    change = np.abs(comp.q - q)
    assert change[1:3, :3].max() < 1e-3  # the joints the wrist singularity leaves alone: sub-mrad
    assert change[1:4].max() < 2.5e-3  # joints 4 and 6 keep the program's split
    assert comp.turn[1:4].max() < 2e-3  # the orientation held to the calibration's order
    # what the six equations alone would do at the wrist-singular poses
    model = calibrated_model(arm.to_modified())
    R = model.predict_pose(model.inputs(q[1:3], {}), model.nominal())[1]
    six = solve_model_pose(model, {}, model.nominal(), xyz[1:3], R, q[1:3])
    assert np.abs(six.q - q[1:3])[:, [3, 5]].max() > 0.1
    d = comp.to_dict()
    assert d["unreachable"] == [7] and d["not_converged"] == [7]
    assert {i for rows in d["singular"].values() for i in rows} >= {1, 2, 3}
    msg = str(comp.unreached())
    assert "1 of 8 targets not reached: 1 unreachable (row 8: (" in msg
    assert "out of the arm's reach" in msg and "singular" not in msg


def test_a_target_beyond_a_stretched_arm_is_named_a_singularity(seed):
    """The UR10 upright, elbow stretched and wrist aligned (q3 = q5 = 0): a target 0.05 mm
    below the calibrated point is reached by bending the elbow, one 0.05 mm above is beyond the
    stretched arm; it is named as a singular pose, with its row, and left at the program."""
    ur = load_robot("ur10_robot")
    c = campaign(ur, "geometric", seed=1)
    p0 = c.truth.nominal()
    arm = c.truth.description(p0 + 0.15 * (c.params - p0), name="truth")
    q = np.array([[-np.pi, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0]] * 2)
    model = calibrated_model(arm.to_modified())
    top = model.predict(model.inputs(q, {}), model.nominal())
    xyz = top + np.array([[0.0, 0.0, 5e-5], [0.0, 0.0, -5e-5]])
    comp = compensate(arm, TargetSet(xyz, q=q), nominal=ur)
    assert list(comp.singular) == ["elbow+wrist"] * 2
    assert list(comp.converged) == [False, True]
    assert np.linalg.norm(fk(arm, comp.q[1:]) - xyz[1:]) < 1e-9  # by the plain kinematics
    np.testing.assert_array_equal(comp.q[0], q[0])
    assert comp.error_mm[0] == pytest.approx(0.05, abs=1e-6)
    msg = str(comp.unreached())
    assert "1 of 2 targets not reached: 1 at a singular pose (row 1: (" in msg
    assert "missed by 0.05 mm, elbow+wrist singularity" in msg and "unreachable" not in msg
    assert comp.to_dict()["unreachable"] == []


def test_the_cli_names_singular_and_unreachable_rows(seed, small_calibration, tmp_path):
    """``lab compensate``: a program with a wrist-singular pose and a target out of reach is
    refused in one line naming the unreachable row; with --keep-unreached the file is written,
    the JSON lists the singular and the unreachable rows, and the text names the singular ones."""
    arm_toml = tmp_path / "truth.toml"
    arm_toml.write_text(small_calibration.to_toml())
    q = sample_poses(seed, 4, np.random.default_rng(8))
    q[1, 4] = 0.0
    xyz = fk(seed, q)
    xyz[3] += [2.0, 0.0, 0.0]
    targets = tmp_path / "program.csv"
    rows = [",".join(f"{v:.17g}" for v in (*a, *b)) for a, b in zip(q, xyz, strict=True)]
    targets.write_text("q1,q2,q3,q4,q5,q6,x,y,z\n" + "\n".join(rows) + "\n")
    out = tmp_path / "joints.csv"
    args = ("compensate", targets, "--robot", arm_toml, "--nominal", "seed", "-o", out)
    one_error_line(
        lab(*args),
        "program.csv: 1 of 4 targets not reached: 1 unreachable (line 5: (",
        "out of the arm's reach",
        "--keep-unreached",
    )
    assert not out.exists()
    res = lab(*args, "--keep-unreached", "--json")
    assert res.exit_code == 0, res.output
    d = json.loads(res.stdout)
    assert d["unreachable"] == [3] and d["singular"] == {"wrist": [1]}
    res = lab(*args, "--keep-unreached")
    assert "singular poses (wrist" in res.stdout and "rows 2" in res.stdout
