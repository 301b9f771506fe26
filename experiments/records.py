"""Run records: one JSON file per run, written atomically, so a sweep can be killed at any moment
and resumed with nothing lost or duplicated.

    runs/<config-name>/
        _sweep.json                          # the sweep: config (normalised), its hash, the command
        mpc__geometric__seed0.json           # one record per run (agent__scenario__seedN)

A record carries everything needed to rerun it (``spec``), what came out (``metrics``, the error
series, the agent's report, the calibration errors), where it came from (``versions``, ``git``) and
how long it took (``timing``). Everything but ``timing`` is reproducible: the same spec gives the
same record. A failed run is a record too, with ``status = "failed"`` and its traceback.
"""

from __future__ import annotations

import functools
import importlib.metadata
import json
import logging
import math
import platform
import subprocess
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from arm.errors import SixAxisError
from arm.measurements import atomic_write_text

__all__ = [
    "RECORD_SCHEMA",
    "TIMING_FIELDS",
    "RecordError",
    "RunStore",
    "environment_info",
    "jsonable",
    "load_record",
    "repo_path",
    "source_root",
    "without_timing",
]

log = logging.getLogger(__name__)

RECORD_SCHEMA = 1
MANIFEST = "_sweep.json"
#: the parts of a record that vary from run to run of the same spec
TIMING_FIELDS = ("timing",)

_PACKAGES = (
    "sixaxis-track",
    "numpy",
    "scipy",
    "mujoco",
    "gymnasium",
    "casadi",
    "torch",
    "stable-baselines3",
)


class RecordError(SixAxisError, ValueError):
    """A record file that cannot be read, naming the file."""


def jsonable(obj: Any) -> Any:
    """Plain JSON data: numpy scalars and arrays to numbers and lists, tuples to lists, non-finite
    floats to null (strict JSON has no NaN)."""
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    tolist = getattr(obj, "tolist", None)  # numpy scalars and arrays
    if tolist is not None:
        return jsonable(tolist())
    return str(obj)


def without_timing(record: Mapping[str, Any]) -> dict[str, Any]:
    """The record without the fields that vary between runs of the same spec."""
    return {k: v for k, v in record.items() if k not in TIMING_FIELDS}


def load_record(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    try:
        rec = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RecordError(f"{p}: no such record") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RecordError(f"{p}: not a readable JSON record: {exc}") from None
    if not isinstance(rec, dict) or "spec" not in rec or "run_key" not in rec:
        raise RecordError(f"{p}: not a run record (no 'spec' or 'run_key')")
    if rec.get("schema") != RECORD_SCHEMA:
        raise RecordError(f"{p}: record schema {rec.get('schema')!r}, expected {RECORD_SCHEMA}")
    return rec


def dumps(record: Mapping[str, Any]) -> str:
    return json.dumps(jsonable(record), indent=1, sort_keys=True, allow_nan=False) + "\n"


class RunStore:
    """The records of one sweep in a directory: one ``<run_key>.json`` per run."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def path(self, run_key: str) -> Path:
        return self.root / f"{run_key}.json"

    def load(self, run_key: str) -> dict[str, Any] | None:
        p = self.path(run_key)
        return load_record(p) if p.exists() else None

    def write(self, record: Mapping[str, Any]) -> Path:
        """Write (or replace) a record atomically: readers see the old file or the whole new one."""
        p = self.path(record["run_key"])
        atomic_write_text(p, dumps(record))
        return p

    def paths(self) -> list[Path]:
        if not self.root.is_dir():
            return []
        return sorted(p for p in self.root.glob("*.json") if not p.name.startswith(("_", ".")))

    def records(self) -> Iterator[dict[str, Any]]:
        for p in self.paths():
            yield load_record(p)

    def write_manifest(self, manifest: Mapping[str, Any]) -> None:
        atomic_write_text(self.root / MANIFEST, dumps(manifest))

    def manifest(self) -> dict[str, Any] | None:
        p = self.root / MANIFEST
        if not p.exists():
            return None
        try:
            return json.loads(p.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise RecordError(f"{p}: not a readable sweep manifest: {exc}") from None


@functools.lru_cache(maxsize=1)
def environment_info() -> dict[str, Any]:
    """Python and package versions, and the git commit of the code (once per process)."""
    versions = {"python": platform.python_version()}
    for pkg in _PACKAGES:
        try:
            versions[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            versions[pkg] = None
    return {"versions": versions, "git": git_state()}


def source_root() -> Path:
    """The directory this package's source tree lives in (the repository, for a checkout)."""
    return Path(__file__).resolve().parents[1]


def repo_path(path: str | Path | None) -> str | None:
    """``path`` relative to the repository this package runs from, when it is an existing file
    inside it (so that a record names the config as any checkout of the repository can find it);
    otherwise as given."""
    if path is None:
        return None
    p = Path(path)
    try:
        return p.resolve().relative_to(source_root()).as_posix() if p.exists() else str(path)
    except (ValueError, OSError):
        return str(path)


def git_state(root: str | Path | None = None) -> dict[str, Any]:
    """The commit of the source tree this package runs from, and whether it has local changes."""
    root = Path(root) if root is not None else source_root()

    def git(*args: str) -> str | None:
        try:
            out = subprocess.run(
                ["git", *args], cwd=root, capture_output=True, text=True, timeout=30, check=False
            )
        except (OSError, subprocess.SubprocessError):
            return None
        return out.stdout.strip() if out.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    if commit is None:
        return {"commit": None, "dirty": None}
    status = git("status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "dirty": bool(status) if status is not None else None}
