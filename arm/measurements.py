"""Measurement files (docs/format.md, the measurement CSV): one header row, comma separated, one
measurement per row; ``#`` comment lines may precede the header (a poses file's, kept when the
measured x, y, z were added to it), none may follow it.

Required columns ``q1..q6`` (rad) and ``x, y, z`` (m); optional ``t`` (s), ``temperature`` (degC),
``payload`` (kg), ``dir1..dir6`` (+-1), ``target`` (integer), ``station`` (integer: the tracker
station the row was measured from), the measured orientation of the tool frame (``rvx, rvy, rvz``, a
rotation vector, or ``roll, pitch, yaw``; blank in a row that measured none), and per-point
standard uncertainties ``std_x, std_y, std_z`` (m) and ``std_rx, std_ry, std_rz`` (rad). Other
numeric columns are kept and offered to custom effects, and named in a :class:`MeasurementWarning`.
Foreign data in mm or degrees is read with explicit unit options, never guessed. Bad input is
refused with the file, line and column named; files are read and written through
:mod:`arm.files` (regular files only, sizes bounded, outputs replaced atomically).

Pose files (the poses to measure, as ``sixaxis lab plan`` writes them) are the same CSV with only
``q1..q6`` required, after a ``#`` line naming their schema version and angle unit; a
measurement file is a pose file too.

It is one module, longer than most, because the measurement, target and pose files share one CSV
reader and one table of units and physical ranges.
"""

from __future__ import annotations

import csv
import difflib
import io
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from arm.errors import MeasurementError, MeasurementWarning, warn
from arm.files import (
    OutputError,
    atomic_path,
    atomic_write_text,
    check_output,
    folder_problem,
    read_input_text,
    remove_stale_temporaries,
)
from arm.ranges import out_of_range, payload_problem, range_text

__all__ = [
    "COMPONENTS",
    "ORIENTATION_FORMS",
    "POSES_SCHEMA_VERSION",
    "MeasurementError",
    "MeasurementSet",
    "MeasurementWarning",
    "NumericTable",
    "OutputError",
    "as_measurements",
    "atomic_path",
    "atomic_write_text",
    "check_output",
    "check_ranges",
    "concatenate",
    "folder_problem",
    "orientation_form",
    "parse_numeric_csv",
    "poses_csv",
    "read_measurements",
    "read_poses",
    "read_text",
    "remove_stale_temporaries",
    "write_measurements",
    "write_poses",
]

JOINTS = tuple(f"q{i}" for i in range(1, 7))
POSITION = ("x", "y", "z")
DIRS = tuple(f"dir{i}" for i in range(1, 7))
OPTIONAL = ("t", "temperature", "payload", *DIRS, "target", "station")
INTEGER_COLUMNS = ("target", "station")
#: the measured orientation of the tool frame (measurement frame <- tool frame), by form
ORIENTATION_FORMS = {"rotvec": ("rvx", "rvy", "rvz"), "rpy": ("roll", "pitch", "yaw")}
#: what a row can measure: the position, and the orientation error about the frame's axes
COMPONENTS = ("x", "y", "z", "rx", "ry", "rz")
STD_COLUMNS = tuple(f"std_{c}" for c in COMPONENTS)
KNOWN = (
    *JOINTS,
    *POSITION,
    *OPTIONAL,
    *(c for cols in ORIENTATION_FORMS.values() for c in cols),
    *STD_COLUMNS,
)
# names of other conventions, refused rather than kept as custom columns: a 6-DoF file whose
# orientation the lab silently left out would fit its positions alone
_ORIENTATION_ALIASES = ("rx", "ry", "rz", "a", "b", "c", "qw", "qx", "qy", "qz", "w")
_ANGLE_COLUMNS = (*ORIENTATION_FORMS["rotvec"], *ORIENTATION_FORMS["rpy"], *STD_COLUMNS[3:])
SCHEMA_VERSION = 1
POSES_SCHEMA_VERSION = 1

LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}


@dataclass(frozen=True)
class Session:
    """One file of several joined into one set (:func:`arm.sessions.join_sessions`): its name,
    how many rows it gave and the station ids of its rows (() for a file read alone without a
    station column)."""

    source: str
    rows: int
    stations: tuple[int, ...] = ()

    def to_dict(self) -> dict:
        return {"source": self.source, "rows": self.rows, "stations": list(self.stations)}

    def text(self) -> str:
        ids = ", ".join(map(str, self.stations))
        where = (
            f", station {ids}" if len(self.stations) == 1 else f", stations {ids}" if ids else ""
        )
        return f"{self.source} ({self.rows} rows{where})"


