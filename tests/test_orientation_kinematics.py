"""The tool frame's orientation and several tracker stations in the error model: the predicted
pose equals an independent product of 4x4 modified-DH matrices written out here (a different
construction from the batched frames), with each station's own base and the tool frame's rotation;
every analytic column, of the point and of the rotation, equals central differences, for the
catalogue's geometric, joint-angle and thermal effects and a user's chain effect without analytic
columns; and a model without stations or orientation keeps its parameter names."""

from __future__ import annotations

import numpy as np
import pytest

from arm.description import seed_robot
from arm.effect_api import EffectError
from arm.effects import ChainEffect
from arm.errormodel import ErrorModel
from arm.so3 import rotation_matrix, rotation_vector
from tests.conftest import random_q, rokae_arm


def _dh(alpha, beta, a, theta, d) -> np.ndarray:
    """RotX(alpha) RotY(beta) TransX(a) RotZ(theta) TransZ(d), one 4x4 matrix."""
    ca, sa, cb, sb, ct, st = (
        np.cos(alpha),
        np.sin(alpha),
        np.cos(beta),
        np.sin(beta),
        np.cos(theta),
        np.sin(theta),
    )
    rx = np.array([[1, 0, 0, 0], [0, ca, -sa, 0], [0, sa, ca, 0], [0, 0, 0, 1.0]])
    ry = np.array([[cb, 0, sb, 0], [0, 1, 0, 0], [-sb, 0, cb, 0], [0, 0, 0, 1.0]])
    tx = np.eye(4)
    tx[0, 3] = a
    rz = np.array([[ct, -st, 0, 0], [st, ct, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    tz = np.eye(4)
    tz[2, 3] = d
    return rx @ ry @ tx @ rz @ tz


def _reference_pose(model: ErrorModel, p: np.ndarray, q: np.ndarray, station_of, target_of):
    """Point and rotation of each pose from the parameters by name, 4x4 products only."""
    v = model.layout.as_dict(p)
    rob = model.robot
    pts, rots = [], []
    for n, qn in enumerate(q):
        sfx = "" if len(model.stations) == 1 else str(station_of[n])
        T = np.eye(4)
        T[:3, :3] = rotation_matrix(np.array([v[f"br{c}{sfx}"] for c in "xyz"]))
        T[:3, 3] = [v[f"b{c}{sfx}"] for c in "xyz"]
        for i, j in enumerate(rob.joints, start=1):
            beta = v.get(f"beta{i - 1}", j.beta)
            T = T @ _dh(
                j.alpha + v[f"dalpha{i}"],
                beta,
                j.a + v[f"da{i}"],
                qn[i - 1] + j.theta_offset + v[f"dtheta{i}"],
                j.d + v.get(f"dd{i}", 0.0),
            )
        k = target_of[n]
        tsfx = "" if len(model.targets) == 1 else str(model.targets[k])
        tool = np.array(rob.tools[min(k, len(rob.tools) - 1)]) + [v[f"t{c}{tsfx}"] for c in "xyz"]
        pts.append(T[:3, :3] @ tool + T[:3, 3])
        turn = np.array([v[f"tr{c}"] for c in "xyz"])
        rots.append(T[:3, :3] @ rotation_matrix(turn))
    return np.array(pts), np.array(rots)


def _parameters(model: ErrorModel, rng) -> np.ndarray:
    """Errors of the typical size, stations metres away and turned, a tool frame far from the
    flange's (the Rokae set's is turned by 120 degrees about (1, 1, 1))."""
    p = model.nominal() + rng.normal(0, 1e-3, len(model.layout))
    for k, name in enumerate(model.layout.names):
        if name.startswith(("bx", "by", "bz")):
            p[k] = rng.uniform(-3, 3)
        elif name.startswith(("brx", "bry", "brz")):
            p[k] = rng.uniform(-1.5, 1.5)
        elif name in ("trx", "try", "trz"):
            p[k] = 2.0944 / np.sqrt(3)
        elif name.startswith("c"):
            p[k] = 5e-6
        elif name == "kappa":
            p[k] = 2e-5
    return p


@pytest.mark.parametrize("robot", [seed_robot(), rokae_arm()], ids=["seed", "rokae"])
def test_pose_equals_4x4_products_with_each_stations_base(robot):
    rng = np.random.default_rng(1)
    model = ErrorModel(robot, "geometric", targets=(0, 4), stations=(1, 2, 5), orientation=True)
    q = random_q(robot, 40, seed=2)
    station = rng.choice([1, 2, 5], len(q))
    target = rng.choice([0, 4], len(q))
    inputs = model.inputs(q, {"station": station.astype(float), "target": target.astype(float)})
    p = _parameters(model, rng)
    xyz, R = model.predict_pose(inputs, p)
    ref_xyz, ref_R = _reference_pose(model, p, q, station, [(0, 4).index(t) for t in target])
    np.testing.assert_allclose(xyz, ref_xyz, atol=1e-12)
    np.testing.assert_allclose(R, ref_R, atol=1e-13)
    # the position-only path agrees, and a pose's station picks its base
    np.testing.assert_allclose(model.predict(inputs, p), xyz, atol=1e-12)
    assert model.layout.names[24:30] == ("bx1", "by1", "bz1", "brx1", "bry1", "brz1")


class _Stretch(ChainEffect):
    """A user's chain effect without analytic columns: row 4's d and alpha change."""

    name = "stretch"
    order = 5  # before thermal scaling, which scales what it changed

    def parameter_names(self, robot, targets):
        return ["s_d4", "s_alpha4"]

    def apply(self, inputs, values, state):
        d = np.array(state.chain.d, dtype=float)
        al = np.array(state.chain.alpha, dtype=float)
        d[..., 3] += values[0]
        al[..., 3] += values[1]
        return state.replace(chain=state.chain.replace(d=d, alpha=al))


def test_every_column_equals_central_differences():
    robot = seed_robot()
    effects = ["geometric", "compliance", "transmission", "joint_scale", "thermal", _Stretch()]
    model = ErrorModel(robot, effects, stations=(3, 7), orientation=True)
    rng = np.random.default_rng(5)
    q = random_q(robot, 25, seed=6)
    cols = {"station": rng.choice([3.0, 7.0], len(q)), "temperature": rng.uniform(15, 35, len(q))}
    inputs = model.inputs(q, cols)
    p = _parameters(model, rng)
    _, _, JP, JW = model.predict_pose(inputs, p, jacobian=True)
    for k, name in enumerate(model.layout.names):
        h = 1e-6 * max(1.0, abs(p[k]))
        pp, pm = p.copy(), p.copy()
        pp[k] += h
        pm[k] -= h
        xp, Rp = model.predict_pose(inputs, pp)
        xm, Rm = model.predict_pose(inputs, pm)
        fd_p = (xp - xm) / (2 * h)
        fd_w = rotation_vector(Rp @ Rm.transpose(0, 2, 1)) / (2 * h)
        scale_p = max(1.0, np.abs(fd_p).max())
        scale_w = max(1.0, np.abs(fd_w).max())
        assert np.abs(JP[:, :, k] - fd_p).max() < 1e-6 * scale_p, name
        assert np.abs(JW[:, :, k] - fd_w).max() < 1e-6 * scale_w, name
    # the position Jacobian is the one predict gives
    np.testing.assert_array_equal(model.predict(inputs, p, jacobian=True)[1], JP)
    # with the tool point on axis 6, dtheta6 moves no point but turns the tool frame about z6
    p[model.layout.indices(["tx", "ty", "tz"])] = 0.0
    _, _, JP, JW = model.predict_pose(inputs, p, jacobian=True)
    k6 = model.layout.index("dtheta6")
    assert np.abs(JP[:, :, k6]).max() < 1e-12
    np.testing.assert_allclose(np.linalg.norm(JW[:, :, k6], axis=1), 1.0, atol=1e-12)


def test_a_plain_model_keeps_its_names_and_stations_are_checked():
    robot = seed_robot()
    plain = ErrorModel(robot)
    assert plain.layout.names[24:] == ("bx", "by", "bz", "brx", "bry", "brz", "tx", "ty", "tz")
    assert ErrorModel(robot, orientation=True).layout.names[-3:] == ("trx", "try", "trz")
    q = random_q(robot, 3)
    # one station named in the data: the model's single base, whatever its id
    one = ErrorModel(robot, stations=(4,))
    assert one.layout.names == plain.layout.names
    one.inputs(q, {"station": np.full(3, 4.0)})
    with pytest.raises(EffectError, match=r"station id\(s\) \[5\]"):
        one.inputs(q, {"station": np.array([4.0, 5.0, 4.0])})
    two = ErrorModel(robot, stations=(1, 2))
    with pytest.raises(EffectError, match="no 'station' column"):
        two.inputs(q)
    with pytest.raises(EffectError, match="need the geometric effect"):
        ErrorModel(robot, "compliance", stations=(1, 2))
    # a calibrated 6-DoF tool frame goes into the description, and back
    model = ErrorModel(robot, orientation=True)
    p = model.nominal()
    p[model.layout.indices(["trx", "try", "trz"])] = [0.1, -0.2, 0.3]
    desc = model.description(p)
    assert desc.effects["geometric"] == {"trx": 0.1, "try": -0.2, "trz": 0.3}
    back = ErrorModel(desc, orientation=True)
    np.testing.assert_allclose(back.nominal()[-3:], [0.1, -0.2, 0.3])
