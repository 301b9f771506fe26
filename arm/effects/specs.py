"""Effects from their specifications: ``compliance``, ``compliance[2,3]``,
``cyclic[2:17,29]``, ``"geometric,compliance[2,3]"``; and the registered effects the diagnosis
tests whole.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence

from arm.effect_api import EffectError
from arm.effects.base import Effect
from arm.effects.joint_angle import Cyclic
from arm.effects.registry import EFFECTS, load_entry_points

__all__ = ["candidate_effects", "make_effect", "parse_effects", "union_of"]

_EFFECT_PATTERN = re.compile(r"^\s*([a-z][a-z0-9_]*)\s*(?:\[([^\]]*)\])?\s*$")


def make_effect(spec: str | Effect) -> Effect:
    """An effect from its name, ``compliance`` or restricted to joints, ``compliance[2,3]``
    (the cyclic effect names joints and orders, ``cyclic[2:17,29]``)."""
    if isinstance(spec, Effect):
        return spec
    m = _EFFECT_PATTERN.match(spec)
    if not m:
        raise EffectError(
            f"bad effect specification {spec!r}; expected e.g. 'compliance', "
            "'compliance[2,3]' or 'cyclic[2:17,29]'"
        )
    name, brackets = m.group(1), m.group(2)
    if name not in EFFECTS:
        load_entry_points()
    if name not in EFFECTS:
        raise EffectError(f"unknown effect {name!r}; known: {', '.join(sorted(EFFECTS))}")
    return EFFECTS[name].from_spec(brackets, spec)


def candidate_effects() -> list[str]:
    """The registered effects the diagnosis tests whole (all but the scanned ones)."""
    return [n for n, cls in EFFECTS.items() if not cls.scan_only]


def parse_effects(spec: str | Sequence[str | Effect]) -> list[Effect]:
    """``"geometric,compliance[2,3]"`` or a list of names/effects -> effect instances."""
    if isinstance(spec, str):
        depth = 0
        for ch in spec:
            depth += {"[": 1, "]": -1}.get(ch, 0)
            if depth not in (0, 1):
                break
        if depth:
            what = {1: "an unclosed '['", 2: "a '[' inside another"}.get(
                depth, "a ']' without its '['"
            )
            raise EffectError(f"bad effect specification {spec!r}: {what}")
        parts = re.findall(r"[^,\[]+(?:\[[^\]]*\])?", spec)
        spec = [p.strip() for p in parts if p.strip()]
    effects = [make_effect(s) for s in spec]
    names = [e.name for e in effects]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise EffectError(f"effect(s) listed twice: {', '.join(sorted(dup))}")
    return effects


def union_of(effects: Iterable[str | Effect]) -> list[Effect]:
    """One effect per name, in the order first met, over what every effect of that name covers:
    ``backlash[1]`` and ``backlash[5]`` give ``backlash[1,5]``; one on all joints covers all; a
    cyclic error's orders are joined per joint. The one union of effects: a diagnosis's
    suggestion, the bag's model of its draws, an online model widened by a candidate."""
    merged: dict[str, Effect] = {}
    for e in map(make_effect, effects):
        merged[e.name] = e if e.name not in merged else _joined(merged[e.name], e)
    return list(merged.values())


def _joined(a: Effect, b: Effect) -> Effect:
    """One effect of ``a``'s kind over what either covers: the joints of both (all where either
    takes all), a cyclic effect's orders per joint."""
    if isinstance(a, Cyclic) and isinstance(b, Cyclic):
        js = {*a.orders, *b.orders}
        return Cyclic({j: [*a.orders.get(j, ()), *b.orders.get(j, ())] for j in js})
    if a.joints is None or b.joints is None:
        return type(a)()
    return type(a)(joints=[*a.joints, *b.joints])
