"""SixAxisTrack-v0 through Gymnasium: the checkers, determinism, the observation and info
contract, the instrument, bad actions, divergence, rendering and vector envs."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest

import envs  # registers SixAxisTrack-v0
from arm.kinematics import Chain, link_frames
from arm.sampling import MIN_TOOL_HEIGHT
from envs.trajectories import KINDS

ENV = "SixAxisTrack-v0"


def _make(**kw):
    return gym.make(ENV, **kw)


def _resolved_rate(task, obs):
    """Nominal resolved-rate control: move the nominal model's tool to the next reference."""
    sl = task.obs_slices
    chain = Chain.from_description(task.robot)
    q = obs[sl["q"]].astype(float)
    f = link_frames(chain, q[None])
    p = f.point(task.robot.tool_points[0])[0]
    J = np.cross(f.z[0], p - f.o[0, 1:]).T
    target = obs[sl["preview"]][:3].astype(float)
    v = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(3), (target - p) / task.dt)
    return np.clip(v / task.v_max, -1, 1).astype(np.float32)


def test_gymnasium_checker_with_render():
    from gymnasium.utils.env_checker import check_env

    env = _make(scenario="all", render_mode="rgb_array", width=160, height=120)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning either
        check_env(env.unwrapped, skip_render_check=False)
    env.close()


def test_stable_baselines3_checker():
    from stable_baselines3.common.env_checker import check_env

    env = _make(scenario="compliance", render_mode="rgb_array", width=160, height=120)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, warn=True, skip_render_check=False)
    env.close()


def test_make_by_module_prefix_and_vector():
    env = gym.make("envs:SixAxisTrack-v0")
    assert env.spec.max_episode_steps == 500
    env.close()
    vec = gym.make_vec(ENV, num_envs=2, vectorization_mode="sync", scenario="geometric")
    obs, info = vec.reset(seed=3)
    assert obs.shape == (2, 52) and obs.dtype == np.float32
    obs, rew, _term, _trunc, info = vec.step(vec.action_space.sample())
    assert rew.shape == (2,) and info["true_error_mm"].shape == (2,)
    assert not np.array_equal(obs[0], obs[1])  # different sub-seeds
    vec.close()


def _rollout(env, seed, actions):
    obs, info = env.reset(seed=seed)
    out = [(obs, 0.0, info)]
    for a in actions:
        obs, r, _term, _trunc, info = env.step(a)
        out.append((obs, r, info))
    return out


def _same(a, b):
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and np.array_equal(a, b)
    return a == b


@pytest.mark.parametrize("scenario", ["all", "geometric"])
def test_same_seed_same_episode_bit_for_bit(scenario):
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, (30, 6)).astype(np.float32)
    e1, e2 = _make(scenario=scenario, latency_steps=2), _make(scenario=scenario, latency_steps=2)
    r1, r2 = _rollout(e1, 42, actions), _rollout(e2, 42, actions)
    for (o1, w1, i1), (o2, w2, i2) in zip(r1, r2, strict=True):
        assert np.array_equal(o1, o2) and w1 == w2 and _same(i1, i2)
    assert np.array_equal(e1.unwrapped.truth.params, e2.unwrapped.truth.params)
    # the same env reset again with the seed reproduces it too
    r3 = _rollout(e1, 42, actions)
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(r1, r3, strict=True))


def test_different_seeds_different_truths_and_trajectories():
    env = _make(scenario="all")
    params, starts = [], []
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        params.append(env.unwrapped.truth.params.copy())
        starts.append(obs[env.unwrapped.task.obs_slices["ref"]].copy())
    for i in range(3):
        for j in range(i):
            assert not np.allclose(params[i], params[j])
            assert not np.allclose(starts[i], starts[j])


def test_task_and_truth_contract():
    env = _make(scenario="compliance", overrides={"compliance": {"c2": 8e-6}})
    obs, _info = env.reset(seed=1)
    u = env.unwrapped
    task, truth = u.task, u.truth
    assert task.robot.name == "seed" and task.dt == pytest.approx(0.02) and task.substeps == 20
    assert task.v_max.shape == task.a_max.shape == (6,)
    assert task.preview_steps == 10 and task.noise_mm == 0.015
    assert set(task.obs_slices) == {
        "q", "qd", "ref", "preview", "meas", "meas_age", "meas_valid", "temperature", "payload",
    }  # fmt: skip
    assert task.obs_size == obs.shape[0] == 52
    assert truth.parameters()["c2"] == 8e-6
    assert truth.hidden.stiffness[1] == pytest.approx(1 / 8e-6)
    assert truth.model.effect_names == ["geometric", "compliance"]
    assert truth.true_robot.effects["compliance"]["c2"] == 8e-6
    # nothing of the truth is in the observation: the encoder reads the motor, the reference is
    # the nominal path
    assert np.array_equal(obs[task.obs_slices["q"]], u.plant.q.astype(np.float32))


