"""Named scenarios as data: which hidden effects the plant carries and the ranges their magnitudes
are drawn from (docs/format.md, parameter names; the error model's ``typical`` tables), and the
draw of one episode's truth from a seed.

    truth = draw_truth("compliance", seed_robot(), rng, overrides={"compliance": {"c2": 8e-6}})
    truth.hidden        # the plant's physical magnitudes (stiffness, gaps, kappa, ...)
    truth.model, truth.params   # an ErrorModel and its true parameters, for evaluation / oracles

Overrides: ``{effect: {name: value}}`` where ``name`` is one parameter (``c2``, ``ts1``, ``bl3``,
``kappa``, ``dalpha2``...) or a family for all six joints (``c``, ``ts``, ``bl``...), and
``value`` is a number (fixed) or a ``(low, high)`` pair (drawn uniformly, the sign still random
where the effect's sign is not physical). ``{"geometric": {"scale": 0}}`` gives a perfect
geometry. Every draw is made whether or not it is overridden, so an override never shifts the other
draws of the same seed.

The ``cyclic`` scenario hides cyclic joint errors of higher orders like those of real arms (the
``cyclic`` effect: gears and encoders that turn faster than the joint, seen at its output):
:data:`CYCLIC_JOINTS` joints drawn at random, each with :data:`CYCLIC_ORDERS` distinct orders
drawn from 2-40 per turn, each of amplitude 0.05-0.3 mrad with a random phase. Overrides:
``amplitude`` (a number or a range, rad), ``order`` (a ``(low, high)`` range of orders) or
``terms``, the whole set ``((joint, order, a_s, a_c), ...)`` (rad: ``a_s sin(k q) + a_c cos(k
q)``). These draws are made in that scenario only and after every other draw, so no other
scenario's arm changes.

The ``payload`` scenario also draws how the operator *declares* the change to the controller (the
observation's payload): the start's payload is declared right, the change ``declare_delay``
seconds late (0.5-3 s) and off by ``declare_error`` kg (0-0.5 kg, either sign; the declared mass
is never below 0). ``overrides={"payload": {"declare_delay": 0, "declare_error": 0}}`` declares
it at once and right. These draws come last, so the arm of a seed is what it was without them.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from arm.description import RobotDescription
from arm.effects import Backlash, Compliance, Cyclic, JointScale, Thermal, Transmission
from arm.errormodel import ErrorModel
from arm.kinematics import gravity_torques
from arm.sampling import sample_parameters, sample_poses
from envs.errors import ScenarioError
from envs.plant import AMBIENT, HiddenEffects

__all__ = [
    "CYCLIC_JOINTS",
    "CYCLIC_ORDERS",
    "EFFECTS",
    "RANGES",
    "SCENARIOS",
    "EpisodeTruth",
    "Scenario",
    "ScenarioError",
    "draw_truth",
]

EFFECTS = ("geometric", "compliance", "transmission", "backlash", "thermal", "payload", "cyclic")
# the scenario "all": every effect the scenarios had before cyclic errors came (its arms stay)
_ALL = ("geometric", "compliance", "transmission", "backlash", "thermal", "payload")
CYCLIC_JOINTS = 3  # joints with cyclic errors in the cyclic scenario
CYCLIC_ORDERS = 2  # orders per such joint


@dataclass(frozen=True)
class Scenario:
    """A named set of hidden physical effects (a subset of :data:`EFFECTS`)."""

    name: str
    effects: tuple[str, ...]
    description: str = ""

    def __post_init__(self) -> None:
        bad = [e for e in self.effects if e not in EFFECTS]
        if bad:
            raise ScenarioError(f"scenario {self.name!r}: unknown effect(s) {bad}; known {EFFECTS}")

    @property
    def elastic(self) -> bool:
        """Whether the plant needs the two-hinge (elastic) drive train."""
        return bool(
            {"compliance", "transmission", "backlash", "payload", "cyclic"} & set(self.effects)
        )


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("nominal", (), "the arm is exactly its description: rigid, no errors"),
        Scenario("geometric", ("geometric",), "DH, base and tool errors; rigid joints"),
        Scenario(
            "compliance",
            ("geometric", "compliance"),
            "elastic joints: gravity deflects the links, fast motion vibrates",
        ),
        Scenario(
            "transmission",
            ("geometric", "transmission"),
            "gear eccentricity and gear-ratio error between motor and link (stiff mesh)",
        ),
        Scenario(
            "backlash",
            ("geometric", "backlash"),
            "a gap in each gear: loaded side under gravity, lagging under friction (stiff mesh)",
        ),
        Scenario(
            "thermal",
            ("geometric", "thermal"),
            "the links grow with the arm's temperature, which rises with motion",
        ),
        Scenario(
            "payload",
            ("geometric", "compliance", "payload"),
            "elastic joints with a payload that changes during the episode",
        ),
        Scenario("all", _ALL, "every effect at once (but the cyclic errors)"),
        Scenario(
            "cyclic",
            ("geometric", "cyclic"),
            "cyclic joint errors of higher orders (2-40 per turn) on three joints, like real "
            "arms' gears and encoders (stiff mesh)",
        ),
    )
}

# Magnitude ranges (SI units) of each effect's parameter families, drawn uniformly per episode.
# Signs: compliance, backlash, friction, kappa, heating are physical (positive); transmission and
# gear-ratio errors take a random sign. Geometric errors follow arm.effects.Geometric.typical.
RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "geometric": {"scale": (1.0, 1.0)},
    "compliance": {"c": Compliance.typical["c"]},
    "transmission": {
        "ts": Transmission.typical["ts"],
        "tc": Transmission.typical["tc"],
        "g": JointScale.typical["g"],
    },
    "backlash": {
        "bl": Backlash.typical["bl"],
        "bf": (1.0, 1.0),  # link-side bearing friction, times BEARING_FRICTION (N*m)
    },
    "thermal": {
        "kappa": Thermal.typical["kappa"],
        "temperature0": (20.0, 35.0),  # degC at the start of the episode
        # K per J of motor losses, and the time constant of cooling towards ambient: a working
        # arm settles 5-25 K above ambient within minutes (a real arm takes about an hour; the
        # time scale is shortened so that a 10 s episode shows the drift)
        "heating": (1e-3, 4e-3),
        "cooling_time": (60.0, 180.0),  # s
    },
    "payload": {
        "payload0": (0.0, 2.0),  # kg at the start
        "payload1": (0.0, 3.0),  # kg after the change
        "change_time": (3.0, 7.0),  # s
        # the operator's declaration of the change to the controller: late and wrong
        "declare_delay": (0.5, 3.0),  # s after the change
        "declare_error": (0.0, 0.5),  # kg, either sign
    },
    "cyclic": {
        "amplitude": Cyclic.typical["cs"],  # rad, of each order (random phase)
        "order": (2.0, 40.0),  # per turn, whole numbers
    },
}
# Link-side bearing friction (N*m) of the seed arm's class, joints 1..6: holds a link in its gap
# where gravity does not (an override of "bf"/"bf3" gives N*m directly).
BEARING_FRICTION = (4.0, 4.0, 3.0, 2.0, 2.0, 0.5)
_SIGNED = {"ts", "tc", "g", "declare_error"}
_PER_JOINT = {"c", "ts", "tc", "g", "bl", "bf"}


@dataclass
class EpisodeTruth:
    """Everything hidden about one episode's arm, for evaluation and oracle controllers only.

    ``true_robot``: the description with the sampled geometric errors folded in (DH rows, Hayati
    beta, base, tool) and the other effects' values in ``effects``; ``model``/``params``: an
    :class:`~arm.errormodel.ErrorModel` on the *nominal* arm whose effects approximate the
    plant's (geometric plus compliance ``c_i = 1/k_i``, transmission and joint_scale, backlash
    where friction holds a link and load_backlash where gravity does, thermal, the cyclic errors
    with their joints and orders, ``cyclic[2:7,31;...]``) and its true
    parameter vector laid out by ``model.layout``; ``hidden``: the plant's physical magnitudes;
    ``magnitudes``: the same as plain values by name (stiffness, gap, kappa, payload schedule...);
    ``declared_payload``: what the operator declares to the controller, ``((time, kg), ...)`` from
    time 0 (in the ``payload`` scenario late and wrong, see the module docstring).
    :meth:`conditions` gives the plant's exact temperature and payload now, once the env has bound
    it to its plant (:meth:`bind`), for oracle controllers.

    The model is exact (to about a micrometre) for a settled arm in the geometric, compliance,
    transmission, cyclic, thermal and payload scenarios. It is an approximation where physics does more
    than the lab's formulas: a joint whose gravity torque is close to its bearing friction sits
    anywhere in its gap; bearing friction holds an elastic link off its spring equilibrium by up to
    friction/stiffness (about 25 um at the tool in ``all``); a heavy link stopped abruptly runs
    ahead to the other flank; and in motion the links vibrate and lag.
    """

    scenario: str
    true_robot: RobotDescription
    model: ErrorModel
    params: np.ndarray
    hidden: HiddenEffects
    magnitudes: dict[str, Any] = field(default_factory=dict)
    declared_payload: tuple[tuple[float, float], ...] = ((0.0, 0.0),)
    _live: Callable[[], Mapping[str, float]] | None = field(default=None, repr=False, compare=False)

    def parameters(self) -> dict[str, float]:
        """The true parameters by name."""
        return self.model.layout.as_dict(self.params)

    def bind(self, live: Callable[[], Mapping[str, float]]) -> None:
        """Make :meth:`conditions` read the plant's state through ``live`` (the env does)."""
        self._live = live

    def conditions(self) -> dict[str, float]:
        """The plant's exact ``temperature`` (degC) and ``payload`` (kg) now; the episode's start
        values if no plant is bound."""
        if self._live is not None:
            return dict(self._live())
        return {
            "temperature": float(self.hidden.temperature0),
            "payload": float(self.true_robot.payload),
        }

    def declared_payload_at(self, t: float) -> float:
        """The payload (kg) declared to the controller at time ``t`` (s)."""
        mass = self.declared_payload[0][1]
        for when, m in self.declared_payload:
            if t + 1e-9 >= when:
                mass = m
        return float(mass)


