"""Stations from calibration to robot (issue 39): a calibration of several tracker stations keeps
every station's frame through both formats (robot TOML, calibrated URDF with its metrology file)
and compensates alike through each; a station the calibration has not seen is registered from
reference points measured there (lab.registration.register_station), checked against the truth's
own frames; a saved calibration exports again without refitting; a bag's discovered effect goes
to a URDF with its module."""

from __future__ import annotations

import warnings
from pathlib import Path

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


# -- the command line --------------------------------------------------------------------------------
def _targets_csv(program: TargetSet, path, station: bool = True):
    cols = ["q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z"] + (["station"] if station else [])
    rows = [
        ",".join(
            [*map(repr, map(float, q)), *map(repr, map(float, x))]
            + ([str(int(s))] if station else [])
        )
        for q, x, s in zip(program.q, program.xyz, program.columns["station"], strict=True)
    ]
    path.write_text(",".join(cols) + "\n" + "\n".join(rows) + "\n")
    return path


def _joints(path) -> np.ndarray:
    table = np.genfromtxt(path, delimiter=",", names=True, skip_header=1)
    return np.column_stack([table[f"q{j}"] for j in range(1, 7)])


def test_the_command_line_registers_a_new_station_for_compensate(calibrated, tmp_path):
    """`lab compensate --references`: through the TOML and the URDF, the same joints and the
    registration's residual said; without them, one error line that says how to register."""
    import json

    from arm.measurements import write_measurements
    from tests._cli import lab as cli
    from tests._cli import one_error_line

    c, _res, _toml, _urdf, where = calibrated
    program = _targets_csv(_program(c, 3), tmp_path / "program.csv")
    refs = tmp_path / "refs.csv"
    write_measurements(_references(c, 3), refs)
    got = {}
    for arm in ("cal.toml", "cal.urdf"):
        out = tmp_path / f"joints_{arm}.csv"
        args = [program, "--robot", where / arm, "--references", refs, "-o", out]
        r = cli("compensate", *args)
        assert r.exit_code == 0, r.output
        assert "station 3 registered on 4 reference points of" in r.stdout
        got[arm] = _joints(out)
        r = cli("compensate", *args, "--json")
        summary = json.loads(r.stdout)
        assert summary["registration"]["station"] == 3 and summary["converged"] == 10
        r = cli("compensate", program, "--robot", where / arm, "-o", tmp_path / "x.csv")
        assert r.exit_code == 2 and "Traceback" not in r.output
        said = r.stderr.splitlines()  # the URDF's note (read with its metrology file), the error
        assert said[-1].startswith("error: ") and "station(s) [3] not among" in said[-1]
        assert "--references REFS.csv" in said[-1] and len(said) == 1 + arm.endswith(".urdf")
    assert np.max(np.abs(got["cal.toml"] - got["cal.urdf"])) < 1e-9
    two = tmp_path / "two.csv"
    write_measurements(_references(c, 3, n=2), two)
    r = cli("compensate", program, "--robot", where / "cal.toml", "--references", two)
    one_error_line(r, "two.csv", "2 reference point(s)", "at least 3")
    r = cli("compensate", program, "--robot", where / "cal.toml", "--references", tmp_path / "no")
    one_error_line(r, "--references")


