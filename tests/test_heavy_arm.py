"""The shipped heavy arm (``r2000ic_like``): the data sheet's reach and, in closed form, the gravity
torque its masses and payload put on joint 2 at the home pose."""

from __future__ import annotations

import numpy as np
import pytest

from arm.description import load_robot
from arm.kinematics import Chain, gravity_torques, tool_points

HOME = np.zeros((1, 6))  # upper arm upright (theta2 = q2 - 90 deg), forearm level


def test_the_heavy_arm_has_the_data_sheets_lengths():
    arm = load_robot("r2000ic_like")
    flange = tool_points(Chain.from_description(arm), HOME, np.zeros(3))[0]
    # J1 offset + forearm + flange ahead; J2 height + upper arm + J3 offset up (mm on the sheet)
    assert flange == pytest.approx([0.312 + 1.280 + 0.215, 0.0, 0.670 + 1.075 + 0.225], abs=1e-9)
    assert arm.payload == 165.0


def test_the_heavy_arms_gravity_torque_on_joint_2_at_home_in_closed_form():
    """Each mass's lever about joint 2's axis at home is its horizontal distance from it: the
    forearm's centre 0.1 m ahead, link 4's 0.55 m short of the wrist (1.28 m), link 5's 0.05 m
    beyond it, the flange's 0.215 m less 0.03 m, the payload's 0.15 m beyond the flange."""
    arm = load_robot("r2000ic_like")
    levers = [(180.0, 0.1), (70.0, 1.28 - 0.55), (25.0, 1.28 + 0.05), (6.0, 1.28 + 0.215 - 0.03)]
    expected = 9.81 * (sum(m * x for m, x in levers) + 165.0 * (1.28 + 0.215 + 0.15))
    tau = gravity_torques(arm, HOME)[0]
    assert abs(tau[1]) == pytest.approx(expected, rel=1e-9)
    assert abs(tau[2]) == pytest.approx(expected, rel=1e-9)  # the upper arm upright adds none
