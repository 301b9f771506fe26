"""The lab's story told in closed loop on the ``compliance`` scenario (issue 5): calibrated over
the workspace, then judged blind in a region the calibration never visited, a geometric-only
model is left with a visible error and adding the joints' compliance brings tracking close to
the oracle's. Also the env's ``posture`` option that places a trajectory in a region."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers SixAxisTrack-v0)
from agents.registry import make_agent
from agents.runner import (
    JUDGE_POSTURES,
    WORKSPACE_POSTURES,
    Phase,
    run_episode,
    workspace_campaign,
)
from arm.description import load_robot
from arm.kinematics import Chain, gravity_torques, tool_points

POSTURE = [None, -1.2, 0.3, None, 0.5, None]


def _reset(seed=0, **kw):
    options = kw.pop("options", None)
    env = gym.make("SixAxisTrack-v0", **kw)
    obs, _ = env.reset(seed=seed, options=options)
    u = env.unwrapped
    out = obs, u.references.copy(), np.asarray(u.truth.params).copy(), u.task.obs_slices
    env.close()
    return out


@pytest.mark.parametrize("kind", ["circle", "lemniscate", "lines", "spline"])
@pytest.mark.parametrize("how", ["kwarg", "option"])
def test_posture_places_the_trajectory_there(kind, how):
    """The arm starts at the posture (the joints given), and the path starts at the nominal tool
    point there: forward kinematics of the description, computed here independently of the
    env's inverse kinematics."""
    kw = {"posture": POSTURE} if how == "kwarg" else {"options": {"posture": POSTURE}}
    obs, refs, _, sl = _reset(seed=4, trajectory=kind, **kw)
    q = obs[sl["q"]].astype(float)
    fixed = [i for i, v in enumerate(POSTURE) if v is not None]
    np.testing.assert_allclose(q[fixed], [POSTURE[i] for i in fixed], atol=1e-6)
    robot = load_robot("seed").to_modified()
    p = tool_points(Chain.from_description(robot), q[None], robot.tool_points[0])[0]
    base = robot.base_matrix
    np.testing.assert_allclose(refs[0], base[:3, :3] @ p + base[:3, 3], atol=1e-5)


def test_no_posture_gives_the_same_episode_and_a_posture_keeps_the_arm():
    """``posture=None`` and a posture of all None leave every draw as it was (the leaderboard's
    episodes do not change); a posture moves the path but not the sampled arm (the runner's
    phases need the same truth)."""
    plain = _reset(seed=3, scenario="compliance")
    free = _reset(seed=3, scenario="compliance", posture=[None] * 6)
    placed = _reset(seed=3, scenario="compliance", posture=POSTURE)
    np.testing.assert_array_equal(plain[0], free[0])
    np.testing.assert_array_equal(plain[1], free[1])
    np.testing.assert_array_equal(plain[2], placed[2])
    assert np.linalg.norm(plain[1][0] - placed[1][0]) > 0.05


@pytest.mark.parametrize(
    ("posture", "match"),
    [
        ([0.0] * 5, "6 entries"),
        ([None, 0.5, 0.0, None, None, None], "joint 2"),
        ([None, -1.2, 0.3, None, None, float("inf")], "joint 6"),
        ([None, "elbow", 0.3, None, None, None], "6 joint angles"),
    ],
)
def test_bad_posture_is_refused_naming_the_joint(posture, match):
    with pytest.raises(ValueError, match=match):
        gym.make("SixAxisTrack-v0", posture=posture)
    env = gym.make("SixAxisTrack-v0")
    with pytest.raises(ValueError, match=match):
        env.reset(seed=0, options={"posture": posture})


