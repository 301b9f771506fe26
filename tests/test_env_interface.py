"""The operational-space interface (``gym.make("SixAxisTrack-v0", interface="tool")``): its
nominal kinematics against the error model and finite differences, Gymnasium's checker, the
displacement it asks for being the one the arm makes, its observation in mm, a linear policy of
it tracking as the ``feedforward`` controller does, the learned agents seeing the same numbers,
and bad options refused."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs  # noqa: F401
from agents.policy import PolicyIO
from agents.registry import make_agent
from agents.runner import run_episode
from arm.description import load_robot
from arm.errormodel import ErrorModel
from envs.sixaxis_track_v0 import EnvOptionError
from envs.task import controller_info
from envs.wrappers import NominalKinematics, NominalToolObservation, ToolDisplacementAction


def _interface(env: gym.Env) -> ToolDisplacementAction:
    while not isinstance(env, ToolDisplacementAction):
        env = env.env  # type: ignore[attr-defined]
    return env


def test_nominal_kinematics_is_the_error_models_point_and_its_derivative():
    """The float kinematics against the error model's batched prediction (another
    implementation) and its Jacobian against central differences, on a description with a base
    transform and a tool offset so that every term is exercised."""
    robot = load_robot("seed")
    import dataclasses

    robot = dataclasses.replace(
        robot, base_translation=(0.1, -0.2, 0.05), base_rotation=(0.01, -0.02, 0.3)
    )
    kin = NominalKinematics(robot)
    model = ErrorModel(robot, "geometric")
    p = model.nominal()
    rng = np.random.default_rng(3)
    for q in rng.uniform(-1.5, 1.5, (5, 6)):
        x, J = kin.point_jacobian(q)
        np.testing.assert_allclose(x, model.predict(model.inputs(q[None]), p)[0], atol=1e-12)
        h = 1e-6
        fd = np.stack([(kin.point(q + e) - kin.point(q - e)) / (2 * h) for e in np.eye(6) * h], 1)
        np.testing.assert_allclose(J, fd, atol=1e-8)


@pytest.mark.filterwarnings("ignore:.*different from the unwrapped version")
def test_the_tool_interface_passes_gymnasiums_checker_and_names_its_parts():
    env = gym.make("SixAxisTrack-v0", scenario="geometric", interface="tool")
    check_env(env.unwrapped, skip_render_check=True)  # the env underneath is unchanged
    check_env(env, skip_render_check=True)
    sl = _interface(env).obs_slices
    assert env.action_space.shape == (3,)
    assert env.observation_space.shape == (10 + 3 * 10,) == (sl["previous_action"].stop,)
    assert [k for k in sl] == [
        "tracking_error",
        "preview",
        "model_error",
        "model_error_age",
        "previous_action",
    ]


def test_the_arm_moves_by_the_displacement_asked_for():
    """On a perfect arm a small displacement is what the tool does: after the servo has caught up
    (a constant request), the encoders' nominal tool point moves by ``a * step_mm`` a step, to
    a few percent; and the observation's tracking error is r - x_nom(q) - e in mm."""
    env = gym.make("SixAxisTrack-v0", scenario="nominal", interface="tool", tool_step_mm=2.0)
    obs, info = env.reset(seed=4)
    w = _interface(env)
    kin = NominalKinematics(env.unwrapped.task.robot)
    q = env.unwrapped._obs[env.unwrapped.task.obs_slices["q"]]
    np.testing.assert_allclose(
        obs[w.obs_slices["tracking_error"]],
        (info["reference"] - kin.point(q)) * 1e3 - obs[w.obs_slices["model_error"]],
        rtol=1e-5,
        atol=1e-4,
    )
    a = np.array([0.3, -0.2, 0.1])
    points = []
    for _ in range(30):
        obs, _, _, _, info = env.step(a)
        points.append(kin.point(env.unwrapped._obs[env.unwrapped.task.obs_slices["q"]]))
    moved = np.diff(np.array(points[-10:]), axis=0) * 1e3
    np.testing.assert_allclose(moved, np.tile(a * 2.0, (9, 1)), rtol=0.05, atol=0.02)
    np.testing.assert_allclose(obs[w.obs_slices["previous_action"]], a, rtol=1e-6)


