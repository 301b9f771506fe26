"""Calibrated URDF out: the arm's URDF with corrected joint origins and nothing else changed, a
metrology file beside it, and, read back by Pinocchio (an independent reader), the calibrated
model's flange pose to 1e-9 m on the fitted poses and on 30 others."""

from __future__ import annotations

import difflib
import tomllib
from pathlib import Path

import numpy as np
import pytest

from arm.description import load_robot
from arm.errormodel import ErrorModel
from arm.ik import forward_pose
from arm.measurements import MeasurementSet, read_measurements
from arm.sampling import sample_parameters, sample_poses
from arm.so3 import rotation_matrix
from lab import fit
from lab.export import ExportError, compensate
from lab.urdf_export import export_urdf, metrology_path, read_calibrated_urdf

pin = pytest.importorskip("pinocchio")


def _campaign(robot, effects: str, n: int, seed: int):
    """A simulated campaign of ``robot``: its errors of typical size, a tracker 3 m away and
    turned, a reflector 80 mm off the tip, 10 um of noise."""
    rng = np.random.default_rng(seed)
    truth = ErrorModel(robot, effects)
    p = sample_parameters(truth, rng)
    lay = truth.layout
    p[lay.index("bx") : lay.index("bx") + 3] = (2.5, -1.2, 0.3)
    p[lay.index("brz")] = 1.3
    p[lay.index("tz")] += 0.08
    q = sample_poses(robot, n, rng)
    xyz = truth.predict(truth.inputs(q), p) + rng.normal(0, 1e-5, (n, 3))
    return MeasurementSet(q, xyz, source="campaign"), rng


@pytest.fixture(scope="module", params=["ur5_robot", "z1", "data/ur5"])
def exported(request, tmp_path_factory):
    """A geometric calibration exported as a URDF: of simulated UR5 and Z1 campaigns, and of the
    real UR5 data set (data/ur5) with the URDF read from UR's `base` to `tool0`."""
    if request.param == "data/ur5":
        robot = load_robot("ur5_robot", base="base", tip="tool0")
        data = read_measurements(Path(__file__).resolve().parents[1] / "data/ur5/calibration.csv")
        rng = np.random.default_rng(5)
    else:
        robot = load_robot(request.param)
        data, rng = _campaign(robot, "geometric", 200, seed=4)
    result = fit(data, robot, "geometric")
    out = tmp_path_factory.mktemp("urdf") / "calibrated.urdf"
    return robot, data, result, export_urdf(result, out), rng


def _pin_tip(text: str, base: str, tip: str, joints, q6: np.ndarray) -> np.ndarray:
    model = pin.buildModelFromXML(text)
    data = model.createData()
    fb, ft = model.getFrameId(base, pin.BODY), model.getFrameId(tip, pin.BODY)
    out = []
    for qk in q6:
        q = pin.neutral(model)
        for k, name in enumerate(joints):
            q[model.joints[model.getJointId(name)].idx_q] = qk[k]
        pin.framesForwardKinematics(model, data, q)
        out.append((data.oMf[fb].inverse() * data.oMf[ft]).homogeneous)
    return np.array(out)


