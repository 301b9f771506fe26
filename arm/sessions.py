"""Several measurement files as the sessions they are: one measurement set whose ``station``
column says which tracker station measured each row.

    data = join_sessions([read_measurements("A.csv"), read_measurements("B.csv")])
    data.sessions      # (Session("A.csv", 11911, (1,)), Session("B.csv", 1495, (2,)))

The rules (docs/format.md, several files):

- a ``station`` column decides a row's station, and the same id in two files means the same
  station (a station measured twice);
- a file without one is a station of its own: it takes a new id, one more than the largest id
  of any file, so that it collides with no station of another file;
- files with different optional columns join: a file without ``std_*`` cells contributes blank
  ones (its rows' uncertainty is the stated instrument noise); an orientation measured in some
  files only is blank (unmeasured) in the rows of the others; any other column that some files
  lack is left out of the joined set, with a :class:`~arm.measurements.MeasurementWarning` that
  names it and the files without it (an effect that reads it then says it is missing).

Rows are named by their index in the joined set (``row 12``): a line number would not say which
file it is of.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from arm.errors import warn
from arm.measurements import MeasurementError, MeasurementSet, MeasurementWarning, Session

__all__ = ["Session", "join_sessions"]


def _station_ids(sets: Sequence[MeasurementSet]) -> list[np.ndarray]:
    """Each set's station id per row: its own ``station`` column, else a new id per set."""
    own = [s.columns.get("station") for s in sets]
    taken = [int(v) for col in own if col is not None for v in np.unique(col)]
    nxt = max(taken, default=0) + 1
    out = []
    for s, col in zip(sets, own, strict=True):
        if col is None:
            col, nxt = np.full(len(s), float(nxt)), nxt + 1
        out.append(np.asarray(col, dtype=float))
    return out


def _shared_columns(sets: Sequence[MeasurementSet]) -> list[str]:
    """The columns every set has (but ``station``, which is made for all), in the first set's
    order; the others are named in a warning."""
    names: list[str] = []
    for s in sets:
        names += [c for c in s.columns if c not in names and c != "station"]
    shared = [c for c in names if all(c in s.columns for s in sets)]
    for c in names:
        if c not in shared:
            without = ", ".join(s.source for s in sets if c not in s.columns)
            text = (
                f"column {c!r} is not in {without}: left out of the joined sessions (an effect "
                "that reads it cannot be fitted on them)"
            )
            warn(text, MeasurementWarning)
    return shared


def _orientation(sets: Sequence[MeasurementSet]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The joined orientations and masks: a set that measured none has blank (unmeasured) ones."""
    if all(s.orientation is None for s in sets):
        return None, None
    rot = np.vstack(
        [np.zeros((len(s), 3)) if s.orientation is None else s.orientation for s in sets]
    )
    return rot, np.vstack([s.measured for s in sets])


def join_sessions(sets: Sequence[MeasurementSet], source: str | None = None) -> MeasurementSet:
    """The rows of several measurement sets (files: sessions) as one, by the module's rules,
    with ``sessions`` naming each file, its rows and its station ids. One set is returned as it
    is (its ``sessions`` filled in)."""
    if not sets:
        raise MeasurementError("no measurement files given")
    if len(sets) == 1:
        s = sets[0]
        return s if s.sessions else _with_sessions(s, [Session(s.source, len(s), _ids(s))])
    forms = {s.orientation_form for s in sets if s.orientation is not None}
    stations = _station_ids(sets)
    cols = {c: np.concatenate([s.columns[c] for s in sets]) for c in _shared_columns(sets)}
    cols["station"] = np.concatenate(stations)
    std = None
    if any(s.std is not None for s in sets):
        std = np.vstack([np.full((len(s), 6), np.nan) if s.std is None else s.std for s in sets])
    rot, mask = _orientation(sets)
    sessions = tuple(
        Session(s.source, len(s), tuple(int(v) for v in np.unique(ids)))
        for s, ids in zip(sets, stations, strict=True)
    )
    return MeasurementSet(
        np.vstack([s.q for s in sets]),
        np.vstack([s.xyz for s in sets]),
        cols,
        source or " + ".join(s.source for s in sets),
        orientation=rot,
        mask=mask,
        std=std,
        orientation_form=forms.pop() if len(forms) == 1 else "rotvec",
        notes=[n for s in sets for n in s.notes],
        sessions=sessions,
        labels={
            c: np.concatenate([s.labels[c] for s in sets])
            for c in sets[0].labels
            if all(c in s.labels for s in sets)
        },
    )


def _ids(s: MeasurementSet) -> tuple[int, ...]:
    return s.stations if "station" in s.columns else ()


def _with_sessions(s: MeasurementSet, sessions: list[Session]) -> MeasurementSet:
    from dataclasses import replace

    return replace(s, sessions=tuple(sessions))
