"""Every ``sixaxis lab`` option comes from one declaration, and a printed next step carries what
the user gave: each step that ``diagnose`` and ``discover`` print (diagnose -> fit, diagnose ->
discover, discover -> fit) is parsed by the command it names, and repeats every option of the run
that printed it which that command takes (its value unchanged), but the few a step replaces on
purpose; it passes none that the command refuses."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from experiments.cli import app
from experiments.cli_inputs import NOT_CARRIED

UR5 = Path(__file__).resolve().parents[1] / "data" / "ur5" / "calibration.csv"
runner = CliRunner()
NEXT = re.compile(r"(?:next:|fit it with:|which explains part:)[^\n]*?sixaxis (lab [^\n]+)")
#: what a step replaces on purpose: the model it fits or starts from (and discover -> fit adds
#: the module it wrote to the user's)
REPLACED = {"effects"}


def _lab_command(name: str):
    group = typer.main.get_command(app)
    lab = group.get_command(None, "lab")  # type: ignore[attr-defined]
    return lab.get_command(None, name)


def _parsed(words: list[str]) -> tuple[str, dict]:
    """``lab COMMAND ARGS...`` parsed by the registered command (unknown or refused options
    raise), without running it: (command, its values by parameter name)."""
    assert words[0] == "lab", words
    cmd = _lab_command(words[1])
    ctx = cmd.make_context(words[1], list(words[2:]))
    return words[1], dict(ctx.params)


def _mm_deg_copy(tmp_path: Path) -> Path:
    """The public UR5 set in millimetres and degrees (non-default units)."""
    raw = np.loadtxt(UR5, delimiter=",", skiprows=1)
    rows = np.hstack([np.degrees(raw[:, :6]), 1e3 * raw[:, 6:9]])
    path = tmp_path / "ur5_mm_deg.csv"
    np.savetxt(
        path, rows, delimiter=",", header="q1,q2,q3,q4,q5,q6,x,y,z", comments="", fmt="%.12g"
    )
    return path


#: a user's effect module (a second harmonic per turn)
MODULE = Path(__file__).resolve().parents[1] / "examples" / "second_harmonic.py"


def _every_option(data: Path, module: Path) -> list[str]:
    """Every shared option away from its default (and diagnose/discover's --alpha)."""
    return [
        "--robot", "ur5", "--noise-mm", "0.03", "--noise-ppm", "6", "--noise-mrad", "0.2",
        "--orientation-unit", "deg", "--measured", "x,y,z", "--length-unit", "mm",
        "--angle-unit", "deg", "--effect-module", str(module), "--solver", "minpack",
        "--max-evaluations", "150", "--no-register", "--alpha", "0.03",
    ]  # fmt: skip


def _check_steps(first: list[str], output: str, kinds: set[str]) -> None:
    """Each printed step parses, repeats every option of ``first`` that its command takes (but
    the replaced ones), and the steps of ``kinds`` were all printed."""
    _, given = _parsed(first)
    first_cmd = _lab_command(first[1])
    set_by_user = {
        p.name for p in first_cmd.params if p.name in given and given[p.name] != p.default
    }
    steps = [shlex.split(s) for s in dict.fromkeys(NEXT.findall(output))]
    assert {s[1] for s in steps} >= kinds, (kinds, steps, output)
    for words in steps:
        name, values = _parsed(words)  # a refused or unknown option raises here
        takes = {p.name for p in _lab_command(name).params}
        carried = (set_by_user & takes) - REPLACED - NOT_CARRIED - {"data"}
        assert carried, words
        for key in carried:
            if key == "effect_module":  # discover -> fit: the user's modules, then its own
                assert list(given[key]) == list(values[key])[: len(given[key])], (key, words)
            else:
                assert values[key] == given[key], (key, values[key], given[key], words)
        assert "--noise-ppm" in words, words


@pytest.mark.slow
def test_diagnose_and_discover_steps_repeat_every_option(tmp_path, monkeypatch, user_effects):
    monkeypatch.chdir(tmp_path)
    module, data = MODULE, _mm_deg_copy(tmp_path)
    options = _every_option(data, module)
    # diagnose: with the screening options discover refuses (none may be passed on)
    first = ["lab", "diagnose", str(data), *options, "--loss", "huber", "--outliers", "keep"]
    first += ["--accept-large", "--f-scale-mm", "0.05"]
    res = runner.invoke(app, first)
    assert res.exit_code == 0, res.output
    _check_steps(first, res.output, {"fit", "discover"})
    # discover -> the fit of the module it wrote
    first = ["lab", "discover", str(data), *options, "--order", "60", "-o", "found.py"]
    res = runner.invoke(app, first)
    assert res.exit_code == 0, res.output
    _check_steps(first, res.output, {"fit"})


@pytest.mark.parametrize(
    ("first", "nxt"), [("diagnose", "fit"), ("diagnose", "discover"), ("discover", "fit")]
)
def test_a_step_repeats_what_its_command_takes_and_nothing_else(first, nxt, tmp_path):
    """Without running the lab: the flags :meth:`LabArgs.next_step` derives for a step, from a
    run given every option its command takes away from its default, parse as the next command's
    and repeat each value it takes (``diagnose --loss huber`` once printed a ``discover`` step
    with ``--loss``, which discover refuses; ``--noise-ppm 6`` was dropped)."""
    from experiments.cli_inputs import LabArgs
    from experiments.cli_output import command_line

    module = tmp_path / "mine.py"
    module.write_text("")
    args = [str(UR5), *_every_option(UR5, module), "--validate", str(UR5)]
    if first == "diagnose":
        args = [a for a in args if a not in ("--validate", str(UR5))] + [str(UR5)]
        args = [args[-1], *args[:-1]]
        args += ["--loss", "huber", "--outliers", "keep", "--accept-large", "--f-scale-mm", "0.05"]
    group = typer.main.get_command(app).get_command(None, "lab")  # type: ignore[attr-defined]
    ctx = _lab_command(first).make_context(
        first, args, parent=typer.Context(group, info_name="lab")
    )
    flags = LabArgs(run=ctx).next_step(nxt)
    step = shlex.split(
        command_line("lab", nxt, UR5, **{"--effects": "geometric,compliance"}, **flags)
    )
    _, values = _parsed(step[1:])  # a refused or unknown option raises here
    takes = {p.name for p in _lab_command(nxt).params}
    given = {p.name for p in _lab_command(first).params if ctx.params.get(p.name) != p.default}
    carried = (given & takes) - REPLACED - NOT_CARRIED - {"data"}
    assert "noise_ppm" in carried and "--noise-ppm" in step, step
    for key in carried:
        assert values[key] == ctx.params[key], (key, step)
    refused = given - takes
    assert not any(
        _lab_command(first).params[[p.name for p in _lab_command(first).params].index(k)].opts[0]
        in step
        for k in refused
    ), step