def test_observation_info_and_reward_are_consistent():
    env = _make(scenario="geometric", noise_mm=0.0, preview_steps=4)
    obs, info = env.reset(seed=5)
    u = env.unwrapped
    sl = u.task.obs_slices
    assert obs.shape == (22 + 12,)
    assert obs[sl["meas_valid"]][0] == 0 and obs[sl["meas_age"]][0] == 10.0
    refs = u.references
    for k in range(1, 12):
        obs, r, term, trunc, info = env.step(_resolved_rate(u.task, obs))
        assert not term and not trunc
        assert np.allclose(obs[sl["ref"]], refs[k]) and np.allclose(info["reference"], refs[k])
        assert np.allclose(obs[sl["preview"]].reshape(4, 3), refs[k + 1 : k + 5])
        err = 1e3 * np.linalg.norm(info["true_tool"] - info["reference"])
        assert info["true_error_mm"] == pytest.approx(err)
        assert r == pytest.approx(info["reward_tracking"] + info["reward_jerk"])
        assert info["reward_tracking"] == pytest.approx(-err)
        assert info["time"] == pytest.approx(0.02 * k)
        valid = k % 5 == 0
        assert info["measurement_valid"] == valid and obs[sl["meas_valid"]][0] == valid
        if valid:  # noise-free and no latency: the measurement is the true tool point now
            assert np.array_equal(info["measurement"], info["true_tool"])
            assert np.allclose(obs[sl["meas"]], info["measurement"])
            assert np.array_equal(info["measurement_q"], u.plant.q)
            assert set(info["measurement_columns"]) == {
                "t", "temperature", "payload", *(f"dir{i}" for i in range(1, 7)),
            }  # fmt: skip
            assert obs[sl["meas_age"]][0] == 0.0
        else:
            assert "measurement" not in info
    assert obs[sl["meas_age"]][0] == pytest.approx(0.02)


def test_tracker_noise_latency_dropout_and_blind():
    env = _make(scenario="nominal", noise_mm=0.015, measure_every=1, latency_steps=3)
    obs, _ = env.reset(seed=2)
    u = env.unwrapped
    tools, qs, errs = [], [], []
    for k in range(1, 301):
        obs, _, _, _, info = env.step(_resolved_rate(u.task, obs))
        tools.append(info["true_tool"])
        qs.append(u.plant.q)
        if k <= 3:
            assert not info["measurement_valid"]
        else:
            assert info["measurement_valid"]
            # sampled three steps ago: its encoder reading and time are those of then
            assert np.array_equal(info["measurement_q"], qs[k - 4])
            assert info["measurement_time"] == pytest.approx(0.02 * (k - 3))
            assert obs[u.task.obs_slices["meas_age"]][0] == pytest.approx(0.06)
            errs.append(info["measurement"] - tools[k - 4])
    sigma = np.std(np.array(errs), axis=0)
    assert np.allclose(sigma, 15e-6, rtol=0.2)

    env = _make(scenario="nominal", measure_every=1, dropout=0.5)
    env.reset(seed=2)
    n = sum(env.step(np.zeros(6, np.float32))[4]["measurement_valid"] for _ in range(200))
    assert 70 < n < 130

    env = _make(scenario="nominal", measurements=False)
    obs, _ = env.reset(seed=2)
    for _ in range(20):
        obs, _, _, _, info = env.step(np.zeros(6, np.float32))
        assert not info["measurement_valid"]
    assert not obs[env.unwrapped.task.obs_slices["meas"]].any()


@pytest.mark.parametrize("kind", KINDS)
def test_reference_is_reachable_and_trackable(kind):
    """On the nominal arm, a nominal resolved-rate controller follows every kind of path within
    velocity limits: the path is above the floor, reachable, and the task is well posed."""
    env = _make(scenario="nominal", trajectory=kind)
    obs, info = env.reset(seed=11)
    assert info["trajectory"] == kind
    assert info["true_error_mm"] < 1e-3  # the arm starts on the path
    u = env.unwrapped
    assert u.references[:, 2].min() > MIN_TOOL_HEIGHT
    errs = []
    for _ in range(500):
        a = _resolved_rate(u.task, obs)
        assert np.abs(a).max() < 1.0  # well within the velocity limits
        obs, _r, term, trunc, info = env.step(a)
        errs.append(info["true_error_mm"])
    assert trunc and not term
    assert np.max(errs) < 0.5