def get_scenario(scenario: str | Scenario) -> Scenario:
    if isinstance(scenario, Scenario):
        return scenario
    try:
        return SCENARIOS[scenario]
    except KeyError:
        raise ScenarioError(
            f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}"
        ) from None


def _check_overrides(
    sc: Scenario, overrides: Mapping[str, Mapping[str, Any]], geometric: set[str]
) -> None:
    for effect, values in overrides.items():
        if effect not in EFFECTS:
            raise ScenarioError(f"override of unknown effect {effect!r}; known: {EFFECTS}")
        if effect not in sc.effects:
            raise ScenarioError(
                f"scenario {sc.name!r} has no {effect!r} effect (it has "
                f"{', '.join(sc.effects) or 'none'}); choose a scenario that does"
            )
        if not isinstance(values, Mapping):
            raise ScenarioError(f"overrides[{effect!r}] must be a mapping of name -> value")
        for name, v in values.items():
            if not _known(effect, name, geometric):
                raise ScenarioError(
                    f"unknown {effect} parameter {name!r}; known: {', '.join(_names(effect))}"
                )
            if effect == "cyclic" and name == "terms":
                _cyclic_terms(v)  # raises with the reason
                continue
            if effect == "cyclic" and name == "order" and not _order_range(v):
                raise ScenarioError(
                    "overrides['cyclic']['order'] must be a (low, high) pair of whole numbers "
                    f">= 1, got {v!r}"
                )
            pair_ok = effect != "geometric"  # a DH error is set, not drawn from a range
            if not _override_value_ok(v, pair_ok):
                want = "a finite number or a (low, high) pair" if pair_ok else "a finite number"
                raise ScenarioError(f"overrides[{effect!r}][{name!r}] must be {want}, got {v!r}")


