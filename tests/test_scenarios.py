"""The scenarios' draws: the cyclic scenario's hidden errors (joints, orders, amplitudes), its
overrides, and that adding it moved no other scenario's arm."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from arm import seed_robot
from envs.scenarios import (
    CYCLIC_JOINTS,
    CYCLIC_ORDERS,
    SCENARIOS,
    ScenarioError,
    draw_truth,
)

ROBOT = seed_robot()


@pytest.mark.parametrize("seed", range(5))
def test_cyclic_scenario_draws_several_orders_on_several_joints(seed):
    truth = draw_truth("cyclic", ROBOT, np.random.default_rng(seed))
    terms = truth.hidden.cyclic
    assert len(terms) == CYCLIC_JOINTS * CYCLIC_ORDERS
    joints = {j for j, _, _, _ in terms}
    assert len(joints) == CYCLIC_JOINTS and joints <= set(range(1, 7))
    for j in joints:
        orders = [k for jj, k, _, _ in terms if jj == j]
        assert len(set(orders)) == CYCLIC_ORDERS and all(2 <= k <= 40 for k in orders)
    for _, _, a_s, a_c in terms:
        assert 5e-5 <= math.hypot(a_s, a_c) <= 3e-4
    # the oracle's truth describes it: the effect with those joints and orders, their values
    values = truth.parameters()
    for j, k, a_s, a_c in terms:
        assert values[f"cs{j}_{k}"] == a_s and values[f"cc{j}_{k}"] == a_c
    assert truth.magnitudes["cyclic"] == terms
    assert SCENARIOS["cyclic"].elastic  # the gear mesh carries them
    again = draw_truth("cyclic", ROBOT, np.random.default_rng(seed))
    assert again.hidden.cyclic == terms


def test_cyclic_draws_come_last_and_move_no_other_scenario():
    """The cyclic scenario's geometric errors are the geometric scenario's of the same seed, and
    the scenario "all" has no cyclic errors: no arm of the other scenarios changed."""
    for seed in range(3):
        cyc = draw_truth("cyclic", ROBOT, np.random.default_rng(seed)).parameters()
        geo = draw_truth("geometric", ROBOT, np.random.default_rng(seed)).parameters()
        assert {n: cyc[n] for n in geo} == geo
    assert "cyclic" not in SCENARIOS["all"].effects
    assert draw_truth("all", ROBOT, np.random.default_rng(0)).hidden.cyclic == ()


def test_cyclic_overrides_set_amplitudes_orders_or_every_term():
    rng = np.random.default_rng
    fixed = draw_truth("cyclic", ROBOT, rng(1), overrides={"cyclic": {"amplitude": 2e-4}})
    assert all(math.hypot(a, c) == pytest.approx(2e-4) for _, _, a, c in fixed.hidden.cyclic)
    low = draw_truth("cyclic", ROBOT, rng(1), overrides={"cyclic": {"order": (2, 3)}})
    assert {k for _, k, _, _ in low.hidden.cyclic} == {2, 3}
    terms = ((2, 17, 1e-4, 0.0), (5, 33, 0.0, -2e-4))
    given = draw_truth("cyclic", ROBOT, rng(1), overrides={"cyclic": {"terms": terms}})
    assert given.hidden.cyclic == terms
    assert [e.label for e in given.model.effects] == ["geometric", "cyclic[2:17;5:33]"]
    # the other draws of the seed stay where they were
    plain = draw_truth("cyclic", ROBOT, rng(1))
    assert given.parameters()["dalpha2"] == plain.parameters()["dalpha2"]


@pytest.mark.parametrize(
    ("over", "message"),
    [
        ({"terms": ((7, 3, 1e-4, 0.0),)}, "is not a sequence of"),
        ({"terms": ((2, 0, 1e-4, 0.0),)}, "is not a sequence of"),
        ({"terms": ((2, 3, 1e-4, 0.0), (2, 3, 0.0, 1e-4))}, "names a joint and order twice"),
        ({"terms": ()}, "must be a sequence of"),
        ({"order": (3, 3)}, "needs at least 2 orders"),
        ({"order": (2.5, 9)}, "must be a (low, high) pair of whole numbers"),
        ({"amplitude": "big"}, "must be a finite number or a (low, high) pair"),
        ({"phase": 1.0}, "unknown cyclic parameter 'phase'"),
    ],
)
def test_bad_cyclic_overrides_are_refused(over, message):
    with pytest.raises(ScenarioError, match=message.replace("(", r"\(").replace(")", r"\)")):
        draw_truth("cyclic", ROBOT, np.random.default_rng(0), overrides={"cyclic": over})


@pytest.mark.parametrize(
    ("scenario", "overrides", "said"),
    [
        ("compliance", {"compliance": {"c2": -1.0}}, "compliance c2 = -1 must be > 0"),
        ("backlash", {"backlash": {"bl3": -0.001}}, "backlash bl3 = -0.001 must be >= 0"),
        ("backlash", {"backlash": {"bf5": -2.0}}, "backlash bf5 = -2 must be >= 0"),
    ],
)
def test_an_override_out_of_range_is_named_by_its_parameter(scenario, overrides, said):
    """The parameter a user wrote (c2), not the whole drawn array."""
    with pytest.raises(ScenarioError, match=re.escape(said)):
        draw_truth(scenario, ROBOT, np.random.default_rng(1), overrides=overrides)
