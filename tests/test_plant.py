"""The MuJoCo plant against independent references: the kinematic model of the same true arm,
the gravity torques and compliance formula of docs/format.md, the transmission and backlash laws."""

from __future__ import annotations

import numpy as np
import pytest

from arm import seed_robot
from arm.description import replace
from arm.kinematics import Chain, gravity_torques, tool_points
from arm.sampling import sample_poses
from arm.so3 import rotation_matrix
from envs.plant import HiddenEffects, Plant, PlantError
from envs.scenarios import draw_truth

ROBOT = seed_robot()


@pytest.fixture(scope="module")
def rigid() -> Plant:
    return Plant(ROBOT, elastic=False)


@pytest.fixture(scope="module")
def elastic() -> Plant:
    return Plant(ROBOT, elastic=True)


def _base_gravity(robot):
    """The robot with gravity expressed in its (rotated) base frame, as MuJoCo applies it."""
    g = rotation_matrix(np.array(robot.base_rotation)).T @ np.array(ROBOT.gravity)
    return replace(robot, gravity=tuple(g))


@pytest.mark.parametrize("seed", [0, 1])
def test_tool_site_equals_kinematic_model_of_the_true_arm(rigid, seed):
    """All effects off: MuJoCo's site_xpos is the kinematic tool point of the same true arm
    (DH errors, Hayati beta, base and tool) to 1e-9 m, computed two independent ways."""
    truth = draw_truth("geometric", ROBOT, np.random.default_rng(seed))
    true = truth.true_robot
    assert true.joints[2].beta != 0.0 and any(true.base_translation)  # the errors are there
    rigid.configure(true, truth.hidden)
    q = sample_poses(ROBOT, 20, np.random.default_rng(seed + 10))
    mj = np.empty((20, 3))
    for i, qi in enumerate(q):
        rigid.place(qi, settle=0.0)
        mj[i] = rigid.tool_point()
    # 1) the true description's chain and base transform
    pb = tool_points(Chain.from_description(true), q, true.tool_points[0])
    kin = pb @ rotation_matrix(np.array(true.base_rotation)).T + np.array(true.base_translation)
    # 2) the error model on the nominal arm with the true parameters
    model = truth.model.predict(truth.model.inputs(q), truth.params)
    assert np.abs(mj - kin).max() < 1e-9
    assert np.abs(mj - model).max() < 1e-9
    # and the errors are not negligible: the nominal arm is off by about a millimetre
    nominal = tool_points(Chain.from_description(ROBOT), q, ROBOT.tool_points[0])
    assert np.linalg.norm(mj - nominal, axis=1).mean() > 2e-4


def test_elastic_plant_geometry_uses_motor_plus_link_angle(elastic):
    truth = draw_truth("geometric", ROBOT, np.random.default_rng(3))
    elastic.configure(truth.true_robot, truth.hidden)
    q = sample_poses(ROBOT, 5, np.random.default_rng(4))
    for qi in q:
        elastic.place(qi, settle=0.0)
        theta = elastic.theta
        true = truth.true_robot
        pb = tool_points(Chain.from_description(true), theta, true.tool_points[0])
        expect = rotation_matrix(np.array(true.base_rotation)) @ pb + true.base_translation
        assert np.abs(elastic.tool_point() - expect).max() < 1e-9


@pytest.mark.parametrize("payload", [0.0, 2.5])
def test_gravity_torques_are_minus_qfrc_bias(rigid, payload):
    """The sign convention of docs/format.md (compliance): arm.kinematics.gravity_torques equals
    minus MuJoCo's qfrc_bias at rest, payload included."""
    truth = draw_truth("geometric", ROBOT, np.random.default_rng(5))
    rigid.configure(truth.true_robot, HiddenEffects(payload0=payload))
    robot = _base_gravity(truth.true_robot)
    for q in sample_poses(ROBOT, 10, np.random.default_rng(6)):
        rigid.place(q, settle=0.0)
        expect = gravity_torques(robot, q, payload=payload)
        assert np.allclose(rigid.gravity_torques(), expect, rtol=1e-9, atol=1e-9)