def _override_value_ok(v: Any, pair_ok: bool) -> bool:
    """A finite number (not a string or a boolean that numpy would take), or a pair of them."""

    def number(x: Any) -> bool:
        return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)

    if number(v):
        return True
    pair = isinstance(v, (list, tuple, np.ndarray)) and len(v) == 2
    return pair_ok and pair and all(map(number, v))


def _order_range(v: Any) -> bool:
    ok = isinstance(v, (list, tuple)) and len(v) == 2
    return (
        ok
        and all(
            isinstance(x, numbers.Real)
            and not isinstance(x, bool)
            and math.isfinite(float(x))
            and float(x) == round(float(x))
            and float(x) >= 1
            for x in v
        )
        and v[0] <= v[1]
    )


def _cyclic_terms(v: Any) -> tuple[tuple[int, int, float, float], ...]:
    """The ``terms`` override, checked: ((joint 1..6, order >= 1, a_s, a_c), ...), each joint and
    order once."""
    want = "a sequence of (joint 1..6, order >= 1, a_s, a_c) in rad"
    if not isinstance(v, (list, tuple)) or not v:
        raise ScenarioError(f"overrides['cyclic']['terms'] must be {want}, got {v!r}")
    out = []
    for t in v:
        ok = isinstance(t, (list, tuple)) and len(t) == 4
        ok = ok and all(
            isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x) for x in t
        )
        ok = ok and t[0] == int(t[0]) and 1 <= t[0] <= 6 and t[1] == int(t[1]) and t[1] >= 1
        if not ok:
            raise ScenarioError(f"overrides['cyclic']['terms']: {t!r} is not {want}")
        out.append((int(t[0]), int(t[1]), float(t[2]), float(t[3])))
    pairs = [(j, k) for j, k, _, _ in out]
    if len(set(pairs)) != len(pairs):
        raise ScenarioError("overrides['cyclic']['terms'] names a joint and order twice")
    return tuple(sorted(out))


