"""Shared by every benchmark script: write one named section of ``results/benchmarks.md``
atomically, leaving the other sections as they are, and describe the machine it ran on."""

from __future__ import annotations

import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from arm.files import atomic_write_text

RESULTS = Path(__file__).resolve().parents[1] / "results"
BENCHMARKS_MD = RESULTS / "benchmarks.md"
HEADER = (
    "# Benchmarks\n\n"
    "Measured by the scripts in `benchmarks/` (`make bench`), each writing its own section below. "
    "Absolute figures are for the machine named in each section; the ratio to the named peer, "
    "measured side by side in the same run, is the figure that travels.\n"
)


def _head() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
        ).stdout.strip()
    except OSError:
        return "?"


#: the commit checked out when the benchmark started (imported this module): a commit made while
#: it ran is not the code it ran
_STARTED_AT = _head()


def code_state(root: Path) -> dict:
    """``{"commit", "clean"}`` of the checkout at ``root``: clean when no tracked file outside
    ``results/`` has local changes. Another benchmark's results written before this one starts
    (``make real-data`` runs two in turn) do not change the code it runs."""
    from experiments.records import git_state, local_changes

    state = git_state(root)
    changed = local_changes(root)
    clean = changed is not None and not [c for c in changed if not c.startswith("results/")]
    return {"commit": state["commit"], "clean": clean}


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    rev = _STARTED_AT
    return (
        f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"commit {rev or '?'}, {time.strftime('%Y-%m-%d')}"
    )


def write_section(name: str, body: str) -> Path:
    """Replace (or append) section ``name`` of results/benchmarks.md with ``body`` (markdown)."""
    text = BENCHMARKS_MD.read_text() if BENCHMARKS_MD.exists() else HEADER
    block = f"<!-- section:{name} -->\n{body.rstrip()}\n<!-- /section:{name} -->"
    pattern = re.compile(
        rf"<!-- section:{re.escape(name)} -->.*?<!-- /section:{re.escape(name)} -->", re.S
    )
    text = (
        pattern.sub(lambda _: block, text)
        if pattern.search(text)
        else text.rstrip() + "\n\n" + block + "\n"
    )
    atomic_write_text(BENCHMARKS_MD, text)
    return BENCHMARKS_MD
