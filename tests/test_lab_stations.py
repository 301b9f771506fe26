"""Stations from calibration to robot (issue 39): a calibration of several tracker stations keeps
every station's frame through both formats (robot TOML, calibrated URDF with its metrology file)
and compensates alike through each; a station the calibration has not seen is registered from
reference points measured there (lab.registration.register_station), checked against the truth's
own frames; a saved calibration exports again without refitting; a bag's discovered effect goes
to a URDF with its module."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import lab
from arm.description import load_robot
from arm.effects import EFFECTS, load_effect_module
from arm.measurements import MeasurementSet
from arm.sampling import sample_poses
from arm.so3 import rotation_matrix
from lab.errors import RegistrationError
from lab.export import (
    CompensationError,
    ExportError,
    TargetSet,
    compensate,
    description_difference,
    export_robot,
    register_references,
)
from lab.urdf_export import export_urdf, read_calibrated_urdf
from tests._beyond_points import STATIONS, pose_campaign

ROBOT = "ur5_robot"


def _quiet(f, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return f(*args, **kw)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A UR5 (its URDF) calibrated from stations 1 and 2, exported as both formats."""
    robot = load_robot(ROBOT)
    c = pose_campaign(robot, seed=3)
    data, _ = c.measure(160, stations=(1, 2))
    res = _quiet(lab.fit, data, robot, "geometric", measured=("x", "y", "z"), noise_mm=0.015)
    where = tmp_path_factory.mktemp("cal")
    toml = export_robot(res, where / "cal.toml")
    _quiet(export_urdf, res, where / "cal.urdf")
    urdf = read_calibrated_urdf(where / "cal.urdf")
    return c, res, toml, urdf, where


def _program(c, station: int, n: int = 10, seed: int = 6) -> TargetSet:
    """A program of ``n`` poses and the points the true arm reaches there, measured from
    ``station``'s frame (noise-free)."""
    q = sample_poses(c.robot, n, np.random.default_rng(seed))
    cols = {"station": np.full(n, float(station))}
    x = c.truth.predict(c.truth.inputs(q, cols), c.params)
    return TargetSet(x, q=q, columns=cols)


def _references(c, station: int, n: int = 4, seed: int = 9, orientation: bool = False):
    data, _ = c.measure(n, stations=(station,), orientation_fraction=1.0 if orientation else 0.0)
    return data


def test_every_station_survives_both_formats_and_compensates_alike(calibrated):
    """Read back, the TOML and the URDF record stations 1 and 2 (the first the base), and a
    program given in either station's frame gets the same joints through both, to 1e-9 rad;
    the true arm at those joints reaches the program's points to the calibration's accuracy."""
    c, _res, toml, urdf, _ = calibrated
    assert [s for s, _, _ in toml.stations] == [s for s, _, _ in urdf.stations] == [1, 2]
    for (_, t1, r1), (_, t2, r2) in zip(toml.stations, urdf.stations, strict=True):
        assert t1 == pytest.approx(t2, abs=1e-12) and r1 == pytest.approx(r2, abs=1e-12)
    assert urdf.base_translation == pytest.approx(urdf.stations[0][1], abs=1e-12)
    assert urdf.nominal is not None and urdf.domain == toml.domain
    assert description_difference(toml, urdf) < 1e-9
    for sid in (1, 2):
        program = _program(c, sid)
        a, b = _quiet(compensate, toml, program), _quiet(compensate, urdf, program)
        assert a.converged.all() and b.converged.all()
        assert np.max(np.abs(a.q - b.q)) < 1e-9
        assert np.max(np.abs(a.error - b.error)) < 1e-9
        # independent of the lab: the truth, at the compensated joints, from that station
        reached = c.truth.predict(c.truth.inputs(a.q, program.columns), c.params)
        assert 1e3 * np.max(np.linalg.norm(reached - program.xyz, axis=1)) < 0.1


