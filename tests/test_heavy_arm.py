"""The shipped heavy arm (``r2000ic_like``): the data sheet's reach and, in closed form, the gravity
torque its masses and payload put on joint 2 at the home pose."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arm.description import load_robot
from arm.kinematics import Chain, gravity_torques, tool_points

HOME = np.array([[0.0, -math.pi / 2, 0.0, 0.0, 0.0, 0.0]])  # upper arm upright, forearm level


def test_the_heavy_arm_has_the_data_sheets_lengths():
    arm = load_robot("r2000ic_like")
    flange = tool_points(Chain.from_description(arm), HOME, np.zeros(3))[0]
    # J1 offset + forearm + flange ahead; J2 height + upper arm + J3 offset up (mm on the sheet)
    assert flange == pytest.approx([0.312 + 1.280 + 0.215, 0.0, 0.670 + 1.075 + 0.225], abs=1e-9)
    assert arm.payload == 165.0


def test_the_heavy_arms_gravity_torque_on_joint_2_at_home_in_closed_form():
    """Each mass's lever about joint 2's axis at home is its horizontal distance from it: the
    forearm's centre 0.45 m ahead, the wrist's bodies at 1.28 m (less 0.3 m for link 4's centre),
    the flange's 0.245 m and the payload's 0.465 m beyond the wrist."""
    arm = load_robot("r2000ic_like")
    levers = {180.0: 0.45, 60.0: 1.28 - 0.3, 25.0: 1.28, 5.0: 1.28 + 0.215 + 0.03}
    expected = 9.81 * (sum(m * x for m, x in levers.items()) + 165.0 * (1.28 + 0.215 + 0.25))
    tau = gravity_torques(arm, HOME)[0]
    assert abs(tau[1]) == pytest.approx(expected, rel=1e-9)
    assert abs(tau[2]) == pytest.approx(expected, rel=1e-9)  # the upper arm upright adds none