def test_static_deflection_matches_the_compliance_formula(elastic):
    """Links start undeflected; MuJoCo's physics settles them. Their deflection (link angle minus
    encoder) equals c_i tau_i (docs/format.md, compliance; c_i = 1/k_i, tau from arm.kinematics)
    within 5 % wherever |tau_i| > 20 N*m."""
    truth = draw_truth("compliance", ROBOT, np.random.default_rng(7))
    c = truth.magnitudes["compliance"]
    elastic.configure(truth.true_robot, truth.hidden)
    robot = _base_gravity(truth.true_robot)
    checked = 0
    for q in sample_poses(ROBOT, 8, np.random.default_rng(8)):
        elastic.place(q, settle=1.5, static=False)
        deflection = elastic.data.qpos[elastic.il]
        tau = gravity_torques(robot, elastic.q)
        big = np.abs(tau) > 20.0
        assert np.allclose(deflection[big], c[big] * tau[big], rtol=0.05, atol=0.0)
        checked += int(big.sum())
        # the settling really moved them (they started at zero)
        assert np.all(np.abs(deflection[big]) > 20.0 * c[big] * 0.9)
    assert checked >= 8


def test_transmission_and_gear_ratio_move_the_link_with_the_motor(elastic):
    truth = draw_truth("transmission", ROBOT, np.random.default_rng(9))
    h = truth.hidden
    elastic.configure(truth.true_robot, h)
    for q in sample_poses(ROBOT, 4, np.random.default_rng(10)):
        elastic.place(q, settle=0.3, static=False)
        qm = elastic.q
        expect = h.ts * np.sin(qm) + h.tc * np.cos(qm) + h.g * qm
        offset = elastic.data.qpos[elastic.il]
        # the stiff mesh adds tau/k (< 2e-7 rad) to the law
        assert np.abs(offset - expect).max() < 5e-7
        assert np.abs(expect).max() > 1e-4


def test_cyclic_errors_move_the_link_at_rest_and_in_motion(elastic):
    """High orders (23-40 per turn) follow their law a_s sin(k q) + a_c cos(k q) on the motor
    angle, settled and while the joints turn: the mesh is relinearised within a control step
    wherever k times its motion is not small (once per control step, joint 6 at 1 rad/s would
    miss its order-40 term by about 7e-5 rad; so, by under 2e-6 rad)."""
    terms = ((1, 37, 3e-4, 0.0), (3, 23, 0.0, 2e-4), (6, 40, 2e-4, 1e-4))
    truth = draw_truth(
        "cyclic", ROBOT, np.random.default_rng(3), overrides={"cyclic": {"terms": terms}}
    )
    h = truth.hidden
    assert h.cyclic == terms
    elastic.configure(truth.true_robot, h)

    def law(qm):
        r = np.zeros(6)
        for j, k, a_s, a_c in terms:
            r[j - 1] += a_s * np.sin(k * qm[j - 1]) + a_c * np.cos(k * qm[j - 1])
        return r

    for q in sample_poses(ROBOT, 3, np.random.default_rng(10)):
        elastic.place(q, settle=0.3, static=False)
        assert np.abs(elastic.data.qpos[elastic.il] - law(elastic.q)).max() < 2e-7
    worst = 0.0
    for i in range(60):
        elastic.step(np.array([0.3, 0.0, 0.3, 0.0, 0.0, 1.0]))
        if i >= 10:  # past the start's transient
            worst = max(worst, np.abs(elastic.data.qpos[elastic.il] - law(elastic.q)).max())
    assert worst < 3e-6