def test_a_station_the_calibration_has_not_seen_is_refused_alike_then_registered(calibrated):
    """Station 3's targets are refused through both formats, saying how to register it; with
    4 reference points measured there, both give the same joints, and the registered frame is
    the truth's (station 3's frame <- station 1's) to the references' noise."""
    c, _res, toml, urdf, _where = calibrated
    program = _program(c, 3)
    said = []
    for arm in (toml, urdf):
        with pytest.raises(CompensationError, match=r"station\(s\) \[3\] not among") as e:
            _quiet(compensate, arm, program)
        said.append(str(e.value))
    assert said[0] == said[1] and "--references REFS.csv" in said[0]
    refs = _references(c, 3)
    a = _quiet(compensate, toml, program, references=refs)
    b = _quiet(compensate, urdf, program, references=refs)
    assert a.converged.all() and b.converged.all()
    assert np.max(np.abs(a.q - b.q)) < 1e-9
    reg = a.registration
    assert reg is not None and reg.station == 3 and reg.n_points == 4
    assert 0.0 < reg.rms_mm < 0.1 and "station 3 registered on 4 reference points" in reg.text()

    # the truth's frames (station 3 <- robot base <- station 1), as well as the fit placed
    # station 2 relative to station 1 (the fitted bases take up some of the arm's errors)
    def frame(t, r):
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = rotation_matrix(np.array(r)), t
        return M

    truth = {s: frame(STATIONS[s][:3], STATIONS[s][3:]) for s in (1, 2, 3)}
    fitted = {s: frame(t, r) for s, t, r in toml.stations}
    rel = np.linalg.inv(truth[1])
    e2 = fitted[2] @ np.linalg.inv(fitted[1]) - truth[2] @ rel
    e3 = reg.base(fitted[1]) @ np.linalg.inv(fitted[1]) - truth[3] @ rel
    assert np.max(np.abs(e3[:3, :3])) < 2 * np.max(np.abs(e2[:3, :3])) + 1e-4
    assert np.max(np.abs(e3[:3, 3])) < 2 * np.max(np.abs(e2[:3, 3])) + 1e-3
    # the true arm at the compensated joints, from station 3: on the program's points
    reached = c.truth.predict(c.truth.inputs(a.q, program.columns), c.params)
    assert 1e3 * np.max(np.linalg.norm(reached - program.xyz, axis=1)) < 0.2
    # the same targets without a station column: the references' station
    bare = TargetSet(program.xyz, q=program.q)
    assert np.max(np.abs(_quiet(compensate, toml, bare, references=refs).q - a.q)) < 1e-12
    # the calibration's own station is not registered again
    own = _references(c, 2)
    with pytest.raises(CompensationError, match="station 2 is the calibration's own"):
        _quiet(compensate, toml, _program(c, 2), references=own)


def test_references_that_cannot_place_a_station_are_refused(calibrated):
    c, _res, toml, _, _ = calibrated
    refs = _references(c, 3, n=6)
    with pytest.raises(RegistrationError, match=r"2 reference point\(s\).*at least 3"):
        register_references(toml, refs.subset([0, 1]))
    line = np.linspace(0.0, 1.0, 5)[:, None] * np.array([[1.0, 2.0, 0.5]]) + 0.3
    on_a_line = MeasurementSet(refs.q[:5], line, {"station": np.full(5, 3.0)}, "line.csv")
    with pytest.raises(RegistrationError, match=r"line.csv: the 5 reference points lie on one"):
        register_references(toml, on_a_line)
    mixed = MeasurementSet(refs.q[:4], refs.xyz[:4], {"station": np.array([3.0, 3, 4, 4])}, "m")
    with pytest.raises(RegistrationError, match=r"stations \[3, 4\]"):
        register_references(toml, mixed)


def test_one_row_with_its_orientation_registers_a_station(tmp_path):
    """A 6-DoF reference row fixes a frame alone: a 6-DoF calibration registers station 3 on
    one row as on four points, to the noise."""
    robot = load_robot(ROBOT)
    c = pose_campaign(robot, seed=4)
    data, _ = c.measure(150, stations=(1, 2))
    res = _quiet(lab.fit, data, robot, "geometric")
    cal = export_robot(res, tmp_path / "cal6.toml")
    one = _references(c, 3, n=1, orientation=True)
    four = _references(c, 3, n=4)
    a, b = register_references(cal, one), register_references(cal, four)
    assert a.n_points == 1
    assert np.max(np.abs(a.R - b.R)) < 2e-4 and np.max(np.abs(a.t - b.t)) < 1e-3