def test_hidden_errors_are_visible_to_a_nominal_controller():
    env = _make(scenario="geometric", trajectory="circle")
    obs, info = env.reset(seed=11)
    assert info["true_error_mm"] > 0.2  # the true arm is off the nominal
    errs = []
    for _ in range(100):
        obs, _r, _term, _trunc, info = env.step(_resolved_rate(env.unwrapped.task, obs))
        errs.append(info["true_error_mm"])
    assert np.mean(errs) > 0.2


@pytest.mark.parametrize(
    "action, match",
    [
        (np.array([0, 0, np.nan, 0, 0, 0], np.float32), "NaN or inf at index \\[2\\]"),
        (np.array([np.inf, 0, 0, 0, 0, 0]), "NaN or inf at index \\[0\\]"),
        (np.zeros(5), "shape \\(6,\\)"),
        (np.zeros((6, 1)), "shape \\(6,\\)"),
        ("fast", "6 numbers"),
    ],
)
def test_bad_actions_are_refused_clearly(action, match):
    env = _make(scenario="geometric")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.unwrapped.step(action)


def test_out_of_range_actions_are_clipped():
    e1, e2 = _make(scenario="geometric"), _make(scenario="geometric")
    e1.reset(seed=0), e2.reset(seed=0)
    a = np.array([5.0, -5.0, 0.5, 2.0, -1.0, 0.0])
    o1 = e1.unwrapped.step(a)[0]
    o2 = e2.unwrapped.step(np.clip(a, -1, 1))[0]
    assert np.array_equal(o1, o2)


def test_divergence_ends_the_episode_with_a_flag():
    env = _make(scenario="compliance")
    obs, _ = env.reset(seed=0)
    env.unwrapped.plant.data.qvel[:] = 1e12  # a blown-up state
    obs2, r, term, trunc, info = env.step(np.zeros(6, np.float32))
    assert term and not trunc and info["diverged"] and r == -1000.0
    assert env.observation_space.contains(obs2) and np.array_equal(obs, obs2)
    _obs3, r, term, _trunc, info = env.step(np.zeros(6, np.float32))  # no crash after the end
    assert term and info["diverged"]
    obs, info = env.reset(seed=0)
    assert not info["diverged"]
    assert not env.step(np.zeros(6, np.float32))[4]["diverged"]


def test_render_draws_arm_path_and_measurements():
    env = _make(scenario="geometric", render_mode="rgb_array", width=320, height=240)
    obs, _ = env.reset(seed=4)
    for _ in range(20):
        obs, *_ = env.step(_resolved_rate(env.unwrapped.task, obs))
    img = env.render()
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    assert img.std() > 10
    # the path overlay is green: some pixels must be clearly green
    r, g, b = (img[..., i].astype(int) for i in range(3))
    assert ((g - r > 60) & (g - b > 40)).sum() > 50
    env.close()
    env = _make(scenario="geometric")
    env.reset(seed=0)
    assert env.render() is None  # no render_mode, no frame


def test_importing_envs_loads_no_mujoco():
    code = "import sys, envs, envs.collect, envs.scenarios; print('mujoco' in sys.modules)"
    code = code.replace("envs.scenarios", "arm.kinematics")
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=os.environ
    )
    assert out.stdout.strip() == "False"


