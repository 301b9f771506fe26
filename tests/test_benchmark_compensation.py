"""benchmarks/compensation.py, one scenario small: the lab's printed path calibrates the plant,
the compensated program runs on it, and the measured error falls to the fit's held-out error;
the results files carry the keys the issue names."""

from __future__ import annotations

import json

import pytest

from benchmarks.compensation import main


def test_one_scenario_small_compensates_on_the_plant(tmp_path):
    doc = main(
        ["--scenarios", "compliance", "--n-cal", "60", "--n-program", "10", "--out", str(tmp_path)]
    )
    written = json.loads((tmp_path / "compensation.json").read_text())
    assert written == json.loads(json.dumps(doc))
    assert len(written["commit"]) == 40
    r = written["scenarios"]["compliance"]
    assert {"nominal_mm", "compensated_mm", "fit_heldout_mm"} <= set(r)
    assert r["verdict"] == "compliance" and r["converged"] == 10
    # millimetres as the program is; the fit's own held-out error once compensated
    assert r["nominal_mm"] > 1.0
    assert r["compensated_mm"] < 0.1 * r["nominal_mm"]
    assert r["compensated_mm"] < 1.5 * r["fit_heldout_mm"]
    assert r["fit_heldout_mm"] == pytest.approx(0.026, rel=0.4)  # the tracker's noise floor
    assert "| compliance | compliance |" in (tmp_path / "compensation.md").read_text()
