"""The physical range of every measured quantity: one rule for every reader.

A value outside its range is not a measurement but a typo, a unit slip or a corrupt cell (one cell
of 1e308 makes the identification's SVD fail). Every reader (the measurement CSV, the targets of
``compensate``, the poses file, the robot TOML) refuses it at read time, naming the row and the
column, with the same bounds:

=============  ================================  =================================================
quantity       range (SI)                        why
=============  ================================  =================================================
q1..q6         abs(q) <= 100 rad                 16 turns: beyond any joint's travel
x, y, z        abs(x) <= 1000 m                  laser trackers reach about 80 m
t              abs(t) <= 1e10 s                  300 years: Unix times fit
temperature    -273.15 <= T <= 1000 degC         absolute zero; no arm works hotter
payload        0 <= m <= 10000 kg                the heaviest industrial arms carry 2.3 t
target         abs(id) <= 1e6                    an id, not a count of reflectors
other columns  abs(v) <= 1e12                    unknown units: far from overflow when squared
=============  ================================  =================================================
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "MAX_EXTRA",
    "RANGES",
    "PhysicalRange",
    "out_of_range",
    "payload_problem",
    "range_text",
]


class PhysicalRange:
    """The closed interval ``[low, high]`` of one quantity, in SI units."""

    __slots__ = ("high", "low", "unit")

    def __init__(self, low: float, high: float, unit: str) -> None:
        self.low, self.high, self.unit = low, high, unit

    def text(self, name: str, factor: float = 1.0, unit: str | None = None) -> str:
        """``-100 <= q1 <= 100 rad``, or in a file's unit (``factor`` SI per file unit)."""
        u = self.unit if unit is None else unit

        def fmt(v: float) -> str:
            return f"{v / factor:.6g}"

        return f"{fmt(self.low)} <= {name} <= {fmt(self.high)} {u}".rstrip()


RANGES: dict[str, PhysicalRange] = {
    **{f"q{i}": PhysicalRange(-100.0, 100.0, "rad") for i in range(1, 7)},
    **{c: PhysicalRange(-1000.0, 1000.0, "m") for c in ("x", "y", "z")},
    "t": PhysicalRange(-1e10, 1e10, "s"),
    "temperature": PhysicalRange(-273.15, 1000.0, "degC"),
    "payload": PhysicalRange(0.0, 10000.0, "kg"),
    "target": PhysicalRange(-1e6, 1e6, ""),
}
MAX_EXTRA = 1e12  # any other numeric column (a custom effect's), whatever its unit


def _range(name: str) -> PhysicalRange:
    r = RANGES.get(name)
    if r is not None:
        return r
    return PhysicalRange(-MAX_EXTRA, MAX_EXTRA, "")


def out_of_range(name: str, values: np.ndarray) -> np.ndarray:
    """Mask of ``values`` (SI) of column ``name`` outside its physical range (NaN counts as out)."""
    r = _range(name)
    v = np.asarray(values, dtype=float)
    return ~((v >= r.low) & (v <= r.high))


def range_text(name: str, factor: float = 1.0, unit: str | None = None) -> str:
    """The range of ``name`` as text, in the unit of the file (``factor`` SI per unit)."""
    return _range(name).text(name, factor, unit)


def payload_problem(value: float) -> str | None:
    """Why ``value`` (kg) cannot be a payload, or None: the one payload rule of every reader."""
    if not math.isfinite(value):
        return f"payload {value!r} is not finite"
    if bool(out_of_range("payload", np.array([value]))[0]):
        if value < 0:
            return f"payload {value:g} kg must be >= 0 kg"
        return f"payload {value:g} kg is beyond {range_text('payload')}"
    return None
