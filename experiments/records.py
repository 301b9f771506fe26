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

import contextlib
import dataclasses
import functools
import importlib.metadata
import json
import logging
import math
import os
import platform
import subprocess
import typing
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from arm.files import (
    OutputError,
    atomic_write_text,
    folder_problem,
    is_dir,
    make_folders,
    shown,
)
from experiments.errors import RecordError

__all__ = [
    "RECORD_SCHEMA",
    "TIMING_FIELDS",
    "RecordError",
    "RunStore",
    "check_writable_dir",
    "environment_info",
    "jsonable",
    "load_record",
    "record_problem",
    "repo_path",
    "source_root",
    "without_timing",
]

log = logging.getLogger(__name__)

RECORD_SCHEMA = 1
MANIFEST = "_sweep.json"
LOCK = "_sweep.lock"
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
    """A record file, checked: every field a reader uses (the spec that reruns it, the status, the
    metrics, the provenance) has its type, else :class:`RecordError` names the file and the
    field, so a hand-edited or damaged record fails here in one line, not later in a rerun."""
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
    problem = record_problem(rec)
    if problem:
        raise RecordError(f"{p}: {problem}")
    return rec


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _field_problem(v: Any, hint: Any) -> str | None:
    """What is wrong with a value of a :class:`RunSpec` field annotated ``hint`` (None: fine)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is str:
        return None if isinstance(v, str) else "expected a string"
    if hint is int:
        ok = isinstance(v, int) and not isinstance(v, bool)
        return None if ok else "expected an integer"
    if hint is float:
        return None if _number(v) else "expected a finite number"
    if hint is dict or origin is dict:
        return None if isinstance(v, dict) else "expected an object"
    if origin is tuple and args and args[-1] is Ellipsis:
        if not isinstance(v, list):
            return "expected an array"
        for i, item in enumerate(v):
            why = _field_problem(item, args[0])
            if why:
                return f"item {i}: {why}"
        return None
    return None  # an annotation this check does not know: the run will judge


#: the spec fields with a range beyond their type
_FIELD_RANGES: dict[str, tuple[Any, str]] = {
    "seed": (lambda v: v >= 0, "must be >= 0"),
    "episode_seconds": (lambda v: v > 0, "must be > 0"),
    "settle_seconds": (lambda v: v >= 0, "must be >= 0"),
    "converge_mm": (lambda v: v > 0, "must be > 0"),
}


#: a phase of a spec: key, check, what it must be (env may be left out)
_PHASE_FIELDS = (
    ("name", lambda v: isinstance(v, str), "a string"),
    ("seconds", lambda v: _number(v) and v > 0, "a positive number"),
    ("judged", lambda v: isinstance(v, bool), "true or false"),
    ("env", lambda v: isinstance(v, dict), "an object"),
)


def record_problem(rec: Mapping[str, Any]) -> str | None:
    """The first malformed field of a record, as ``field: what is wrong, got value``; None if
    the record can be read, rerun and summarised."""
    from experiments.config import RunSpec

    spec = rec.get("spec")
    if not isinstance(spec, dict):
        return f"spec: expected an object, got {spec!r}"
    why = _spec_problem(spec)
    if why is not None:
        return why
    run_key = RunSpec.from_dict(spec).run_key
    if rec.get("run_key") != run_key:
        return f"run_key: {rec.get('run_key')!r} is not its spec's run ({run_key!r})"
    return _body_problem(rec)


def _spec_problem(spec: Mapping[str, Any]) -> str | None:
    """The first field of a record's spec (a :class:`~experiments.config.RunSpec`'s, then its
    phases') that is missing or malformed."""
    from experiments.config import RunSpec

    hints = typing.get_type_hints(RunSpec)
    for f in dataclasses.fields(RunSpec):
        if f.name not in spec:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                if f.name != "phases":  # optional in every record written so far
                    return f"spec.{f.name}: missing"
            continue
        v = spec[f.name]
        why = _field_problem(v, hints[f.name])
        if why is None and f.name in _FIELD_RANGES and not _FIELD_RANGES[f.name][0](v):
            why = _FIELD_RANGES[f.name][1]
        if why:
            return f"spec.{f.name}: {why}, got {v!r}"
    for i, ph in enumerate(spec.get("phases") or ()):
        for key, ok, want in _PHASE_FIELDS:
            if key in ph or key != "env":
                v = ph.get(key)
                if not ok(v):
                    return f"spec.phases[{i}].{key}: expected {want}, got {v!r}"
    return None


def _body_problem(rec: Mapping[str, Any]) -> str | None:
    """The first malformed field of a record beside its spec: its status, its objects, its
    metrics, its error."""
    if rec.get("status") not in ("ok", "failed"):
        return f"status: expected 'ok' or 'failed', got {rec.get('status')!r}"
    for key in ("metrics", "timing", "versions", "git", "series", "report", "calibration"):
        if key in rec and not isinstance(rec[key], dict):
            return f"{key}: expected an object, got {rec[key]!r}"
    for name, v in (rec.get("metrics") or {}).items():
        if not (v is None or isinstance(v, bool) or _number(v)):
            return f"metrics.{name}: expected a number, true/false or null, got {v!r}"
    if rec.get("error") is not None and not isinstance(rec["error"], dict):
        return f"error: expected an object or null, got {rec['error']!r}"
    return None


def dumps(record: Mapping[str, Any]) -> str:
    return json.dumps(jsonable(record), indent=1, sort_keys=True, allow_nan=False) + "\n"


