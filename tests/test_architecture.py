"""The layers stay apart: the arm model and the lab load no simulator, and the task contract loads
no plant."""

from __future__ import annotations

import subprocess
import sys


def _loaded_after(statement: str, modules: list[str]) -> list[str]:
    """The ``modules`` loaded by a fresh interpreter after ``statement``."""
    code = f"import sys\n{statement}\nprint(','.join(m for m in {modules!r} if m in sys.modules))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    return [m for m in out.stdout.strip().split(",") if m]


def test_arm_and_lab_load_neither_mujoco_nor_gymnasium():
    assert _loaded_after("import arm, lab", ["mujoco", "gymnasium"]) == []


def test_the_task_contract_loads_no_plant():
    loaded = _loaded_after("import envs.task", ["mujoco", "envs.plant", "envs.sixaxis_track_v0"])
    assert loaded == []