def test_the_calibrated_urdf_read_by_pinocchio_gives_the_calibrated_flange_pose(exported):
    """Must show (issue 19): the written URDF, read back by Pinocchio, with the metrology file's
    tracker frame, gives the calibrated model's flange (tip link) pose to 1e-9 m on the fitted
    poses and on 30 others."""
    robot, data, result, out, rng = exported
    side = tomllib.loads(out.metrology.read_text())
    tracker = np.eye(4)
    tracker[:3, :3] = rotation_matrix(np.array(side["tracker"]["rotation_vector"]))
    tracker[:3, 3] = side["tracker"]["translation"]
    cal = result.description()
    q = np.vstack([data.q, sample_poses(robot, 30, rng)])
    expected = cal.base_matrix @ forward_pose(cal, q)  # measurement frame <- tip link
    got = tracker @ _pin_tip(
        out.urdf.read_text(), robot.urdf.base_link, robot.urdf.tip_link, out.joints, q
    )
    np.testing.assert_allclose(got[:, :3, 3], expected[:, :3, 3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got[:, :3, :3], expected[:, :3, :3], rtol=0, atol=1e-9)
    # and the tool point (the reflector) the fit saw, from the metrology file's tip-frame point
    tool = np.array(side["tools"][0]["point"])
    pts = got[:, :3, :3] @ tool + got[:, :3, 3]
    np.testing.assert_allclose(pts[: len(data)], result.predict(data), rtol=0, atol=1e-9)


def test_only_the_arm_joints_origins_change(exported):
    """Links, meshes (their package:// paths), inertials, limits, other joints and comments are
    the original text: the diff is the six arm joints' <origin> lines."""
    robot, _, _, out, _ = exported
    before = robot.urdf.text.splitlines()
    after = out.urdf.read_text().splitlines()
    changed = [
        line
        for line in difflib.unified_diff(before, after, lineterm="", n=0)
        if line[:1] in "+-" and not line.startswith(("+++", "---"))
    ]
    removed = [line for line in changed if line.startswith("-")]
    # at most the six arm joints' lines (a joint whose row the poses cannot move keeps its own)
    assert 4 <= len(removed) <= 6 and len(changed) == 2 * len(removed), changed
    assert all("<origin" in line for line in changed)
    assert len(before) == len(after)
    assert sum("package://" in line for line in after) == sum(
        "package://" in line for line in before
    )


def test_the_metrology_file_and_the_read_back_arm(exported):
    robot, data, result, out, _ = exported
    assert out.metrology == metrology_path(out.urdf)
    assert out.metrology.name == "calibrated.metrology.toml"
    side = tomllib.loads(out.metrology.read_text())
    assert side["base_link"] == robot.urdf.base_link and side["tip_link"] == robot.urdf.tip_link
    assert side["joints"] == list(out.joints)
    if (
        data.source == "campaign"
    ):  # the reflector 80 mm out along joint 6's axis, in the tip's frame
        assert np.linalg.norm(side["tools"][0]["point"]) == pytest.approx(0.08, abs=0.005)
    back = read_calibrated_urdf(out.urdf)
    np.testing.assert_allclose(
        ErrorModel(back).predict(ErrorModel(back).inputs(data.q), ErrorModel(back).nominal()),
        result.predict(data),
        rtol=0,
        atol=1e-9,
    )
    assert out.difference_m <= 1e-9


def test_effects_a_urdf_cannot_express_go_beside_it(tmp_path):
    """Compliance (gravity torques from the URDF's inertials) fitted on a UR5 campaign: its
    values are in the metrology file, and the arm read back from both files predicts the fit."""
    robot = load_robot("ur5_robot")
    data, _ = _campaign(robot, "geometric,compliance[2,3]", 250, seed=6)
    result = fit(data, robot, "geometric,compliance[2,3]")
    out = export_urdf(result, tmp_path / "arm.urdf")
    side = tomllib.loads(out.metrology.read_text())
    assert set(side["effects"]["compliance"]) == {"c2", "c3"}
    back = read_calibrated_urdf(out.urdf)
    assert back.effects["compliance"] == pytest.approx(side["effects"]["compliance"])
    assert back.nominal == robot  # the arm the fit started from, for compensation's start
    # usable as a calibrated arm: compensation reaches the fitted points through it
    comp = compensate(back, result.predict(data)[:5], nominal=robot, free_orientation=True)
    assert np.all(comp.error_mm < 1e-6)


def test_a_toml_robot_has_no_urdf_to_correct(tmp_path):
    data, _ = _campaign(load_robot("ur5"), "geometric", 120, seed=2)
    result = fit(data, "ur5", "geometric")
    with pytest.raises(ExportError, match="was not read from a URDF"):
        export_urdf(result, tmp_path / "x.urdf")
    assert not (tmp_path / "x.urdf").exists()
    assert not (tmp_path / "x.metrology.toml").exists()


def test_an_effect_tied_to_the_dh_tables_form_is_refused_not_mangled(tmp_path):
    """Thermal growth scales the DH table's lengths about frame 0: the URDF's own frames, read
    back, are another table, and the fitted poses come out 30 nm off. The export says so and
    writes nothing (a robot TOML keeps the table)."""
    robot = load_robot("ur5_robot")
    rng = np.random.default_rng(1)
    truth = ErrorModel(robot, "geometric,thermal")
    p = sample_parameters(truth, rng)
    q = sample_poses(robot, 250, rng)
    cols = {"temperature": rng.uniform(15, 35, 250)}
    data = MeasurementSet(q, truth.predict(truth.inputs(q, cols), p), cols, "thermal campaign")
    result = fit(data, robot, "geometric,thermal")
    with pytest.raises(ExportError, match=r"read back, predict the fitted poses .* mm away"):
        export_urdf(result, tmp_path / "warm.urdf")
    assert list(tmp_path.iterdir()) == []


def test_the_export_command_writes_the_calibrated_urdf(tmp_path):
    """sixaxis lab export DATA --robot ARM.urdf --format urdf -o calibrated.urdf: both files; a
    TOML arm with --format urdf is one error line, nothing written."""
    from typer.testing import CliRunner

    from arm.measurements import write_measurements
    from experiments.cli import app

    robot = load_robot("z1")
    data, _ = _campaign(robot, "geometric", 150, seed=8)
    csv = tmp_path / "data.csv"
    write_measurements(data, csv)
    out = tmp_path / "calibrated.urdf"
    runner = CliRunner()
    res = runner.invoke(
        app, ["lab", "export", str(csv), "--robot", "z1", "--format", "urdf", "-o", str(out)]
    )
    assert res.exit_code == 0, res.output
    assert out.is_file() and (tmp_path / "calibrated.metrology.toml").is_file()
    assert "docs/format.md, the calibrated URDF" in res.output
    back = read_calibrated_urdf(out)
    np.testing.assert_allclose(
        ErrorModel(back).predict(ErrorModel(back).inputs(data.q), ErrorModel(back).nominal()),
        data.xyz,
        atol=1e-4,  # the fit's residual: 10 um noise
    )
    bad = tmp_path / "seed.urdf"
    res = runner.invoke(app, ["lab", "export", str(csv), "--format", "urdf", "-o", str(bad)])
    assert res.exit_code == 2 and "was not read from a URDF" in res.output
    assert not bad.exists()
    res = runner.invoke(app, ["lab", "export", str(csv), "--format", "xml", "-o", str(bad)])
    assert res.exit_code == 2 and "--format must be one of toml, urdf" in res.output


def test_a_calibrated_urdf_with_its_metrology_file_is_the_calibrated_arm_on_the_command_line(
    tmp_path,
):
    """`--robot calibrated.urdf` reads the metrology file beside it (the tracker frame, the tool
    point, the compliance fitted): `lab compensate` gives the joint angles it gives through the
    same calibration exported as a robot TOML, and says which file it read."""
    import csv

    from typer.testing import CliRunner

    from arm.measurements import write_measurements
    from experiments.cli import app

    robot = load_robot("ur5_robot")
    data, _ = _campaign(robot, "geometric,compliance[2,3]", 250, seed=6)
    path = tmp_path / "data.csv"
    write_measurements(data, path)
    runner = CliRunner()
    fitted = ["lab", "export", str(path), "--robot", "ur5_robot"]
    fitted += ["--effects", "geometric,compliance[2,3]"]
    for out, form in (("cal.urdf", "urdf"), ("cal.toml", "toml")):
        res = runner.invoke(app, [*fitted, "--format", form, "-o", str(tmp_path / out)])
        assert res.exit_code == 0, res.output
    targets = tmp_path / "targets.csv"
    with open(targets, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["x", "y", "z"])
        w.writerows(data.xyz[:6].tolist())
    angles, said = {}, {}
    for arm in ("cal.urdf", "cal.toml"):
        out = tmp_path / f"{arm}.joints.csv"
        command = ["lab", "compensate", str(targets), "--robot", str(tmp_path / arm)]
        res = runner.invoke(
            app, [*command, "--nominal", "ur5_robot", "--free-orientation", "-o", str(out)]
        )
        assert res.exit_code == 0, res.output
        said[arm] = res.output
        with open(out, newline="") as fh:
            rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
        angles[arm] = np.array([[float(r[f"q{j}"]) for j in range(1, 7)] for r in rows])
    assert "cal.metrology.toml beside it" in said["cal.urdf"]
    assert "beside it" not in said["cal.toml"]
    assert angles["cal.urdf"].shape == (6, 6)
    np.testing.assert_allclose(angles["cal.urdf"], angles["cal.toml"], rtol=0, atol=1e-8)
