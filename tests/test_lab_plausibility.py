"""The plausibility of an identified model (issue 13, item 1): a stated bound per kind of
parameter, declared by its effect (a user's too), the likely cause named, an expert let through."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import pytest

from arm.effects import (
    EFFECTS,
    Backlash,
    Compliance,
    Geometric,
    JointAngleEffect,
    LoadBacklash,
    Thermal,
    Transmission,
)
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from lab import FitError, fit
from lab.plausibility import implausible, likely_cause
from tests._lab_data import campaign


def test_the_bound_of_each_kind():
    g = Geometric()
    for name, bound in (
        ("da2", 0.01),
        ("dd4", 0.01),
        ("dalpha3", 0.05),
        ("dtheta6", 0.05),
        ("beta2", 0.05),
    ):
        assert g.plausible_bound(name) == bound, name
    for name in ("bx", "brz", "tx", "tz", "tx1", "ty2"):  # the base and the tools: never
        assert g.plausible_bound(name) is None, name
    # the catalogue: ten times the top of the typical range
    assert Compliance().plausible_bound("c2") == pytest.approx(1e-4)
    assert Transmission().plausible_bound("ts1") == pytest.approx(5e-3)
    assert Backlash().plausible_bound("bl3") == pytest.approx(6e-3)
    assert LoadBacklash().plausible_bound("lb2") == pytest.approx(6e-3)
    assert Thermal().plausible_bound("kappa") == pytest.approx(2.3e-4)


class _Wobble(JointAngleEffect):
    name = "wobble_test"
    terms = ("w",)
    bounds: ClassVar[dict[str, float | None]] = {"w": 2e-3}

    def basis(self, inputs, joint, term):
        return np.sin(3 * inputs.q[:, joint - 1])


class _Unbounded(JointAngleEffect):
    name = "unbounded_test"
    terms = ("u",)

    def basis(self, inputs, joint, term):
        return np.cos(3 * inputs.q[:, joint - 1])


def test_a_user_effect_declares_its_own_bound_or_has_none():
    assert _Wobble().plausible_bound("w2") == 2e-3
    assert _Unbounded().plausible_bound("u2") is None  # neither bounds nor typical


def test_implausible_lists_identified_parameters_beyond_their_bound(seed):
    model = ErrorModel(seed, "geometric,compliance")
    p = model.nominal()
    lay = model.layout
    p[lay.index("da3")] = -0.6195
    p[lay.index("dtheta2")] = -np.pi
    p[lay.index("bz")] = -0.593  # the base: exempt however far
    p[lay.index("c2")] = 5e-3
    p[lay.index("c3")] = 5e-3
    ident = np.ones(len(lay), dtype=bool)
    ident[lay.index("c3")] = False  # fixed at nominal: not identified, not judged
    got = {b.name: b for b in implausible(model, p, ident)}
    assert set(got) == {"da3", "dtheta2", "c2"}
    assert got["da3"].text() == "da3 = -619.5 mm (bound 10 mm)"
    assert got["dtheta2"].text() == "dtheta2 = -3142 mrad (bound 50 mrad)"
    assert "rad/(N·m)" in got["c2"].text()
    # the pattern says why: lengths a thousandfold smaller, a joint turned by 180 degrees
    assert "1000 times smaller" in likely_cause(model, [got["da3"]])
    assert "multiple of 90 degrees" in likely_cause(model, [got["dtheta2"]])


def test_fit_refuses_an_implausible_model_unless_accepted(seed):
    c = campaign(seed, "geometric", seed=21)
    d = c.measure(120)
    in_mm_read_as_m = MeasurementSet(d.q, d.xyz * 1e-3, d.columns, "m_as_mm.csv")
    with pytest.raises(FitError, match=r"m_as_mm.csv: not a plausible model of 'seed'.*da3"):
        fit(in_mm_read_as_m, seed, "geometric")
    res = fit(in_mm_read_as_m, seed, "geometric", accept_large=True)
    assert "da3" in {b.name for b in res.implausible}
    assert res.to_dict()["implausible"][0]["bound"] == 0.01
    assert "accepted beyond the plausible bound" in res.summary()
    # an ordinary calibration has nothing to accept
    assert not fit(d, seed, "geometric").implausible


def test_user_effect_bound_applies_in_a_fit(seed, monkeypatch):
    monkeypatch.setitem(EFFECTS, _Wobble.name, _Wobble)
    c = campaign(seed, "geometric", seed=22)
    d = c.measure(150)
    # a 3rd harmonic of 5 mrad on joint 2 (beyond the effect's 2 mrad bound)
    model = ErrorModel(seed, ["geometric", _Wobble(joints=[2])])
    p = model.nominal()
    p[: len(c.params)] = c.params
    p[model.layout.index("w2")] = 5e-3
    xyz = model.predict(model.inputs(d.q, d.columns), p)
    data = MeasurementSet(d.q, xyz, d.columns, "wobble.csv")
    with pytest.raises(FitError, match=r"w2 = \+0.005 \(bound 0.002\)"):
        fit(data, seed, ["geometric", _Wobble(joints=[2])])
    res = fit(data, seed, ["geometric", _Wobble(joints=[2])], accept_large=True)
    assert res["w2"] == pytest.approx(5e-3, rel=1e-6)
