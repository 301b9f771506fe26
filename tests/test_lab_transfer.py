"""Terms chosen by whether they transfer (issue 32, item 2): with a ``session`` (or ``station``)
column the diagnosis's choice is confirmed by leaving each session out in turn. An effect both
sessions share is kept; one present in a single session helps nowhere it was not fitted, and is
dropped, though the diagnosis's tests on the pooled rows chose it."""

from __future__ import annotations

import numpy as np
import pytest

from arm.description import load_robot
from arm.measurements import concatenate
from lab import diagnose, discover
from lab.options import LabOptions
from lab.transfer import block_column, blocked_rms
from tests._lab_data import session

SIGMA = 15e-6
SHARED = {"c2": 6e-6, "c3": 4e-6, "da2": 2e-4, "dtheta3": 8e-4}


def test_an_effect_of_one_session_only_is_not_kept():
    one = session(SHARED, 120, 1, 1)
    two = session(SHARED | {"ts4": 6e-4, "tc4": -3e-4}, 120, 2, 2)
    three = session(SHARED, 120, 3, 5)
    data = concatenate([one, two, three], source="three-sessions.csv")
    assert block_column(data) == "session" and block_column(one) is None
    # two sessions: confirmed only when asked (each fold would fit one session alone)
    pair = concatenate([one, two])
    assert diagnose(pair, "seed", "geometric", noise_mm=0.015).blocked_cv is None
    d = diagnose(data, "seed", "geometric", noise_mm=0.015)
    assert d.blocked_cv is not None and d.blocked_cv["column"] == "session"
    tried = {r["without"] for r in d.blocked_cv["models"]}
    assert {"compliance", "transmission"} <= tried  # the pooled tests chose both
    # the one session's gear error is dropped, and so is what the pooled tests took for parts
    # of it (a gear-ratio error, harmonics of that joint): the shared compliance stays
    assert "transmission" in d.blocked_cv["dropped"]
    assert d.suggestion == "geometric,compliance[2,3]"
    assert "dropped, no help where not fitted: " in d.summary()
    assert d.to_dict()["blocked_cv"] == d.blocked_cv


def test_the_blocked_rms_predicts_each_session_from_the_other():
    one = session(SHARED, 120, 1, 3)
    two = session(SHARED, 120, 2, 4)
    data = concatenate([one, two])
    opts = LabOptions(noise_mm=0.015)
    rms = blocked_rms(data, load_robot("seed"), "geometric,compliance", opts)
    assert set(rms) == {1.0, 2.0}
    # the shared effects transfer: each session predicted near the noise floor (sigma sqrt 3)
    assert all(v < 2.0 * SIGMA * np.sqrt(3) for v in rms.values())
    worse = blocked_rms(data, load_robot("seed"), "geometric", opts)
    assert all(worse[b] > 2 * rms[b] for b in rms)
    with pytest.raises(Exception, match="no session or station column"):
        blocked_rms(one, load_robot("seed"), "geometric", opts)


def test_a_term_discovered_in_one_session_only_is_not_kept():
    one = session(SHARED, 120, 1, 1)
    two = session(SHARED | {"ts4": 6e-4, "tc4": -3e-4}, 120, 2, 2)
    three = session(SHARED, 120, 3, 5)
    data = concatenate([one, two, three], source="three-sessions.csv")
    pooled = discover(data, "seed", "geometric,compliance", noise_mm=0.015, across_blocks=False)
    assert pooled.terms and pooled.blocked_cv is None  # the pooled search finds joint 4's error
    d = discover(data, "seed", "geometric,compliance", noise_mm=0.015)
    assert d.blocked_cv is not None and d.blocked_cv["dropped"] == ["discovered"]
    assert not d.terms and d.suggestion is None and d.verdict != "discovered"
    assert d.to_dict()["blocked_cv"]["column"] == "session"
