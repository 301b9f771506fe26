"""The error model: the parameter names of docs/format.md, predictions, and its analytic
identification Jacobian against central finite differences for every parameter of every effect."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from arm.description import seed_robot
from arm.effect_api import EffectError
from arm.effects import CATALOGUE, EFFECTS
from arm.errormodel import ErrorModel
from arm.kinematics import Chain, gravity_torques, tool_points
from arm.sampling import sample_parameters
from tests.conftest import random_q, rokae_arm

# every catalogued effect; the cyclic one with its example's joints and orders
ALL = ",".join(EFFECTS[n].example or n for n in CATALOGUE)
SEED = seed_robot()
ROKAE = rokae_arm()


def _fd_step(name: str) -> float:
    """Central-difference steps that move the point by about 1e-6 m."""
    if name.startswith("c") and name[1:].isdigit():
        return 1e-8  # rad/(N m); torques reach ~100 N m
    if name == "kappa":
        return 1e-7  # 1/K; temperatures differ from 20 degC by up to ~20 K
    return 1e-6


def _finite_differences(model, inputs, p):
    J = np.empty((inputs.n, 3, len(p)))
    for k, name in enumerate(model.layout.names):
        h = _fd_step(name)
        pp, pm = p.copy(), p.copy()
        pp[k] += h
        pm[k] -= h
        J[:, :, k] = (model.predict(inputs, pp) - model.predict(inputs, pm)) / (2 * h)
    return J


def _assert_columns_match(model, J, J_fd):
    scale = np.maximum(1.0, np.abs(J).max(axis=(0, 1)))
    err = np.abs(J - J_fd).max(axis=(0, 1)) / scale
    worst = int(np.argmax(err))
    assert err[worst] < 1e-7, f"{model.layout.names[worst]}: relative error {err[worst]:.3g}"


def _columns(rng, n, n_targets):
    return {
        "temperature": rng.uniform(0.0, 45.0, n),
        "payload": rng.uniform(0.0, 8.0, n),
        "target": rng.integers(0, n_targets, n).astype(float),
        **{f"dir{j}": rng.choice((-1.0, 1.0), n) for j in range(1, 7)},
    }


@settings(max_examples=30, derandomize=True, deadline=None)
@given(
    q=arrays(np.float64, (6, 6), elements=st.floats(-3.0, 3.0)),
    base_rotation=arrays(np.float64, 3, elements=st.floats(-2.0, 2.0)),
    base_translation=arrays(np.float64, 3, elements=st.floats(-4.0, 4.0)),
    n_targets=st.integers(1, 3),
    scale=st.sampled_from([1.0, 30.0]),
    seed=st.integers(0, 2**31 - 1),
    arm=st.sampled_from(["seed", "rokae"]),
)
def test_identification_jacobian_equals_finite_differences(
    q, base_rotation, base_translation, n_targets, scale, seed, arm
):
    """Every parameter of every catalogued effect at once: random configurations, random errors
    (up to 30 times the typical magnitudes of docs/format.md), a large base rotation and
    translation, several targets, thermal with temperatures, backlash with directions, payloads."""
    robot = SEED if arm == "seed" else ROKAE
    tools = tuple((0.01 * k, -0.02 * k, 0.05 + 0.03 * k) for k in range(n_targets))
    robot = replace(robot, tools=tools)
    model = ErrorModel(robot, ALL, targets=tuple(range(n_targets)))
    rng = np.random.default_rng(seed)
    p = sample_parameters(model, rng, scale=scale)
    for name, v in zip(("brx", "bry", "brz"), base_rotation, strict=True):
        p[model.layout.index(name)] = v
    for name, v in zip(("bx", "by", "bz"), base_translation, strict=True):
        p[model.layout.index(name)] = v
    inputs = model.inputs(q, _columns(rng, len(q), n_targets))
    xyz, J = model.predict(inputs, p, jacobian=True)
    np.testing.assert_allclose(xyz, model.predict(inputs, p), rtol=0, atol=1e-13)
    _assert_columns_match(model, J, _finite_differences(model, inputs, p))


@pytest.mark.parametrize(
    "effects",
    [
        "geometric",
        "compliance[2,3]",
        "transmission[1,4]",
        "joint_scale",
        "thermal",
        "backlash[6]",
        "cyclic[1:3;2:1,17,29;6:40-42]",
    ],
)
def test_each_effect_alone_equals_finite_differences(effects):
    model = ErrorModel(SEED, effects)
    rng = np.random.default_rng(1)
    p = sample_parameters(model, rng, scale=10.0)
    q = random_q(SEED, 9, seed=1)
    inputs = model.inputs(q, _columns(rng, 9, 1) | {"target": np.zeros(9)})
    _, J = model.predict(inputs, p, jacobian=True)
    _assert_columns_match(model, J, _finite_differences(model, inputs, p))


def test_joint_jacobian_equals_finite_differences():
    """d point / d theta, the direction inverse kinematics on a calibrated model steps along."""
    model = ErrorModel(SEED, "geometric,thermal")
    rng = np.random.default_rng(2)
    p = sample_parameters(model, rng, scale=5.0)
    p[model.layout.index("brz")] = 2.0
    q = random_q(SEED, 8, seed=2)
    cols = {"temperature": rng.uniform(10, 40, 8)}
    xyz, J = model.joint_jacobian(model.inputs(q, cols), p)
    np.testing.assert_allclose(xyz, model.predict(model.inputs(q, cols), p), atol=1e-15)
    h = 1e-6
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        fd = (
            model.predict(model.inputs(q + dq, cols), p)
            - model.predict(model.inputs(q - dq, cols), p)
        ) / (2 * h)
        np.testing.assert_allclose(J[:, :, i], fd, atol=1e-8)


def test_parameter_names_follow_docs_format():
    """docs/format.md, parameter names: 6 x (dalpha, da, dtheta, dd) with dd3 replaced by Hayati's
    beta2 where joints 2 and 3 are parallel, base bx..brz, tool tx ty tz (tx1.. with several
    targets): 33 names (the seed paper's "34" counts beta2 before dd3 is dropped)."""
    names = ErrorModel(SEED, "geometric").layout.names
    assert len(names) == 33
    assert "dd3" not in names and "beta2" in names
    for k in range(1, 7):
        assert {f"dalpha{k}", f"da{k}", f"dtheta{k}"} <= set(names)
    assert names[-9:] == ("bx", "by", "bz", "brx", "bry", "brz", "tx", "ty", "tz")
    multi = ErrorModel(
        replace(SEED, tools=((0, 0, 0.05), (0, 0.02, 0.05))), "geometric", targets=(1, 2)
    )
    assert multi.layout.names[-6:] == ("tx1", "ty1", "tz1", "tx2", "ty2", "tz2")
    full = ErrorModel(SEED, ALL).layout
    assert full.slice("compliance") == slice(33, 39)
    assert full.names[full.slice("transmission")] == tuple(
        [f"ts{j}" for j in range(1, 7)] + [f"tc{j}" for j in range(1, 7)]
    )
    assert full.names[-1] == "kappa"
    assert ErrorModel(SEED, "compliance[2,3]").layout.names == ("c2", "c3")


def test_parallel_axes_are_found_from_the_description():
    """Not hard-coded for joints 2 and 3: an arm whose joints 3 and 4 are parallel instead gets
    beta3 and loses dd4."""
    joints = list(SEED.joints)
    joints[2] = replace(joints[2], alpha=-math.pi / 2)
    joints[3] = replace(joints[3], alpha=0.0)
    arm = replace(SEED, joints=tuple(joints))
    assert arm.parallel_rows() == (4,)
    names = ErrorModel(arm, "geometric").layout.names
    assert "beta3" in names and "dd4" not in names and "dd3" in names and "beta2" not in names


def test_nominal_parameters_reproduce_the_description():
    model = ErrorModel(ROKAE, ALL)
    q = random_q(ROKAE, 10, seed=3)
    inputs = model.inputs(
        q, {"temperature": np.full(10, 20.0), **{f"dir{j}": np.ones(10) for j in range(1, 7)}}
    )
    chain = Chain.from_description(ROKAE)
    np.testing.assert_allclose(
        model.predict(inputs, model.nominal()),
        tool_points(chain, q, ROKAE.tool_points[0]),
        atol=1e-15,
    )


def test_joint_angle_effects_follow_their_laws():
    """Each law of docs/format.md, parameter names on the effective angles, against its formula."""
    rng = np.random.default_rng(4)
    q = random_q(SEED, 12, seed=4)
    cols = {f"dir{j}": rng.choice((-1.0, 1.0), 12) for j in range(1, 7)} | {
        "payload": rng.uniform(0, 5, 12)
    }
    model = ErrorModel(SEED, "compliance,transmission,joint_scale,backlash,load_backlash")
    p = sample_parameters(model, rng)
    v = model.layout.as_dict(p)
    tau = gravity_torques(SEED, q, payload=cols["payload"])
    expected = q.copy()
    for j in range(6):
        k = j + 1
        expected[:, j] += v[f"c{k}"] * tau[:, j]
        expected[:, j] += v[f"ts{k}"] * np.sin(q[:, j]) + v[f"tc{k}"] * np.cos(q[:, j])
        expected[:, j] += v[f"g{k}"] * q[:, j]
        expected[:, j] -= v[f"bl{k}"] / 2 * cols[f"dir{k}"]
        loaded = np.where(np.abs(tau[:, j]) < 1e-9, 0.0, np.sign(tau[:, j]))
        expected[:, j] += v[f"lb{k}"] / 2 * loaded
    np.testing.assert_allclose(model.joint_angles(model.inputs(q, cols), p), expected, atol=1e-15)


def test_cyclic_errors_follow_their_law_and_their_specification():
    """cyclic[2:17,29;4:1-3]: theta_j = q_j + sum_k cs{j}_{k} sin(k q_j) + cc{j}_{k} cos(k q_j)
    over the orders named for joint j, none on the other joints; the label reads back."""
    model = ErrorModel(SEED, "cyclic[2:17,29;4:1-3]")
    cyc = model.effects[0]
    assert cyc.label == "cyclic[2:17,29;4:1-3]"
    assert model.layout.names == (
        *("cs2_17", "cc2_17", "cs2_29", "cc2_29"),
        *("cs4_1", "cc4_1", "cs4_2", "cc4_2", "cs4_3", "cc4_3"),
    )
    rng = np.random.default_rng(5)
    p = sample_parameters(model, rng)
    v = model.layout.as_dict(p)
    assert all(5e-5 <= abs(x) <= 3e-4 for x in v.values())
    q = random_q(SEED, 20, seed=5)
    expected = q.copy()
    for j, ks in ((2, (17, 29)), (4, (1, 2, 3))):
        for k in ks:
            expected[:, j - 1] += v[f"cs{j}_{k}"] * np.sin(k * q[:, j - 1])
            expected[:, j - 1] += v[f"cc{j}_{k}"] * np.cos(k * q[:, j - 1])
    np.testing.assert_allclose(model.joint_angles(model.inputs(q), p), expected, atol=1e-15)
    # order 1 is the catalogue's transmission, to rounding
    one = ErrorModel(SEED, "transmission[3]")
    same = ErrorModel(SEED, "cyclic[3:1]")
    x = np.array([2e-4, -1e-4])
    np.testing.assert_allclose(
        same.joint_angles(same.inputs(q), x), one.joint_angles(one.inputs(q), x), atol=1e-16
    )


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("cyclic", "needs its joints and orders"),
        ("cyclic[]", "needs its joints and orders"),
        ("cyclic[2]", "bad joint and orders '2'"),
        ("cyclic[7:3]", "joints must be within 1..6"),
        ("cyclic[2:0]", "must lie within 1..1000"),
        ("cyclic[2:3;2:4]", "joint 2 is named twice"),
        ("cyclic[2:x]", "bad joint and orders"),
        ("cyclic[2:9-3]", "bad range of orders"),
    ],
)
def test_a_bad_cyclic_specification_is_refused_with_its_reason(spec, message):
    with pytest.raises(EffectError, match=message):
        ErrorModel(SEED, f"geometric,{spec}")