def _draw_cyclic(
    rng: np.random.Generator, over: Mapping[str, Any]
) -> tuple[tuple[int, int, float, float], ...]:
    """The cyclic scenario's errors: CYCLIC_JOINTS joints, CYCLIC_ORDERS distinct orders each,
    amplitudes from the range (or the override) with a random phase; drawn even when the
    ``terms`` override replaces them, to keep the stream."""
    lo, hi = (int(x) for x in over.get("order", RANGES["cyclic"]["order"]))
    if hi - lo + 1 < CYCLIC_ORDERS:
        raise ScenarioError(
            f"the cyclic scenario needs at least {CYCLIC_ORDERS} orders to draw from, got {lo}-{hi}"
        )
    joints = np.sort(rng.choice(np.arange(1, 7), CYCLIC_JOINTS, replace=False))
    drawn = []
    for j in joints:
        for k in np.sort(rng.choice(np.arange(lo, hi + 1), CYCLIC_ORDERS, replace=False)):
            amp = _draw(rng, "cyclic", "amplitude", over)
            phase = rng.uniform(0.0, 2.0 * math.pi)
            drawn.append((int(j), int(k), amp * math.cos(phase), amp * math.sin(phase)))
    if "terms" in over:
        return _cyclic_terms(over["terms"])
    return tuple(drawn)