def test_the_env_class_is_reachable_from_envs_on_demand():
    from envs.sixaxis_track_v0 import SixAxisTrackEnv

    assert envs.SixAxisTrackEnv is SixAxisTrackEnv
    with pytest.raises(AttributeError, match="no attribute 'SixAxisTrack'"):
        envs.SixAxisTrack  # noqa: B018


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="unknown scenario"):
        _make(scenario="windy")
    with pytest.raises(ValueError, match="trajectory: expected None or one of circle"):
        _make(trajectory="zigzag")
    with pytest.raises(ValueError, match="has no 'thermal' effect"):
        _make(scenario="geometric", overrides={"thermal": {"kappa": 1e-5}})
    with pytest.raises(ValueError, match="measure_every"):
        _make(measure_every=0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        # an override given as a string, or with a string that numpy would have read as a number
        ({"overrides": "compliance"}, "overrides: overrides must be a mapping {effect:"),
        (
            {"scenario": "compliance", "overrides": {"compliance": {"c2": "8e-6"}}},
            "overrides: overrides['compliance']['c2'] must be a finite number or a (low, high) "
            "pair, got '8e-6'",
        ),
        (
            {"scenario": "compliance", "overrides": {"compliance": {"c2": True}}},
            "overrides['compliance']['c2'] must be a finite number",
        ),
        (  # a DH error is a value, not a range (float() of the pair crashed at reset)
            {"overrides": {"geometric": {"da2": [1e-4, 2e-4]}}},
            "overrides['geometric']['da2'] must be a finite number, got [0.0001, 0.0002]",
        ),
        (
            {"render_mode": "rgb_array", "width": -5},
            "width: expected an integer in [1, 4096] (pixels)",
        ),
        ({"height": 0}, "height: expected an integer in [1, 4096] (pixels), got 0"),
        ({"width": "640"}, "width: expected an integer in [1, 4096] (pixels), got '640'"),
        ({"noise_mm": -0.01}, "noise_mm: expected a number >= 0 (mm), got -0.01"),
        ({"noise_mm": "0.01"}, "noise_mm: expected a number >= 0 (mm), got '0.01'"),
        ({"measure_every": 2.5}, "measure_every: expected an integer >= 1"),  # was taken as 2
        ({"dropout": 1.0}, "dropout: expected a number in [0, 1) (a probability), got 1.0"),
        ({"latency_steps": -1}, "latency_steps: expected an integer >= 0"),
        ({"jerk_weight": -1.0}, "jerk_weight: expected a number >= 0, got -1.0"),
        (
            {"episode_seconds": 0.001},
            "episode_seconds: expected a number >= 0.02 (one control step)",
        ),
        ({"measurements": "yes"}, "measurements: expected true or false, got 'yes'"),
        ({"temperature_lag": -3.0}, "temperature_lag: expected a number >= 0 (s), got -3.0"),
        ({"robot": "no-such-arm"}, "robot: unknown robot 'no-such-arm'"),
        ({"posture": [0.0] * 5}, "posture: posture must have 6 entries"),
    ],
)
def test_bad_options_are_one_clear_error_naming_the_key(kwargs, message):
    """At construction, before any MuJoCo model is built, an :class:`EnvOptionError` (a
    ``ValueError``) whose message names the key; ``check_options`` says the same without
    building anything."""
    from arm.errors import SixAxisError
    from envs.sixaxis_track_v0 import SixAxisTrackEnv

    with pytest.raises(SixAxisError) as info:
        _make(**kwargs)
    assert isinstance(info.value, ValueError)
    assert message in str(info.value)
    (key,) = [k for k in kwargs if k in message.split(":")[0]] or ["overrides"]
    assert key in SixAxisTrackEnv.check_options(**kwargs)
    assert SixAxisTrackEnv.check_options(**{k: v for k, v in kwargs.items() if k != key}) == {}


def test_every_bad_option_is_named_at_once():
    from envs.sixaxis_track_v0 import SixAxisTrackEnv

    problems = SixAxisTrackEnv.check_options(noise_mm=-1, measure_every=0, trajectory="zig", x=1)
    assert sorted(problems) == ["measure_every", "noise_mm", "trajectory", "x"]
    assert problems["x"].startswith("unknown option; the env takes scenario, overrides,")


def test_the_bare_env_refuses_step_and_render_before_reset():
    """``gym.make``'s order-enforcing wrapper says so; the unwrapped env crashed in an
    attribute of None."""
    from gymnasium.error import ResetNeeded

    from arm.errors import SixAxisError

    env = _make(render_mode="rgb_array").unwrapped
    with pytest.raises(ResetNeeded, match=r"call reset\(\) before step\(\)") as info:
        env.step(np.zeros(6))
    assert isinstance(info.value, SixAxisError)
    with pytest.raises(ResetNeeded, match=r"call reset\(\) before render\(\)"):
        env.render()
    env.reset(seed=0)
    env.step(np.zeros(6))  # and then it works
    env.close()


def test_a_frame_larger_than_the_default_offscreen_buffer_renders():
    env = _make(render_mode="rgb_array", width=800, height=600)
    env.reset(seed=0)
    assert env.render().shape == (600, 800, 3)
    env.close()


def test_a_closed_env_is_freed_without_the_cyclic_collector():
    """An env dropped after use frees its MuJoCo state at once (reference counting), not when
    the cyclic collector happens to run: a sweep's worker that makes an env per run would
    otherwise hold the state of many, and its address space grew past the run's limit. The
    episode's truth reads the env's live conditions while it exists, its start values after."""
    import gc
    import weakref

    env = gym.make("SixAxisTrack-v0", scenario="thermal")
    env.reset(seed=3)
    env.step(np.zeros(env.action_space.shape))
    u = env.unwrapped
    truth = u.truth
    assert truth.conditions()["temperature"] == u._conditions()["temperature"]
    ref, plant = weakref.ref(u), weakref.ref(u.plant)
    gc.disable()
    try:
        env.close()
        del env, u
        assert ref() is None and plant() is None
    finally:
        gc.enable()
    # no plant any more: the episode's start values, as a truth never bound gives
    assert truth.conditions() == {
        "temperature": float(truth.hidden.temperature0),
        "payload": float(truth.true_robot.payload),
    }
