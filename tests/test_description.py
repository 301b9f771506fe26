"""Robot descriptions: the shipped seed arm is the one of docs/format.md, TOML round trips in any
units, and bad files are refused naming the key at fault."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from arm.description import (
    DescriptionError,
    Joint,
    RobotDescription,
    load_robot,
)
from arm.so3 import rotation_matrix, rotation_vector
from tests.conftest import puma_arm, rokae_arm

# docs/format.md, the seed arm, transcribed: alpha_{i-1} (deg), a_{i-1} (m), d_i (m), limits (rad),
# mass (kg), com.
SEED_TABLE = [
    (0, 0.0, 0.080, (-2.97, 2.97), 15.0, (0, 0, -0.04)),
    (-90, 0.132, 0.0, (-2.80, 0.30), 12.0, (0.31, 0, 0)),
    (0, 0.620, 0.0, (-1.60, 1.60), 8.0, (0.12, 0.10, 0)),
    (-90, 0.1634, 0.350, (-3.30, 3.30), 3.0, (0, 0, -0.10)),
    (90, 0.0, 0.0, (-2.10, 2.10), 2.0, (0, 0, 0)),
    (-90, 0.0, 0.2356, (-6.28, 6.28), 0.5, (0, 0, 0.02)),
]


def test_seed_toml_is_spec_section_1(seed):
    assert seed.name == "seed" and seed.convention == "modified"
    for j, (alpha, a, d, (lo, hi), mass, com) in zip(seed.joints, SEED_TABLE, strict=True):
        assert j.alpha == pytest.approx(math.radians(alpha), abs=1e-15)
        assert (j.a, j.d, j.lower, j.upper, j.mass) == (a, d, lo, hi, mass)
        assert j.com == pytest.approx(com, abs=0)
        assert j.theta_offset == 0.0 and j.beta == 0.0
    assert seed.tools == ((0.0, 0.0, 0.050),)
    assert seed.gravity == (0.0, 0.0, -9.81)
    assert seed.payload == 0.0
    assert seed.base_translation == (0, 0, 0) and seed.base_rotation == (0, 0, 0)
    assert seed.parallel_rows() == (3,)
    assert load_robot() == seed and load_robot("seed") == seed


def _assert_same(a: RobotDescription, b: RobotDescription, rtol: float = 1e-14) -> None:
    assert (a.name, a.convention, a.effects) == (b.name, b.convention, b.effects)
    for ja, jb in zip(a.joints, b.joints, strict=True):
        for key in ("alpha", "a", "d", "theta_offset", "lower", "upper", "mass", "beta"):
            assert getattr(ja, key) == pytest.approx(getattr(jb, key), rel=rtol, abs=1e-15), key
        assert ja.com == pytest.approx(jb.com, rel=rtol, abs=1e-15)
    for key in ("tools", "base_translation", "base_rotation", "flange", "gravity"):
        assert np.allclose(getattr(a, key), getattr(b, key), rtol=rtol, atol=1e-15), key
    assert a.payload == b.payload


def _rich_arm() -> RobotDescription:
    """Every field set: standard DH with a flange, offsets, beta, base, several tools, effects."""
    arm = puma_arm()
    joints = list(arm.joints)
    joints[2] = replace(joints[2], beta=1.2e-3, mass=4.5, com=(0.01, -0.02, 0.03))
    return replace(
        arm,
        joints=tuple(joints),
        tools=((0.0, 0.0, 0.1), (0.02, 0.01, 0.12)),
        payload=1.5,
        base_translation=(2.5, -1.0, 0.3),
        base_rotation=(0.1, -0.2, 1.4),
        effects={"compliance": {"c2": 6e-6, "c3": 4e-6}, "thermal": {"kappa": 1.2e-5}},
    )


@pytest.mark.parametrize(
    ("length_unit", "angle_unit"), [("m", "deg"), ("mm", "rad"), ("mm", "deg")]
)
@pytest.mark.parametrize("make", [_rich_arm, rokae_arm, lambda: load_robot("seed")])
def test_toml_round_trip(tmp_path, make, length_unit, angle_unit):
    arm = make()
    path = tmp_path / "arm.toml"
    arm.save(path, length_unit=length_unit, angle_unit=angle_unit)
    text = path.read_text()
    assert f'length_unit = "{length_unit}"' in text and f'angle_unit = "{angle_unit}"' in text
    _assert_same(load_robot(path), arm)


def test_units_are_read_as_stated():
    text = (
        """
    name = "mm-deg"
    length_unit = "mm"
    angle_unit = "deg"
    [[joints]]
    alpha = 0
    a = 0
    d = 487
    limits = [-100, 100]
    com = [0, 0, -40]
    """
        + "\n".join(
            f"[[joints]]\nalpha = {al}\na = {a}\nd = {d}\ntheta_offset = {th}"
            for al, a, d, th in [
                (-90, 85, 0, -90),
                (0, 640, 0, 0),
                (-90, 205, 720, 0),
                (90, 0, 0, 0),
                (-90, 0, 75, 180),
            ]
        )
        + "\n[[tools]]\npoint = [0, 0, 240]\n"
    )
    arm = RobotDescription.from_toml(text)
    assert arm.joints[0].d == pytest.approx(0.487)
    assert arm.joints[0].lower == pytest.approx(math.radians(-100))
    assert arm.joints[0].com == pytest.approx((0, 0, -0.04))
    assert arm.joints[1].theta_offset == pytest.approx(-math.pi / 2)
    assert arm.joints[5].theta_offset == pytest.approx(math.pi)
    assert arm.tools[0] == pytest.approx((0, 0, 0.24))
    # limits default to +-180 deg in the file's own unit
    assert arm.joints[2].upper == pytest.approx(math.pi)


def _seed_text() -> str:
    return load_robot("seed").to_toml()


def _replace_line(text: str, old: str, new: str, count: int = 1) -> str:
    assert old in text, old
    return text.replace(old, new, count)


BAD = [
    (lambda t: t + "\n[[joints\n", "not valid TOML"),
    (lambda t: _replace_line(t, 'length_unit = "m"', 'length_unit = "inch"'), "length_unit"),
    (lambda t: _replace_line(t, 'angle_unit = "deg"', 'angle_unit = "grad"'), "angle_unit"),
    (lambda t: _replace_line(t, 'convention = "modified"', 'convention = "craig"'), "convention"),
    (lambda t: _replace_line(t, "d = 0.08\n", ""), "joint 1: missing key 'd'"),
    (lambda t: _replace_line(t, "a = 0.62\n", 'a = "0.62"\n'), "joint 3: 'a' must be a number"),
    (lambda t: _replace_line(t, "mass = 8.0", "mass = -8.0"), "joint 3 mass"),
    (
        lambda t: _replace_line(t, "limits = [\n    -160.42", "limits = [\n    160.42"),
        "joint 2 limits",
    ),
    (lambda t: _replace_line(t, "d = 0.2356", "d = nan"), "joint 6: 'd' is not finite"),
    (
        lambda t: _replace_line(t, "com = [\n    0.31", "com = [\n    0.31,\n    1.0"),
        "joint 2: 'com' must be a list of 3",
    ),
    (
        lambda t: t[: t.rindex("[[joints]]")] + "[[tools]]\npoint = [0.0, 0.0, 0.05]\n",
        "exactly 6 times",
    ),
    (
        lambda t: _replace_line(t, "point = [", "point = [\n    1.0,"),
        "tool 1: 'point' must be a list of 3",
    ),
    (lambda t: t + "\n[effects]\ncompliance = 3\n", "[effects.compliance] must be a table"),
    (
        lambda t: t + '\n[effects.compliance]\nc2 = "big"\n',
        "effects.compliance: 'c2' must be a number",
    ),
    (
        lambda t: t + "\n[base]\ntranslation = [1.0, 2.0]\n",
        "base: 'translation' must be a list of 3",
    ),
    (lambda t: _replace_line(t, 'name = "seed"', "name = 7"), "'name' must be a string"),
    (lambda t: _replace_line(t, "payload = 0.0", "payload = true"), "'payload' must be a number"),
    (
        lambda t: _replace_line(t, "theta_offset = 0.0", "thetaoffset = 5.0"),
        "joint 1: unknown key(s) 'thetaoffset'",
    ),
    (
        lambda t: t.replace("[[tools]]\npoint", "[[tools]]\npoint_mm = [1.0, 2.0, 3.0]\npoint"),
        "tool 1: unknown key(s) 'point_mm'",
    ),
    (lambda t: "mass_unit = 'kg'\n" + t, "unknown key(s) 'mass_unit'"),
]


@pytest.mark.parametrize(("edit", "message"), BAD, ids=[m for _, m in BAD])
def test_bad_description_names_the_key(tmp_path, edit, message):
    path = tmp_path / "bad.toml"
    path.write_text(edit(_seed_text()))
    with pytest.raises(DescriptionError) as err:
        load_robot(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)


def test_joints_must_be_tables(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("joints = [1, 2, 3, 4, 5, 6]\n")
    with pytest.raises(DescriptionError, match=r"joint 1: must be a table"):
        load_robot(path)


def test_unknown_robot_and_missing_file(tmp_path):
    with pytest.raises(DescriptionError, match="unknown robot 'kuka'"):
        load_robot("kuka")
    with pytest.raises(DescriptionError, match="not found"):
        load_robot(tmp_path / "none.toml")


def test_description_validates_itself():
    j = Joint(alpha=0.0, a=0.0, d=0.1)
    with pytest.raises(DescriptionError, match="6 joints expected"):
        RobotDescription("five", (j,) * 5)
    with pytest.raises(DescriptionError, match="at least one tool point"):
        RobotDescription("x", (j,) * 6, tools=())


def test_rotation_vector_round_trip():
    rng = np.random.default_rng(0)
    r = rng.normal(size=(50, 3))
    r *= (rng.uniform(0, math.pi - 1e-6, 50) / np.linalg.norm(r, axis=1))[:, None]
    R = rotation_matrix(r)
    np.testing.assert_allclose(
        R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-14
    )
    np.testing.assert_allclose(rotation_vector(R), r, atol=1e-12)
    # about z by 90 deg turns x into y
    np.testing.assert_allclose(
        rotation_matrix(np.array([0, 0, math.pi / 2])) @ [1, 0, 0], [0, 1, 0], atol=1e-15
    )


def test_standard_conversion_moves_coms_and_tools_into_modified_frames():
    """Standard frame i = modified frame i . TransX(a_i) RotX(alpha_i): a point given in the
    standard frame keeps its place in space."""
    arm = _rich_arm()
    m = arm.to_modified()
    assert m.convention == "modified" and m.flange == (arm.joints[5].a, arm.joints[5].alpha)
    assert m.to_modified() is m
    j = arm.joints[2]
    c, s = math.cos(j.alpha), math.sin(j.alpha)
    x, y, z = j.com
    assert m.joints[2].com == pytest.approx((x + j.a, c * y - s * z, s * y + c * z))
    assert [r.alpha for r in m.joints[1:]] == [r.alpha for r in arm.joints[:5]]
    assert [r.a for r in m.joints[1:]] == [r.a for r in arm.joints[:5]]