def test_a_linear_policy_of_the_interface_tracks_as_feedforward_does():
    """``a = (p_1 + 0.5 t) / step_mm`` is the feedforward law in the interface's terms: its settled
    error is the feedforward agent's, within 30 %, on the same episode."""
    kw = {"scenario": "geometric", "noise_mm": 0.015, "measure_every": 5}
    ff = run_episode(make_agent("feedforward"), kw, seed=5, episode_seconds=4.0)
    env = gym.make("SixAxisTrack-v0", interface="tool", episode_seconds=4.0, **kw)
    sl = _interface(env).obs_slices
    f, _ = env.reset(seed=5)
    errors = []
    done = False
    while not done:
        p1 = f[sl["preview"]][:3]
        a = (p1 + 0.5 * f[sl["tracking_error"]]) / 5.0
        f, _, term, trunc, info = env.step(a)
        errors.append(info["true_error_mm"])
        done = term or trunc
    settled = float(np.sqrt(np.mean(np.square(errors[100:]))))
    assert settled == pytest.approx(ff.rms_mm(start=2.0), rel=0.3)
    assert settled < 0.2  # mm; nominal tracking makes 2-3 mm on this scenario


def test_the_learned_agents_see_the_wrappers_numbers():
    """PolicyIO's tool variant (what a shipped policy sees, from the controllers' info only) and
    the gym wrapper give the same observation and send the same command."""
    env = gym.make("SixAxisTrack-v0", scenario="backlash", interface="tool", latency_steps=2)
    raw = gym.make("SixAxisTrack-v0", scenario="backlash", latency_steps=2)
    obs, info = env.reset(seed=6)
    robs, rinfo = raw.reset(seed=6)
    io = PolicyIO("tool")
    io.reset(raw.unwrapped.task)
    rng = np.random.default_rng(0)
    for _ in range(40):
        f = io.features(robs, controller_info(rinfo))
        np.testing.assert_allclose(f, obs, rtol=1e-6, atol=1e-6)
        a = rng.uniform(-0.2, 0.2, 3)
        cmd = io.action(a)
        obs, _, _, _, info = env.step(a)
        robs, _, _, _, rinfo = raw.step(cmd)
        assert info["true_error_mm"] == rinfo["true_error_mm"]


def test_nominal_tool_observation_is_the_error_models_point():
    env = NominalToolObservation(gym.make("SixAxisTrack-v0", scenario="geometric"))
    obs, _ = env.reset(seed=2)
    for _ in range(5):
        obs, *_ = env.step(np.full(6, 0.05))
    sl = env.obs_slices
    model = ErrorModel(env.unwrapped.task.robot, "geometric")
    q = obs[sl["q"]].astype(float)
    x = model.predict(model.inputs(q[None]), model.nominal())[0]
    np.testing.assert_allclose(obs[sl["tool_nominal"]], x, atol=1e-6)


@pytest.mark.parametrize(
    ("options", "key"),
    [
        ({"interface": "cartesian"}, "interface"),
        ({"interface": "tool", "tool_step_mm": 0}, "tool_step_mm"),
    ],
)
def test_bad_interface_options_are_refused_by_name(options, key):
    with pytest.raises(EnvOptionError, match=key):
        gym.make("SixAxisTrack-v0", **options)


def test_a_bad_displacement_is_refused():
    env = gym.make("SixAxisTrack-v0", interface="tool")
    env.reset(seed=0)
    for bad in ([np.nan, 0, 0], [0.1, 0.2]):
        with pytest.raises(ValueError, match="3 finite numbers"):
            env.step(np.array(bad, dtype=float))


def _motor_state(env: gym.Env) -> tuple[np.ndarray, np.ndarray]:
    """The motor hinges' angles and velocities, read from MuJoCo's own data by joint name."""
    import mujoco

    plant = env.unwrapped.plant
    m, d = plant.model, plant.data
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"motor{i}") for i in range(1, 7)]
    return d.qpos[m.jnt_qposadr[ids]].copy(), d.qvel[m.jnt_dofadr[ids]].copy()


