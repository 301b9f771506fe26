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
target         0 <= id <= 1e6                    an id, not a count of reflectors; its tool
                                                 parameters are named after it (tx0, tx1 ...)
station        0 <= id <= 1e6                    an id, not a count of tracker stations; its
                                                 base parameters are named after it (bx0 ...)
rvx, roll ...  abs(a) <= 7 rad                   an orientation angle: a turn and a little
std_x ...      0 < s <= 1 m                      a point's standard uncertainty; 0 is infinite
                                                 weight, a metre is not a measurement
std_rx ...     0 < s <= 1 rad                    the same for an orientation
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
    """The interval ``[low, high]`` of one quantity, in SI units; ``(low, high]`` when
    ``open_low`` (a standard uncertainty must be above zero)."""

    __slots__ = ("high", "low", "open_low", "unit")

    def __init__(self, low: float, high: float, unit: str, open_low: bool = False) -> None:
        self.low, self.high, self.unit, self.open_low = low, high, unit, open_low

    def outside(self, v: np.ndarray) -> np.ndarray:
        """Mask of the values (SI) outside the interval (NaN counts as outside)."""
        above = (v > self.low) if self.open_low else (v >= self.low)
        return ~(above & (v <= self.high))

    def text(self, name: str, factor: float = 1.0, unit: str | None = None) -> str:
        """``-100 <= q1 <= 100 rad``, or in a file's unit (``factor`` SI per file unit)."""
        u = self.unit if unit is None else unit

        def fmt(v: float) -> str:
            return f"{v / factor:.6g}"

        lower = "<" if self.open_low else "<="
        return f"{fmt(self.low)} {lower} {name} <= {fmt(self.high)} {u}".rstrip()


RANGES: dict[str, PhysicalRange] = {
    **{f"q{i}": PhysicalRange(-100.0, 100.0, "rad") for i in range(1, 7)},
    **{c: PhysicalRange(-1000.0, 1000.0, "m") for c in ("x", "y", "z")},
    "t": PhysicalRange(-1e10, 1e10, "s"),
    "temperature": PhysicalRange(-273.15, 1000.0, "degC"),
    "payload": PhysicalRange(0.0, 10000.0, "kg"),
    "target": PhysicalRange(0.0, 1e6, ""),
    "station": PhysicalRange(0.0, 1e6, ""),
    **{c: PhysicalRange(-7.0, 7.0, "rad") for c in ("rvx", "rvy", "rvz", "roll", "pitch", "yaw")},
    **{f"std_{c}": PhysicalRange(0.0, 1.0, "m", open_low=True) for c in ("x", "y", "z")},
    **{f"std_{c}": PhysicalRange(0.0, 1.0, "rad", open_low=True) for c in ("rx", "ry", "rz")},
}
MAX_EXTRA = 1e12  # any other numeric column (a custom effect's), whatever its unit


def _range(name: str) -> PhysicalRange:
    r = RANGES.get(name)
    if r is not None:
        return r
    return PhysicalRange(-MAX_EXTRA, MAX_EXTRA, "")


def out_of_range(name: str, values: np.ndarray) -> np.ndarray:
    """Mask of ``values`` (SI) of column ``name`` outside its physical range (NaN counts as out)."""
    return _range(name).outside(np.asarray(values, dtype=float))


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
