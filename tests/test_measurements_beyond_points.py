"""The measurement CSV beyond one 3-D point (docs/format.md): the orientation of the tool frame as
a rotation vector or as roll-pitch-yaw (checked against rotation matrices multiplied out by hand),
in rad or deg; blank orientation cells where a row measured none; the instrument's mask; per-point
standard uncertainties in the file's units; the station column; and the columns the format does
not know, named in a warning or refused. Every refusal names the file, the line and the column."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from arm.measurements import (
    MeasurementError,
    MeasurementSet,
    MeasurementWarning,
    read_measurements,
    write_measurements,
)
from arm.so3 import rotation_matrix

Q = "0.1,-1.2,0.3,0.4,0.5,0.6"
HEAD = "q1,q2,q3,q4,q5,q6,x,y,z"


def _file(tmp_path, text: str):
    path = tmp_path / "data.csv"
    path.write_text(text, encoding="utf-8")
    return path


def _rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll), written out: the convention docs/format.md states."""
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def test_roll_pitch_yaw_in_degrees_is_the_stated_convention(tmp_path):
    angles = [(166.7134, -63.6497, -24.6327), (-174.8057, -61.8494, -46.6957), (10.0, 20.0, 30.0)]
    text = HEAD + ",roll,pitch,yaw\n"
    text += "".join(f"{Q},1,2,0.5,{r},{p},{y}\n" for r, p, y in angles)
    data = read_measurements(_file(tmp_path, text), orientation_unit="deg")
    assert data.has_orientation and data.orientation_form == "rpy"
    for k, a in enumerate(angles):
        want = _rpy_matrix(*np.radians(a))
        np.testing.assert_allclose(rotation_matrix(data.orientation[k]), want, atol=1e-14)
    assert data.measured.all()
    # q stays in rad: the orientation's unit is its own
    np.testing.assert_allclose(data.q[0], [0.1, -1.2, 0.3, 0.4, 0.5, 0.6])


def test_rotation_vector_and_blank_rows_and_the_instruments_mask(tmp_path):
    text = HEAD + ",rvx,rvy,rvz\n"
    text += f"{Q},1,2,0.5,0.1,-0.2,0.3\n{Q},1,2,0.6,,,\n{Q},1,2,0.7,0,0,1.5\n"
    path = _file(tmp_path, text)
    data = read_measurements(path)
    np.testing.assert_array_equal(data.orientation[0], [0.1, -0.2, 0.3])
    np.testing.assert_array_equal(data.measured[:, 3:].any(axis=1), [True, False, True])
    assert data.measured[:, :3].all()
    tilt = read_measurements(path, measured=["x", "y", "z", "rx", "ry"])
    np.testing.assert_array_equal(tilt.measured[0], [1, 1, 1, 1, 1, 0])
    np.testing.assert_array_equal(tilt.measured[1], [1, 1, 1, 0, 0, 0])
    # a subset keeps what each row measured
    np.testing.assert_array_equal(tilt.subset([2]).measured, [[1, 1, 1, 1, 1, 0]])
    with pytest.raises(MeasurementError, match="every row measures its position"):
        read_measurements(path, measured=["x", "y", "rx"])
    with pytest.raises(MeasurementError, match="'roll' not among"):
        read_measurements(path, measured=["x", "y", "z", "roll"])
    plain = _file(tmp_path, HEAD + f"\n{Q},1,2,3\n")
    with pytest.raises(MeasurementError, match="has no orientation columns"):
        read_measurements(plain, measured=["x", "y", "z", "rz"])


def test_stds_are_read_in_the_files_units(tmp_path):
    text = HEAD + ",roll,pitch,yaw,std_x,std_y,std_z,std_rx,std_ry,std_rz,station\n"
    text += f"{Q},1000,2000,500,10,20,30,0.015,0.02,0.025,0.01,0.01,0.02,1\n"
    text += f"{Q},1000,2000,600,,,,0.03,0.03,0.03,,,,2\n"
    data = read_measurements(
        _file(tmp_path, text), length_unit="mm", angle_unit="rad", orientation_unit="deg"
    )
    np.testing.assert_allclose(data.std[0], [15e-6, 2e-5, 2.5e-5, *np.radians([0.01, 0.01, 0.02])])
    np.testing.assert_allclose(data.std[1, :3], 3e-5)
    assert np.isnan(data.std[1, 3:]).all()  # no orientation in that row, no uncertainty of it
    assert data.stations == (1, 2) and "station" in data.columns
    assert data.notes == []


def test_round_trip_of_every_new_column(tmp_path):
    rng = np.random.default_rng(3)
    n = 6
    mask = np.ones((n, 6), dtype=bool)
    mask[2, 3:] = False
    std = np.column_stack([rng.uniform(1e-5, 3e-5, (n, 3)), rng.uniform(1e-5, 5e-5, (n, 3))])
    std[2, 3:] = np.nan
    for form, lu, au in (("rotvec", "m", "rad"), ("rpy", "mm", "deg")):
        data = MeasurementSet(
            rng.uniform(-1, 1, (n, 6)),
            rng.uniform(-2, 2, (n, 3)),
            {"station": rng.choice([1.0, 3.0], n), "target": np.zeros(n)},
            orientation=rng.uniform(-1, 1, (n, 3)),
            mask=mask,
            std=std,
            orientation_form=form,
        )
        path = tmp_path / f"{form}.csv"
        write_measurements(data, path, lu, "rad", orientation_unit=au)
        assert ",,," in path.read_text()  # the row without orientation is blank there
        back = read_measurements(path, lu, "rad", orientation_unit=au)
        assert back.orientation_form == form
        np.testing.assert_array_equal(back.measured, mask)
        keep = mask[:, 3]
        R0 = rotation_matrix(data.orientation[keep])
        np.testing.assert_allclose(rotation_matrix(back.orientation[keep]), R0, atol=1e-13)
        np.testing.assert_allclose(back.std, std, rtol=1e-13)
        np.testing.assert_array_equal(back.columns["station"], data.columns["station"])