def test_load_backlash_ignores_torques_that_are_zero_by_construction():
    """tau_1 and tau_6 of the seed arm are zero up to rounding (+-1e-15): the gap must not be
    taken on a side picked by rounding noise, so lb1 and lb6 move nothing."""
    model = ErrorModel(SEED, "load_backlash")
    q = random_q(SEED, 50, seed=6)
    inputs = model.inputs(q, {"payload": np.full(50, 2.0)})
    assert np.abs(inputs.tau[:, [0, 5]]).max() < 1e-9
    _, J = model.predict(inputs, model.nominal(), jacobian=True)
    names = model.layout.names
    assert np.all(J[:, :, [names.index("lb1"), names.index("lb6")]] == 0.0)
    assert np.all(np.abs(J[:, :, names.index("lb2")]).max(axis=1) > 0)


def test_thermal_grows_the_arm_not_base_or_tool():
    """kappa scales every a and d: at home the tool height grows by kappa dT (d1 + a2 + a3)."""
    model = ErrorModel(SEED, "thermal")
    q = np.array([[0, -math.pi / 2, 0, 0, 0, 0]])
    kappa, T = 2e-5, 35.0
    xyz = model.predict(model.inputs(q, {"temperature": [T]}), np.array([kappa]))
    growth = kappa * (T - 20.0)
    np.testing.assert_allclose(
        xyz[0], [0.7176 * (1 + growth) + 0.05, 0, 0.8634 * (1 + growth)], atol=1e-15
    )


