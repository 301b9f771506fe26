"""Named parameter vectors: one small type maps names to positions and effects to slices, so a
table row, a Jacobian column and a JSON key all say ``dalpha2``, never "index 7"; and the one
parser of the catalogue's parameter names (their grammar is in docs/format.md).

    dalpha{i} da{i} dtheta{i} dd{i}   row i of the DH table (i = 1..6): alpha_{i-1}, a_{i-1},
                                      theta_i, d_i
    beta{k}                           Hayati's rotation about y_k, in row k+1 in place of dd{k+1}
    bx by bz brx bry brz              the base transform (translation, rotation vector)
    bx{s} ... brz{s}                  the base of tracker station s, when there are several
    dtheta{i}_s{s}                    joint i's zero offset in station s's session, beyond
                                      dtheta{i} (the sessions' mean), when there are several
    tx ty tz, tx{k} ty{k} tz{k}       the tool offset (of target k when there are several)
    trx try trz                       the tool frame's rotation (where an orientation is measured)
    c{i} ts{i} tc{i} g{i} bl{i} lb{i} per-joint effects (i = 1..6)
    cs{i}_{k} cc{i}_{k}               a cyclic error of order k (k per turn) of joint i
    lc{i}_{x|y|z}{k}                  joint i's gravity deflection from link k's first moment
                                      along x, y or z (lumped_compliance)
    kappa                             thermal expansion

Any other name belongs to a user's effect.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from arm.errors import ModelError, UnknownNameError

__all__ = [
    "BASE_NAMES",
    "ROW_FAMILIES",
    "TOOL_ROTATION_NAMES",
    "ParameterLayout",
    "ParameterName",
    "parameter_unit",
    "parse_parameter_name",
]


@dataclass(frozen=True)
class ParameterLayout:
    """The ordered parameter names of a model, grouped by effect."""

    groups: tuple[tuple[str, tuple[str, ...]], ...]
    _index: dict[str, int] = field(init=False, repr=False, compare=False)
    _slices: dict[str, slice] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        index: dict[str, int] = {}
        slices: dict[str, slice] = {}
        k = 0
        for effect, names in self.groups:
            if effect in slices:
                raise ModelError(f"effect {effect!r} appears twice in the model")
            slices[effect] = slice(k, k + len(names))
            for n in names:
                if n in index:
                    raise ModelError(f"parameter {n!r} is declared by two effects")
                index[n] = k
                k += 1
        object.__setattr__(self, "_index", index)
        object.__setattr__(self, "_slices", slices)

    @classmethod
    def of(cls, groups: Iterable[tuple[str, Sequence[str]]]) -> ParameterLayout:
        return cls(tuple((e, tuple(n)) for e, n in groups))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for _, names in self.groups for n in names)

    @property
    def effects(self) -> tuple[str, ...]:
        return tuple(e for e, _ in self.groups)

    def __len__(self) -> int:
        return len(self._index)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def index(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise UnknownNameError(
                f"unknown parameter {name!r}; the model has {', '.join(self.names)}"
            ) from None

    def indices(self, names: Iterable[str]) -> np.ndarray:
        return np.array([self.index(n) for n in names], dtype=int)

    def slice(self, effect: str) -> slice:
        try:
            return self._slices[effect]
        except KeyError:
            raise UnknownNameError(
                f"effect {effect!r} is not in the model ({', '.join(self.effects)})"
            ) from None

    def effect_of(self, name: str) -> str:
        i = self.index(name)
        return next(e for e, s in self._slices.items() if s.start <= i < s.stop)

    def as_dict(self, values: np.ndarray) -> dict[str, float]:
        values = np.asarray(values, dtype=float)
        if values.shape != (len(self),):
            raise ModelError(f"expected {len(self)} parameter values, got shape {values.shape}")
        return {n: float(v) for n, v in zip(self.names, values, strict=True)}

    def vector(self, values: Mapping[str, float], default: np.ndarray | float = 0.0) -> np.ndarray:
        """A vector from a name -> value mapping; names not given take ``default``."""
        out = np.array(np.broadcast_to(default, (len(self),)), dtype=float)
        for n, v in values.items():
            out[self.index(n)] = v
        return out


# --------------------------------------------------------------------------------------------------
ParameterKind = Literal[
    "row", "beta", "base", "rehome", "tool", "tool_rotation", "joint", "global", "extra_joint"
]

#: the DH row families in the order of the table's columns (alpha, a, theta, d)
ROW_FAMILIES = ("dalpha", "da", "dtheta", "dd")
#: the base transform's parameters, translation then rotation vector
BASE_NAMES = ("bx", "by", "bz", "brx", "bry", "brz")
#: the tool frame's rotation (rotation vector in the last frame), fitted where an orientation is
#: measured
TOOL_ROTATION_NAMES = ("trx", "try", "trz")

_GRAMMAR = re.compile(
    r"(?P<row>dalpha|dtheta|da|dd)(?P<row_i>[1-6])"
    r"|(?P<rehome>dtheta)(?P<rehome_i>[1-6])_s(?P<rehome_s>[0-9]+)"
    r"|beta(?P<beta_k>[0-5])"
    r"|(?P<base>brx|bry|brz|bx|by|bz)(?P<station>[0-9]*)"
    r"|(?P<turn>trx|try|trz)"
    r"|(?P<tool>tx|ty|tz)(?P<target>[0-9]*)"
    r"|(?P<cyclic>cs|cc)(?P<cyclic_i>[1-6])_(?P<order>[1-9][0-9]*)"
    r"|(?P<lumped>lc)(?P<lumped_i>[1-6])_(?P<link_axis>[xyz][1-6])"
    r"|(?P<joint>ts|tc|bl|lb|c|g)(?P<joint_i>[1-6])"
    r"|(?P<global>kappa)"
    r"|(?P<extra>xs|xt1|xt2)_(?P<extra_name>[A-Za-z_][A-Za-z0-9_.-]*)"
)

# SI units of the catalogue's parameter families (docs/format.md, the parameter names)
_UNITS = {
    "dalpha": "rad",
    "dtheta": "rad",
    "beta": "rad",
    "da": "m",
    "dd": "m",
    "brx": "rad",
    "bry": "rad",
    "brz": "rad",
    "bx": "m",
    "by": "m",
    "bz": "m",
    "trx": "rad",
    "try": "rad",
    "trz": "rad",
    "tx": "m",
    "ty": "m",
    "tz": "m",
    "c": "rad/(N·m)",
    "ts": "rad",
    "tc": "rad",
    "cs": "rad",
    "cc": "rad",
    "lc": "rad",
    "g": "1",
    "bl": "rad",
    "lb": "rad",
    "kappa": "1/K",
    "xs": "1",
    "xt1": "rad",
    "xt2": "rad",
}


@dataclass(frozen=True)
class ParameterName:
    """A catalogued parameter's name, parsed.

    ``kind``: ``row`` (a DH row's error), ``beta`` (Hayati's), ``base``, ``rehome`` (a
    session's own zero offset of a joint, ``dtheta{i}_s{s}``), ``tool``,
    ``tool_rotation``, ``joint`` (a per-joint effect's) or ``global``; ``family``: the name
    without its number (``dalpha``, ``beta``, ``brx``, ``tx``, ``c``, ``cs``, ``kappa``...);
    ``number``: the number as written (the row for ``row`` and ``rehome``, k of ``beta{k}``, the
    station of ``bx{s}``, the target of ``tx{k}``, the joint for ``joint``), or None; ``order``:
    the order per turn of a cyclic error (``cs2_17``: 17), else None; ``station``: the station
    of a ``rehome`` parameter, else None.
    """

    name: str
    kind: ParameterKind
    family: str
    number: int | None = None
    order: int | None = None
    station: int | None = None

    @property
    def row(self) -> int | None:
        """The DH row (1..6) a ``row`` or ``beta`` parameter corrects (``beta{k}`` sits in row
        k+1, in place of ``dd{k+1}``); None for the others."""
        if self.kind == "row":
            return self.number
        if self.kind == "beta":
            return None if self.number is None else self.number + 1
        return None

    @property
    def unit(self) -> str:
        """The SI unit of the family."""
        return _UNITS[self.family]


def parse_parameter_name(name: str) -> ParameterName | None:
    """The parsed name of a catalogued parameter, or None for any other (a user effect's)."""
    m = _GRAMMAR.fullmatch(name)
    if m is None:
        return None
    g = m.groupdict()
    if g["row"] is not None:
        return ParameterName(name, "row", g["row"], int(g["row_i"]))
    if g["rehome"] is not None:
        return ParameterName(
            name, "rehome", "dtheta", int(g["rehome_i"]), station=int(g["rehome_s"])
        )
    if g["beta_k"] is not None:
        return ParameterName(name, "beta", "beta", int(g["beta_k"]))
    if g["base"] is not None:
        return ParameterName(name, "base", g["base"], int(g["station"]) if g["station"] else None)
    if g["turn"] is not None:
        return ParameterName(name, "tool_rotation", g["turn"])
    if g["tool"] is not None:
        return ParameterName(name, "tool", g["tool"], int(g["target"]) if g["target"] else None)
    if g["cyclic"] is not None:
        return ParameterName(name, "joint", g["cyclic"], int(g["cyclic_i"]), int(g["order"]))
    if g["lumped"] is not None:
        return ParameterName(name, "joint", "lc", int(g["lumped_i"]))
    if g["joint"] is not None:
        return ParameterName(name, "joint", g["joint"], int(g["joint_i"]))
    if g["extra"] is not None:
        return ParameterName(name, "extra_joint", g["extra"])
    return ParameterName(name, "global", g["global"])


def parameter_unit(name: str) -> str:
    """The SI unit of a catalogued parameter (``""`` for a user effect's)."""
    parsed = parse_parameter_name(name)
    return "" if parsed is None else parsed.unit