def test_backlash_load_side_and_friction_lag(elastic):
    """Joint 2 (gravity-loaded) rests against the side its gravity torque pushes it to, whatever
    the motion; joint 6 (no gravity torque, held by friction) lags its motor's last motion."""
    truth = draw_truth("backlash", ROBOT, np.random.default_rng(11))
    gap = truth.hidden.gap
    elastic.configure(truth.true_robot, truth.hidden)
    q = np.array([0.2, -0.9, 0.3, 0.4, 0.8, 0.0])
    elastic.place(q, dirs=np.ones(6))
    for direction in (1.0, -1.0, 1.0):
        v = np.zeros(6)
        v[[1, 5]] = 0.05 * direction
        for k in range(40):  # move, then slow down gently (an abrupt stop lets the motor recoil)
            elastic.step(v * min(1.0, (40 - k) / 15))
        for _ in range(25):
            elastic.step(np.zeros(6))
        link = elastic.data.qpos[elastic.il]
        tau2 = gravity_torques(ROBOT, elastic.q)[1]
        assert tau2 > 20.0
        assert link[1] == pytest.approx(gap[1] / 2 + tau2 / truth.hidden.stiffness[1], abs=2e-5)
        assert link[5] == pytest.approx(-direction * gap[5] / 2, abs=2e-5)
        assert elastic.dirs[5] == direction


def test_thermal_growth_scales_link_lengths_and_heats_with_motion(rigid):
    truth = draw_truth("thermal", ROBOT, np.random.default_rng(12))
    rigid.configure(truth.true_robot, truth.hidden)
    q = np.array([0.2, -1.0, 0.3, 0.4, 0.8, 0.0])
    rigid.place(q, settle=0.0)
    T0 = rigid.temperature
    assert T0 == truth.magnitudes["temperature0"]
    for _ in range(50):
        rigid.step(np.array([0.5, 0.5, -0.5, 1.0, 1.0, 1.0]))
    assert rigid.temperature > T0  # motion heats the arm
    cols = {"temperature": np.array([rigid.temperature])}
    model = truth.model.predict(truth.model.inputs(rigid.q[None], cols), truth.params)[0]
    assert np.abs(rigid.tool_point() - model).max() < 1e-9


def test_payload_change_keeps_the_state(elastic):
    truth = draw_truth("payload", ROBOT, np.random.default_rng(13))
    elastic.configure(truth.true_robot, truth.hidden)
    q = np.array([0.2, -1.0, 0.3, 0.4, 0.8, 0.0])
    elastic.place(q)
    before = elastic.data.qpos.copy()
    elastic.set_payload(2.0)
    assert np.array_equal(elastic.data.qpos, before)
    assert elastic.model.body_mass[elastic._payload] == 2.0


def test_servo_respects_velocity_and_acceleration_limits(rigid):
    rigid.configure(ROBOT, HiddenEffects())
    rigid.place(np.array([0.0, -1.2, 0.3, 0.0, 0.8, 0.0]), settle=0.0)
    d = rigid.drive
    refs = []
    for _ in range(30):
        rigid.step(np.full(6, 100.0))
        refs.append(rigid._v_ref.copy())
    refs = np.array(refs)
    assert np.all(np.abs(refs) <= d.v_max + 1e-12)
    assert np.all(np.abs(np.diff(refs, axis=0)) <= d.a_max * rigid.dt + 1e-12)
    assert np.allclose(refs[-1], d.v_max)
    assert np.allclose(rigid.qd, d.v_max, rtol=0.05)  # the motors follow


def test_rigid_plant_refuses_elastic_effects(rigid):
    with pytest.raises(PlantError, match="elastic"):
        rigid.configure(ROBOT, HiddenEffects(stiffness=np.full(6, 1e5)))


def test_divergence_is_detected(rigid):
    rigid.configure(ROBOT, HiddenEffects())
    rigid.place(np.zeros(6), settle=0.0)
    assert not rigid.diverged()
    rigid.data.qvel[:] = 1e9
    assert rigid.diverged()