def _names(effect: str) -> list[str]:
    if effect == "cyclic":
        return [*RANGES[effect], "terms"]
    if effect == "geometric":
        return ["scale", "dalpha1..6", "da1..6", "dtheta1..6", "dd1..6", "beta*", "bx..brz", "tx.."]
    fams = RANGES[effect]
    out = []
    for f in fams:
        out += [f, *(f"{f}{k}" for k in range(1, 7))] if f in _PER_JOINT else [f]
    return out


def _known(effect: str, name: str, geometric: set[str]) -> bool:
    if effect == "cyclic":
        return name in _names(effect)
    if effect == "geometric":
        return name == "scale" or name in geometric
    fams = RANGES[effect]
    if name in fams:
        return True
    fam, digit = name.rstrip("123456"), name[len(name.rstrip("123456")) :]
    return fam in _PER_JOINT and fam in fams and len(digit) == 1


def _lookup(over: Mapping[str, Any], family: str, joint: int | None) -> Any:
    if joint is not None and f"{family}{joint}" in over:
        return over[f"{family}{joint}"]
    return over.get(family)


def _draw(
    rng: np.random.Generator,
    effect: str,
    family: str,
    over: Mapping[str, Any],
    joint: int | None = None,
) -> float:
    """One magnitude: drawn from the range (always, to keep the stream), then overridden."""
    lo, hi = RANGES[effect][family]
    if family == "bf":
        if joint is None:
            raise ScenarioError("bearing friction (bf) is drawn per joint")
        lo, hi = lo * BEARING_FRICTION[joint - 1], hi * BEARING_FRICTION[joint - 1]
    value = rng.uniform(lo, hi)
    sign = rng.choice((-1.0, 1.0)) if family in _SIGNED else 1.0
    o = _lookup(over, family, joint)
    if o is None:
        return float(sign * value)
    o = np.atleast_1d(np.asarray(o, dtype=float))
    if o.size == 2:  # a range of magnitudes: reuse the same uniform draw
        u = (value - lo) / (hi - lo) if hi > lo else 0.5
        return float(sign * (o[0] + u * (o[1] - o[0])))
    return float(o[0])


def draw_truth(
    scenario: str | Scenario,
    robot: RobotDescription,
    rng: np.random.Generator,
    overrides: Mapping[str, Mapping[str, Any]] | None = None,
) -> EpisodeTruth:
    """One episode's hidden arm: the scenario's effects with magnitudes drawn from ``rng``.

    The steps: the geometric errors, every effect's magnitudes (each drawn in every scenario, in
    one order, so that a scenario's draws do not move when another effect is on; the cyclic
    terms last, in their scenario only), the plant's hidden effects, the error model that
    approximates the plant, and the magnitudes the episode reports."""
    sc = get_scenario(scenario)
    nominal = robot.to_modified()
    if overrides is not None and not isinstance(overrides, Mapping):
        raise ScenarioError(
            "overrides must be a mapping {effect: {parameter: value}}, e.g. "
            f"{{'compliance': {{'c2': 8e-6}}}}; got {overrides!r}"
        )
    overrides = dict(overrides or {})
    geo = ErrorModel(nominal, "geometric")
    _check_overrides(sc, overrides, set(geo.layout.names))
    on = set(sc.effects)
    p_geo = _draw_geometric(geo, rng, overrides.get("geometric", {}), "geometric" in on)
    d = _draw_effects(rng, overrides, on)
    hidden = _hidden_effects(d, on)
    kind = _backlash_kinds(nominal, d["bf"], hidden.payload0) if "backlash" in on else {}
    model = ErrorModel(nominal, _model_effects(on, kind, d["cyclic"]))
    values = dict(geo.layout.as_dict(p_geo))
    for family, key in (("c", "c"), ("ts", "ts"), ("tc", "tc"), ("g", "g"), ("bl", "gap")):
        values |= {f"{family}{k}": float(d[key][k - 1]) for k in range(1, 7)}
    values |= {f"lb{k}": float(d["gap"][k - 1]) for k in range(1, 7)}
    values["kappa"] = d["kappa"]
    values |= {f"cs{j}_{k}": a_s for j, k, a_s, _ in d["cyclic"]}
    values |= {f"cc{j}_{k}": a_c for j, k, _, a_c in d["cyclic"]}
    params = np.array([values[n] for n in model.layout.names], dtype=float)
    true_robot = model.description(params, name=f"{nominal.name}-true")
    true_robot = replace(true_robot, payload=hidden.payload0)
    mags, declared = _magnitudes(d, hidden, kind, on)
    return EpisodeTruth(sc.name, true_robot, model, params, hidden, mags, declared)