def test_a_single_station_calibration_records_its_station(tmp_path):
    """A calibration of one station's data records that station's id, so that targets of
    another are refused through the TOML and the URDF alike, not taken as its own."""
    robot = load_robot(ROBOT)
    c = pose_campaign(robot, seed=5)
    data, _ = c.measure(120, stations=(2,))
    res = _quiet(lab.fit, data, robot, "geometric", measured=("x", "y", "z"), noise_mm=0.015)
    toml = export_robot(res, tmp_path / "one.toml")
    _quiet(export_urdf, res, tmp_path / "one.urdf")
    urdf = read_calibrated_urdf(tmp_path / "one.urdf")
    assert [s for s, _, _ in toml.stations] == [s for s, _, _ in urdf.stations] == [2]
    program = _program(c, 2)
    a, b = _quiet(compensate, toml, program), _quiet(compensate, urdf, program)
    assert np.max(np.abs(a.q - b.q)) < 1e-9
    for arm in (toml, urdf):
        with pytest.raises(CompensationError, match=r"station\(s\) \[1\] not among"):
            _quiet(compensate, arm, _program(c, 1))


def test_a_saved_calibration_exports_to_the_other_format_without_refitting(calibrated):
    """TOML -> URDF (with the arm it was fitted to) and URDF -> TOML: the same arm, every station,
    to 1 nm; another nominal arm is refused."""
    _c, _res, toml, urdf, where = calibrated
    out = _quiet(export_urdf, toml, where / "again.urdf", nominal=load_robot(ROBOT))
    assert description_difference(toml, out.robot) < 1e-9
    assert [s for s, _, _ in out.robot.stations] == [1, 2]
    back = export_robot(urdf, where / "again.toml")
    assert description_difference(urdf, back) < 1e-9 and back.stations == urdf.stations
    # a calibrated URDF exports again from its own URDF
    twice = _quiet(export_urdf, urdf, where / "twice.urdf")
    assert description_difference(urdf, twice.robot) < 1e-9
    with pytest.raises(ExportError, match="records no URDF to correct"):
        export_urdf(toml, where / "x.urdf")
    with pytest.raises(ExportError, match="is not the arm"):
        export_urdf(toml, where / "x.urdf", nominal=load_robot("ur10_robot"))
    assert not (where / "x.urdf").exists()


def test_a_bags_discovered_effect_goes_to_a_urdf_with_its_module(tmp_path):
    """export_urdf(bag.result, ...) works as for any fit: the discovered effect, made in memory,
    is registered and its module written beside; loaded from that file (as another process
    would), the calibrated URDF is the same arm."""
    from arm.description import seed_robot
    from tests import _hidden_forms as hidden

    (tmp_path / "seed.urdf").write_text(seed_robot().to_urdf())
    robot = load_robot(tmp_path / "seed.urdf")
    c = hidden.campaign(seed_robot(), "cubic_q2", seed=11)
    before = set(EFFECTS)
    try:
        b = _quiet(lab.bag, c.data, robot, bags=2, poses=150, seed=0, noise_mm=0.015)
        assert b.discovered is not None
        out = _quiet(export_urdf, b.result, tmp_path / "bagged.urdf")
        assert out.modules == (tmp_path / "bagged.py",)
        assert "effect_modules" in out.metrology.read_text()
        in_memory = read_calibrated_urdf(out.urdf)
        for extra in set(EFFECTS) - before:  # a fresh process: only the file
            del EFFECTS[extra]
        load_effect_module(out.modules[0])
        from_file = read_calibrated_urdf(out.urdf)
        assert description_difference(in_memory, from_file) < 1e-12
        assert "bagged" in from_file.effects
    finally:
        for extra in set(EFFECTS) - before:
            del EFFECTS[extra]
