"""One calibration from many draws of the poses (lab.bagging): the lab's path on each draw of at
most ``poses`` poses per session, and the models averaged by parameter name into one model of
the union of their effects, only the stations' bases fitted again."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from arm.description import load_robot
from arm.measurements import MeasurementSet, concatenate
from lab import FitError, FitResult, bag
from lab.bagging import union_effects
from tests._lab_data import session

SIGMA = 15e-6
TRUE = {"c2": 6e-6, "c3": 4e-6, "da2": 2e-4, "dtheta3": 8e-4, "ts1": 3e-4, "tc1": -2e-4}


def test_the_union_of_effects_strings_joins_joints_and_orders():
    assert (
        union_effects(["geometric,compliance[2],cyclic[1:4,8;3:2-3]", "compliance[3],cyclic[1:5]"])
        == "geometric,compliance[2,3],cyclic[1:4,5,8;3:2,3]"
    )
    assert union_effects(["geometric", "geometric,thermal"]) == "geometric,thermal"
    # runs of three or more orders as ranges, as the fit's label writes them: on the UR10 the
    # suggestion ran to 300 characters where the fitted effects read 200
    assert union_effects(["cyclic[2:8-10,13]", "cyclic[2:11;3:5,6]"]) == "cyclic[2:8-11,13;3:5,6]"


@pytest.fixture(scope="module")
def sessions() -> MeasurementSet:
    return concatenate([session(TRUE, 260, 1, 11), session(TRUE, 90, 2, 12)], source="two.csv")


@pytest.fixture(scope="module")
def bagged(sessions):
    return bag(sessions, "seed", bags=3, poses=120, seed=0, noise_mm=0.015)


def test_each_draw_takes_at_most_poses_per_session_and_the_draws_differ(sessions, bagged):
    s = sessions.columns["session"]
    for d in bagged.draws:
        assert np.sum(s[d.rows] == 1) == 120 and np.sum(s[d.rows] == 2) == 90
        assert len(np.unique(d.rows)) == len(d.rows)
    assert not np.array_equal(bagged.draws[0].rows, bagged.draws[1].rows)


def test_the_model_is_the_mean_of_the_draws_by_name_bases_fitted_again(bagged):
    res = bagged.result
    assert isinstance(res, FitResult)
    names = list(res.model.layout.names)
    for n in ("da2", "dtheta3", "c2", "c3"):
        draws = [d.result[n] if n in d.result.model.layout.names else 0.0 for d in bagged.draws]
        assert res[n] == pytest.approx(float(np.mean(draws)), rel=1e-12, abs=1e-15)
    # what the draws share is the truth, within what 120 + 90 poses tell
    assert res["c2"] == pytest.approx(TRUE["c2"], rel=0.2)
    assert res["dtheta3"] == pytest.approx(TRUE["dtheta3"], abs=1e-4)
    # only the bases were fitted on the whole: a station's base, not the draws' mean
    assert any(n.startswith("bx") for n in names)
    assert res.rms_mm < 3 * SIGMA * np.sqrt(3) * 1e3
    # every effect a draw chose is in the union, and the suggestion names them
    union = {t.split("[")[0] for t in bagged.effects.split(",")}
    assert "compliance" in union  # the draws found the planted compliance
    for d in bagged.draws:
        assert {t.split("[")[0] for t in d.choice.split(",")} <= union
    assert bagged.suggestion.startswith(bagged.effects)
    # the summary names a dozen of the parameters held, then counts the rest
    held = len(res.identifiability.held)
    assert held > 12 and f"held at the values given ({held}): " in res.summary()
    assert f", and {held - 12} more" in res.summary()


def test_one_draw_of_every_pose_is_the_lab_path_itself(sessions):
    one = bag(sessions, "seed", bags=1, poses=10_000, noise_mm=0.015)
    (d,) = one.draws
    assert len(d.rows) == len(sessions)
    for n in d.result.model.layout.names:
        if not n.startswith(("bx", "by", "bz", "brx", "bry", "brz")):
            assert one.result[n] == pytest.approx(d.result[n], rel=1e-12, abs=1e-15)
    held = session(TRUE, 80, 3, 13)
    v = one.result.validate(held)
    assert v.validation_rms_mm == pytest.approx(d.result.validate(held).validation_rms_mm, rel=1e-3)


def test_bad_settings_are_refused(sessions):
    with pytest.raises(FitError, match="bags must be an integer >= 1"):
        bag(sessions, "seed", bags=0)
    with pytest.raises(FitError, match="poses"):
        bag(sessions, "seed", poses=3)


def test_a_draw_the_lab_refuses_is_left_out_and_named_more_than_half_refuse(sessions, monkeypatch):
    import lab.bagging

    path = lab.bagging._path
    calls = []

    def refuse_the_second(data, robot, opts, name):
        calls.append(name)
        if len(calls) == 2:
            raise FitError(f"{data.source}: not a plausible model")
        return path(data, robot, opts, name)

    monkeypatch.setattr(lab.bagging, "_path", refuse_the_second)
    b = bag(sessions, "seed", bags=3, poses=120, noise_mm=0.015)
    assert len(b.draws) == 2 and len(b.refused) == 1
    assert b.refused[0].startswith("draw 2 of 3 (210 poses): ") and "plausible" in b.refused[0]

    def refuse(data, robot, opts, name):
        raise FitError(f"{data.source}: not a plausible model")

    monkeypatch.setattr(lab.bagging, "_path", refuse)
    with pytest.raises(
        FitError, match=r"2 of 2 draws refused, the first: draw 1 of 2 \(210 poses\)"
    ):
        bag(sessions, "seed", bags=2, poses=120, noise_mm=0.015)


def test_the_command_line_bags_exports_and_says_it(sessions, bagged, tmp_path):
    """`sixaxis lab bag`: the averaged model's fit as the library makes it, --json with `bag`,
    --export the calibration as a robot TOML loadable with its module."""
    import json

    from arm.effects import load_effect_module
    from arm.measurements import write_measurements
    from tests._cli import lab

    data = tmp_path / "two.csv"
    write_measurements(sessions, data)
    out, arm = tmp_path / "bag.json", tmp_path / "cal.toml"
    args = ["--bags", 3, "--poses", 120, "--noise-mm", 0.015]
    res = lab("bag", data, *args, "--json", "--out", out, "--export", arm)
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)
    assert json.loads(out.read_text()) == got
    assert got["bag"] | {"refused": []} == {
        "bags": 3,
        "poses": 120,
        "seed": 0,
        "effects": bagged.suggestion,
        "refused": [],
    }
    assert got["rms_mm"] == pytest.approx(bagged.result.rms_mm, rel=1e-9)
    from arm.effects import EFFECTS

    before = set(EFFECTS)
    try:
        if bagged.discovered is not None:
            load_effect_module(arm.with_suffix(".py"))
        robot = load_robot(arm)
    finally:
        for extra in set(EFFECTS) - before:
            del EFFECTS[extra]
    assert "compliance" in robot.effects
    assert robot.effects["compliance"]["c2"] == pytest.approx(bagged.result["c2"], rel=1e-9)


def test_export_to_a_urdf_of_an_arm_without_one_is_refused_before_any_work(sessions, tmp_path):
    """`--export cal.urdf` of an arm read from a TOML: there is no URDF to correct; refused
    before the draws, nothing written (an arm read from a URDF exports: test_lab_stations)."""
    from arm.measurements import write_measurements
    from tests._cli import lab

    data = tmp_path / "two.csv"
    write_measurements(sessions, data)
    res = lab("bag", data, "--bags", 1, "--export", tmp_path / "cal.urdf")
    assert res.exit_code == 2 and "Traceback" not in res.output
    said = res.stderr.splitlines()[-1]  # after the warning of the session column
    assert said.startswith("error: ") and "not read from a URDF" in said
    assert not (tmp_path / "cal.urdf").exists()


def test_the_draws_cautions_are_not_logged_the_wholes_once(sessions, caplog):
    """Each draw's path logged its own cautions (an outlier of that draw, named by its row in
    the draw): on the UR10 149 warnings of 10 draws buried the one calibration's. The whole's
    fit gives them once, with the rows of the data."""
    import logging
    import warnings

    from lab import RowsLeftOutWarning

    xyz = sessions.xyz.copy()
    xyz[[5, 100]] += 0.003  # two gross errors, rows 5 and 100
    data = replace(sessions, xyz=xyz)
    with caplog.at_level(logging.INFO), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        bag(data, "seed", bags=3, poses=40, seed=0, noise_mm=0.015)
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(said) == 1 and "2 outlier(s) left out" in said[0], said
    assert sum(w.category is RowsLeftOutWarning for w in caught) == 1
    # the draws still say what they chose, at INFO
    assert sum("draw " in r.getMessage() for r in caplog.records) == 3


def test_when_every_draw_would_take_every_pose_it_says_so_and_runs_one_path(caplog, tmp_path):
    """One session of fewer poses than --poses: every draw is the whole, the same path ten
    times over, in ten times the time, and the output said "10 draws"."""
    import json
    import logging

    from arm.measurements import write_measurements
    from lab import LabWarning
    from tests._cli import lab

    one = session(TRUE, 80, 1, 11)
    with caplog.at_level(logging.WARNING), pytest.warns(LabWarning, match="the same"):
        b = bag(one, "seed", bags=3, poses=120, noise_mm=0.015)
    assert len(b.draws) == 1 and b.bags == 1
    assert "at most 120 poses" in caplog.text and "one path, not 3 draws" in caplog.text
    # a draw of each pose: the lab's path itself
    assert len(b.draws[0].rows) == 80
    data = tmp_path / "one.csv"
    write_measurements(one, data)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        res = lab("bag", data, "--bags", 3, "--poses", 120, "--noise-mm", 0.015, "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["bag"]["bags"] == 1
    assert "one path, not 3 draws" in caplog.text  # the command's log, on stderr


def test_held_out_data_of_another_arm_is_warned_about_as_fit_does(sessions, caplog, tmp_path):
    """`lab bag --validate` of foreign data gave a held-out RMS of metres without the warning
    `lab fit` gives (lab.sanity.check_validation)."""
    import json
    import logging

    from arm.measurements import write_measurements
    from tests._cli import lab

    data, held = tmp_path / "two.csv", tmp_path / "other.csv"
    write_measurements(sessions, data)
    other = session(TRUE, 30, 1, 13)
    write_measurements(replace(other, xyz=other.xyz * 1.5), held)  # another arm, or units
    args = ("bag", data, "--bags", 1, "--noise-mm", 0.015, "--validate", held)
    with caplog.at_level(logging.WARNING):
        res = lab(*args, "--accept-other-frame", "--json")
    assert res.exit_code == 0, res.output
    assert "other.csv: validation RMS" in caplog.text and "another arm" in caplog.text
    codes = [w["code"] for w in json.loads(res.stdout)["warnings"]]
    assert "ValidationMismatchWarning" in codes
    # hundreds of times the fit's RMS: refused without --accept-other-frame, as lab fit does
    res = lab(*args)
    assert res.exit_code == 2 and "Traceback" not in res.output
    error = res.stderr.splitlines()[-1]  # after the reader's notes of the 'session' column
    assert error.startswith("error: ") and "other.csv: validation RMS" in error
    assert "another arm" in error and "--accept-other-frame" in error


def test_the_draws_refits_outside_the_domain_are_not_logged_either(sessions, caplog):
    """Validated outside the fitted domain, the mean without the terms that do not hold refits
    every draw: on the UR10 each refit logged its draw's poor pose set, 12 warnings."""
    import logging
    import warnings

    from lab import PoorPoseSetWarning
    from lab.errors import LabWarning

    b = bag(sessions, "seed", bags=2, poses=120, noise_mm=0.015)

    def noisy(refit):
        def run(names):
            logging.getLogger("lab.identifiability").warning("poor pose set: a draw's")
            warnings.warn("poor pose set: a draw's", PoorPoseSetWarning, stacklevel=2)
            return refit(names)

        return run

    for d in b.draws:
        d.result = replace(d.result, refit=noisy(d.result.refit))
    name = next(n for n in b.result.model.layout.names if n.startswith("c"))
    assert b.result.refit is not None
    with caplog.at_level(logging.INFO), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        p = b.result.refit([name])
    assert p[b.result.model.layout.names.index(name)] == 0.0
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert not [w for w in caught if issubclass(w.category, LabWarning)]