def _draw_geometric(
    geo: ErrorModel, rng: np.random.Generator, go: Mapping[str, Any], on: bool
) -> np.ndarray:
    """The geometric errors: always drawn (so that other effects keep their draws across
    scenarios), scaled by the override ``scale`` (zero when the scenario has none), any
    parameter overridden."""
    p_geo = sample_parameters(geo, rng)
    p0 = geo.nominal()
    scale = float(go.get("scale", 1.0)) if on else 0.0
    p_geo = p0 + scale * (p_geo - p0)
    for name, v in go.items():
        if name != "scale":
            p_geo[geo.layout.index(name)] = float(v)
    return p_geo


def _draw_effects(
    rng: np.random.Generator, overrides: Mapping[str, Mapping[str, Any]], on: set[str]
) -> dict[str, Any]:
    """Every effect's magnitudes, in one order (the cyclic terms last, in their scenario
    only: no other scenario's draws move); those out of range refused."""

    def per_joint(effect: str, family: str) -> np.ndarray:
        o = overrides.get(effect, {})
        return np.array([_draw(rng, effect, family, o, k) for k in range(1, 7)])

    d: dict[str, Any] = {
        "c": per_joint("compliance", "c"),
        "ts": per_joint("transmission", "ts"),
        "tc": per_joint("transmission", "tc"),
        "g": per_joint("transmission", "g"),
        "gap": per_joint("backlash", "bl"),
        "bf": per_joint("backlash", "bf"),
    }
    to = overrides.get("thermal", {})
    for key in ("kappa", "temperature0", "heating", "cooling_time"):
        d[key] = _draw(rng, "thermal", key, to)
    po = overrides.get("payload", {})
    for key in ("payload0", "payload1", "change_time", "declare_delay", "declare_error"):
        d[key] = _draw(rng, "payload", key, po)
    if d["declare_delay"] < 0:
        raise ScenarioError(f"payload declare_delay must be >= 0 s, got {d['declare_delay']}")
    d["cyclic"] = _draw_cyclic(rng, overrides.get("cyclic", {})) if "cyclic" in on else ()
    if "compliance" in on and np.any(d["c"] <= 0):
        raise ScenarioError(f"compliance {_named(d['c'] <= 0, 'c', d['c'])} must be > 0 rad/(N*m)")
    for family, text in (("gap", "bl"), ("bf", "bf")):
        if np.any(d[family] < 0):
            raise ScenarioError(f"backlash {_named(d[family] < 0, text, d[family])} must be >= 0")
    return d


def _named(bad: np.ndarray, family: str, values: np.ndarray) -> str:
    """The per-joint parameters that are out of range, by name: ``c2 = -1``."""
    return ", ".join(f"{family}{k + 1} = {values[k]:g}" for k in np.flatnonzero(bad))


