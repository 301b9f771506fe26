"""A user's own agent, end to end, as docs/benchmark.md shows it: a package in a blank working
folder (no PYTHONPATH, nothing installed) swept by class path with the ``sixaxis`` console script,
the leaderboard built, its run recording the module's file and hash, and ``sixaxis reproduce`` of
its row from another folder; a changed module is named and its row not rerun."""

from __future__ import annotations

import csv
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.records import git_state

GIT = git_state()
CLEAN = bool(GIT.get("commit")) and GIT.get("dirty") is False
SIXAXIS = Path(sys.executable).with_name("sixaxis")

AGENT = '''from agents.reference import NominalAgent


class MyAgent(NominalAgent):
    """The nominal controller with a stiffer gain."""

    name = "my-agent"

    def __init__(self, gain: float = 0.8) -> None:
        super().__init__(gain=gain)
'''
CONFIG = """name = "my_sweep"
seeds = 2
episode_seconds = 1.0
settle_seconds = 0.5
scenarios = ["geometric"]
agents = ["nominal", "mypkg.myagent:MyAgent"]
"""


def sixaxis(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["COLUMNS"] = "200"
    return subprocess.run(
        [str(SIXAXIS), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """A blank folder with a package and a config, swept and tabled by the console script."""
    work = tmp_path_factory.mktemp("my-bench")
    (work / "mypkg").mkdir()
    (work / "mypkg" / "__init__.py").write_text("")
    (work / "mypkg" / "myagent.py").write_text(AGENT)
    (work / "my_sweep.toml").write_text(CONFIG)
    res = sixaxis(work, "sweep", "my_sweep.toml", "--out", "runs", "-w", "0")
    assert res.returncode == 0, res.stdout + res.stderr
    args = ["leaderboard", "runs", "--out", "lb", "--no-plots"]
    res = sixaxis(work, *args, *([] if CLEAN else ["--allow-dirty"]))
    assert res.returncode == 0, res.stdout + res.stderr
    return work


@pytest.mark.slow
@pytest.mark.skipif(not SIXAXIS.exists(), reason="the sixaxis console script is not installed")
def test_a_package_in_the_working_folder_is_swept_and_its_module_recorded(swept):
    module = swept / "mypkg" / "myagent.py"
    record = json.loads((swept / "runs" / "MyAgent__geometric__ep0.json").read_text())
    assert record["status"] == "ok"
    assert record["agent_module"] == {
        "module": "mypkg.myagent",
        "file": str(module.resolve()),
        "root": str(swept.resolve()),
        "sha256": hashlib.sha256(module.read_bytes()).hexdigest(),
    }
    assert record["config_path"] == str((swept / "my_sweep.toml").resolve())
    rows = {r["run_key"]: r for r in csv.DictReader((swept / "lb" / "leaderboard_runs.csv").open())}
    mine = rows["MyAgent__geometric__ep0"]
    assert mine["agent_module"] == str(module.resolve())
    assert mine["agent_module_sha256"] == record["agent_module"]["sha256"]
    assert rows["nominal__geometric__ep0"]["agent_module"] == ""  # the commit holds its code
    # the agent did run: its stiffer gain tracks otherwise than nominal on the same episode
    assert mine["rms_mm"] != rows["nominal__geometric__ep0"]["rms_mm"]


@pytest.mark.slow
@pytest.mark.skipif(not SIXAXIS.exists(), reason="the sixaxis console script is not installed")
@pytest.mark.skipif(
    not CLEAN, reason="the rows name this checkout's commit: it must have no local changes"
)
def test_its_row_reproduces_from_another_folder_and_a_changed_module_is_named(swept, tmp_path):
    summary = swept / "lb" / "leaderboard_runs.csv"
    res = sixaxis(tmp_path, "reproduce", str(summary), "--run", "MyAgent__geometric__ep0")
    assert res.returncode == 0, res.stdout + res.stderr
    assert "reproduced: every metric of 1 row(s) is the same" in res.stdout
    module = swept / "mypkg" / "myagent.py"
    module.write_text(AGENT.replace("gain: float = 0.8", "gain: float = 0.9"))
    res = sixaxis(tmp_path, "reproduce", str(summary), "--run", "MyAgent__geometric__ep0")
    assert res.returncode == 1
    assert "the agent module mypkg.myagent" in res.stdout and "changed since the run" in res.stdout
    assert "MyAgent__geometric__ep0 (line" in res.stdout and "not rerun" in res.stdout