def test_calibrated_description_reproduces_the_model():
    model = ErrorModel(ROKAE, "geometric,compliance")
    p = sample_parameters(model, np.random.default_rng(5), scale=3.0)
    cal = model.description(p)
    q = random_q(ROKAE, 10, seed=5)
    again = ErrorModel(cal, "geometric,compliance")
    inputs = model.inputs(q)
    np.testing.assert_allclose(
        again.predict(again.inputs(q), again.nominal()),
        model.predict(inputs, p) - _compliance(model, inputs, p),
        atol=1e-12,
    )
    assert cal.effects["compliance"] == {
        f"c{j}": p[model.layout.index(f"c{j}")] for j in range(1, 7)
    }


def _compliance(model, inputs, p):
    """The compliance part of a prediction, which a description keeps as an effect value."""
    p0 = p.copy()
    p0[model.layout.slice("compliance")] = 0.0
    return model.predict(inputs, p) - model.predict(inputs, p0)


def test_missing_columns_and_bad_targets_are_named():
    model = ErrorModel(SEED, "geometric,thermal,backlash")
    with pytest.raises(EffectError, match=r"temperature \(needed by thermal\)"):
        model.inputs(np.zeros((2, 6)), {f"dir{j}": np.ones(2) for j in range(1, 7)})
    multi = ErrorModel(SEED, "geometric", targets=(1, 2))
    with pytest.raises(EffectError, match=r"target id\(s\) \[3\]"):
        multi.inputs(np.zeros((2, 6)), {"target": [1, 3]})
    with pytest.raises(EffectError, match="no 'target' column"):
        multi.inputs(np.zeros((2, 6)))
    with pytest.raises(ValueError, match="expected 33 parameters"):
        ErrorModel(SEED).predict(ErrorModel(SEED).inputs(np.zeros((1, 6))), np.zeros(3))


