"""Is the identified model an arm at all? A fit can reach a tiny RMS with a wrong model: data in
metres read as millimetres make every DH length shrink a thousandfold, another robot's file
turns a joint by 180 degrees. The RMS says nothing; the parameters do.

Every *identified* parameter of the arm itself is compared with the largest plausible magnitude
of its kind, declared by its effect (:meth:`arm.effects.Effect.plausible_bound`):

==================================  ============================================================
kind                                bound
==================================  ============================================================
DH length error (da, dd)            10 mm up to a UR10's size (reach 1.6 m by
                                    :attr:`~arm.description.RobotDescription.reach`), in
                                    proportion to the reach beyond (19 mm for a FANUC R-2000iC)
DH angle error (dalpha, dtheta)     50 mrad (2.9 deg) at any size; Hayati's beta likewise
base transform, tool offsets        none: a tracker stands metres away, a reflector far off the
                                    flange
a catalogued effect                 10 times the top of its typical range (compliance 1e-4
                                    rad/(N·m), gear terms 5e-3, gaps 6e-3 rad, kappa 2.3e-4/K)
a user's effect                     its ``bounds``, else 10 times its ``typical`` range, else
                                    none; the families it names in ``lengths`` scale with the
                                    arm as the DH lengths do
==================================  ============================================================

An effect's bound is its :meth:`~arm.effects.Effect.plausible_bound` of the parameter and the
arm's size (:class:`arm.effect_api.ArmSize`: reach, payload); a user's effect that overrides
``plausible_bound(self, name)`` without the size is asked as it was written.

A parameter beyond its bound is an error naming it and the likely cause (the scale of the
lengths says "units", angles near 90 or 180 degrees say "convention or another robot");
``accept_large=True`` (``--accept-large``) lets an expert through, and the result lists what it
accepted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from arm.effect_api import ArmSize
from arm.effects import plausible_bound_of
from arm.errormodel import ErrorModel
from arm.params import parse_parameter_name

__all__ = ["Implausible", "implausible"]

_LENGTH_FIELD = {"da": "a", "dd": "d"}


@dataclass(frozen=True)
class Implausible:
    """One identified parameter beyond the bound of its kind (SI units)."""

    name: str
    effect: str
    value: float
    bound: float
    unit: str

    def text(self) -> str:
        if self.unit == "m":
            return f"{self.name} = {self.value * 1e3:+.4g} mm (bound {self.bound * 1e3:.3g} mm)"
        if self.unit == "rad":
            return f"{self.name} = {self.value * 1e3:+.4g} mrad (bound {self.bound * 1e3:.3g} mrad)"
        unit = f" {self.unit}" if self.unit else ""
        return f"{self.name} = {self.value:+.4g}{unit} (bound {self.bound:.3g}{unit})"

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "effect": self.effect,
            "value": self.value,
            "bound": self.bound,
            "unit": self.unit,
        }


def implausible(
    model: ErrorModel, params: np.ndarray, identifiable: np.ndarray
) -> list[Implausible]:
    """The identified parameters of ``model`` (those marked ``identifiable``; fixed ones sit at
    their nominal) whose magnitude exceeds the bound their effect declares for an arm of the
    model's size (:class:`arm.effect_api.ArmSize`)."""
    lay = model.layout
    size = ArmSize.of(model.robot)
    out = []
    for e in model.effects:
        sl = lay.slice(e.name)
        for k, name in zip(range(sl.start, sl.stop), lay.names[sl], strict=True):
            if not identifiable[k]:
                continue
            bound = plausible_bound_of(e, name, size)
            if bound is None or not abs(params[k]) > bound:
                continue
            parsed = parse_parameter_name(name)
            unit = parsed.unit if parsed is not None else ""
            out.append(Implausible(name, e.label, float(params[k]), float(bound), unit))
    return out


#: implausible values at most this many times their bound are a model's strain, not a unit slip
NEAR_BOUND = 2.0


def likely_cause(model: ErrorModel, items: list[Implausible]) -> str:
    """The likeliest reason for these implausible parameters, from their pattern."""
    rob = model.robot
    ratios = []
    angles = []
    for it in items:
        p = parse_parameter_name(it.name)
        if p is None:
            continue
        if p.kind == "row" and p.family in _LENGTH_FIELD and p.number is not None:
            nominal = getattr(rob.joints[p.number - 1], _LENGTH_FIELD[p.family])
            if abs(nominal) > 0.02:  # a real link, not a zero offset
                ratios.append((nominal + it.value) / nominal)
        elif p.kind in ("row", "beta") and it.unit == "rad":
            angles.append(it.value)
    if ratios:
        r = float(np.median(ratios))
        if 0.5e-3 < r < 2e-3:
            return (
                "the measured points are about 1000 times smaller than the arm: x, y, z in "
                "metres read as millimetres (--length-unit m)"
            )
        if 500 < r < 2000:
            return (
                "the measured points are about 1000 times larger than the arm: x, y, z in "
                "millimetres read as metres (--length-unit mm)"
            )
        if 0.02 < abs(r) < 0.05 or 20 < abs(r) < 50:
            return "lengths in inches or another unit: check the data's and the arm's units"
    if all(abs(it.value) <= NEAR_BOUND * it.bound for it in items):
        # just beyond the bound: no unit slip (those are 57 or 1000 times off) but the model
        # leaning on parameters the poses barely separate to explain what it lacks
        return (
            "an effect the model lacks (sixaxis lab diagnose), taken up by parameters the poses "
            "barely separate; or another robot's file or convention"
        )
    quarter = [a for a in angles if abs(a) > 0.3 and _near_quarter_turn(a)]
    if quarter:
        return (
            "a DH angle off by a multiple of 90 degrees: the robot file's convention (modified "
            "or standard DH, its `convention` key), its joint offsets, or another robot's file"
        )
    if angles and not ratios:
        return (
            "DH angles far from the drawing: another robot's file, another convention, or "
            "joint angles in degrees read as radians (--angle-unit deg)"
        )
    if any(parse_parameter_name(it.name) is None or it.effect != "geometric" for it in items):
        return (
            "an effect absorbing what the model lacks, or the arm's units (masses in kg, "
            "temperatures in degC) or the data's (--length-unit, --angle-unit)"
        )
    return "the data's units (--length-unit, --angle-unit), another robot's file or convention"


def _near_quarter_turn(a: float) -> bool:
    k = round(a / (math.pi / 2))
    return k != 0 and abs(a - k * math.pi / 2) < 0.15
