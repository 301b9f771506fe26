"""Bad values derived from every declaration are refused in one line naming the option, from the
library and from the command line (as scikit-learn's ``generate_invalid_param_val`` feeds its
common checks): for a range, values just outside each end, NaN, inf and a string; for a choice, a
value not in it; for a boolean, a non-boolean. And the instrument's noise has one rule wherever
it is taken."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from arm.constraints import Constraint, Interval, OneOf, TypeOf, constraints_of
from arm.noise import NOISE_MM, NOISE_MRAD, NOISE_PPM, InstrumentNoise, NoiseError
from envs.instrument import InstrumentError, TrackerConfig
from experiments.cli_inputs import LabInputs, cli_fields, flag_of
from lab.errors import FitError
from lab.options import LabOptions
from tests._cli import lab, one_error_line

UR5 = Path(__file__).resolve().parents[1] / "data" / "ur5" / "calibration.csv"


def invalid_values(c: Constraint) -> list[Any]:
    """Values that ``c`` refuses: just outside each end of a range (the end itself where it is
    open), NaN, inf, a string; a value not among a choice's; a non-boolean for a boolean."""
    if isinstance(c, Interval):
        out: list[Any] = [math.nan, math.inf, -math.inf, "15um"]
        step = 1 if c.kind is int else 1e-9
        if c.low is not None:
            out.append(c.low if c.closed in ("right", "neither") else c.low - step)
        if c.high is not None:
            out.append(c.high if c.closed in ("left", "neither") else c.high + step)
        if c.kind is int:
            out.append(1.5)
        return out
    if isinstance(c, OneOf):
        return ["no-such-choice", 1]
    if isinstance(c, TypeOf) and c.kind is bool:
        return [1, "yes"]
    return []


def _cases(cls: type, only: list[str] | None = None) -> list[tuple[str, Any]]:
    cases = []
    for name, (cons, _) in constraints_of(cls).items():
        if only is not None and name not in only:
            continue
        for c in cons:
            cases += [(name, v) for v in invalid_values(c)]
    return cases


def test_every_declaration_gives_bad_values():
    """The generator covers every declared field of the lab's options (a field it could not judge
    would be left untested)."""
    judged = {name for name, _ in _cases(LabOptions)}
    assert judged == set(cli_fields(LabOptions)), judged


@pytest.mark.parametrize(("name", "bad"), _cases(LabOptions))
def test_the_lab_options_refuse_each_bad_value_naming_it(name, bad):
    with pytest.raises(FitError) as info:
        LabOptions(**{name: bad})
    text = str(info.value)
    assert "\n" not in text and text.startswith(f"{name} must "), text


@pytest.mark.parametrize(("name", "bad"), _cases(TrackerConfig))
def test_the_tracker_refuses_each_bad_value_naming_it(name, bad):
    with pytest.raises(InstrumentError) as info:
        TrackerConfig(**{name: bad})
    text = str(info.value)
    assert "\n" not in text and text.startswith(f"{name} must "), text


@pytest.mark.parametrize(
    ("key", "quantity"), [("mm", NOISE_MM), ("ppm", NOISE_PPM), ("mrad", NOISE_MRAD)]
)
def test_the_instrument_model_refuses_each_bad_value_naming_it(key, quantity):
    for bad in invalid_values(quantity.constraint):
        with pytest.raises(NoiseError) as info:
            InstrumentNoise(**{key: bad})
        assert str(info.value).startswith(f"--noise-{key} must"), (bad, info.value)


def _cli_cases() -> list[tuple[str, str]]:
    """(flag, bad value as typed) of every option of ``lab fit`` that a declaration judges."""
    out = []
    for cls in (LabOptions, LabInputs):
        for name in cli_fields(cls):
            for c in constraints_of(cls)[name][0]:
                if isinstance(c, TypeOf):  # a bare flag takes no value to get wrong
                    continue
                out += [(flag_of(name), str(v)) for v in invalid_values(c)]
    return out


@pytest.mark.parametrize(("flag", "bad"), _cli_cases())
def test_the_command_line_refuses_each_bad_value_naming_the_flag(flag, bad):
    one_error_line(lab("fit", UR5, flag, bad), flag)


@pytest.mark.parametrize(
    ("command", "args"),
    [
        ("plan", []),
        ("collect", ["-o", "never.csv"]),
        ("diagnose", [str(UR5)]),
        ("discover", [str(UR5)]),
    ],
)
@pytest.mark.parametrize("flag", ["--noise-mm", "--noise-mrad"])
def test_every_command_takes_the_noise_by_one_rule(command, args, flag, tmp_path, monkeypatch):
    """The instrument's quantities are the same options everywhere: -1, NaN and a string are
    refused by each command in the same words."""
    monkeypatch.chdir(tmp_path)
    lines = set()
    for bad in ("-1", "nan", "15um"):
        err = one_error_line(lab(command, *args, flag, bad), flag)
        lines.add(err.split(", got")[0])
    assert lines == {f"error: {flag} must be >= 0 ({'mm' if flag == '--noise-mm' else 'mrad'})"}


def test_a_zero_noise_needs_a_distance_term_where_it_weighs_rows():
    """0 mm per axis states no noise unless a ppm term makes it grow with the distance: the lab
    and the instrument model take it with --noise-ppm and refuse it without, saying why; a
    simulated tracker draws none from it."""
    assert LabOptions(noise_mm=0.0, noise_ppm=6.0).instrument.ppm == 6.0
    assert InstrumentNoise(0.0, 6.0).positions_stated
    with pytest.raises(FitError, match="noise_mm 0 without noise_ppm"):
        LabOptions(noise_mm=0.0)
    with pytest.raises(NoiseError, match="--noise-mm 0 without --noise-ppm"):
        InstrumentNoise(0.0)
    assert TrackerConfig(noise_mm=0.0).noise_mm == 0.0
    one_error_line(lab("fit", UR5, "--noise-mm", "0"), "--noise-mm 0 without --noise-ppm")
    one_error_line(lab("plan", "--noise-mm", "0"), "--noise-mm 0 without --noise-ppm")
