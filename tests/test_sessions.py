"""Several measurement files as the sessions they are (arm.sessions): a station column decides a
row's station, a file without one is a station of its own, the same id in two files is the same
station, and files with different optional columns join."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import lab
from arm.measurements import (
    MeasurementError,
    MeasurementSet,
    MeasurementWarning,
    read_measurements,
)
from arm.sessions import join_sessions


def _draw(name: str, n: int, seed: int) -> MeasurementSet:
    data = read_measurements(f"data/ur10/series_{name}.csv")
    rows = np.sort(np.random.default_rng(seed).choice(len(data), n, replace=False))
    return data.subset(rows)


def _without(data: MeasurementSet, column: str) -> MeasurementSet:
    cols = {k: v for k, v in data.columns.items() if k != column}
    return MeasurementSet(data.q, data.xyz, cols, data.source, std=data.std)


def test_the_ur10_series_join_as_their_stations_and_name_the_sessions():
    a, b, d = _draw("A", 60, 0), _draw("B", 50, 1), _draw("D", 40, 2)
    joined = join_sessions([a, b, d])
    assert joined.stations == (1, 2, 4)  # the files' own station ids
    assert [(s.source, s.rows, s.stations) for s in joined.sessions] == [
        ("data/ur10/series_A.csv", 60, (1,)),
        ("data/ur10/series_B.csv", 50, (2,)),
        ("data/ur10/series_D.csv", 40, (4,)),
    ]
    # A states no std_*: its rows take the stated noise (blank cells), B's and D's keep theirs
    assert joined.std is not None
    assert np.isnan(joined.std[:60, :3]).all()
    np.testing.assert_array_equal(joined.std[60:110, :3], b.std[:, :3])
    np.testing.assert_array_equal(joined.xyz, np.vstack([a.xyz, b.xyz, d.xyz]))
    # and the lab fits them: one base per station, the rows weighted where they state a sigma
    result = lab.fit(joined, "ur10_robot", "geometric", noise_mm=0.015, noise_ppm=6.0)
    assert result.model.stations == (1, 2, 4)
    assert {"bx1", "bx2", "bx4"} <= set(result.names)


def test_a_file_without_a_station_column_is_a_station_of_its_own():
    a, b = _without(_draw("A", 20, 3), "station"), _draw("B", 20, 4)
    c = _without(_draw("D", 20, 5), "station")
    joined = join_sessions([a, b, c])
    ids = [s.stations for s in joined.sessions]
    assert ids[1] == (2,)
    # new ids, none another file's: one past the largest id of any file, in turn
    assert ids[0] == (3,) and ids[2] == (4,)
    np.testing.assert_array_equal(joined.columns["station"], np.repeat([3.0, 2.0, 4.0], 20))


def test_the_same_station_id_in_two_files_is_one_station():
    b1, b2 = _draw("B", 20, 6), _draw("B", 25, 7)
    joined = join_sessions([b1, b2])
    assert joined.stations == (2,)
    assert [s.stations for s in joined.sessions] == [(2,), (2,)]


def test_a_column_some_files_lack_is_left_out_and_named():
    a, b = _draw("A", 20, 8), _without(_draw("B", 20, 9), "temperature")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        joined = join_sessions([a, b])
    assert "temperature" not in joined.columns
    said = [str(w.message) for w in caught if issubclass(w.category, MeasurementWarning)]
    assert any("'temperature'" in m and "series_B.csv" in m for m in said)


def test_one_file_is_itself_and_no_file_is_refused():
    a = _draw("A", 10, 10)
    one = join_sessions([a])
    np.testing.assert_array_equal(one.xyz, a.xyz)
    assert [(s.rows, s.stations) for s in one.sessions] == [(10, (1,))]
    with pytest.raises(MeasurementError, match="no measurement files"):
        join_sessions([])
