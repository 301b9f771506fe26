"""Named parameter vectors: one small type maps names to positions and effects to slices, so a
table row, a Jacobian column and a JSON key all say ``dalpha2``, never "index 7"."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["ParameterLayout", "parameter_unit"]


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
                raise ValueError(f"effect {effect!r} appears twice in the model")
            slices[effect] = slice(k, k + len(names))
            for n in names:
                if n in index:
                    raise ValueError(f"parameter {n!r} is declared by two effects")
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
            raise KeyError(
                f"unknown parameter {name!r}; the model has {', '.join(self.names)}"
            ) from None

    def indices(self, names: Iterable[str]) -> np.ndarray:
        return np.array([self.index(n) for n in names], dtype=int)

    def slice(self, effect: str) -> slice:
        try:
            return self._slices[effect]
        except KeyError:
            raise KeyError(
                f"effect {effect!r} is not in the model ({', '.join(self.effects)})"
            ) from None

    def effect_of(self, name: str) -> str:
        i = self.index(name)
        return next(e for e, s in self._slices.items() if s.start <= i < s.stop)

    def as_dict(self, values: np.ndarray) -> dict[str, float]:
        values = np.asarray(values, dtype=float)
        if values.shape != (len(self),):
            raise ValueError(f"expected {len(self)} parameter values, got shape {values.shape}")
        return {n: float(v) for n, v in zip(self.names, values, strict=True)}

    def vector(self, values: Mapping[str, float], default: np.ndarray | float = 0.0) -> np.ndarray:
        """A vector from a name -> value mapping; names not given take ``default``."""
        out = np.array(np.broadcast_to(default, (len(self),)), dtype=float)
        for n, v in values.items():
            out[self.index(n)] = v
        return out


# Units of the catalogue's parameter families (SPEC section 2), by name prefix.
_UNITS = (
    ("dalpha", "rad"),
    ("dtheta", "rad"),
    ("beta", "rad"),
    ("da", "m"),
    ("dd", "m"),
    ("brx", "rad"),
    ("bry", "rad"),
    ("brz", "rad"),
    ("bx", "m"),
    ("by", "m"),
    ("bz", "m"),
    ("tx", "m"),
    ("ty", "m"),
    ("tz", "m"),
    ("c", "rad/(N·m)"),
    ("ts", "rad"),
    ("tc", "rad"),
    ("g", "1"),
    ("bl", "rad"),
    ("lb", "rad"),
    ("kappa", "1/K"),
)


def parameter_unit(name: str) -> str:
    """The SI unit of a catalogued parameter (``""`` for a user effect's)."""
    for prefix, unit in _UNITS:
        if name.startswith(prefix) and (name[len(prefix) :].isdigit() or name == prefix):
            return unit
    return ""
