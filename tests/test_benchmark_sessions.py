"""benchmarks/sessions.py: a campaign's sessions differ as the issue says (a new station, the
joints re-homed, the physics the same), every method is scored on rows it did not fit, and the
summary counts the targets from the records."""

from __future__ import annotations

import numpy as np
import pytest

from arm import seed_robot
from benchmarks.sessions import (
    KS,
    PLANNED,
    REHOME_MRAD,
    Session,
    _physics,
    draw,
    run_campaign,
    summarise,
)


def test_a_new_session_keeps_the_physics_and_moves_the_rest():
    rng = np.random.default_rng(0)
    spec = draw(3)
    truth, physics, _ = _physics(spec, seed_robot(), rng)
    a = Session(truth, physics, 1, rng, 15e-6)
    b = Session(truth, physics, 9, rng, 15e-6, remount_mm=1.0)
    la, lb = a.model.layout, b.model.layout
    for n in ("da2", "dalpha3", "dd4"):
        assert a.p[la.index(n)] == b.p[lb.index(n)]
    shifts = [abs(a.p[la.index(f"dtheta{j}")] - b.p[lb.index(f"dtheta{j}")]) for j in range(1, 7)]
    assert 0 < max(shifts) <= 2e-3 * REHOME_MRAD
    assert np.linalg.norm(a.p[la.index("bx")] - b.p[lb.index("bx")]) > 0
    q = b.poses(50)  # in the session's own box of the joint space (a little wider)
    assert np.all(q >= b.box[0] - 0.2) and np.all(q <= b.box[1] + 0.2)


@pytest.mark.slow
def test_a_campaign_records_every_method_and_the_summary_counts_them():
    rec = run_campaign(1)
    assert "error" not in rec, rec.get("error")
    assert set(rec["k"]) == {str(k) for k in KS} and set(rec["planned"]) == {
        str(k) for k in PLANNED
    }
    assert rec["k"]["10"]["geometric_alone"] is None  # 10 poses cannot fit 30 parameters alone
    # the update from 50 poses is near the floor; the prior alone (re-homed) is not
    assert rec["k"]["50"]["update"] < 3 * rec["floor_mm"] < rec["k"]["50"]["prior"]
    s = summarise([rec, {"seed": 2, "error": "FitError: x"}])
    assert s["campaigns"] == 2 and s["failed"] == 1
    assert s["k"]["50"]["median_mm"]["update"] == rec["k"]["50"]["update"]
    assert set(s["targets"]) >= {"k0_never_above_geometric", "prediction_within"}
