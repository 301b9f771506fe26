"""The CasADi tool model against the numpy error model (an independent implementation) and
against finite differences."""

from __future__ import annotations

import copy

import casadi as ca
import numpy as np
import pytest

from agents.tool_model import (
    BufferedFunction,
    ToolModel,
    UnsupportedEffectError,
    cached_tool_model,
)
from arm import ErrorModel, seed_robot
from arm.effects import ChainEffect, JointAngleEffect
from arm.sampling import sample_parameters, sample_poses

ALL = (
    "geometric,compliance,transmission,cyclic[2:17,29;6:40],joint_scale,backlash,"
    "load_backlash[2,3,4,5],thermal"
)


def _columns(n, rng):
    cols = {"temperature": rng.uniform(15, 45, n), "payload": rng.uniform(0, 3, n)}
    cols |= {f"dir{i}": rng.choice((-1.0, 1.0), n) for i in range(1, 7)}
    return cols


@pytest.fixture(scope="module")
def model():
    return ErrorModel(seed_robot(), ALL)


@pytest.fixture(scope="module")
def tool(model):
    return ToolModel(model)


def test_point_and_parameter_jacobian_equal_the_error_model(model, tool):
    rng = np.random.default_rng(0)
    q = sample_poses(model.robot, 20, rng)
    cols = _columns(20, rng)
    p = sample_parameters(model, rng, scale=3.0)
    x, J = model.predict(model.inputs(q, cols), p, jacobian=True)
    for k in range(len(q)):
        ck = {c: float(v[k]) for c, v in cols.items()}
        ev = tool.evaluate(q[k], p, ck)
        np.testing.assert_allclose(ev.x, x[k], rtol=0, atol=1e-13)
        np.testing.assert_allclose(ev.Jp, J[k], rtol=1e-9, atol=1e-12)


def test_joint_jacobian_equals_central_differences_of_the_error_model(model, tool):
    rng = np.random.default_rng(1)
    q = sample_poses(model.robot, 5, rng)
    p = sample_parameters(model, rng)
    cols = {"temperature": 30.0, "payload": 1.5} | {f"dir{i}": 1.0 for i in range(1, 7)}
    h = 1e-6
    for qk in q:
        _, Jq = tool.point_dq(qk, p, cols)
        fd = np.empty((3, 6))
        for i in range(6):
            dq = np.zeros(6)
            dq[i] = h
            arr = {c: np.array([v, v]) for c, v in cols.items()}
            xs = model.predict(model.inputs(np.stack([qk + dq, qk - dq]), arr), p)
            fd[:, i] = (xs[0] - xs[1]) / (2 * h)
        np.testing.assert_allclose(Jq, fd, rtol=0, atol=1e-8)


def test_expression_works_inside_mx_graphs(model, tool):
    rng = np.random.default_rng(2)
    q = sample_poses(model.robot, 1, rng)[0]
    p = sample_parameters(model, rng)
    c = tool.column_vector({"temperature": 25.0})
    qs = ca.MX.sym("q", 6)
    f = ca.Function("f", [qs], [tool.expression(qs, ca.DM(p), ca.DM(c))])
    np.testing.assert_allclose(np.asarray(f(q)).ravel(), tool.point(q, p, c), atol=1e-14)


class SecondHarmonic(JointAngleEffect):
    """A user's effect: theta_i += s2_i sin(2 q_i) (not in the CasADi catalogue)."""

    name = "second_harmonic_test"
    terms = ("s2h",)
    typical = {"s2h": (1e-4, 3e-4)}

    def basis(self, inputs, joint, term):
        return np.sin(2 * inputs.q[:, joint - 1])


def test_user_joint_angle_effect_enters_through_numpy_offsets():
    model = ErrorModel(seed_robot(), ["geometric", SecondHarmonic(joints=[2, 3])])
    tool = ToolModel(model)
    rng = np.random.default_rng(3)
    q = sample_poses(model.robot, 4, rng)
    p = sample_parameters(model, rng)
    x = model.predict(model.inputs(q), p)
    for k in range(4):
        np.testing.assert_allclose(tool.point(q[k], p), x[k], atol=1e-13)


class Bend(ChainEffect):
    name = "bend_test"

    def parameter_names(self, robot, targets):
        return ["bend"]


def test_user_chain_effect_is_refused_by_name():
    model = ErrorModel(seed_robot(), ["geometric", Bend()])
    with pytest.raises(UnsupportedEffectError, match="bend_test"):
        ToolModel(model)


def test_cached_tool_model_is_reused_for_an_equal_model():
    a = cached_tool_model(ErrorModel(seed_robot(), "geometric"))
    b = cached_tool_model(ErrorModel(seed_robot(), "geometric"))
    assert a._f_q is b._f_q


def test_wrong_parameter_count_is_refused(tool):
    with pytest.raises(ValueError, match="parameters"):
        tool.point(np.zeros(6), np.zeros(3))


def test_buffered_call_equals_the_plain_call_and_copies_have_their_own_buffers():
    x = ca.SX.sym("x", 3)
    f = ca.Function("f", [x], [ca.vertcat(ca.sin(x[0]) * x[1], x[2] ** 2, ca.dot(x, x))])
    b = BufferedFunction(f)
    c = copy.deepcopy(b)
    u, v = np.array([0.3, -1.2, 2.0]), np.array([1.0, 2.0, 3.0])
    out_b = b(u).copy()
    out_c = c(v).copy()
    np.testing.assert_array_equal(out_b, np.asarray(f(u)).ravel())
    np.testing.assert_array_equal(out_c, np.asarray(f(v)).ravel())
    np.testing.assert_array_equal(b.res, out_b)  # the other's call did not write here
    with pytest.raises(ValueError, match="dense"):
        BufferedFunction(ca.Function("g", [x], [ca.jacobian(ca.vertcat(x[0], x[1] * x[2]), x)]))
