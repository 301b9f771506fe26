"""The catalogue's joint-angle effects (:class:`arm.effects.base.JointAngleEffect`): compliance,
transmission, cyclic errors of chosen orders (and what an order usually is), joint scale,
backlash and gravity-loaded backlash.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np

from arm.description import RobotDescription
from arm.effect_api import EffectError, ModelInputs
from arm.effects.base import Effect, JointAngleEffect
from arm.params import parse_parameter_name

__all__ = [
    "FAST_PARTS",
    "MAX_ORDER",
    "Backlash",
    "Compliance",
    "Cyclic",
    "JointScale",
    "LoadBacklash",
    "Transmission",
    "cyclic_readings",
    "order_reading",
]


class Compliance(JointAngleEffect):
    name = "compliance"
    extrapolates = True  # a law of the arm over its whole range
    terms = ("c",)
    typical = {"c": (3e-6, 1e-5)}
    positive = True
    needs_masses = True
    description = "elastic joints: theta_i = q_i + c_i * tau_i(q), tau the gravity torque"

    def basis(self, inputs, joint, term):
        return inputs.tau[:, joint - 1]


class Transmission(JointAngleEffect):
    name = "transmission"
    terms = ("ts", "tc")
    typical = {"ts": (1e-4, 5e-4), "tc": (1e-4, 5e-4)}
    description = "gear eccentricity: theta_i = q_i + ts_i sin(q_i) + tc_i cos(q_i)"

    def basis(self, inputs, joint, term):
        qj = inputs.q[:, joint - 1]
        return np.sin(qj) if term == "ts" else np.cos(qj)


MAX_ORDER = 1000  # the highest order per turn a cyclic term may have


def order_reading(k: int) -> str:
    """What a cyclic joint error of order ``k`` (k cycles per turn of the joint) usually is."""
    if k == 1:
        return (
            "once per turn: an eccentricity of the gear or the encoder on the joint's output "
            "(the catalogue's transmission)"
        )
    if k == 2:
        return (
            "twice per turn: an elliptical part on the output side (a strain-wave gear's "
            "flexspline and circular spline, an oval bearing race) or an encoder tilted on its "
            "shaft"
        )
    if k == 3:
        return "three times per turn: a three-lobed bearing race or wave generator on the output"
    half = f"{k / 2:g}"
    return (
        f"{k} times per turn of the joint: a part that turns faster than the joint, seen at its "
        f"output. A strain-wave gear's error repeats twice per turn of its wave generator (order "
        f"{k} if the wave generator turns {half} times per output turn); a magnetic encoder's with "
        f"its pole pairs (p pole pairs on a shaft turning {k}/p times per output turn); a gear "
        f"stage's with its teeth (order {k}: {k} teeth on a wheel that turns once per output "
        "turn, or fewer on a faster one)"
    )


FAST_PARTS = (
    "a part that turns faster than the joint, seen at its output: a strain-wave gear's error "
    "repeats twice per turn of its wave generator (order 2r if it turns r times per output "
    "turn), a magnetic encoder's with its pole pairs (p pole pairs on a shaft turning s times "
    "per output turn: order p*s), a gear stage's with its teeth"
)


def cyclic_readings(orders: Mapping[int, Sequence[int]]) -> list[str]:
    """What the cyclic errors of ``orders`` (joint -> orders per turn) usually are, one line per
    kind: orders 1, 2 and 3 each their own, the higher ones together."""
    by_order: dict[int, list[int]] = {}
    for j, ks in sorted(orders.items()):
        for k in ks:
            by_order.setdefault(int(k), []).append(int(j))
    out = []
    for k in (1, 2, 3):
        if k in by_order:
            js = ", ".join(map(str, by_order[k]))
            out.append(f"order {k} (joint {js}): {order_reading(k)}")
    high = sorted(k for k in by_order if k > 3)
    if high:
        out.append(f"orders {', '.join(map(str, high))}: {FAST_PARTS}")
    return out


_CYCLIC_SYNTAX = (
    "cyclic[2:17,29] (orders 17 and 29 of joint 2); several joints: cyclic[2:17,29;4:2]"
)


class Cyclic(JointAngleEffect):
    """Cyclic joint errors of chosen orders per joint: ``theta_j = q_j + sum_k cs{j}_{k}
    sin(k q_j) + cc{j}_{k} cos(k q_j)``, for the orders k of joint j named in the
    specification, ``cyclic[2:17,29;4:2,40]`` (orders 17 and 29 of joint 2, 2 and 40 of joint
    4; ``a-b`` is a range of orders). An order k repeats k times per turn of the joint: order 1
    is the catalogue's ``transmission``; the higher orders come from the gears and encoders that
    turn faster than the joint (:func:`order_reading`). ``lab.spectral`` finds which orders a data
    set needs; the diagnosis does not test this effect whole (``scan_only``)."""

    name = "cyclic"
    typical = {"cs": (5e-5, 3e-4), "cc": (5e-5, 3e-4)}
    description = (
        "cyclic joint errors: theta_j = q_j + sum over the orders k of joint j of "
        "cs{j}_{k} sin(k q_j) + cc{j}_{k} cos(k q_j)"
    )
    scan_only = True
    example = "cyclic[2:17,29;4:2]"

    def __init__(
        self,
        orders: Mapping[int, Sequence[int]] | None = None,
        joints: Sequence[int] | None = None,
    ) -> None:
        if orders is None or joints is not None:
            raise EffectError(f"effect 'cyclic' needs its joints and orders: {_CYCLIC_SYNTAX}")
        clean: dict[int, tuple[int, ...]] = {}
        for j, ks in orders.items():
            if not (isinstance(j, int | np.integer) and 1 <= j <= 6):
                raise EffectError(f"effect 'cyclic': joints must be within 1..6, got {j!r}")
            ks = tuple(sorted({int(k) for k in ks}))
            if not ks:
                raise EffectError(f"effect 'cyclic': joint {j} has no orders; {_CYCLIC_SYNTAX}")
            bad = [k for k in ks if not 1 <= k <= MAX_ORDER]
            if bad:
                raise EffectError(
                    f"effect 'cyclic': orders of joint {j} must lie within 1..{MAX_ORDER}, got "
                    f"{', '.join(map(str, bad))}"
                )
            clean[int(j)] = ks
        if not clean:
            raise EffectError(f"effect 'cyclic' needs at least one joint: {_CYCLIC_SYNTAX}")
        super().__init__(joints=sorted(clean))
        self.orders: dict[int, tuple[int, ...]] = dict(sorted(clean.items()))

    @classmethod
    def from_spec(cls, brackets: str | None, spec: str = "") -> Effect:
        if brackets is None or not brackets.strip():
            raise EffectError(
                f"effect specification {spec or 'cyclic'!r}: cyclic needs its joints and "
                f"orders: {_CYCLIC_SYNTAX}"
            )
        orders: dict[int, list[int]] = {}
        for part in brackets.split(";"):
            m = re.fullmatch(r"\s*([0-9]+)\s*:\s*([0-9,\s-]+?)\s*", part)
            if not m:
                raise EffectError(
                    f"bad joint and orders {part.strip()!r} in effect specification {spec!r}; "
                    f"expected {_CYCLIC_SYNTAX}"
                )
            j = int(m.group(1))
            if j in orders:
                raise EffectError(f"joint {j} is named twice in effect specification {spec!r}")
            ks: list[int] = []
            for item in m.group(2).split(","):
                item = item.strip()
                r = re.fullmatch(r"([0-9]+)(?:\s*-\s*([0-9]+))?", item)
                if not r:
                    raise EffectError(
                        f"bad order {item!r} of joint {j} in effect specification {spec!r}; "
                        "an order is a whole number (17) or a range (2-8)"
                    )
                lo, hi = int(r.group(1)), int(r.group(2) or r.group(1))
                if hi < lo or hi - lo > MAX_ORDER:
                    raise EffectError(
                        f"bad range of orders {item!r} of joint {j} in effect specification "
                        f"{spec!r}"
                    )
                ks += range(lo, hi + 1)
            orders[j] = ks
        return cls(orders)

    @classmethod
    def from_parameters(cls, names: Sequence[str]) -> Effect:
        orders: dict[int, list[int]] = {}
        for n in names:
            p = parse_parameter_name(n)
            if p is None or p.family not in ("cs", "cc") or p.number is None or p.order is None:
                raise EffectError(f"{n!r} is not a parameter of the cyclic effect (cs2_17, cc2_17)")
            orders.setdefault(p.number, []).append(p.order)
        return cls(orders)

    @property
    def label(self) -> str:
        return (
            "cyclic[" + ";".join(f"{j}:{_orders_text(ks)}" for j, ks in self.orders.items()) + "]"
        )

    def parameter_terms(self) -> list[tuple[int, str]]:
        return [(j, f"{t}{k}") for j, ks in self.orders.items() for k in ks for t in "sc"]

    def parameter_names(self, robot: RobotDescription, targets: Sequence[int]) -> list[str]:
        return [f"c{t[0]}{j}_{t[1:]}" for j, t in self.parameter_terms()]

    def basis(self, inputs, joint, term):
        angle = int(term[1:]) * inputs.q[:, joint - 1]
        return np.sin(angle) if term[0] == "s" else np.cos(angle)


def _orders_text(ks: Sequence[int]) -> str:
    """``1-4,17,29``: runs of three or more consecutive orders as ranges."""
    out: list[str] = []
    i = 0
    while i < len(ks):
        j = i
        while j + 1 < len(ks) and ks[j + 1] == ks[j] + 1:
            j += 1
        if j - i >= 2:
            out.append(f"{ks[i]}-{ks[j]}")
        else:
            out += [str(k) for k in ks[i : j + 1]]
        i = j + 1
    return ",".join(out)


class JointScale(JointAngleEffect):
    name = "joint_scale"
    # Not a law over the whole range as fitted: a line in q_i identified over part of a joint's
    # range is its local slope, which no fit can tell from that of the joint's other errors
    # (the UR10's series B, its joint scales carried 2-6 rad beyond its range, missed series D
    # by 1.11x the geometric fit's). Outside the fitted range it is left out (lab.domain).
    terms = ("g",)
    typical = {"g": (1e-4, 5e-4)}
    description = "gear-ratio error: theta_i = q_i + g_i q_i"

    def basis(self, inputs, joint, term):
        return inputs.q[:, joint - 1]


class Backlash(JointAngleEffect):
    name = "backlash"
    extrapolates = True  # a law of the arm over its whole range
    terms = ("bl",)
    typical = {"bl": (3e-4, 6e-4)}
    positive = True
    columns = ("dir1", "dir2", "dir3", "dir4", "dir5", "dir6")
    description = "friction-held backlash: theta_i = q_i - bl_i/2 dir_i (lags the last motion)"

    def basis(self, inputs, joint, term):
        return -0.5 * inputs.column(f"dir{joint}")


class LoadBacklash(JointAngleEffect):
    """Where gravity loads a joint, its link rests against the side of the gap that the gravity
    torque pushes it to: ``theta_i = q_i + lb_i/2 sign(tau_i(q))``.

    Near zero torque gravity picks no side (friction and the last motion do): a pose whose
    torque about an active joint lies within :attr:`torque_band` (0.5 N·m) is *ambiguous*
    (:meth:`ambiguous`). The law keeps the sign there: a pose that landed on the other side
    misses by the whole gap, stands out, and the lab's outlier screening leaves it out and names
    it as ambiguous. (A smooth transition, ``tanh(tau / tau0)``, was measured to do worse: it
    halves such a pose's miss, into the range where it is neither fitted nor flagged, and
    mis-models every pose within the band of an arm whose gravity does pick the side.)"""

    name = "load_backlash"
    extrapolates = True  # a law of the arm over its whole range
    terms = ("lb",)
    typical = {"lb": (3e-4, 6e-4)}
    positive = True
    needs_masses = True
    description = "gravity-loaded backlash: theta_i = q_i + lb_i/2 sign(tau_i(q))"

    torque_band: ClassVar[float] = 0.5  # N·m: within it gravity does not pick the side
    # Below this the gravity torque is rounding noise (tau_1 and tau_6 of the seed arm are zero
    # by construction but come out as +-1e-15): its sign must not pick a side of the gap.
    zero_torque: ClassVar[float] = 1e-9  # N·m

    def basis(self, inputs, joint, term):
        tau = inputs.tau[:, joint - 1]
        return 0.5 * np.where(np.abs(tau) < self.zero_torque, 0.0, np.sign(tau))

    def ambiguous(self, inputs: ModelInputs) -> np.ndarray:
        """(N, 6): the poses whose gravity torque about an active joint lies within the band
        (and is not zero by construction): which side of the gap they rest on, gravity does
        not say."""
        out = np.zeros((inputs.n, 6), dtype=bool)
        for j in self.active_joints():
            t = np.abs(inputs.tau[:, j - 1])
            out[:, j - 1] = (t >= self.zero_torque) & (t < self.torque_band)
        return out

    def ambiguity_note(self, inputs: ModelInputs, i: int) -> str | None:
        amb = np.flatnonzero(self.ambiguous(inputs)[i])
        if not amb.size:
            return None
        taus = ", ".join(f"tau{j + 1} = {inputs.tau[i, j]:+.3g} N·m" for j in amb)
        return (
            f"ambiguous for {self.name}: {taus}, within +-{self.torque_band:g} N·m, where "
            "gravity does not pick the side of the gap"
        )