REFUSED = {
    "half an orientation blank": (
        ",rvx,rvy,rvz\n" + f"{Q},1,2,3,0.1,,0.2\n",
        {},
        ["line 2", "'rvy'", "leave all three blank"],
    ),
    "two orientation forms": (",rvx,rvy,rvz,roll\n" + f"{Q},1,2,3,0,0,0,0\n", {}, ["one form"]),
    "an incomplete orientation": (",roll,pitch\n" + f"{Q},1,2,3,0,0\n", {}, ["missing", "yaw"]),
    "orientation degrees read as radians": (
        ",roll,pitch,yaw\n" + f"{Q},1,2,3,166.7,-63.6,-24.6\n",
        {},
        ["line 2", "'roll'", "--orientation-unit deg"],
    ),
    "a zero std": (
        ",std_x,std_y,std_z\n" + f"{Q},1,2,3,0.001,0,0.001\n",
        {},
        ["line 2", "'std_y'", "0 < std_y <= 1 m"],
    ),
    "stds not together": (",std_x,std_y\n" + f"{Q},1,2,3,0.001,0.001\n", {}, ["'std_z'"]),
    "an orientation std without an orientation": (
        ",std_rx,std_ry,std_rz\n" + f"{Q},1,2,3,0.001,0.001,0.001\n",
        {},
        ["'std_rx'", "no orientation columns"],
    ),
    "an orientation without its std": (
        ",rvx,rvy,rvz,std_rx,std_ry,std_rz\n"
        + f"{Q},1,2,3,0,0,0,0.001,0.001,0.001\n{Q},1,2,3,0,0,0,,,\n",
        {},
        ["line 3", "'std_rx'", "measured an orientation"],
    ),
    "a blank std of a position": (
        ",std_x,std_y,std_z\n" + f"{Q},1,2,3,,0.1,0.1\n",
        {},
        ["'std_x'"],
    ),
    "a station that is not an integer": (
        ",station\n" + f"{Q},1,2,3,1.5\n",
        {},
        ["line 2", "'station'", "integer"],
    ),
    "a tracker's Rx Ry Rz": (
        ",Rx,Ry,Rz\n" + f"{Q},1,2,3,1,2,3\n",
        {},
        ["line 1", "'Rx'", "rvx, rvy, rvz", "roll, pitch, yaw"],
    ),
    "a quaternion": (",qw,qx,qy,qz\n" + f"{Q},1,2,3,1,0,0,0\n", {}, ["'qw'"]),
    "a known name in other case": (",Temperature\n" + f"{Q},1,2,3,20\n", {}, ["'temperature'"]),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_bad_new_columns_are_refused_naming_where(tmp_path, case):
    tail, kw, fragments = REFUSED[case]
    path = _file(tmp_path, HEAD + tail)
    with pytest.raises(MeasurementError) as err:
        read_measurements(path, **kw)
    msg = str(err.value)
    assert str(path) in msg
    for f in fragments:
        assert f in msg, (case, f, msg)


def test_an_unknown_column_is_kept_and_named_in_a_warning(tmp_path):
    path = _file(tmp_path, HEAD + ",humidity,stdx\n" + f"{Q},1,2,3,45,0.01\n")
    with pytest.warns(MeasurementWarning) as record:
        data = read_measurements(path)
    text = str(record[0].message)
    assert "'humidity'" in text and "'stdx' (did you mean 'std_x'?)" in text
    assert data.notes == [text]
    assert set(data.columns) == {"humidity", "stdx"}  # kept, offered to custom effects
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a file of known columns reads without a warning
        read_measurements(_file(tmp_path, HEAD + ",t,station\n" + f"{Q},1,2,3,0,1\n"))


def test_the_instrument_model_and_the_rows_own_uncertainties():
    from arm.noise import InstrumentNoise, NoiseError

    xyz = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 2.0], [1.0, 0.0, 0.0]])
    std = np.full((3, 6), np.nan)
    std[1, :3] = 1e-4  # the second row states its own
    mask = np.ones((3, 6), dtype=bool)
    mask[2, 3:] = False  # the third measured no orientation
    data = MeasurementSet(np.zeros((3, 6)), xyz, orientation=np.zeros((3, 3)), mask=mask, std=std)
    sig = InstrumentNoise(mm=0.015, ppm=6.0, mrad=0.1).sigmas(data)
    np.testing.assert_allclose(sig[0, :3], 15e-6 + 6e-6 * 5.0)  # 5 m from the tracker
    np.testing.assert_allclose(sig[1, :3], 1e-4)
    np.testing.assert_allclose(sig[:2, 3:], 1e-4)
    assert np.isnan(sig[2, 3:]).all()
    assert np.isnan(InstrumentNoise(mm=0.015).sigmas(data)[0, 3:]).all()  # not stated
    assert "15 um + 6 um/m" in InstrumentNoise(mm=0.015, ppm=6.0).text()
    for bad in (dict(mm=-1.0), dict(ppm=float("nan")), dict(mrad=0.0), dict(mm=0.0)):
        with pytest.raises(NoiseError):
            InstrumentNoise(**bad)
