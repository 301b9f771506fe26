"""The agents' and the tool interface's settings are declared (:mod:`arm.constraints`), not
checked by hand: a value beyond each declaration is refused where it is given, with one line that
names the setting and says what it must be; the value at a closed bound is taken."""

from __future__ import annotations

import re
from typing import Any

import pytest

from agents.errors import AgentError
from agents.model_selection import SELECTION_SETTINGS, SequentialSelection, ShadowEstimator
from agents.mpc import MPC_SETTINGS, MPCAgent
from agents.online_calibration import (
    BUFFER_SETTINGS,
    ESTIMATOR_SETTINGS,
    MeasurementBuffer,
    RecursiveLeastSquares,
)
from agents.policy import POLICY_SETTINGS, PolicyIO
from agents.reference import REFERENCE_SETTINGS, CalibratedAgent, NominalAgent
from envs.errors import EnvOptionError
from envs.wrappers import TOOL_STEP_MM, ToolDisplacement
from tests.test_declared_rules import invalid_values

# who takes each declared setting: a call that makes it with that one setting given
MAKERS = {
    ("mpc", "solver"): lambda v: MPCAgent(solver=v),
    ("mpc", "horizon"): lambda v: MPCAgent(horizon=v),
    ("mpc", "error_decay"): lambda v: MPCAgent(error_decay=v),
    ("mpc", "buffer"): lambda v: MPCAgent(buffer=v),
    ("mpc", "sigma"): lambda v: MPCAgent(sigma=v),
    ("mpc", "forgetting"): lambda v: MPCAgent(forgetting=v),
    ("rls", "sigma"): lambda v: RecursiveLeastSquares(None, sigma=v),
    ("rls", "forgetting"): lambda v: RecursiveLeastSquares(None, forgetting=v),
    ("shadow", "sigma"): lambda v: ShadowEstimator(None, sigma=v),
    ("shadow", "forgetting"): lambda v: ShadowEstimator(None, 1e-5, forgetting=v),
    ("selection", "alpha"): lambda v: SequentialSelection(None, [], 1e-5, alpha=v),
    ("selection", "burn_in"): lambda v: SequentialSelection(None, [], 1e-5, burn_in=v),
    ("buffer", "capacity"): lambda v: MeasurementBuffer(capacity=v),
    ("policy", "variant"): lambda v: PolicyIO(variant=v),
    ("policy", "offset_mm"): lambda v: PolicyIO(offset_mm=v),
    ("policy", "tool_step_mm"): lambda v: PolicyIO(tool_step_mm=v),
    ("nominal", "gain"): lambda v: NominalAgent(gain=v),
    ("calibrated", "calibration_seconds"): lambda v: CalibratedAgent(calibration_seconds=v),
}
DECLARED = {
    "mpc": MPC_SETTINGS | ESTIMATOR_SETTINGS,
    "rls": ESTIMATOR_SETTINGS,
    "shadow": ESTIMATOR_SETTINGS,
    "selection": SELECTION_SETTINGS,
    "buffer": BUFFER_SETTINGS,
    "policy": POLICY_SETTINGS,
    "nominal": {"gain": REFERENCE_SETTINGS["gain"]},
    "calibrated": {"calibration_seconds": REFERENCE_SETTINGS["calibration_seconds"]},
}
CASES = [
    (who, name, value)
    for who, declared in DECLARED.items()
    for name, c in declared.items()
    for value in invalid_values(c)
]


def test_every_declared_setting_has_a_maker():
    assert {(w, n) for w, d in DECLARED.items() for n in d} == set(MAKERS)


@pytest.mark.parametrize(("who", "name", "value"), CASES, ids=lambda v: repr(v))
def test_a_value_beyond_its_declaration_is_refused_naming_the_setting(who, name, value):
    if who == "calibrated" and isinstance(value, str):
        value = "each-phase"  # a string it takes is its one word, 'each_phase'
    with pytest.raises(AgentError) as exc:
        MAKERS[who, name](value)
    message = str(exc.value)
    assert "\n" not in message
    assert message.startswith(f"{name} must "), message


@pytest.mark.parametrize(
    ("make", "said"),
    [
        (lambda: MPCAgent(horizon=0), "horizon must be an integer >= 1, got 0"),
        (lambda: MPCAgent(solver="gurobi"), "solver must be one of daqp, osqp, qpoases, proxqp"),
        (lambda: MPCAgent(error_decay=1.0), "error_decay must lie in [0, 1), got 1.0"),
        (lambda: MeasurementBuffer(0), "capacity must be an integer >= 1, got 0"),
        (lambda: NominalAgent(gain=0), "gain must lie in (0, 1], got 0"),
        (lambda: PolicyIO(offset_mm=0), "offset_mm must be positive, got 0"),
    ],
)
def test_the_refusal_says_what_the_setting_must_be(make, said):
    with pytest.raises(AgentError, match=re.escape(said)):
        make()


def test_every_bad_setting_is_named_at_once():
    with pytest.raises(AgentError, match=r"horizon .*; error_decay .*; buffer "):
        MPCAgent(horizon=0, error_decay=2.0, buffer=-1)


def test_the_closed_bounds_are_taken():
    MPCAgent(horizon=1, error_decay=0.0, buffer=0, forgetting=1.0)
    NominalAgent(gain=1.0)
    CalibratedAgent(calibration_seconds=0.0)
    CalibratedAgent(calibration_seconds="each_phase")
    MeasurementBuffer(1)


class _Task:
    robot = None


@pytest.mark.parametrize("value", invalid_values(TOOL_STEP_MM))
def test_the_tool_interface_refuses_a_step_beyond_its_declaration(value):
    with pytest.raises(EnvOptionError, match="tool_step_mm must be positive"):
        ToolDisplacement(_Task(), step_mm=value)


def _plant_cases() -> list[tuple[str, Any]]:
    from arm.constraints import constraints_of
    from envs.plant import HiddenEffects

    declared = constraints_of(HiddenEffects)
    return [(k, v) for k in ("cooling_time", "payload0") for v in invalid_values(declared[k][0][0])]


@pytest.mark.parametrize(("name", "value"), _plant_cases())
def test_the_plants_scalars_are_refused_beyond_their_declaration(name, value):
    from envs.plant import HiddenEffects, PlantError

    with pytest.raises(PlantError, match=rf"^{name} must "):
        HiddenEffects(**{name: value})