@dataclass
class MeasurementSet:
    """Joint readings ``q`` (N, 6) in rad, measured points ``xyz`` (N, 3) in m, other columns.

    ``lines``: the file's line number of each row when read from a file (None in memory), so that
    a row is named as the user sees it in an editor (:meth:`row_name`).

    Beyond one 3-D point (docs/format.md): ``orientation`` (N, 3), the measured rotation of the
    tool frame (measurement frame <- tool frame) as rotation vectors in rad, or None;
    ``mask`` (N, 6), which of ``x y z rx ry rz`` each row measured (``rx ry rz``: the rotation
    about the measurement frame's axes), None for positions alone; ``std`` (N, 6), each row's
    standard uncertainty of those components (m, rad; NaN where the file states none), or None;
    ``orientation_form``, the form the file gave it in (``rotvec`` or ``rpy``), for writing it
    back; ``notes``, the warnings given when the file was read; ``sessions``, the files the set
    was joined from (:mod:`arm.sessions`), () for a set read from one file or made in memory; ``labels``, the columns of
    text (a ``set`` column of ``stationing`` rows), each row's cell as a string, which no fit or
    effect reads."""

    q: np.ndarray
    xyz: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = "<memory>"
    lines: np.ndarray | None = None
    orientation: np.ndarray | None = None
    mask: np.ndarray | None = None
    std: np.ndarray | None = None
    orientation_form: str = "rotvec"
    notes: list[str] = field(default_factory=list)
    sessions: tuple[Session, ...] = ()
    labels: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.q = np.asarray(self.q, dtype=float).reshape(-1, 6)
        self.xyz = np.asarray(self.xyz, dtype=float).reshape(-1, 3)
        if len(self.q) != len(self.xyz):
            raise MeasurementError(
                f"{self.source}: {len(self.q)} joint rows but {len(self.xyz)} points"
            )
        self.columns = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in self.columns.items()}
        for k, v in self.columns.items():
            if len(v) != len(self.q):
                raise MeasurementError(
                    f"{self.source}: column {k!r} has {len(v)} rows, not {len(self.q)}"
                )
        if self.lines is not None:
            self.lines = np.asarray(self.lines, dtype=int).reshape(-1)
            if len(self.lines) != len(self.q):
                raise MeasurementError(
                    f"{self.source}: {len(self.lines)} line numbers for {len(self.q)} rows"
                )
        # the readers' rule, for data built in memory too: finite, within physical range
        named = {c: self.q[:, k] for k, c in enumerate(JOINTS)}
        named |= {c: self.xyz[:, k] for k, c in enumerate(POSITION)}
        for k, v in (*named.items(), *self.columns.items()):
            bad = np.flatnonzero(out_of_range(k, v))
            if bad.size:
                r = int(bad[0])
                raise MeasurementError(
                    f"{self.source}, {self.row_name(r)}, column {k!r}: {v[r]!r} is outside the "
                    f"physical range {range_text(k)}"
                )
        self._check_beyond_points()

    def _check_beyond_points(self) -> None:
        """The orientation, mask and stds: shapes, finiteness, ranges (in memory too)."""
        n = len(self.q)
        if self.orientation_form not in ORIENTATION_FORMS:
            raise MeasurementError(
                f"{self.source}: orientation form {self.orientation_form!r} is not one of "
                f"{', '.join(ORIENTATION_FORMS)}"
            )
        if self.orientation is not None:
            self.orientation = np.asarray(self.orientation, dtype=float).reshape(n, 3)
            if self.mask is None:
                self.mask = np.ones((n, 6), dtype=bool)
        if self.mask is not None:
            self.mask = np.asarray(self.mask, dtype=bool).reshape(n, 6)
            if not self.mask[:, :3].all():
                raise MeasurementError(
                    f"{self.source}: every row measures its position x, y, z (the mask leaves "
                    "one out)"
                )
            if self.orientation is None:
                if self.mask[:, 3:].any():
                    raise MeasurementError(
                        f"{self.source}: the mask names orientation components, but there is "
                        "no orientation"
                    )
                self.mask = None
        if self.orientation is not None and self.mask is not None:
            bad = np.flatnonzero(
                self.mask[:, 3:].any(axis=1) & ~np.isfinite(self.orientation).all(axis=1)
            )
            if bad.size:
                raise MeasurementError(
                    f"{self.source}, {self.row_name(int(bad[0]))}: the orientation of a row "
                    "that measured one is not finite"
                )
            seen = np.asarray(self.mask[:, 3:].any(axis=1))
            self.orientation = np.where(seen[:, None], self.orientation, 0.0)
        if self.std is not None:
            self.std = np.asarray(self.std, dtype=float).reshape(n, 6)
            for k, c in enumerate(STD_COLUMNS):
                v = self.std[:, k]
                stated = np.isfinite(v)
                bad = np.flatnonzero(stated & out_of_range(c, v))
                if bad.size:
                    r = int(bad[0])
                    raise MeasurementError(
                        f"{self.source}, {self.row_name(r)}, column {c!r}: {v[r]!r} is outside "
                        f"the physical range {range_text(c)}"
                    )
                bad = np.flatnonzero(np.isinf(v))
                if bad.size:
                    raise MeasurementError(
                        f"{self.source}, {self.row_name(int(bad[0]))}, column {c!r}: not finite"
                    )

    @property
    def has_orientation(self) -> bool:
        """Whether any row measured an orientation component."""
        return self.mask is not None and bool(self.mask[:, 3:].any())

    @property
    def measured(self) -> np.ndarray:
        """(N, 6) bool: which of ``x y z rx ry rz`` each row measured."""
        if self.mask is not None:
            return self.mask
        out = np.zeros((len(self), 6), dtype=bool)
        out[:, :3] = True
        return out

    @property
    def stations(self) -> tuple[int, ...]:
        """Distinct station ids, sorted; ``(0,)`` without a station column."""
        if "station" not in self.columns:
            return (0,)
        return tuple(int(t) for t in np.unique(self.columns["station"]))

    def row_name(self, i: int) -> str:
        """Row ``i`` (0-based) as the user finds it: ``line 57`` of the file, else ``row 3``."""
        if self.lines is not None:
            return f"line {int(self.lines[i])}"
        return f"row {int(i) + 1}"

    def __len__(self) -> int:
        return len(self.q)

    @property
    def targets(self) -> tuple[int, ...]:
        """Distinct target ids, sorted; ``(0,)`` without a target column."""
        if "target" not in self.columns:
            return (0,)
        return tuple(int(t) for t in np.unique(self.columns["target"]))

    def subset(self, idx) -> MeasurementSet:
        idx = np.asarray(idx)

        def rows(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[idx]

        return MeasurementSet(
            self.q[idx],
            self.xyz[idx],
            {k: v[idx] for k, v in self.columns.items()},
            self.source,
            rows(self.lines),
            rows(self.orientation),
            rows(self.mask),
            rows(self.std),
            self.orientation_form,
            list(self.notes),
            self.sessions,
            {k: v[idx] for k, v in self.labels.items()},
        )

    def split(
        self, fraction: float, rng: np.random.Generator
    ) -> tuple[MeasurementSet, MeasurementSet]:
        """A random split into (first, rest) with ``fraction`` of the poses in the first."""
        perm = rng.permutation(len(self))
        k = round(fraction * len(self))
        return self.subset(np.sort(perm[:k])), self.subset(np.sort(perm[k:]))

    def to_csv(
        self, length_unit: str = "m", angle_unit: str = "rad", orientation_unit: str | None = None
    ) -> str:
        """The measurement CSV text (docs/format.md); q in ``angle_unit``, x, y, z (and their
        stds) in ``length_unit``, the orientation (and its stds) in ``orientation_unit`` (default
        ``angle_unit``), in the set's ``orientation_form``; a row that measured no orientation
        has blank orientation cells. Refuses values that the reader would refuse (non-finite
        numbers, bad dir or target values)."""
        L, A = _length_factor(length_unit), _angle_factor(angle_unit)
        O = _angle_factor(orientation_unit or angle_unit)
        extra = [c for c in self.columns if c not in OPTIONAL]
        names = [*JOINTS, *POSITION]
        data = [self.q / A, self.xyz / L]
        blank_ok: set[str] = set()
        if self.orientation is not None and self.mask is not None:
            cols = ORIENTATION_FORMS[self.orientation_form]
            seen = np.asarray(self.mask[:, 3:].any(axis=1))
            angles = orientation_angles(self.orientation, self.orientation_form)
            names += cols
            data.append(np.where(seen[:, None], angles / O, np.nan))
            blank_ok |= set(cols)
        if self.std is not None:
            for k, c in enumerate(STD_COLUMNS):
                v = self.std[:, k]
                if np.isfinite(v).any():
                    names.append(c)
                    data.append((v / (L if k < 3 else O))[:, None])
                    if k >= 3:
                        blank_ok.add(c)
        n_fixed = len(names)
        names += [*(c for c in OPTIONAL if c in self.columns), *extra]
        data += [self.columns[c][:, None] for c in names[n_fixed:]]
        table = np.hstack(data)
        bad = ~np.isfinite(table)
        for k, c in enumerate(names):
            if c in blank_ok:
                bad[:, k] = np.isinf(table[:, k])
            if c in DIRS:
                bad[:, k] |= ~np.isin(table[:, k], (-1.0, 1.0))
            elif c in INTEGER_COLUMNS:
                bad[:, k] |= table[:, k] != np.round(table[:, k])
        if bad.any():
            r, k = np.argwhere(bad)[0]
            raise MeasurementError(
                f"{self.source}: row {r + 1}, column {names[k]!r}: {table[r, k]!r} cannot be "
                "written (values must be finite, dir +-1, target and station integers)"
            )
        buf = io.StringIO()
        buf.write(",".join([*names, *self.labels]) + "\n")
        ints = {i for i, c in enumerate(names) if c in (*DIRS, *INTEGER_COLUMNS)}

        def cell(i: int, v: float) -> str:
            if i in ints:
                return str(int(v))
            return "" if math.isnan(v) else repr(float(v))

        def text(t: str) -> str:
            return f'"{t.replace(chr(34), chr(34) * 2)}"' if any(c in t for c in ',"') else t

        labels = list(self.labels.values())
        for r, row in enumerate(table):
            cells = [cell(i, v) for i, v in enumerate(row)] + [text(str(x[r])) for x in labels]
            buf.write(",".join(cells) + "\n")
        return buf.getvalue()


def _length_factor(unit: str) -> float:
    if unit not in LENGTH_UNITS:
        raise MeasurementError(f"length unit must be one of {sorted(LENGTH_UNITS)}, got {unit!r}")
    return LENGTH_UNITS[unit]


def _angle_factor(unit: str) -> float:
    if unit not in ANGLE_UNITS:
        raise MeasurementError(f"angle unit must be one of {sorted(ANGLE_UNITS)}, got {unit!r}")
    return ANGLE_UNITS[unit]


def orientation_angles(rotvec: np.ndarray, form: str) -> np.ndarray:
    """Rotation vectors (N, 3) in rad as the columns of ``form`` (rad): themselves for
    ``rotvec``; ``roll, pitch, yaw`` for ``rpy``, R = Rz(yaw) Ry(pitch) Rx(roll) (rotations
    about the fixed x, then y, then z axis: scipy's ``as_euler("xyz")``)."""
    from scipy.spatial.transform import Rotation

    rotvec = np.asarray(rotvec, dtype=float).reshape(-1, 3)
    if form == "rotvec":
        return rotvec.copy()
    if form == "rpy":
        return Rotation.from_rotvec(rotvec).as_euler("xyz")
    raise MeasurementError(f"orientation form must be one of {', '.join(ORIENTATION_FORMS)}")


def orientation_rotvec(angles: np.ndarray, form: str) -> np.ndarray:
    """The inverse of :func:`orientation_angles`: the columns of ``form`` (N, 3), rad, as
    rotation vectors (N, 3)."""
    from scipy.spatial.transform import Rotation

    angles = np.asarray(angles, dtype=float).reshape(-1, 3)
    if form == "rotvec":
        return angles.copy()
    if form == "rpy":
        return Rotation.from_euler("xyz", angles).as_rotvec()
    raise MeasurementError(f"orientation form must be one of {', '.join(ORIENTATION_FORMS)}")


def concatenate(sets: Sequence[MeasurementSet], source: str | None = None) -> MeasurementSet:
    """The rows of several measurement sets as one (several sessions or stations in one fit):
    the same columns in each (a ``station`` column says which station measured which rows); a
    set without ``std_*`` cells contributes blank ones (its rows' sigma is the instrument
    model's). Positions alone: a set with orientations is refused."""
    if not sets:
        raise MeasurementError("concatenate: no measurement sets given")
    names = set(sets[0].columns)
    for s in sets[1:]:
        if set(s.columns) != names:
            odd = sorted(names ^ set(s.columns))[0]
            raise MeasurementError(
                f"{s.source}: column {odd!r} is in some of the sets concatenated but not in "
                f"{sets[0].source if odd not in names else s.source}"
            )
    for s in sets:
        if s.orientation is not None:
            raise MeasurementError(f"{s.source}: concatenate takes positions alone")
    std = None
    if any(s.std is not None for s in sets):
        std = np.vstack([np.full((len(s), 6), np.nan) if s.std is None else s.std for s in sets])
    shared = [c for c in sets[0].labels if all(c in s.labels for s in sets)]
    return MeasurementSet(
        np.vstack([s.q for s in sets]),
        np.vstack([s.xyz for s in sets]),
        {c: np.concatenate([s.columns[c] for s in sets]) for c in sets[0].columns},
        source or " + ".join(s.source for s in sets),
        std=std,
        labels={c: np.concatenate([s.labels[c] for s in sets]) for c in shared},
    )


def write_measurements(
    data: MeasurementSet,
    path: str | Path,
    length_unit: str = "m",
    angle_unit: str = "rad",
    orientation_unit: str | None = None,
) -> None:
    atomic_write_text(Path(path), data.to_csv(length_unit, angle_unit, orientation_unit))


def read_text(path: str | Path, error: type[Exception] = MeasurementError) -> str:
    """The text of a CSV file (UTF-8, a byte-order mark allowed); ``error`` names the file. Only
    a regular file of at most ``arm.files.MAX_INPUT_BYTES["csv"]`` is read (a FIFO or
    ``/dev/zero`` is refused before reading)."""
    return read_input_text(path, "file", "csv", error)


@dataclass
class NumericTable:
    """The numeric columns of a CSV: ``header`` (names), ``values`` (rows, columns), the file's
    line number of each row and of the header."""

    header: list[str]
    values: np.ndarray
    lines: np.ndarray
    header_line: int = 1
    # text columns (``text_columns``): each one's cells, and the line of its first text cell
    labels: dict[str, np.ndarray] = field(default_factory=dict)
    label_lines: dict[str, int] = field(default_factory=dict)


def _lines(text: str) -> Iterator[str]:
    """The lines of ``text`` with their ends, one at a time (``io.StringIO`` holds a copy of
    the whole text at four bytes a character)."""
    start, n = 0, len(text)
    while start < n:
        end = text.find("\n", start)
        if end < 0:
            yield text[start:]
            return
        yield text[start : end + 1]
        start = end + 1


#: the longest cell the CSV reader takes, characters (the csv module's own field limit); a number
#: needs a few dozen
MAX_CELL = csv.field_size_limit()


def _csv_rows(text: str, source: str, error: type[Exception]) -> Iterator[tuple[int, list[str]]]:
    """(number, cells) of each row; what the csv module cannot read (a cell beyond
    :data:`MAX_CELL`, a stray quote or carriage return) is ``error`` naming the line (and the
    column, for a cell too long)."""
    lines = _lines(text)
    reader = csv.reader(lines)
    number = 0
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            number += 1
            if "field limit" in str(exc):
                raise error(
                    f"{source}, line {number}: a cell longer than {MAX_CELL} characters (the "
                    "CSV reader's limit; a number needs a few dozen)"
                ) from None
            raise error(f"{source}, line {number}: not CSV ({exc})") from None
        number += 1
        yield number, row


def parse_numeric_csv(  # noqa: C901  (one reader: each branch a cell or a header of the CSV format)
    text: str,
    source: str,
    required: Sequence[str],
    *,
    blank_lines: bool = False,
    columns: Sequence[str] | None = None,
    error: type[Exception] = MeasurementError,
    may_be_blank: Sequence[str] = (),
    text_columns: bool = False,
) -> NumericTable:
    """Parse a CSV of numbers whose header names the ``required`` columns (and any others).

    Lines starting with ``#`` and blank lines before the header row are skipped (the lab's poses
    and joints files begin with a ``#`` line); a ``#`` line after the header is refused, naming
    its line (a note of another session or a row commented out, which a reader that skipped it
    would pass over in silence). Every reader of these CSVs (measurements, poses, targets)
    follows this one rule. ``blank_lines``: blank lines among the rows are skipped too (else
    only trailing ones). ``columns``: read only these (others may hold anything), else every
    column. The columns read must have distinct, non-empty names and finite numbers in every row,
    except that a cell of a ``may_be_blank`` column may be empty (read as NaN: not measured);
    ``error`` names the source, the line and the column of the first problem. ``text_columns``:
    a column the format does not know (:data:`KNOWN`) that holds text (a cell neither a number
    nor blank) is kept as labels (``labels``, the cells as strings), not refused."""
    # one row at a time into a growing array: a list of every row's cells would take 1.5 KB per
    # row of 200,000 (the text itself is a third of that)
    rows_in = _csv_rows(text, source, error)

    def blank(row: list[str]) -> bool:
        return not any(c.strip() for c in row)

    comments = 0  # '#' lines before the header
    first = None
    for number, cells in rows_in:
        if _is_comment(cells):
            comments += 1
        elif not blank(cells):
            first = (number, cells)
            break
    if first is None:
        what = "only comment lines" if comments else "empty file"
        raise error(f"{source}: {what}, expected a header row with {', '.join(required)}")
    hline, header = first[0], [h.strip() for h in first[1]]
    read = (
        list(range(len(header)))
        if columns is None
        else [k for k, h in enumerate(header) if h in columns]
    )
    _check_header(header, read, required, f"{source}, line {hline}", error)
    values = np.empty((1024, len(read)))
    line_of = np.empty(1024, dtype=int)
    n = 0
    # the columns that may hold text: their cells as written, and the first cell of each that
    # is no number (text: the column is labels; blank: refused unless some other cell is text)
    raw: dict[int, list[str]] = (
        {j: [] for j, k in enumerate(read) if header[k] not in KNOWN} if text_columns else {}
    )
    not_number: dict[int, tuple[int, str]] = {}
    textual: set[int] = set()
    pending: list[tuple[int, int]] = []  # blank lines, allowed only at the end (no blank_lines)
    for r, row in rows_in:
        if _is_comment(row):
            raise error(
                f"{source}, line {r}: a comment line ('#') among the rows; comments go before "
                "the header row only: remove it, or move it above the header"
            )
        if blank(row):
            if not blank_lines:
                pending.append((r, len(row)))
            continue
        if pending:
            br, _ = pending[0]
            raise error(
                f"{source}, line {br}: a blank line among the rows (another table, or rows "
                "lost?): remove it"
            )
        if len(row) != len(header):
            raise error(f"{source}, line {r}: {len(row)} fields, but the header has {len(header)}")
        if n == len(values):
            values = np.resize(values, (2 * n, len(read)))
            line_of = np.resize(line_of, 2 * n)
        for j, k in enumerate(read):
            cell = row[k]
            if may_be_blank and not cell.strip() and header[k] in may_be_blank:
                values[n, j] = math.nan
                continue
            if j in raw:
                raw[j].append(cell.strip())
            try:
                v = float(cell)
            except ValueError:
                if j in raw:  # text, or a blank judged once the column is read
                    not_number.setdefault(j, (r, cell))
                    if cell.strip():
                        textual.add(j)
                    values[n, j] = math.nan
                    continue
                extra = (
                    ""
                    if header[k] in KNOWN
                    else " (extra columns are kept for custom effects and must be numeric)"
                )
                raise error(
                    f"{source}, line {r}, column {header[k]!r}: {cell.strip()!r} is not a number{extra}"
                ) from None
            if not math.isfinite(v):
                raise error(
                    f"{source}, line {r}, column {header[k]!r}: {cell.strip()} is not finite"
                )
            values[n, j] = v
        line_of[n] = r
        n += 1
    names = [header[k] for k in read]
    table = NumericTable(names, values[:n].copy(), line_of[:n].copy(), hline)
    return _with_labels(table, raw, not_number, textual, source, error)


def _check_header(
    header: list[str],
    read: list[int],
    required: Sequence[str],
    where: str,
    error: type[Exception],
) -> None:
    """The columns read have distinct, non-empty names and the required ones are there."""
    seen: set[str] = set()
    for k in read:
        h = header[k]
        if not h:
            raise error(f"{where}: column {k + 1} has an empty name")
        if h in seen:
            raise error(f"{where}: column {h!r} appears twice")
        seen.add(h)
    missing = [c for c in required if c not in seen]
    if missing:
        raise error(
            f"{where}: missing required column(s) {', '.join(missing)} "
            f"(found: {', '.join(header)}){_header_cause(header, required)}"
        )


def _with_labels(
    table: NumericTable,
    raw: Mapping[int, list[str]],
    not_number: Mapping[int, tuple[int, str]],
    textual: set[int],
    source: str,
    error: type[Exception],
) -> NumericTable:
    """``table`` with its text columns (``textual``, by position among those read) moved to
    ``labels``; a column of numbers with a cell that is none (a blank) refused, naming it."""
    for j, (r, cell) in not_number.items():
        if j not in textual:  # a blank cell in a column of numbers
            raise error(
                f"{source}, line {r}, column {table.header[j]!r}: {cell.strip()!r} is not a "
                "number (extra columns are kept for custom effects as numbers, or as labels "
                "where they hold text)"
            )
    keep = [j for j in range(len(table.header)) if j not in textual]
    return NumericTable(
        [table.header[j] for j in keep],
        table.values[:, keep],
        table.lines,
        table.header_line,
        {table.header[j]: np.array(raw[j], dtype=str) for j in sorted(textual)},
        {table.header[j]: not_number[j][0] for j in sorted(textual)},
    )


#: separators that a CSV written elsewhere may use instead of the comma
_OTHER_SEPARATORS = {";": "semicolons", "\t": "tabs", "|": "bars"}


def _is_comment(row: list[str]) -> bool:
    """Whether a CSV row is a comment line (its first cell starts with ``#``)."""
    return bool(row) and row[0].lstrip().startswith("#")


def _header_cause(header: Sequence[str], required: Sequence[str]) -> str:
    """Why a header lacks the required columns, where the file says it: another separator than
    the comma."""
    line = ",".join(header)
    for sep, name in _OTHER_SEPARATORS.items():
        cells = {c.strip() for part in header for c in part.split(sep)}
        if sep in line and any(c in cells for c in required):
            return (
                f"; the header is separated by {name}, not commas: write the file "
                "comma-separated (with a decimal point)"
            )
    return ""


def as_measurements(data: MeasurementSet | str | Path) -> MeasurementSet:
    """``data`` itself if it is a measurement set, else the file it names (in SI units)."""
    return data if isinstance(data, MeasurementSet) else read_measurements(data)


def read_measurements(
    path: str | Path,
    length_unit: str | None = None,
    angle_unit: str | None = None,
    min_rows: int = 1,
    orientation_unit: str | None = None,
    measured: Sequence[str] | None = None,
    *,
    fallback: tuple[str, str] = ("m", "rad"),
) -> MeasurementSet:
    """Read a measurement CSV (docs/format.md). ``length_unit`` (m|mm) applies to x, y, z and
    their stds; ``angle_unit`` (rad|deg) to q1..q6; ``orientation_unit`` (default
    ``angle_unit``) to the orientation columns and their stds. ``measured``: the components
    (of ``x y z rx ry rz``) the instrument measures, default every one the file has columns
    for. ``#`` lines before the header are skipped; where one declares the units (``x, y, z in
    mm``, ``q1..q6 in deg``: :func:`file_units`), a unit not given is that one, and one given
    must be it; a unit neither given nor declared is ``fallback``'s (m, rad). Raises
    :class:`MeasurementError` naming file, line and column; warns (:class:`MeasurementWarning`)
    of columns the format does not know."""
    path = Path(path)
    if length_unit is not None:
        _length_factor(length_unit)
    if angle_unit is not None:
        _angle_factor(angle_unit)
    if orientation_unit is not None:
        _angle_factor(orientation_unit)
    text = read_text(path)
    return parse_measurements(
        text,
        str(path),
        length_unit,
        angle_unit,
        min_rows,
        orientation_unit,
        measured,
        fallback=fallback,
    )


def _unknown_columns(header: Sequence[str], source: str, line: int) -> list[str]:
    """Refuse the names of other conventions (``Rx``, ``qw``: an orientation the lab would not
    read) and a known name in other case; return the notes that name the other unknown columns."""
    known_lower = {k.lower(): k for k in KNOWN}
    unknown = [h for h in header if h not in KNOWN]
    for h in unknown:
        low = h.lower()
        if low in _ORIENTATION_ALIASES:
            raise MeasurementError(
                f"{source}, line {line}: column {h!r} looks like an orientation, which the lab "
                "reads from columns rvx, rvy, rvz (a rotation vector) or roll, pitch, yaw "
                "(R = Rz(yaw) Ry(pitch) Rx(roll)); rename the columns to say which it is "
                "(docs/format.md, the measurement CSV)"
            )
        if low in known_lower:
            raise MeasurementError(
                f"{source}, line {line}: column {h!r} is not {known_lower[low]!r} (column names "
                "are case-sensitive); rename it"
            )
    if not unknown:
        return []
    # a close spelling, else a known name the column begins (temp: temperature)
    close = {
        h: difflib.get_close_matches(h, KNOWN, n=1, cutoff=0.8)
        or [k for k in KNOWN if len(h) >= 3 and k.startswith(h.lower()) and k != h.lower()][:1]
        for h in unknown
    }
    named = ", ".join(
        f"{h!r} (did you mean {close[h][0]!r}?)" if close[h] else repr(h) for h in unknown
    )
    return [
        f"{source}: column(s) {named} are not among the format's columns (docs/format.md): "
        "they are kept and offered to custom effects (inputs.column) and the diagnosis's "
        "hints, and no catalogued effect reads them (but a column named after an extra joint "
        "of the robot file holds its value)"
    ]


def parse_measurements(  # noqa: C901  (one reader: each branch a column family of docs/format.md)
    text: str,
    source: str,
    length_unit: str | None = None,
    angle_unit: str | None = None,
    min_rows: int = 1,
    orientation_unit: str | None = None,
    measured: Sequence[str] | None = None,
    *,
    fallback: tuple[str, str] = ("m", "rad"),
) -> MeasurementSet:
    length_unit, angle_unit = file_units(text, source, length_unit, angle_unit, fallback)
    blanks = (*ORIENTATION_FORMS["rotvec"], *ORIENTATION_FORMS["rpy"], *STD_COLUMNS[3:])
    table = parse_numeric_csv(
        text, source, (*JOINTS, *POSITION), may_be_blank=blanks, text_columns=True
    )
    header, values = table.header, table.values
    n = values.shape[0]
    if n < min_rows:
        raise MeasurementError(f"{source}: {n} measurement rows, at least {min_rows} needed")
    notes = _unknown_columns(header, source, table.header_line) + _label_notes(table, source)
    col = {h: values[:, k] for k, h in enumerate(header)}

    def check(name: str, ok: np.ndarray, what: str) -> None:
        bad = np.flatnonzero(~ok)
        if bad.size:
            r = int(bad[0])
            raise MeasurementError(
                f"{source}, line {table.lines[r]}, column {name!r}: {values[r, header.index(name)]:g} {what}"
            )

    for d in DIRS:
        if d in col:
            check(d, np.isin(col[d], (-1.0, 1.0)), "must be -1 or +1")
    for c in INTEGER_COLUMNS:
        if c in col:
            check(c, col[c] == np.round(col[c]), "must be an integer")
    orientation_unit = orientation_unit or angle_unit
    A, L = ANGLE_UNITS[angle_unit], LENGTH_UNITS[length_unit]
    O = ANGLE_UNITS[orientation_unit]
    form = orientation_form(header, source, table.header_line)
    ocols = ORIENTATION_FORMS[form] if form else ()
    check_ranges(
        table,
        source,
        [
            (angle_unit, A, JOINTS),
            (length_unit, L, (*POSITION, *STD_COLUMNS[:3])),
            (orientation_unit, O, (*ocols, *STD_COLUMNS[3:])),
        ],
    )
    q = np.column_stack([col[c] for c in JOINTS]) * A
    xyz = np.column_stack([col[c] for c in POSITION]) * L
    beyond = set(ocols) | set(STD_COLUMNS)
    other = {h: col[h] for h in header if h not in (*JOINTS, *POSITION) and h not in beyond}
    orientation = mask = std = None
    components = _measured_components(measured, bool(form), source)
    if form:
        angles = np.column_stack([col[c] for c in ocols]) * O
        blank = np.isnan(angles)
        seen = np.asarray(~blank.all(axis=1))
        partial = np.flatnonzero(blank.any(axis=1) & seen)
        if partial.size:
            r = int(partial[0])
            c = ocols[int(np.flatnonzero(blank[r])[0])]
            raise MeasurementError(
                f"{source}, line {table.lines[r]}, column {c!r}: blank, but the row's other "
                "orientation cells are not (leave all three blank where no orientation was "
                "measured)"
            )
        orientation = orientation_rotvec(np.where(seen[:, None], angles, 0.0), form)
        mask = np.zeros((n, 6), dtype=bool)
        mask[:, :3] = True
        mask[:, 3:] = seen[:, None] & np.array([c in components for c in COMPONENTS[3:]])
    for c in STD_COLUMNS[:3]:
        if any(h in col for h in STD_COLUMNS[:3]) and c not in col:
            raise MeasurementError(
                f"{source}, line {table.header_line}: column {c!r} is missing (std_x, std_y "
                "and std_z come together)"
            )
    ostd = [c for c in STD_COLUMNS[3:] if c in col]
    if ostd and not form:
        raise MeasurementError(
            f"{source}, line {table.header_line}: column {ostd[0]!r} is the uncertainty of an "
            "orientation, but the file has no orientation columns"
        )
    if ostd and len(ostd) < 3:
        missing = next(c for c in STD_COLUMNS[3:] if c not in col)
        raise MeasurementError(
            f"{source}, line {table.header_line}: column {missing!r} is missing (std_rx, std_ry "
            "and std_rz come together)"
        )
    if any(c in col for c in STD_COLUMNS):
        std = np.full((n, 6), np.nan)
        for k, c in enumerate(STD_COLUMNS):
            if c in col:
                std[:, k] = col[c] * (L if k < 3 else O)
        if mask is not None and ostd:
            lacking = mask[:, 3:] & np.isnan(std[:, 3:])
            if lacking.any():
                r, k = np.argwhere(lacking)[0]
                raise MeasurementError(
                    f"{source}, line {table.lines[r]}, column {STD_COLUMNS[3 + k]!r}: blank, but "
                    "the row measured an orientation (give its uncertainty)"
                )
    for note in notes:
        warn(note, MeasurementWarning)
    return MeasurementSet(
        q,
        xyz,
        other,
        source,
        table.lines,
        orientation,
        mask,
        std,
        form or "rotvec",
        notes,
        labels=table.labels,
    )


def _label_notes(table: NumericTable, source: str) -> list[str]:
    """One note naming the text columns (kept as labels, ignored by the fits)."""
    if not table.labels:
        return []
    named = ", ".join(
        f"{h!r} ({str(table.labels[h][table.lines.tolist().index(r)])!r} on line {r})"
        for h, r in table.label_lines.items()
    )
    return [
        f"{source}: column(s) {named} hold text: kept as labels (MeasurementSet.labels), "
        "ignored by the fits and offered to no effect"
    ]


def orientation_form(
    header: Sequence[str], source: str, line: int, error: type[Exception] = MeasurementError
) -> str | None:
    """Which orientation form the header gives (all three columns of one form), or None; the
    measurement and target readers' one check of it: ``error`` names the file and the header's
    line where the columns mix two forms or leave one out."""
    present = {form: [c for c in cols if c in header] for form, cols in ORIENTATION_FORMS.items()}
    given = [f for f, cols in present.items() if cols]
    if len(given) > 1:
        raise error(
            f"{source}, line {line}: columns {', '.join(present['rotvec'] + present['rpy'])}: "
            "give the orientation in one form, rvx, rvy, rvz or roll, pitch, yaw"
        )
    if not given:
        return None
    form = given[0]
    missing = [c for c in ORIENTATION_FORMS[form] if c not in header]
    if missing:
        raise error(
            f"{source}, line {line}: missing column(s) {', '.join(missing)} (an orientation "
            f"takes all of {', '.join(ORIENTATION_FORMS[form])})"
        )
    return form


def _measured_components(
    measured: Sequence[str] | None, has_orientation: bool, source: str
) -> tuple[str, ...]:
    """The components a ``measured`` option names (``x,y,z,rx,ry``), checked."""
    if measured is None:
        return COMPONENTS if has_orientation else POSITION
    names = tuple(m.strip() for m in measured)
    unknown = [m for m in names if m not in COMPONENTS]
    if unknown:
        raise MeasurementError(
            f"--measured: {', '.join(map(repr, unknown))} not among {', '.join(COMPONENTS)}"
        )
    if not set(POSITION) <= set(names):
        raise MeasurementError(
            f"--measured: every row measures its position; name x, y and z (got {','.join(names)})"
        )
    if not has_orientation and set(names) - set(POSITION):
        raise MeasurementError(
            f"--measured {','.join(names)}: {source} has no orientation columns (rvx, rvy, rvz "
            "or roll, pitch, yaw)"
        )
    return names


def check_ranges(
    table: NumericTable,
    source: str,
    units: dict[str, tuple[float, Sequence[str]]]
    | Sequence[tuple[str, float, Sequence[str]]]
    | None = None,
    error: type[Exception] = MeasurementError,
) -> None:
    """Refuse the first value outside its physical range (:mod:`arm.ranges`), naming the line and
    the column, the range in the file's unit. ``units``: unit name -> (SI per unit, columns), or
    (unit name, SI per unit, columns) triples."""
    factor: dict[str, tuple[float, str | None]] = {}
    triples = [(u, f, cols) for u, (f, cols) in units.items()] if isinstance(units, dict) else units
    for unit, f, cols in triples or ():
        factor |= {c: (f, unit) for c in cols}
    for k, h in enumerate(table.header):
        f, unit_name = factor.get(h, (1.0, None))
        column = table.values[:, k]  # NaN: a blank cell where one is allowed (not measured)
        bad = np.flatnonzero(out_of_range(h, column * f) & ~np.isnan(column))
        if bad.size:
            r = int(bad[0])
            v = table.values[r, k]
            why = payload_problem(v) if h == "payload" else None
            hint = ""
            if h in JOINTS and unit_name == "rad":
                hint = " (degrees read as radians? say --angle-unit deg)"
            elif h in _ANGLE_COLUMNS and unit_name == "rad":
                hint = " (degrees read as radians? say --orientation-unit deg)"
            elif h in POSITION and unit_name == "m":
                hint = " (millimetres read as metres? say --length-unit mm)"
            raise error(
                f"{source}, line {table.lines[r]}, column {h!r}: "
                + (
                    why
                    or f"{v:g} is outside the physical range {range_text(h, f, unit_name)}{hint}"
                )
            )


# -- pose files -------------------------------------------------------------------------------------
def poses_csv(q: np.ndarray, angle_unit: str = "rad") -> str:
    """Joint angles (N, 6) as a poses file: a ``#`` line with the schema version and unit, a
    header q1..q6, one pose per row."""
    f = 1.0 / ANGLE_UNITS[angle_unit]
    buf = io.StringIO()
    buf.write(
        f"# sixaxis-track poses to measure, schema_version {POSES_SCHEMA_VERSION}, "
        f"q1..q6 in {angle_unit}\n"
    )
    buf.write(",".join(JOINTS) + "\n")
    for row in np.asarray(q, dtype=float) * f:
        buf.write(",".join(repr(float(v)) for v in row) + "\n")
    return buf.getvalue()


def write_poses(q: np.ndarray, path: str | Path, angle_unit: str = "rad") -> None:
    """Write joint angles (N, 6) as a poses file, atomically."""
    atomic_write_text(Path(path), poses_csv(q, angle_unit))


_DECLARED_UNIT = re.compile(r"^\s*#.*\bq1\.\.q6 in (\w+)")
_DECLARED_LENGTH = re.compile(r"^\s*#.*\bx, ?y, ?z in (\w+)")


def _declared(
    text: str, source: str, pattern: re.Pattern[str], what: str, units: Mapping[str, float]
) -> tuple[str, int] | None:
    """The unit a ``#`` line before the header declares for ``what`` (``pattern``), with its
    line number, or None; an unknown unit is refused, naming the line."""
    for number, line in enumerate(_lines(text), start=1):
        if not line.strip():
            continue
        if not line.lstrip().startswith("#"):
            return None
        m = pattern.match(line)
        if m:
            if m.group(1) not in units:
                raise MeasurementError(
                    f"{source}, line {number}: declares {what} in {m.group(1)!r}; "
                    f"known units: {', '.join(sorted(units))}"
                )
            return m.group(1), number
    return None


def declared_angle_unit(text: str, source: str) -> tuple[str, int] | None:
    """The angle unit a poses file's ``#`` line declares (``q1..q6 in deg``), with its line
    number, or None where no such line precedes the header."""
    return _declared(text, source, _DECLARED_UNIT, "q1..q6", ANGLE_UNITS)


def declared_length_unit(text: str, source: str) -> tuple[str, int] | None:
    """The length unit a measurement file's ``#`` line declares (``x, y, z in mm``), with its
    line number, or None where no such line precedes the header."""
    return _declared(text, source, _DECLARED_LENGTH, "x, y, z", LENGTH_UNITS)


def file_units(
    text: str,
    source: str,
    length_unit: str | None,
    angle_unit: str | None,
    fallback: tuple[str, str] = ("m", "rad"),
) -> tuple[str, str]:
    """The units to read a measurement file in: those given, else those its ``#`` lines declare
    (``x, y, z in mm``, ``q1..q6 in deg``), else ``fallback``. A given unit that contradicts
    the declared one is refused, naming the line: read in the wrong unit, every row would be
    another."""
    out = []
    for given, found, what, option, default in (
        (length_unit, declared_length_unit(text, source), "x, y, z", "--length-unit", fallback[0]),
        (angle_unit, declared_angle_unit(text, source), "q1..q6", "--angle-unit", fallback[1]),
    ):
        if found is not None and given is not None and found[0] != given:
            raise MeasurementError(
                f"{source}, line {found[1]}: the file declares {what} in {found[0]}, but they "
                f"were to be read in {given}; say {option} {found[0]}"
            )
        out.append(given or (found[0] if found else default))
    return out[0], out[1]


def _declared_unit(text: str, source: str, angle_unit: str | None, or_else: str = "") -> str | None:
    """The angle unit the file's ``#`` line declares, or None; refused (naming that line) where
    it contradicts ``angle_unit``: read in the wrong unit, every pose would be another pose."""
    declared = declared_angle_unit(text, source)
    if declared is not None and angle_unit is not None and declared[0] != angle_unit:
        raise MeasurementError(
            f"{source}, line {declared[1]}: the file declares q1..q6 in {declared[0]}, but they "
            f"were to be read in {angle_unit}; say --angle-unit {declared[0]}{or_else}"
        )
    return None if declared is None else declared[0]


def read_poses(path: str | Path, angle_unit: str | None = None) -> np.ndarray:
    """Joint angles (N, 6) in rad from a CSV with columns q1..q6 (other columns are ignored: a
    measurement file is a poses file too). ``#`` lines before the header are skipped, one among
    the rows is refused (:func:`parse_numeric_csv`); blank lines are skipped.

    The unit is the one the file's ``#`` line declares (``sixaxis lab plan`` writes it), else
    ``angle_unit``, else rad. An ``angle_unit`` that contradicts the declaration is refused, naming
    the line: read in the wrong unit, every pose would be another pose."""
    text = read_text(path)
    declared = _declared_unit(text, str(path), angle_unit, " (or leave it out)")
    unit = declared or angle_unit or "rad"
    table = parse_numeric_csv(text, str(path), JOINTS, blank_lines=True, columns=JOINTS)
    if not len(table.values):
        raise MeasurementError(f"{path}: no pose rows")
    angle_unit = unit
    check_ranges(table, str(path), {angle_unit: (ANGLE_UNITS[angle_unit], JOINTS)})
    return table.values[:, [table.header.index(c) for c in JOINTS]] * ANGLE_UNITS[angle_unit]
