"""No printed next step ends in an error: the commands that ``sixaxis lab diagnose`` and
``sixaxis lab discover`` print (the fit of a suggestion, the discovery that continues an
unexplained diagnosis, the fit of a written module) are run as printed, and so are theirs, on the
public UR5 set and on a simulated arm with cyclic errors."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from arm import seed_robot
from arm.errormodel import ErrorModel
from arm.sampling import sample_parameters, sample_poses
from experiments.cli import app

UR5 = Path(__file__).resolve().parents[1] / "data" / "ur5"
runner = CliRunner()
# a printed next step: after "next:", "fit it with:" or "which explains part:", to the line's end
NEXT = re.compile(r"(?:next:|fit it with:|which explains part:)[^\n]*?(sixaxis lab [^\n]+)")


def _walk(command: str, depth: int = 4) -> list[str]:
    """Run ``command`` as printed, then every next step it prints (depth first); returns every
    command run, in order. Each must succeed."""
    words = shlex.split(command)
    assert words[:2] == ["sixaxis", "lab"], command
    res = runner.invoke(app, words[1:])
    assert res.exit_code == 0, f"{command}\n{res.output}"
    ran = [command]
    if depth:
        for nxt in dict.fromkeys(m for line in res.output.splitlines() for m in NEXT.findall(line)):
            ran += _walk(nxt.strip(), depth - 1)
    return ran


@pytest.mark.slow
def test_the_ur5_sets_next_steps_run_as_printed(tmp_path, monkeypatch, user_effects):
    """diagnose -> (the catalogue's best fit; discover -> the fit of its module): each printed
    command runs, with the arm, units and noise the user gave."""
    monkeypatch.chdir(tmp_path)
    ran = _walk(f"sixaxis lab diagnose {UR5 / 'calibration.csv'} --robot ur5 --noise-mm 0.03")
    kinds = [shlex.split(c)[2] for c in ran]
    assert kinds[0] == "diagnose" and "discover" in kinds, ran
    assert sum(k == "fit" for k in kinds) >= 2, ran  # the suggestion, and the module
    assert any("--effect-module discovered.py" in c for c in ran), ran
    assert all("--robot ur5" in c for c in ran), ran


def test_a_simulated_arms_next_steps_run_as_printed(tmp_path, monkeypatch, user_effects):
    """A compliant arm with a cyclic error of order 19 on joint 2, in millimetres and degrees:
    the diagnosis's suggestion (compliance and the cyclic error) fits as printed."""
    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(8)
    truth = ErrorModel(seed_robot(), "geometric,compliance[2,3],cyclic[2:19]")
    p = sample_parameters(truth, rng)
    q = sample_poses(seed_robot(), 250, rng)
    xyz = truth.predict(truth.inputs(q), p) + rng.normal(0.0, 15e-6, (250, 3))
    path = tmp_path / "sim.csv"
    rows = np.hstack([np.degrees(q), 1e3 * xyz])
    header = "q1,q2,q3,q4,q5,q6,x,y,z"
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt="%.12g")
    ran = _walk(f"sixaxis lab diagnose {path} --length-unit mm --angle-unit deg --noise-mm 0.015")
    assert len(ran) >= 2 and "cyclic[2:19]" in ran[1] and "compliance[2,3]" in ran[1], ran
    assert all("--length-unit mm --angle-unit deg" in c for c in ran), ran
