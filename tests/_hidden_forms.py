"""Simulated campaigns with a hidden effect whose *form* the catalogue lacks (issue 11): the seed
arm with random geometric errors of the typical size, 15 um tracker noise per axis, and one of

* ``harmonic3_q1``: a 3rd harmonic on joint 1, theta1 = q1 + s sin(3 q1) + c cos(3 q1), ~3e-4 rad;
* ``cubic_q2``: a hardening gear mesh on joint 2, theta2 = q2 + c tau2 + k tau2^3 (c = 5e-6
  rad/(N·m), k = 4e-10 rad/(N·m)^3);
* ``thermal_zero_q3``: joint 3's encoder zero drifting by 3e-5 rad/K while the arm warms from 20
  to 32 degC over the campaign (a first-order warm-up in time ``t``);
* ``harmonic2_q2``: a 2nd harmonic on joint 2, ~4e-4 rad.

The truth is written as effect classes here (never registered): the lab must find the form from
the data alone. ``campaign`` gives the calibration set, a held-out set measured on the same arm,
and the true coefficients keyed by the discovered parameter names the lab uses."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arm.description import RobotDescription
from arm.effects import JointAngleEffect, parse_effects
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from arm.sampling import sample_parameters, sample_poses

SIGMA = 15e-6  # m per axis
CAMPAIGN_S = 4 * 3600.0  # the campaign's duration
WARM_UP_S = 3600.0  # the arm's thermal time constant


class _Harmonic(JointAngleEffect):
    name = "_hidden_harmonic"
    m = 1
    terms = ("s", "c")

    def basis(self, inputs, joint, term):
        q = inputs.q[:, joint - 1]
        return np.sin(self.m * q) if term == "s" else np.cos(self.m * q)


class _Harmonic2(_Harmonic):
    name = "_hidden_harmonic2"
    m = 2


class _Harmonic3(_Harmonic):
    name = "_hidden_harmonic3"
    m = 3


class _Cubic(JointAngleEffect):
    name = "_hidden_cubic"
    terms = ("c", "k")

    def basis(self, inputs, joint, term):
        tau = inputs.tau[:, joint - 1]
        return tau if term == "c" else tau**3


class _ThermalZero(JointAngleEffect):
    name = "_hidden_thermal_zero"
    terms = ("z",)

    def basis(self, inputs, joint, term):
        return inputs.column("temperature") - 20.0


@dataclass(frozen=True)
class Form:
    effect: type[JointAngleEffect]
    joint: int
    values: dict[str, float]  # the truth effect's parameters
    truth: dict[str, float]  # the same, by the names discovery gives its terms
    expressions: frozenset[str]  # the terms discovery must find


FORMS = {
    "harmonic3_q1": Form(
        _Harmonic3,
        1,
        {"s1": 2.4e-4, "c1": -1.8e-4},
        {"k_sin3q1": 2.4e-4, "k_cos3q1": -1.8e-4},
        frozenset({"sin(3*q1)", "cos(3*q1)"}),
    ),
    "cubic_q2": Form(
        _Cubic,
        2,
        {"c2": 5e-6, "k2": 4e-10},
        {"k_tau2": 5e-6, "k_taucube_2": 4e-10},
        frozenset({"tau2", "tau2^3"}),
    ),
    "thermal_zero_q3": Form(
        _ThermalZero,
        3,
        {"z3": 3e-5},
        {"k_temp_q3": 3e-5},
        frozenset({"(temperature - 20)"}),
    ),
    "harmonic2_q2": Form(
        _Harmonic2,
        2,
        {"s2": 3.2e-4, "c2": 2.4e-4},
        {"k_sin2q2": 3.2e-4, "k_cos2q2": 2.4e-4},
        frozenset({"sin(2*q2)", "cos(2*q2)"}),
    ),
}


@dataclass
class HiddenCampaign:
    data: MeasurementSet
    validation: MeasurementSet
    form: Form | None


def _measure(truth, p, robot, n, rng, sigma) -> MeasurementSet:
    q = sample_poses(robot, n, rng)
    t = np.sort(rng.uniform(0.0, CAMPAIGN_S, n))
    cols = {
        "t": t,
        # warming from 20 to 32 degC, first order, plus 0.1 K of sensor noise
        "temperature": 32.0 - 12.0 * np.exp(-t / WARM_UP_S) + rng.normal(0.0, 0.1, n),
    }
    cols |= {f"dir{j}": rng.choice([-1.0, 1.0], n) for j in range(1, 7)}
    xyz = truth.predict(truth.inputs(q, cols), p) + rng.normal(0.0, sigma, (n, 3))
    return MeasurementSet(q, xyz, cols, "simulated")


def campaign(
    robot: RobotDescription,
    form: str | None,
    seed: int = 0,
    n: int = 200,
    n_validation: int = 300,
    effects: str = "geometric",
    sigma: float = SIGMA,
) -> HiddenCampaign:
    """Measure an arm with random geometric errors (and the other ``effects``, at the low end of
    their range) and the hidden ``form`` (None: nothing hidden)."""
    rng = np.random.default_rng(seed)
    fm = None if form is None else FORMS[form]
    specs: list = parse_effects(effects)
    if fm is not None:
        specs.append(fm.effect(joints=[fm.joint]))
    truth = ErrorModel(robot, specs)
    geo = truth.layout.names[truth.layout.slice("geometric")]
    p = sample_parameters(truth, rng, only=geo)
    hidden = "geometric" if fm is None else fm.effect.name
    others = [
        n
        for e in truth.effects
        if e.name not in ("geometric", hidden)
        for n in truth.layout.names[truth.layout.slice(e.name)]
    ]
    if others:
        low = sample_parameters(truth, rng, level="low", only=others)
        idx = truth.layout.indices(others)
        p[idx] = low[idx]
    if fm is not None:
        p[truth.layout.indices(list(fm.values))] = list(fm.values.values())
    data = _measure(truth, p, robot, n, rng, sigma)
    val = _measure(truth, p, robot, n_validation, rng, sigma)
    return HiddenCampaign(data, val, fm)