@pytest.mark.filterwarnings("ignore:.*different from the unwrapped version")
def test_the_observe_option_appends_the_envs_readings_at_the_declared_scales():
    """``observe=[...]`` appends, after the interface's 40 numbers (unchanged), the encoders'
    angles and velocities (MuJoCo's motor hinges), the declared payload and the temperature
    sensor's reading (with a prompt, right declaration and a sensor without lag or noise: the
    plant's exact values in ``info``), in the env's units, with the documented fixed scales; the
    wrapper's bounds are the env's and Gymnasium's checker passes."""
    kw = {
        "scenario": "all",
        "temperature_noise": 0.0,
        "temperature_lag": 0.0,
        "overrides": {"payload": {"declare_delay": 0.0, "declare_error": 0.0}},
    }
    env = gym.make(
        "SixAxisTrack-v0", interface="tool", observe=["temperature", "joints", "payload"], **kw
    )
    plain = gym.make("SixAxisTrack-v0", interface="tool", **kw)
    check_env(env, skip_render_check=True)
    w = _interface(env)
    sl = w.obs_slices
    assert list(sl)[5:] == ["q", "qd", "payload", "temperature"]
    assert (sl["q"], sl["qd"], sl["payload"], sl["temperature"]) == (
        slice(40, 46),
        slice(46, 52),
        slice(52, 53),
        slice(53, 54),
    )
    raw_space = env.unwrapped.observation_space
    raw = env.unwrapped.task.obs_slices
    for name in ("q", "qd", "payload", "temperature"):
        np.testing.assert_array_equal(env.observation_space.low[sl[name]], raw_space.low[raw[name]])
        np.testing.assert_array_equal(
            env.observation_space.high[sl[name]], raw_space.high[raw[name]]
        )
    offset, scale = w.feature_offset, w.feature_scale
    np.testing.assert_array_equal(offset[40:], [0.0] * 12 + [0.0, 20.0])
    np.testing.assert_array_equal(scale[40:], [1.0] * 12 + [1.0, 5.0])
    obs, info = env.reset(seed=11)
    base, _ = plain.reset(seed=11)
    rng = np.random.default_rng(1)
    for _ in range(60):
        np.testing.assert_array_equal(obs[:40], base)
        q, qd = _motor_state(env)
        np.testing.assert_allclose(obs[sl["q"]], q, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(obs[sl["qd"]], qd, rtol=1e-6, atol=1e-6)
        assert obs[sl["payload"]][0] == pytest.approx(info["payload"], abs=1e-6)
        assert obs[sl["temperature"]][0] == pytest.approx(info["temperature"], abs=1e-4)
        features = (obs - offset) / scale
        assert features[53] == pytest.approx((info["temperature"] - 20.0) / 5.0, abs=1e-4)
        a = rng.uniform(-0.3, 0.3, 3)
        obs, _, _, _, info = env.step(a)
        base, *_ = plain.step(a)
    assert np.ptp(obs[sl["qd"]]) > 0  # the arm moved


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"interface": "tool", "observe": ["torque"]}, "observe"),
        ({"interface": "tool", "observe": "joints"}, "observe"),
        ({"interface": "tool", "observe": ["joints", "joints"]}, "observe"),
        ({"observe": ["joints"]}, "tool interface"),
    ],
)
def test_bad_observe_options_are_refused_by_name(options, message):
    with pytest.raises(EnvOptionError, match=message):
        gym.make("SixAxisTrack-v0", **options)


def test_the_learned_agents_see_the_observe_options_numbers():
    """PolicyIO with ``observe`` gives the wrapper's observation, from the raw env's stream."""
    env = gym.make(
        "SixAxisTrack-v0",
        scenario="payload",
        interface="tool",
        observe=["joints", "payload", "temperature"],
    )
    raw = gym.make("SixAxisTrack-v0", scenario="payload")
    obs, _ = env.reset(seed=2)
    robs, rinfo = raw.reset(seed=2)
    io = PolicyIO("tool", observe=("payload", "joints", "temperature"))
    io.reset(raw.unwrapped.task)
    assert io.observation_size(raw.unwrapped.task) == 54
    for _ in range(20):
        np.testing.assert_allclose(
            io.features(robs, controller_info(rinfo)), obs, rtol=1e-6, atol=1e-5
        )
        a = np.array([0.1, -0.1, 0.05])
        cmd = io.action(a)
        obs, *_ = env.step(a)
        robs, _, _, _, rinfo = raw.step(cmd)


def test_nominal_tool_observation_passes_gymnasiums_checker_with_finite_bounds():
    """Finite bounds that hold (the nominal tool point within the arm's reach) and the
    constructor recorded (``RecordConstructorArgs``), so Gymnasium's checker passes with every
    warning but the wrapped-env notice treated as an error."""
    import warnings

    from envs.wrappers import nominal_reach

    env = NominalToolObservation(gym.make("SixAxisTrack-v0", scenario="geometric"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", ".*different from the unwrapped version")
        check_env(env, skip_render_check=True)
    assert np.isfinite(env.observation_space.low).all()
    assert np.isfinite(env.observation_space.high).all()
    # its spec records it: gym.make rebuilds the wrapped env from the spec alone
    again = gym.make(env.spec)
    assert isinstance(again, NominalToolObservation)
    assert again.observation_space == env.observation_space
    robot = env.unwrapped.task.robot
    rng = np.random.default_rng(0)
    kin = NominalKinematics(robot)
    reach = nominal_reach(robot)
    farthest = max(
        float(np.linalg.norm(kin.point(q) - np.asarray(kin.o0)))
        for q in rng.uniform(robot.lower, robot.upper, (2000, 6))
    )
    assert farthest <= reach < 2.0 * farthest  # a bound, and not a loose one