def test_sampling_is_reproducible_and_of_the_spec_magnitudes():
    """Same seed, same arm; magnitudes within each effect's typical range (docs/format.md,
    parameter names), with physical signs where the effect has one."""
    from arm.sampling import MIN_TOOL_HEIGHT, sample_poses

    model = ErrorModel(SEED, ALL)
    a = sample_parameters(model, np.random.default_rng(7))
    b = sample_parameters(model, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, sample_parameters(model, np.random.default_rng(8)))
    v = model.layout.as_dict(a)
    assert all(6e-4 <= abs(v[f"dalpha{i}"]) <= 1.5e-3 for i in range(1, 7))
    assert all(1e-4 <= abs(v[f"da{i}"]) <= 3e-4 for i in range(1, 7))
    assert 6e-4 <= abs(v["beta2"]) <= 1.5e-3
    assert all(3e-6 <= v[f"c{i}"] <= 1e-5 for i in range(1, 7))
    assert all(3e-4 <= v[f"bl{i}"] <= 6e-4 for i in range(1, 7))
    assert 1.2e-5 <= v["kappa"] <= 2.3e-5
    low = model.layout.as_dict(sample_parameters(model, np.random.default_rng(7), level="low"))
    assert abs(low["dalpha3"]) == 6e-4 and low["c2"] == 3e-6
    only = sample_parameters(model, np.random.default_rng(7), only=["c2", "c3"])
    assert np.count_nonzero(only) == 2
    q = sample_poses(SEED, 500, np.random.default_rng(9))
    np.testing.assert_array_equal(q, sample_poses(SEED, 500, np.random.default_rng(9)))
    assert q.shape == (500, 6) and np.all(SEED.within_limits(q))
    tool = tool_points(Chain.from_description(SEED), q, SEED.tool_points[0])
    assert np.all(tool[:, 2] > MIN_TOOL_HEIGHT)
