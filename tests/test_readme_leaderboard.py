"""The README's leaderboard section is the committed results: every figure and every ordering it
states is written from ``results/leaderboard.json`` by ``sixaxis leaderboard --readme``, and
the README holds exactly that; its sentences claim only orderings the paired intervals resolve."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from experiments.leaderboard import README_BEGIN, README_END, readme_block, update_readme
from experiments.records import RecordError

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results" / "leaderboard.json"
README = ROOT / "README.md"


def _section(text: str) -> str:
    i, j = text.index(README_BEGIN), text.index(README_END)
    return text[i : j + len(README_END)] + "\n"


@pytest.mark.skipif(not RESULTS.exists(), reason="no leaderboard.json committed yet")
def test_the_readme_leaderboard_section_is_the_committed_results():
    data = json.loads(RESULTS.read_text())
    text = README.read_text()
    assert README_BEGIN in text and README_END in text
    assert _section(text) == readme_block(data)
    assert data["clean"] and data["drawn_seeds"] and data["episodes"] >= 20
    # every number of the section is the JSON's (rounded as the tables round)
    assert re.search(r"\d", _section(text))


def _fake(resolved: bool) -> dict:
    cell = {"value": 1.0, "lo": 0.9, "hi": 1.1, "n": 20}
    ratio = {"value": 0.9, "lo": 0.85, "hi": 0.95 if resolved else 1.05, "n": 20}
    return {
        "rank_by": "rms_settled_mm",
        "reference": "b",
        "scenarios": ["s"],
        "agents": ["a", "b", "o"],
        "oracles": ["o"],
        "informed": [],
        "order": ["o", "a", "b"],
        "cells": {
            a: {"s": {"rms_settled_mm": cell | {"value": v}}}
            for a, v in (("a", 0.5), ("b", 0.6), ("o", 0.7))
        },
        "best": {"s": "a"},
        "ranking": {"s": ["a", "b", "o"]},
        "orderings": {
            "s": [
                {"scenario": "s", "better": "a", "worse": "b", **ratio, "resolved": resolved},
                {"scenario": "s", "better": "b", "worse": "o", **ratio, "resolved": resolved},
            ]
        },
        "pairs": [
            {"scenario": "s", "better": "a", "worse": "b", **ratio, "resolved": resolved},
            {"scenario": "s", "better": "a", "worse": "o", **ratio, "resolved": resolved},
            {"scenario": "s", "better": "b", "worse": "o", **ratio, "resolved": resolved},
        ],
        "aggregate": {a: {"iqm": cell, "geomean": cell} for a in ("a", "b", "o")},
        "commits": ["c0ffee" * 6 + "c0ff"],
        "clean": True,
        "episodes": 20,
        "drawn_seeds": True,
        "runs": 60,
        "failed": 0,
        "settle_seconds": 2.0,
    }


def test_the_sentences_claim_only_resolved_orderings():
    yes = readme_block(_fake(resolved=True))
    assert "- `s`: `a` < `b` < `o`" in yes
    assert "`a` is the best contender, resolved against every other one" in yes
    assert "`a` tracks below `o` (oracle) on `s` (resolved)" in yes
    no = readme_block(_fake(resolved=False))
    assert "- `s`: `a` ≈ `b` ≈ `o`" in no
    assert "not resolved from it: `b`" in no
    assert "tracks below" not in no and " < " not in no
    assert "| a | **0.500** | 1.00 [0.900, 1.10] |" in no


def test_the_readme_section_is_rewritten_in_place_and_refused_without_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\nbefore\n\n{README_BEGIN}\nold\n{README_END}\n\nafter\n")
    block = readme_block(_fake(resolved=True))
    update_readme(readme, block)
    text = readme.read_text()
    assert text.startswith("# x\n\nbefore\n\n") and text.endswith("\n\nafter\n")
    assert _section(text) == block
    readme.write_text("# no markers\n")
    with pytest.raises(RecordError, match="no leaderboard section"):
        update_readme(readme, block)
    assert readme.read_text() == "# no markers\n"


def test_the_readme_says_what_each_learned_row_is_over():
    data = _fake(resolved=True) | {
        "compute": {
            "a": {"ranked_seeds": [1, 2, 3, 4, 5], "training_seeds": 5.0},
            "b": {"ranked_seeds": [], "training_seeds": None},
            "o": {"ranked_seeds": [], "training_seeds": 3.0, "training_picked": "median"},
        }
    }
    block = readme_block(data)
    assert "| a (5 seeds) | **0.500** |" in block
    assert "| b | 0.600 |" in block
    assert "| o (oracle) (1 seed: the median of 3 trained) |" in block
