"""Pose planning: the planned poses beat as many random poses on O1 (computed here from an SVD)
and on the validation RMS of the calibration they lead to."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arm.errormodel import ErrorModel
from arm.sampling import NEAR_MARGIN, sample_poses
from lab import FitError, fit, plan
from tests._lab_data import campaign

N = 15  # few poses for 25 identifiable parameters: where the choice matters


def o1_of(robot, q, ident) -> float:
    """Borm & Menq's O1 of poses ``q`` on the plan's identifiable columns and column scaling."""
    model = ErrorModel(robot, "geometric")
    _, J = model.predict(model.inputs(q), model.nominal(), jacobian=True)
    A = J.reshape(-1, J.shape[2])[:, ident.identifiable] * ident.scale[ident.identifiable]
    s = np.linalg.svd(A, compute_uv=False)
    return float(np.exp(np.mean(np.log(s))) / math.sqrt(len(q)))


@pytest.fixture(scope="module")
def planned(seed):
    return plan(N, seed, "geometric", criterion="o1", seed=0)


def test_planned_poses_beat_random_ones_on_o1(seed, planned):
    assert planned.q.shape == (N, 6)
    assert np.all(seed.within_limits(planned.q))
    ident = planned.identifiability
    assert ident.rank == 25
    mine = o1_of(seed, planned.q, ident)
    assert mine == pytest.approx(planned.o1, rel=1e-6)
    rng = np.random.default_rng(1)
    random = [o1_of(seed, sample_poses(seed, N, rng), ident) for _ in range(20)]
    assert mine > max(random)
    assert planned.o1 > planned.random_o1


def test_planned_poses_calibrate_better_than_random_ones(seed, planned):
    val_plan, val_random = [], []
    for trial in range(8):
        c = campaign(seed, "geometric", seed=500 + trial)
        val = c.measure(400)
        val_plan.append(fit(c.measure(planned.q), seed, validate=val).validation_rms_mm)
        val_random.append(fit(c.measure(N), seed, validate=val).validation_rms_mm)
    assert np.mean(val_plan) < np.mean(val_random)
    assert np.median(val_plan) < np.median(val_random)


def test_o4_criterion(seed):
    p4 = plan(N, seed, "geometric", criterion="o4", seed=0, candidates=800)
    assert p4.o4 > 2 * p4.random_o4
    assert p4.identifiability.condition_number < 20


def test_same_seed_same_plan(seed):
    a = plan(12, seed, candidates=500, seed=3)
    b = plan(12, seed, candidates=500, seed=3)
    assert np.array_equal(a.indices, b.indices)
    d = a.to_dict()
    assert d["n_poses"] == 12 and len(d["q"]) == 12 and d["o1"] > d["random_o1"]


def test_plan_errors(seed):
    with pytest.raises(FitError, match=r"8 poses give 24 equations for the 25 identifiable"):
        plan(8, seed, candidates=300)
    with pytest.raises(FitError, match="criterion must be one of o1, o4"):
        plan(20, seed, criterion="d")
    with pytest.raises(FitError, match=r"dir1 \(needed by backlash\).*columns="):
        plan(20, seed, "geometric,backlash", candidates=100)


def test_poses_planned_near_a_program_lie_in_its_region_and_beat_random_ones_there(seed):
    """``near=``: the candidates come from the program's joint region (each joint's range, 0.1
    rad wider), and the plan beats as many random poses of that region on O1."""
    rng = np.random.default_rng(3)
    program = sample_poses(seed, 200, rng)
    program[:, 0] = rng.uniform(1.0, 1.6, 200)  # the program works in one sector of q1
    program[:, 3] = rng.uniform(-0.5, 0.2, 200)
    p = plan(20, seed, "geometric", near=program, candidates=1500, seed=0)
    lo, hi = program.min(axis=0) - NEAR_MARGIN, program.max(axis=0) + NEAR_MARGIN
    assert np.all((p.candidates >= lo) & (p.candidates <= hi))
    assert np.all((p.q >= lo) & (p.q <= hi))
    assert np.ptp(p.q[:, 0]) < 0.6 + 2 * NEAR_MARGIN  # not the whole turn of q1
    assert p.o1 > 1.25 * p.random_o1  # 1.40 here
    region = p.candidates[np.random.default_rng(9).choice(len(p.candidates), 20, replace=False)]
    assert p.o1 > o1_of(seed, region, p.identifiability)


def test_a_program_outside_the_limits_is_refused_by_joint(seed):
    program = np.zeros((5, 6))
    program[:, 2] = 9.0  # beyond q3's limits
    with pytest.raises(FitError, match="q3"):
        plan(10, seed, "geometric", near=program)
    with pytest.raises(FitError, match="near="):
        plan(10, seed, "geometric", near=np.zeros((5, 6)), candidates=np.zeros((40, 6)))


def test_poses_planned_for_an_update_beat_random_ones_where_the_program_runs():
    """plan_update chooses, among a new session's poses, those whose update errs least on a
    program's poses (the update's posterior there): updated with them, the calibration errs on
    the program's measured poses no more than with random poses of the same session (the mean
    of five sets), and as much as the plan expected (within [0.67, 1.5])."""
    import warnings

    from arm.sessions import join_sessions
    from lab.errors import LabWarning
    from lab.planning import plan_update
    from lab.update import prior_of, update
    from tests._lab_data import drifting_session

    rng = np.random.default_rng(5)
    values = {f"da{j}": rng.normal(0.0, 3e-4) for j in range(1, 7)} | {"c2": 6e-6}
    lo, hi = np.array([-2.0, -1.8, -0.8, -2.0, -1.4, -2.5]), np.array([2, -0.7, 0.8, 2, 1.4, 2.5])
    sessions = [
        drifting_session(values, 250, s, s, region=(rng.uniform(lo, hi), 0.9)) for s in (1, 2, 3)
    ]
    new = drifting_session(values, 500, 9, 9, region=(rng.uniform(lo, hi), 0.7))
    pool, program = new.subset(np.arange(300)), new.subset(np.arange(300, 500))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LabWarning)
        prior = prior_of(fit(join_sessions(sessions), "seed", "geometric,compliance"))

        def held_out(rows) -> float:
            u = update(prior, pool.subset(rows))
            return float(u.result.validate(program).validation_rms_mm)

        p = plan_update(15, prior, program.q, candidates=pool.q, seed=1)
        planned = held_out(p.indices)
        random = np.mean([held_out(rng.choice(300, 15, replace=False)) for _ in range(5)])
    assert np.array_equal(p.q, pool.q[p.indices]) and p.free == (
        "bx",
        "by",
        "bz",
        "brx",
        "bry",
        "brz",
    )
    assert p.predicted_mm < p.random_mm
    assert planned <= random
    assert 0.67 <= planned / p.predicted_mm <= 1.5