def check_writable_dir(folder: str | Path, what: str = "files") -> None:
    """Prove, before any work, that files can be written in ``folder``: it, or the nearest folder
    above it that exists (where it will be made), takes a new file. A read-only or impossible
    place is a :class:`RecordError` naming it now, not a traceback once the work is done.
    Creates nothing."""
    why = folder_problem(folder)
    if why:
        raise RecordError(f"{shown(folder)}: cannot write {what} there: {why}")


class RunStore:
    """The records of one sweep in a directory: one ``<run_key>.json`` per run."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def check_writable(self) -> None:
        """Prove, before any run, that the records can be written (:func:`check_writable_dir`)."""
        check_writable_dir(self.root, "the sweep's records")

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold the directory for one sweep (an exclusive ``flock`` on ``_sweep.lock``, released
        when this process ends, however it ends). A second sweep into it is a
        :class:`RecordError` naming the first one's pid; and as no other writer can be at work,
        the temporaries a killed sweep left (``.NAME.XXXX.tmp``) are removed. Where ``fcntl`` is
        missing (Windows) it only yields."""
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            yield
            return
        make_folders(self.root)
        fd = os.open(self.root / LOCK, os.O_RDWR | os.O_CREAT, 0o666)  # not inherited
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                raise RecordError(
                    f"{self.root}: another sweep (pid {holder}) is writing its records here; "
                    "wait for it to end, or give another output directory"
                ) from None
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            for tmp in self.root.glob(".*.tmp"):
                with contextlib.suppress(OSError):
                    tmp.unlink()
                    log.info("removed %s, left by a sweep that was killed", tmp)
            yield
        finally:
            os.close(fd)

    def path(self, run_key: str) -> Path:
        return self.root / f"{run_key}.json"

    def load(self, run_key: str) -> dict[str, Any] | None:
        p = self.path(run_key)
        return load_record(p) if os.path.exists(p) else None

    def write(self, record: Mapping[str, Any]) -> Path:
        """Write (or replace) a record atomically: readers see the old file or the whole new one.
        A write that fails (a full disk) is a :class:`RecordError` naming the file."""
        p = self.path(record["run_key"])
        try:
            atomic_write_text(p, dumps(record))
        except (OSError, OutputError) as exc:
            why = exc.strerror if isinstance(exc, OSError) else exc
            raise RecordError(f"{p}: cannot write the record ({why})") from None
        return p

    def paths(self) -> list[Path]:
        if not is_dir(self.root):
            return []
        return sorted(p for p in self.root.glob("*.json") if not p.name.startswith(("_", ".")))

    def records(self) -> Iterator[dict[str, Any]]:
        for p in self.paths():
            yield load_record(p)

    def write_manifest(self, manifest: Mapping[str, Any]) -> None:
        p = self.root / MANIFEST
        try:
            atomic_write_text(p, dumps(manifest))
        except (OSError, OutputError) as exc:
            why = exc.strerror if isinstance(exc, OSError) else exc
            raise RecordError(f"{p}: cannot write the manifest ({why})") from None

    def manifest(self) -> dict[str, Any] | None:
        p = self.root / MANIFEST
        if not os.path.exists(p):
            return None
        try:
            manifest = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise RecordError(f"{p}: not a readable sweep manifest: {exc}") from None
        if not isinstance(manifest, dict):
            raise RecordError(f"{p}: not a sweep manifest (expected an object)")
        for key in ("runs", "config"):
            if key in manifest and not isinstance(manifest[key], dict):
                raise RecordError(f"{p}: {key}: expected an object, got {manifest[key]!r}")
        return manifest


@functools.lru_cache(maxsize=1)
def environment_info() -> dict[str, Any]:
    """Python and package versions, and the git commit of the code (once per process)."""
    versions: dict[str, str | None] = {"python": platform.python_version()}
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
    an existing file elsewhere (a user's config in their working folder) by its absolute path, so
    that ``sixaxis reproduce`` finds it where the sweep did from any folder; otherwise as given."""
    if path is None:
        return None
    p = Path(path)
    try:
        if not os.path.exists(p):
            return str(path)
        resolved = p.resolve()
    except OSError:
        return str(path)
    try:
        return resolved.relative_to(source_root()).as_posix()
    except ValueError:
        return str(resolved)


#: the tracked files with local changes, one a line (``XY path``)
_STATUS = ("status", "--porcelain", "--untracked-files=no")


def _git(root: Path, *args: str) -> str | None:
    """``git ARGS``' output in ``root``, None where git fails or is not there."""
    try:
        out = subprocess.run(
            ["git", *args], cwd=root, capture_output=True, text=True, timeout=30, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout if out.returncode == 0 else None


def local_changes(root: str | Path | None = None) -> list[str] | None:
    """The tracked files with local changes in the source tree this package runs from (``git
    status``'s paths), [] for a clean tree, None outside a git checkout."""
    status = _git(Path(root) if root is not None else source_root(), *_STATUS)
    if status is None:
        return None
    return [line[3:] for line in status.splitlines() if line.strip()]


def git_state(root: str | Path | None = None) -> dict[str, Any]:
    """The commit of the source tree this package runs from, and whether it has local changes."""
    root = Path(root) if root is not None else source_root()
    commit = _git(root, "rev-parse", "HEAD")
    if commit is None:
        return {"commit": None, "dirty": None}
    status = _git(root, *_STATUS)
    return {"commit": commit.strip(), "dirty": bool(status.strip()) if status is not None else None}