def test_the_command_line_validates_a_new_station_on_its_references(tmp_path):
    """`lab fit --validate NEW.csv --references REFS.csv`: the new station registered on the
    references, which stay out of the figure; without them, or references without --validate,
    one error line."""
    import json

    from arm.measurements import write_measurements
    from tests._cli import lab as cli
    from tests._cli import one_error_line

    c = pose_campaign(load_robot(ROBOT), seed=7)
    data, val, refs = tmp_path / "data.csv", tmp_path / "val.csv", tmp_path / "refs.csv"
    write_measurements(c.measure(120, stations=(1, 2))[0], data)
    write_measurements(c.measure(30, stations=(3,))[0], val)
    write_measurements(_references(c, 3, n=5), refs)
    common = [data, "--robot", ROBOT, "--measured", "x,y,z", "--noise-mm", 0.015]
    r = cli("fit", *common, "--validate", val, "--references", refs, "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["validation_registered"] == [3]
    (reg,) = out["validation_registrations"]
    assert reg["n_points"] == 5 and reg["source"] == str(refs)
    assert out["validation_rms_mm"] < 0.2
    r = cli("fit", *common, "--validate", val, "--references", refs)
    assert "validation: station 3 registered on 5 reference points" in r.stdout
    one_error_line(cli("fit", *common, "--validate", val), "station(s) 3", "--references")
    one_error_line(cli("fit", *common, "--references", refs), "--references", "--validate")


def test_the_command_line_exports_a_saved_calibration(calibrated, tmp_path):
    """`lab export --from`: TOML -> URDF (the nominal arm's URDF by --robot) and back, without
    refitting; DATA and --from are alternatives, exactly one; the fit's options are refused."""
    from tests._cli import lab as cli
    from tests._cli import one_error_line

    _c, _res, toml, _urdf, where = calibrated
    out = tmp_path / "again.urdf"
    r = cli("export", "--from", where / "cal.toml", "--robot", ROBOT, "-o", out)
    assert r.exit_code == 0, r.output
    assert "tracker frames of its stations" in r.stdout
    assert description_difference(toml, read_calibrated_urdf(out)) < 1e-9
    r = cli("export", "--from", out, "-o", tmp_path / "back.toml")
    assert r.exit_code == 0, r.output
    assert description_difference(toml, load_robot(tmp_path / "back.toml")) < 1e-9
    one_error_line(
        cli("export", where / "x.csv", "--from", where / "cal.toml"), "DATA.csv", "not both"
    )
    one_error_line(cli("export", "-o", tmp_path / "y.toml"), "--from", "one of them")
    one_error_line(
        cli("export", "--from", where / "cal.toml", "-o", tmp_path / "z.urdf"),
        "records no URDF",
        "--robot ARM.urdf",
    )
    one_error_line(
        cli("export", "--from", where / "cal.toml", "--effects", "geometric,thermal"),
        "--effects",
        "nothing is fitted",
    )
    assert not (tmp_path / "z.urdf").exists()


def test_the_command_line_bags_to_a_urdf(tmp_path):
    """`lab bag --export FILE.urdf`: the averaged calibration as the calibrated URDF and its
    metrology file (refused before: only a TOML), read back by --robot FILE.urdf."""
    from arm.description import seed_robot
    from arm.measurements import concatenate, write_measurements
    from tests._cli import lab as cli
    from tests._cli import one_error_line
    from tests._lab_data import session

    true = {"c2": 6e-6, "c3": 4e-6, "da2": 2e-4}
    (tmp_path / "seed.urdf").write_text(seed_robot().to_urdf())
    data = tmp_path / "two.csv"
    two = concatenate([session(true, 150, 1, 11), session(true, 60, 2, 12)])
    two.columns["station"] = two.columns.pop("session")  # one tracker station per session
    write_measurements(two, data)
    urdf = tmp_path / "bagged.urdf"
    common = ["--robot", tmp_path / "seed.urdf", "--bags", 2, "--poses", 100, "--noise-mm", 0.015]
    r = cli("bag", data, *common, "--export", urdf)
    assert r.exit_code == 0, r.output
    assert urdf.is_file() and (tmp_path / "bagged.metrology.toml").is_file()
    back = read_calibrated_urdf(urdf)
    assert "compliance" in back.effects
    r = cli("compensate", data, "--robot", urdf, "--free-orientation", "-o", tmp_path / "j.csv")
    assert r.exit_code == 0, r.output
    # an arm read from a TOML has no URDF to correct: refused before the draws
    r = cli("bag", data, "--bags", 1, "--export", tmp_path / "x.urdf")
    one_error_line(r, "not read from a URDF")
    assert not (tmp_path / "x.urdf").exists()


def test_the_ur10_tour_through_the_urdf_and_the_toml(tmp_path, monkeypatch):
    """docs/lab.md's tour, its files cut by examples/ur10_tour.py: B and D (stations 2 and 4)
    calibrated, exported as a URDF and from it as a TOML; 40 of A's poses (station 1, unseen)
    registered on 4 of A's points and compensated through each: every point converges, the two
    give the same joints to 1e-6 rad, and the start error (the calibration's residual at those
    poses) is printed beside the joint change."""
    import json
    import runpy

    from tests._cli import lab as cli

    monkeypatch.chdir(tmp_path)
    tour = runpy.run_path(str(Path(__file__).resolve().parents[1] / "examples" / "ur10_tour.py"))
    assert tour["main"](["-o", "tour"]) == 0
    fit_args = ["--robot", "ur10_robot", "--effects", "geometric,compliance[2,3]"]
    noise = ["--noise-mm", 0.015, "--noise-ppm", 6]
    r = cli("export", "tour/BD.csv", *fit_args, *noise, "-o", "ur10.urdf")
    assert r.exit_code == 0, r.output
    r = cli("export", "--from", "ur10.urdf", "-o", "ur10.toml")
    assert r.exit_code == 0, r.output
    joints = {}
    for arm in ("ur10.urdf", "ur10.toml"):
        out = f"joints_{arm}.csv"
        args = ["tour/A_program.csv", "--robot", arm, "--references", "tour/A_references.csv"]
        r = cli("compensate", *args, "-o", out, "--json")
        assert r.exit_code == 0, r.output
        summary = json.loads(r.stdout)
        assert summary["converged"] == summary["n_targets"] == 40
        assert summary["registration"]["station"] == 1
        assert summary["registration"]["n_points"] == 4
        assert 0.1 < summary["start_rms_mm"] < 2.0  # the calibration's residual there
        joints[arm] = _joints(out)
    assert np.max(np.abs(joints["ur10.urdf"] - joints["ur10.toml"])) < 1e-6


@pytest.mark.parametrize("command", ["discover", "report", "export", "bag"])
def test_every_command_that_validates_takes_references(command, tmp_path):
    """--validate at a station the fit has not seen: refused without --references in one line
    that says how to register it, run with them (the flag is declared once for every command
    that validates)."""
    from arm.measurements import write_measurements
    from tests._cli import lab as cli
    from tests._cli import one_error_line

    c = pose_campaign(load_robot(ROBOT), seed=8)
    data, val, refs = tmp_path / "data.csv", tmp_path / "val.csv", tmp_path / "refs.csv"
    write_measurements(c.measure(80, stations=(1, 2))[0], data)
    write_measurements(c.measure(20, stations=(3,))[0], val)
    write_measurements(_references(c, 3, n=4), refs)
    out = {
        "discover": [],
        "report": ["-o", tmp_path / "r.html", "--rounds", 0],
        "export": ["-o", tmp_path / "cal.toml"],
        "bag": ["--bags", 1],
    }[command]
    common = [data, "--robot", ROBOT, "--measured", "x,y,z", "--noise-mm", 0.015, *out]
    one_error_line(cli(command, *common, "--validate", val), "station(s) 3", "--references")
    r = cli(command, *common, "--validate", val, "--references", refs)
    assert r.exit_code == 0, r.output


def test_update_validates_a_new_station_on_its_references(tmp_path):
    """`lab update CAL NEW.csv --validate OTHER.csv --references REFS.csv`: held-out poses of a
    station neither the calibration nor the update has seen are validated through the frame the
    references register; without them, refused in one line."""
    import json

    from arm.measurements import write_measurements
    from arm.sessions import join_sessions
    from tests._cli import lab as cli
    from tests._cli import one_error_line
    from tests._lab_data import drifting_session

    rng = np.random.default_rng(100)
    values = {
        f"{f}{j}": rng.normal(0.0, s)
        for j in range(1, 7)
        for f, s in (("dalpha", 3e-4), ("da", 3e-4), ("dtheta", 1e-3))
    } | {"c2": 6e-6, "c3": 4e-6}
    lo, hi = np.array([-2.0, -1.8, -0.8, -2.0, -1.4, -2.5]), np.array([2.0, -0.7, 0.8, 2, 1.4, 2.5])

    def drawn(n: int, station: int, seed: int):
        return drifting_session(values, n, station, seed, region=(rng.uniform(lo, hi), 0.9))

    sessions = [drawn(200, s, s) for s in (1, 2, 3)]
    res = _quiet(lab.fit, join_sessions(sessions), "seed", "geometric,compliance")
    export_robot(res, tmp_path / "cal.toml")
    new, other = tmp_path / "new.csv", tmp_path / "other.csv"
    write_measurements(drawn(40, 9, 9), new)
    held = drawn(40, 7, 7)  # another station again
    write_measurements(held, other)
    refs = tmp_path / "refs.csv"
    write_measurements(held.subset(np.arange(4)), refs)
    args = ["update", tmp_path / "cal.toml", new, "--validate", other]
    one_error_line(cli(*args), "station(s) 7", "--references")
    r = cli(*args, "--references", refs, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["validation_registered"] == [7]
