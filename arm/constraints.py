"""Declared constraints on options and settings, checked all at once.

An options class says what each value may be beside its name, instead of a hand-written ``if`` per
value (scikit-learn's ``_param_validation`` is the model): a ``Literal`` type is a choice of
modes, ``bool`` is true or false, ``| None`` lets None through, and :func:`declare` adds a range.
:func:`problems` lists every value that breaks its constraint, so that one error names them all:

    @dataclass(frozen=True)
    class Options:
        noise_mm: float | None = declare(None, Interval(float, 0, None, closed="neither"))
        loss: Literal["linear", "huber"] = "linear"

        def __post_init__(self) -> None:
            refuse(problems(self), OptionsError)  # a SixAxisError and a ValueError

    Options(noise_mm=-1, loss="l2")
    # OptionsError: noise_mm must be positive, got -1; loss must be one of linear, huber, got 'l2'

The same constraints feed the command line's choices and ranges (:func:`choices`,
:func:`Interval.bounds`) and the checks of a mapping (a TOML table, an agent's settings) with
:func:`check`. Plain data, the standard library and :mod:`arm.errors` only: every layer can use
it.

A declaration also says what a value is (``help=``, ``unit=``), so that a command line's option
is made from it (``experiments.cli_inputs.option_of``) and nothing about an option is written
twice; a quantity taken in several places (the instrument's noise, :mod:`arm.noise`) is one
:class:`Quantity`, its rule, unit and text, that each place declares its field with:

    noise_mm: float | None = declare(None, NOISE_MM, help="Default: estimated.")
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol

from arm.errors import UnknownNameError

__all__ = [
    "NON_NEGATIVE",
    "POSITIVE",
    "AnyOf",
    "Constraint",
    "Interval",
    "ListOf",
    "OneOf",
    "Quantity",
    "TypeOf",
    "check",
    "choices",
    "constraints_of",
    "declaration",
    "declare",
    "description",
    "expectation",
    "from_annotation",
    "problems",
    "refuse",
    "type_name",
]


class Constraint(Protocol):
    """What a value must be: ``holds(value)``; ``predicate`` for the message ("be positive":
    "noise_mm must be positive, got -1"), and ``noun``, the kind of value it takes ("a
    number": "expected a number, got a string '15um'")."""

    @property
    def predicate(self) -> str: ...

    @property
    def noun(self) -> str: ...

    def holds(self, value: Any) -> bool: ...

    def kind_holds(self, value: Any) -> bool: ...


def type_name(v: Any) -> str:
    """A value's kind as a config's author reads it (TOML's words)."""
    return {
        bool: "a boolean",
        int: "an integer",
        float: "a float",
        str: "a string",
        list: "an array",
        tuple: "an array",
        dict: "a table",
    }.get(type(v), type(v).__name__)


def _number(v: Any, kind: type) -> bool:
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        return False
    return kind is float or isinstance(v, numbers.Integral)


@dataclass(frozen=True)
class Interval:
    """A finite number (``kind`` float: any real; int: an integer) between ``low`` and ``high``
    (None: unbounded), ``closed`` on the sides named."""

    kind: type
    low: float | None = None
    high: float | None = None
    closed: Literal["both", "left", "right", "neither"] = "both"
    why: str = ""  # the reason for the bound, said with it: "(seeds below are the leaderboard's)"

    @property
    def noun(self) -> str:
        return "an integer" if self.kind is int else "a number"

    def kind_holds(self, value: Any) -> bool:
        return _number(value, self.kind)

    def holds(self, value: Any) -> bool:
        if not _number(value, self.kind) or not math.isfinite(value):
            return False
        lo_in = self.closed in ("both", "left")
        hi_in = self.closed in ("both", "right")
        if self.low is not None and (value < self.low or (value == self.low and not lo_in)):
            return False
        return not (
            self.high is not None and (value > self.high or (value == self.high and not hi_in))
        )

    @property
    def predicate(self) -> str:
        return self._bound() + (f" ({self.why})" if self.why else "")

    def _bound(self) -> str:
        lo_in, hi_in = self.closed in ("both", "left"), self.closed in ("both", "right")
        noun = "an integer" if self.kind is int else "a number"
        if self.low is not None and self.high is not None:
            return (
                f"lie in {'[' if lo_in else '('}{self.low:g}, {self.high:g}{']' if hi_in else ')'}"
            )
        if self.low == 0 and self.kind is float:
            return "be >= 0" if lo_in else "be positive"
        if self.low is not None:
            return f"be {noun} {'>=' if lo_in else '>'} {self.low:g}"
        if self.high is not None:
            return f"be {noun} {'<=' if hi_in else '<'} {self.high:g}"
        return f"be {'a finite number' if self.kind is float else noun}"

    def bounds(self) -> tuple[float | None, float | None]:
        """(min, max) for a command line's range (closed ends only; open ends are checked)."""
        lo = self.low if self.closed in ("both", "left") else None
        hi = self.high if self.closed in ("both", "right") else None
        return lo, hi


#: a number > 0, and one >= 0 (the commonest ranges of a physical quantity)
POSITIVE = Interval(float, 0.0, None, closed="neither")
NON_NEGATIVE = Interval(float, 0.0, None, closed="left")


@dataclass(frozen=True)
class OneOf:
    """One of a few values (a ``Literal`` type's modes)."""

    values: tuple[Any, ...]

    def holds(self, value: Any) -> bool:
        return any(type(value) is type(v) and value == v for v in self.values)

    def kind_holds(self, value: Any) -> bool:
        return True

    @property
    def predicate(self) -> str:
        return f"be one of {', '.join(map(str, self.values))}"

    @property
    def noun(self) -> str:
        return f"one of {', '.join(map(str, self.values))}"


@dataclass(frozen=True)
class TypeOf:
    """An instance of ``kind`` (``bool``: exactly True or False)."""

    kind: type

    def holds(self, value: Any) -> bool:
        if self.kind is not bool and isinstance(value, bool):
            return False  # TOML keeps booleans and numbers apart, and so do we
        return isinstance(value, self.kind)

    kind_holds = holds

    @property
    def predicate(self) -> str:
        if self.kind is bool:
            return "be true or false"
        return f"be {self.noun}"

    @property
    def noun(self) -> str:
        return {bool: "a boolean", str: "a string", list: "an array", dict: "a table"}.get(
            self.kind, f"a {self.kind.__name__}"
        )


@dataclass(frozen=True)
class ListOf:
    """An array (a list or tuple) whose every item meets ``item``."""

    item: Constraint

    def kind_holds(self, value: Any) -> bool:
        return isinstance(value, list | tuple)

    def holds(self, value: Any) -> bool:
        return self.kind_holds(value) and all(self.item.holds(v) for v in value)

    @property
    def predicate(self) -> str:
        return f"be an array of {self.item.noun.removeprefix('a ').removeprefix('an ')}s"

    @property
    def noun(self) -> str:
        return "an array"


@dataclass(frozen=True)
class AnyOf:
    """One of several kinds (``int | str``; a count or an array of seeds)."""

    options: tuple[Constraint, ...]

    def holds(self, value: Any) -> bool:
        return any(c.holds(value) for c in self.options)

    def kind_holds(self, value: Any) -> bool:
        return any(c.kind_holds(value) for c in self.options)

    @property
    def predicate(self) -> str:
        return "be " + self.noun

    @property
    def noun(self) -> str:
        return " or ".join(c.noun for c in self.options)


@dataclass(frozen=True)
class Quantity:
    """A quantity declared once, wherever it is taken: what values it may have, its unit and
    what it is, in words that read after its name or flag (``help``). A field or an option takes
    it whole (:func:`declare`, the command line's declarations), so that one rule and one text
    hold for it everywhere:

        NOISE_MM = Quantity(NON_NEGATIVE, "mm", "The instrument's per-axis standard uncertainty")
        noise_mm: float | None = declare(None, NOISE_MM, help="Default: estimated.")
    """

    constraint: Constraint
    unit: str = ""
    help: str = ""

    @property
    def rule(self) -> Constraint:
        """The constraint, its unit said with a range's bound: ``must be >= 0 (mm)``."""
        c = self.constraint
        if isinstance(c, Interval) and self.unit and not c.why:
            return dataclasses.replace(c, why=self.unit)
        return c

    def text(self, more: str = "") -> str:
        """The help: what it is, its unit, then ``more`` (what one use adds)."""
        unit = f" ({self.unit})" if self.unit else ""
        return " ".join(t for t in (f"{self.help}{unit}." if self.help else "", more) if t)


def declare(
    default: Any,
    *constraints: Constraint | Quantity,
    help: str = "",
    unit: str = "",
    **cli: Any,
) -> Any:
    """A dataclass field with ``default``, the constraints beyond its type, what it is
    (``help``) and its ``unit``; a :class:`Quantity` gives its constraint, unit and help (``help``
    then adds to its text). ``cli``: how a command line takes it, where its name and type do not
    say (``flags=("--robot", "-r")``, ``metavar=...``, ``cli=False``: not an option there); read
    back with :func:`declaration`."""
    cons: list[Constraint] = []
    for c in constraints:
        if isinstance(c, Quantity):
            cons.append(c.rule)
            unit = unit or c.unit
            help = c.text(help)
        else:
            cons.append(c)
    meta = {"constraints": tuple(cons), "help": help, "unit": unit, **cli}
    return dataclasses.field(default=default, metadata=meta)


def declaration(cls: type, name: str) -> Mapping[str, Any]:
    """What :func:`declare` said of the field ``name`` of the dataclass ``cls`` (``help``,
    ``unit``, ``constraints`` and the command line's keys); empty where nothing was declared."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            return f.metadata
    raise UnknownNameError(f"{cls.__name__} has no field {name!r}")


@dataclass(frozen=True)
class _Anything:
    predicate = "be anything"
    noun = "anything"

    def holds(self, value: Any) -> bool:
        return True

    kind_holds = holds


_ANYTHING = _Anything()


def from_annotation(hint: Any) -> tuple[list[Constraint], bool]:
    """The constraints a type annotation states (nothing for one it cannot judge: ``Any``, a
    class), and whether it lets None through."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        parts = [from_annotation(a)[0] for a in args]
        none_ok = type(None) in typing.get_args(hint)
        if any(not p for p in parts):  # one alternative cannot be judged: neither can the union
            return [], none_ok
        flat = [p[0] for p in parts]
        return ([flat[0]] if len(flat) == 1 else [AnyOf(tuple(flat))]), none_ok
    if origin is Literal:
        return [OneOf(typing.get_args(hint))], False
    if hint is bool:
        return [TypeOf(bool)], False
    if hint in (int, float):
        return [Interval(hint)], False
    if hint is str:
        return [TypeOf(str)], False
    target = origin or hint
    if target in (list, tuple, Sequence, typing.Sequence):
        items = [a for a in typing.get_args(hint) if a is not Ellipsis]
        inner = from_annotation(items[0])[0] if len(items) == 1 else []
        return [ListOf(inner[0]) if inner else ListOf(_ANYTHING)], False
    if target in (dict, Mapping, typing.Mapping):
        return [TypeOf(dict)], False
    return [], False


def expectation(constraint: Constraint, value: Any) -> str | None:
    """Why ``value`` breaks ``constraint``, in a config's words: ``expected a number, got a string
    '15um'`` when it is not of the kind, ``must be positive, got -1.0`` when it is but out of
    range; None when it holds."""
    if not constraint.kind_holds(value):
        return f"expected {constraint.noun}, got {type_name(value)} {value!r}"
    if not constraint.holds(value):
        return f"must {constraint.predicate}, got {value!r}"
    return None


def description(constraint: Constraint, none_ok: bool = False) -> str:
    """What a value must be, as a noun phrase for ``expected ..., got ...``: ``a number >= 0
    (mm)``, ``an integer in [1, 4096] (pixels)``, ``true or false``, ``None or one of a, b``."""
    if isinstance(constraint, Interval):
        phrase = constraint._bound().removeprefix("lie ").removeprefix("be ")
        if phrase == "positive":
            phrase = "a positive number"
        elif not phrase.startswith(("a ", "an ")):
            phrase = f"{constraint.noun} {phrase}"
        phrase += f" ({constraint.why})" if constraint.why else ""
    elif isinstance(constraint, OneOf):
        phrase = constraint.noun
    else:
        phrase = constraint.predicate.removeprefix("be ")
    return f"None or {phrase}" if none_ok else phrase


_CACHE: dict[type, dict[str, tuple[list[Constraint], bool]]] = {}


def constraints_of(cls: type) -> dict[str, tuple[list[Constraint], bool]]:
    """Per field of the dataclass ``cls``: its constraints (declared ones replace the bare type's)
    and whether None is allowed."""
    if cls not in _CACHE:
        _CACHE[cls] = _constraints_of(cls)
    return _CACHE[cls]


def _constraints_of(cls: type) -> dict[str, tuple[list[Constraint], bool]]:
    hints = typing.get_type_hints(cls)
    out: dict[str, tuple[list[Constraint], bool]] = {}
    for f in dataclasses.fields(cls):
        typed, none_ok = from_annotation(hints.get(f.name))
        declared = list(f.metadata.get("constraints", ()))
        out[f.name] = (declared or typed, none_ok)
    return out


def choices(cls: type, name: str) -> tuple[Any, ...]:
    """The modes of the ``Literal`` field ``name`` of ``cls`` (for a command line's choices)."""
    for c in constraints_of(cls)[name][0]:
        if isinstance(c, OneOf):
            return c.values
    raise UnknownNameError(f"{cls.__name__}.{name} is not a choice of modes")


def check(
    values: Mapping[str, Any],
    constraints: Mapping[str, tuple[Sequence[Constraint], bool]],
    where: str = "",
    name: Callable[[str], str] = str,
) -> list[str]:
    """Every value of ``values`` that breaks its constraints, as ``"<where><name(key)> must ...,
    got ..."`` (``name``: how a key is called, e.g. as a command-line flag); keys without
    constraints are not judged here."""
    out = []
    for key, value in values.items():
        if key not in constraints:
            continue
        cons, none_ok = constraints[key]
        if value is None and none_ok:
            continue
        for c in cons:
            if not c.holds(value):
                out.append(f"{where}{name(key)} must {c.predicate}, got {value!r}")
                break
    return out


def problems(obj: Any, where: str = "") -> list[str]:
    """Every field of the dataclass instance ``obj`` that breaks its constraints."""
    values = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    return check(values, constraints_of(type(obj)), where)


def refuse(found: Sequence[str], error: type[Exception], prefix: str = "") -> None:
    """Raise ``error`` naming every problem found at once (nothing when there is none)."""
    if found:
        raise error(prefix + "; ".join(found))
