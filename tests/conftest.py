"""Shared fixtures: the seed arm and a few other arms whose structure the kinematics must handle."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arm.description import Joint, RobotDescription, seed_robot


def _arm(name, rows, convention="modified", limits_deg=None, tools=((0.0, 0.0, 0.0),)):
    joints = []
    for k, (alpha, a, d, offset) in enumerate(rows):
        lo, hi = (-180.0, 180.0) if limits_deg is None else limits_deg[k]
        joints.append(
            Joint(
                alpha=math.radians(alpha),
                a=a,
                d=d,
                theta_offset=math.radians(offset),
                lower=math.radians(lo),
                upper=math.radians(hi),
            )
        )
    return RobotDescription(name, tuple(joints), tools=tools, convention=convention)


def rokae_arm() -> RobotDescription:
    """The nominal modified-DH table of the arm in data/real/rokae-laser-tracker (alpha deg, a and d
    in m, theta offsets -90 and 180 deg) and its controller's limits: a description, not data."""
    rows = [
        (0, 0.0, 0.487, 0),
        (-90, 0.085, 0.0, -90),
        (0, 0.640, 0.0, 0),
        (-90, 0.205, 0.720, 0),
        (90, 0.0, 0.0, 0),
        (-90, 0.0, 0.075, 180),
    ]
    limits = [(-100, 100), (-90, 100), (-100, 60), (-100, 100), (-90, 90), (-120, 120)]
    return _arm("rokae", rows, limits_deg=limits, tools=((-0.0005, -0.0006, 0.2399),))


def puma_arm() -> RobotDescription:
    """PUMA 560 in standard DH (Corke): a spherical wrist with a lateral offset d_3."""
    rows = [
        (90, 0.0, 0.0, 0),
        (0, 0.4318, 0.0, 0),
        (-90, 0.0203, 0.15005, 0),
        (90, 0.0, 0.4318, 0),
        (-90, 0.0, 0.0, 0),
        (0, 0.0, 0.0, 0),
    ]
    limits = [(-160, 160), (-225, 45), (-45, 225), (-110, 170), (-100, 100), (-266, 266)]
    return _arm("puma560", rows, "standard", limits, tools=((0.0, 0.0, 0.1),))


def ur5_arm() -> RobotDescription:
    """UR5 in standard DH: no spherical wrist (d_5 != 0), so no closed form of the supported kind."""
    rows = [
        (90, 0.0, 0.089159, 0),
        (0, -0.425, 0.0, 0),
        (0, -0.39225, 0.0, 0),
        (90, 0.0, 0.10915, 0),
        (-90, 0.0, 0.09465, 0),
        (0, 0.0, 0.0823, 0),
    ]
    return _arm("ur5", rows, "standard", [(-360, 360)] * 6, tools=((0.0, 0.0, 0.05),))


@pytest.fixture(scope="session")
def seed():
    return seed_robot()


@pytest.fixture(scope="session")
def rokae():
    return rokae_arm()


@pytest.fixture(scope="session")
def puma():
    return puma_arm()


@pytest.fixture(scope="session")
def ur5():
    return ur5_arm()


@pytest.fixture
def user_effects():
    """The effect registry (``arm.effects.EFFECTS``) as it was before the test: a module a test
    loads registers its effects for the rest of the process."""
    from arm.effects import EFFECTS

    before = dict(EFFECTS)
    yield EFFECTS
    EFFECTS.clear()
    EFFECTS.update(before)


def random_q(robot: RobotDescription, n: int, seed: int = 0) -> np.ndarray:
    """``n`` joint configurations uniform within the limits, from a fixed seed."""
    return np.random.default_rng(seed).uniform(robot.lower, robot.upper, (n, 6))
