"""The lab's numbers as people read them: one place for units and text.

Results hold SI values (m, rad) with the unit in the name or beside the value; for people, a
length shows in mm, an angle error in mrad and a nominal angle in degrees. Every presenter uses
these helpers: :meth:`lab.FitResult.table` and ``summary``, the command line's tables
(``experiments.cli_output``) and the HTML report (:mod:`lab.report_html`), so a parameter reads
the same everywhere.

    display_unit("rad")                 # (1000.0, "mrad")
    nominal_text(1.5708, "rad")         # "90.000 deg"
    error_text(1.2e-5, "m")             # "+0.01200"  (mm)
    left_out_lines(dups, outliers, rule, of="the fit")
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

__all__ = ["left_out_lines", "mm_text", "p_value_text", "parameter_cells", "signed_text"]


def display_unit(unit: str) -> tuple[float, str]:
    """The factor from SI and the unit people read: m -> mm, rad -> mrad, others as they are."""
    if unit == "m":
        return 1e3, "mm"
    if unit == "rad":
        return 1e3, "mrad"
    return 1.0, unit


def signed_text(x: float, digits: int = 4) -> str:
    """``x`` with a sign and ``digits`` significant digits, trailing zeros kept (+10.00, +3300)."""
    if x == 0 or not math.isfinite(x):
        return f"{x:+.{digits - 1}f}"
    decimals = max(0, digits - 1 - math.floor(math.log10(abs(x))))
    return f"{x:+.{decimals}f}"


def mm_text(v: float | None, digits: int = 4) -> str:
    """A length in mm with ``digits`` decimals; ``-`` for none."""
    return "-" if v is None else f"{v:.{digits}f}"


def p_value_text(p: float | None) -> str:
    """A p-value as text: below double precision's smallest normal a bound, not 0."""
    if p is None or not math.isfinite(p):
        return "-"
    return f"{p:.2g}" if p >= 1e-300 else "< 1e-300"


def nominal_text(value: float, unit: str, symbols: bool = False) -> str:
    """A described (nominal) value: a length in mm, an angle in degrees (``symbols``: ``°``
    and no ``mm``, for a table whose header names the unit)."""
    if unit == "m":
        return f"{value * 1e3:.3f}" + ("" if symbols else " mm")
    if unit == "rad":
        return f"{math.degrees(value):.3f}" + ("°" if symbols else " deg")
    return f"{value:.4g}"


def error_text(value: float, unit: str) -> str:
    """An identified error in the unit people read, signed, 4 significant digits."""
    f, shown = display_unit(unit)
    return signed_text(value * f) if shown in ("mm", "mrad") else f"{value:+.4g}"


def std_text(value: float | None, unit: str) -> str:
    """A standard error in the unit people read, 2 significant digits; ``-`` for none."""
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value * display_unit(unit)[0]:.2g}"


def readable(value: float | None, unit: str, signed: bool = False) -> tuple[str, str]:
    """A SI value in the unit people read with 4 decimals (others: 4 significant digits).
    Returns (number, unit); ``("-", "")`` for none."""
    if value is None or not math.isfinite(value):
        return "-", ""
    f, shown = display_unit(unit)
    sign = "+" if signed else ""
    if shown in ("mm", "mrad"):
        return f"{value * f:{sign}.4f}", shown
    return f"{value:{sign}.4g}", shown


def parameter_cells(row: dict[str, Any]) -> dict[str, str]:
    """One parameter of :meth:`lab.FitResult.rows` as text: name, effect, nominal, error, std
    and the unit they show in (error and std empty-fixed when the parameter is not fitted)."""
    unit = row["unit"]
    fitted = bool(row["identifiable"])
    return {
        "name": row["name"],
        "effect": row["effect"],
        "nominal": nominal_text(row["nominal"], unit),
        "error": error_text(row["error"], unit) if fitted else "fixed",
        "std": std_text(row["std"], unit) if fitted else "",
        "unit": display_unit(unit)[1],
        "fitted": "yes" if fitted else "no",
    }


def _ranges(values: Iterable[int]) -> str:
    """``3-11, 13``: sorted integers as ranges."""
    out: list[str] = []
    start: int | None = None
    prev: int | None = None
    for v in [*sorted(values), None]:
        if start is not None and (v is None or prev is None or v != prev + 1):
            out.append(str(start) if start == prev else f"{start}-{prev}")
            start = None
        if v is not None and start is None:
            start = v
        prev = v
    return ", ".join(out)


def duplicates_text(dups: Sequence[Any], limit: int = 5) -> str:
    """The copies (:class:`lab.screening.Duplicate`) grouped by the row they repeat: ``line 2
    (copied on lines 3-11)``."""
    groups: dict[tuple[int, int | None], list[int]] = {}
    for d in dups:
        key = (d.first, d.first_line)
        groups.setdefault(key, []).append(d.line if d.line is not None else d.index + 1)
    word = "line" if all(d.line is not None for d in dups) else "row"
    parts = []
    for (first, first_line), copies in list(groups.items())[:limit]:
        where = f"{word} {first_line if first_line is not None else first + 1}"
        parts.append(f"{where} (copied on {word}s {_ranges(copies)})")
    if len(groups) > limit:
        parts.append(f"... {len(groups) - limit} more rows copied")
    return "; ".join(parts)


def outliers_text(outliers: Sequence[Any], limit: int = 10) -> str:
    """The outliers (:class:`lab.screening.Outlier`) by line, with their residual and the note
    of an effect that cannot say where such a pose is."""
    shown = ", ".join(
        f"{o.where} ({o.residual_mm:.3g} mm{'; ' + o.note if o.note else ''})"
        for o in outliers[:limit]
    )
    more = f", ... {len(outliers) - limit} more" if len(outliers) > limit else ""
    return shown + more


def left_out_lines(
    duplicates: Sequence[Any],
    outliers: Sequence[Any],
    rule: str | None,
    *,
    of: str = "the fit",
    note: str = "",
    limit: int = 10,
) -> list[str]:
    """What a fit, a diagnosis or a report left out of ``of``, by line, and why, for people."""
    out = []
    if duplicates:
        out.append(
            f"{len(duplicates)} duplicate row(s) counted once: {duplicates_text(duplicates)} "
            "(a copy of a measurement is not a second one)"
        )
    if outliers:
        out.append(
            f"{len(outliers)} outlier(s) left out of {of}: {outliers_text(outliers, limit)} "
            f"(rule: {rule}; --outliers keep fits them)"
        )
    elif note:
        out.append(f"outliers: {note}")
    return out