def test_workspace_campaign_judges_blind_where_gravity_loads_the_arm_differently():
    """Calibration phases measured, one per posture; the judged phase blind, on a new kind of
    trajectory, in a posture whose shoulder torque lies outside every calibration posture's
    (``reach``, ``raised``) or between them (``inside``)."""
    phases = workspace_campaign()
    assert [p.judged for p in phases] == [False] * len(WORKSPACE_POSTURES) + [True]
    assert all(p.overrides.get("measurements", True) for p in phases[:-1])
    blind = phases[-1]
    assert blind.overrides["measurements"] is False
    assert blind.overrides["trajectory"] not in {p.overrides["trajectory"] for p in phases[:-1]}
    assert blind.overrides["posture"] == list(JUDGE_POSTURES["reach"])
    robot = load_robot("seed")
    tau = gravity_torques(robot, np.array(WORKSPACE_POSTURES))[:, 1]
    assert tau.max() - tau.min() > 100.0  # N m: the calibration spans the shoulder's loads
    t = {k: gravity_torques(robot, np.array(q))[1] for k, q in JUDGE_POSTURES.items()}
    assert t["reach"] > tau.max() + 10 and t["raised"] < tau.min() - 10
    assert tau.min() < t["inside"] < tau.max()
    assert workspace_campaign(judge_posture="inside")[-1].overrides["posture"] == list(
        JUDGE_POSTURES["inside"]
    )
    with pytest.raises(ValueError, match="unknown judge_posture 'far'"):
        workspace_campaign(judge_posture="far")


def test_workspace_campaign_phases_run_on_one_arm():
    """Short phases of the campaign run in one episode: every phase is the same sampled arm
    (the runner refuses otherwise), the calibration phases measure and the blind one does not."""
    phases = [Phase(p.name, 0.3, p.overrides, p.judged) for p in workspace_campaign()]
    r = run_episode(make_agent("nominal"), {"scenario": "compliance"}, seed=1, phases=phases)
    assert not r.diverged
    assert np.isfinite(r.measurement[~r.judged]).any()
    assert not np.isfinite(r.measurement[r.judged]).any()


def _blind_rms(name, seed, region, **settings):
    r = run_episode(
        make_agent(name, **settings),
        {"scenario": "compliance"},
        seed=seed,
        phases=workspace_campaign(judge_posture=region),
    )
    assert not r.diverged
    return r.rms_mm(start=2.0)


# Margins from benchmarks/compliance_story.py over seeds 0-11 in each judged region (blind RMS
# after 2 s, ratio to mpc-oracle seed by seed; results/benchmarks.md, section compliance-story).
# mpc without forgetting: geometric-only 2.6x-16x the oracle where the judged posture's gravity
# load lies outside the calibration's (``reach``, ``raised``; 1.3x-3.7x ``inside``, where a
# geometric compromise interpolates), geometric+compliance 0.97x-1.19x in all three.
# The seeds tested are the hardest of those: ``reach`` seed 10 the compliant model's largest
# ratio (1.19x), ``raised`` seed 8 geometric-only's smallest (2.6x).


@pytest.mark.slow
@pytest.mark.parametrize(("region", "seed"), [("reach", 10), ("raised", 8)])
def test_adding_compliance_brings_blind_tracking_to_the_oracle(region, seed):
    """The must-show: calibrated over the workspace and judged blind in a region it never
    visited, geometric-only calibration is left with a visible error; geometric+compliance falls
    close to ``mpc-oracle``. Without forgetting: the campaign is a calibration, and forgetting
    (default 0.995) lets the last postures outweigh the first (the compliant model then reached
    up to 2.1x the oracle at ``reach``)."""
    oracle = _blind_rms("mpc-oracle", seed, region)
    geo = _blind_rms("mpc", seed, region, effects="geometric", forgetting=1.0)
    comp = _blind_rms("mpc", seed, region, effects="geometric,compliance", forgetting=1.0)
    assert geo >= 2.0 * oracle
    assert geo >= 2.0 * comp
    assert comp <= 1.3 * oracle


@pytest.mark.slow
def test_lab_calibration_with_compliance_removes_the_blind_error():
    """The same with the lab's batch fit (``calibrated``: every calibration measurement, refitted
    at each phase, then a resolved-rate tracker, whose own floor is about 1.2-1.5x the MPC
    oracle's): adding compliance cuts the blind error at ``reach`` 4x-13x over seeds 0-11."""
    geo = _blind_rms("calibrated", 10, "reach", effects="geometric", calibration_seconds=None)
    comp = _blind_rms(
        "calibrated", 10, "reach", effects="geometric,compliance", calibration_seconds=None
    )
    assert geo >= 3.0 * comp
    assert comp <= 0.1
