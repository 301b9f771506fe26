"""``sixaxis demo``'s lab story: on the simulated arm with hidden elastic joints, the lab names
compliance and the model with it reaches the noise floor on held-out poses."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from experiments.cli import app
from experiments.cli_demo import lab_story


@pytest.mark.slow
def test_lab_story_names_the_hidden_effect_and_reaches_the_floor(tmp_path):
    out = lab_story("compliance", n=200, seed=7, out=tmp_path)
    assert out["verdict"] == "compliance"
    assert out["suggestion"].startswith("geometric,compliance")
    assert out["geometric_validation_rms_mm"] > 3 * out["noise_floor_mm"]  # visibly wrong
    assert out["full_validation_rms_mm"] < 1.2 * out["noise_floor_mm"]
    assert (tmp_path / "calibration.csv").exists() and (tmp_path / "validation.csv").exists()


def test_demo_refuses_an_unknown_scenario():
    result = CliRunner().invoke(app, ["demo", "--scenario", "warp", "--no-sweep"])
    assert result.exit_code == 2
    assert "warp" in result.output