def _hidden_effects(d: Mapping[str, Any], on: set[str]) -> HiddenEffects:
    """The plant's hidden effects: the drawn magnitudes of the scenario's effects, the others
    off."""

    def zeros() -> np.ndarray:
        return np.zeros(6)

    return HiddenEffects(
        stiffness=1.0 / d["c"] if "compliance" in on else np.full(6, np.inf),
        gap=d["gap"] if "backlash" in on else zeros(),
        bearing_friction=d["bf"] if "backlash" in on else zeros(),
        ts=d["ts"] if "transmission" in on else zeros(),
        tc=d["tc"] if "transmission" in on else zeros(),
        g=d["g"] if "transmission" in on else zeros(),
        kappa=d["kappa"] if "thermal" in on else 0.0,
        temperature0=d["temperature0"] if "thermal" in on else AMBIENT,
        heating=d["heating"] if "thermal" in on else 0.0,
        cooling_time=d["cooling_time"],
        payload0=d["payload0"] if "payload" in on else 0.0,
        payload_schedule=((d["change_time"], d["payload1"]),) if "payload" in on else (),
        cyclic=d["cyclic"],
    )


def _model_effects(on: set[str], kind: Mapping[int, str], cyclic: Sequence[Any]) -> list[str]:
    """The error model's effects that approximate the plant's (``kind``: each joint's backlash,
    held by friction or by the load)."""
    effects = ["geometric"]
    if "compliance" in on:
        effects.append("compliance")
    if "transmission" in on:
        effects += ["transmission", "joint_scale"]
    if "backlash" in on:
        fr = [k for k in range(1, 7) if kind[k] == "friction"]
        ld = [k for k in range(1, 7) if kind[k] == "load"]
        if fr:
            effects.append(f"backlash[{','.join(map(str, fr))}]")
        if ld:
            effects.append(f"load_backlash[{','.join(map(str, ld))}]")
    if "thermal" in on:
        effects.append("thermal")
    if cyclic:
        orders: dict[int, list[int]] = {}
        for j, k, _, _ in cyclic:
            orders.setdefault(j, []).append(k)
        effects.append(Cyclic(orders).label)
    return effects


def _magnitudes(
    d: Mapping[str, Any], hidden: HiddenEffects, kind: Mapping[int, str], on: set[str]
) -> tuple[dict[str, Any], tuple[tuple[float, float], ...]]:
    """The magnitudes an episode reports of its scenario's effects, and the payload schedule
    the operator declares (late, and wrong, in the payload scenario)."""
    mags: dict[str, Any] = {"stiffness": hidden.stiffness.copy()}
    if "compliance" in on:
        mags["compliance"] = d["c"].copy()
    if "transmission" in on:
        mags |= {"ts": d["ts"].copy(), "tc": d["tc"].copy(), "g": d["g"].copy()}
    if "backlash" in on:
        mags |= {"gap": d["gap"].copy(), "bearing_friction": d["bf"].copy(), "backlash_kind": kind}
    if "thermal" in on:
        mags |= {k: d[k] for k in ("kappa", "temperature0", "heating", "cooling_time")}
    if d["cyclic"]:
        mags["cyclic"] = d["cyclic"]
    declared: tuple[tuple[float, float], ...] = ((0.0, hidden.payload0),)
    if "payload" in on:
        declared += (
            (
                d["change_time"] + d["declare_delay"],
                max(0.0, d["payload1"] + d["declare_error"]),
            ),
        )
        mags |= {
            "payload0": d["payload0"],
            "payload_schedule": hidden.payload_schedule,
            "declared_payload": declared,
        }
    return mags, declared


def _backlash_kinds(
    robot: RobotDescription, friction: np.ndarray, payload: float
) -> dict[int, str]:
    """Per joint, whether gravity ("load") or friction ("friction") usually holds its link in
    the gap: gravity where the median |gravity torque| over the workspace exceeds twice the
    bearing friction. A fixed pose sample, so that the answer depends on the arm only."""
    q = sample_poses(robot, 256, np.random.default_rng(12345))
    tau = np.median(np.abs(gravity_torques(robot, q, payload=payload)), axis=0)
    return {k: ("load" if tau[k - 1] > 2.0 * friction[k - 1] else "friction") for k in range(1, 7)}
