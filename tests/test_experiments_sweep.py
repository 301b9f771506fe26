"""The sweep runner: one atomic record per run, resumable, failures recorded, the same records from
every backend; and for real: the actual agents on the actual env, run twice, killed and resumed,
and on a Dask cluster.

The bookkeeping tests inject a small deterministic run function (the runner takes one, for users
too); the real-run tests run hold/nominal and a user's class on SixAxisTrack-v0 for 1 s episodes.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agents.base import Agent
from envs.task import TaskInfo, Truth
from experiments.config import RunSpec, parse_config
from experiments.leaderboard import build_leaderboard, to_csv
from experiments.records import RecordError, RunStore, load_record, without_timing
from experiments.sweep import SweepError, run_sweep

ROOT = Path(__file__).resolve().parents[1]


# -- a user's controller, joining by its class path ---------------------------------------------


class DampedHold(Agent):
    """A user's agent: commands a fixed fraction of the previous joint velocity (nearly hold)."""

    name = "damped-hold"

    def __init__(self, factor: float = 0.5) -> None:
        super().__init__()
        self.factor = float(factor)

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task = task
        self.steps = 0

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        self.steps += 1
        qd = np.asarray(obs, dtype=float)[self.task.obs_slices["qd"]]
        return np.clip(self.factor * qd / np.asarray(self.task.v_max), -1.0, 1.0)

    def report(self) -> dict:
        return {"steps": self.steps}


# -- a deterministic stand-in for a run (dependency injection) ----------------------------------


def fake_run(spec: RunSpec) -> dict:
    """Numbers that depend only on the spec; seed 13 fails, like a run that raises."""
    if spec.seed == 13:
        raise RuntimeError(f"deliberate failure of {spec.run_key}")
    rng = np.random.default_rng(
        [spec.seed, zlib.crc32(spec.agent_label.encode()), zlib.crc32(spec.scenario.encode())]
    )
    err = rng.uniform(0.1, 2.0, 20)
    return {
        "metrics": {"rms_mm": float(np.sqrt(np.mean(err**2))), "max_mm": float(err.max())},
        "timing_metrics": {"solve_time_median_ms": float(time.perf_counter() % 1)},
        "series": {"time": (np.arange(20) * 0.02 + 0.02).tolist(), "true_error_mm": err.tolist()},
    }


def config(**changes):
    raw = {
        "name": "fake",
        "seeds": [0, 1, 2],
        "episode_seconds": 1.0,
        "settle_seconds": 0.5,
        "metrics": ["rms_mm", "max_mm", "solve_time_median_ms"],
        "scenarios": ["nominal", "geometric"],
        "agents": ["hold", "nominal"],
    } | changes
    return parse_config(raw, source="fake.toml", check_agents=False)


def comparable(store: RunStore) -> dict[str, dict]:
    return {p.name: without_timing(load_record(p)) for p in store.paths()}


def test_every_run_writes_one_whole_record(tmp_path):
    cfg = config()
    calls = []
    summary = run_sweep(
        cfg,
        tmp_path,
        workers=0,
        run_fn=fake_run,
        progress=lambda s: calls.append((s.done, s.running, s.failed)),
    )
    store = RunStore(tmp_path)
    names = sorted(p.name for p in store.paths())
    assert names == sorted(f"{s.run_key}.json" for s in cfg.runs())
    assert summary.done == 12 and summary.skipped == 0 and not summary.failed
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left
    rec = store.load("nominal__geometric__seed2")
    spec = RunSpec.from_dict(rec["spec"])
    assert spec == next(s for s in cfg.runs() if s.run_key == "nominal__geometric__seed2")
    assert rec["run_hash"] == spec.run_hash and rec["config_hash"] == cfg.hash
    assert rec["status"] == "ok" and rec["metrics"] == fake_run(spec)["metrics"]
    assert "solve_time_median_ms" in rec["timing"] and "solve_time_median_ms" not in rec["metrics"]
    assert rec["versions"]["numpy"] == np.__version__ and "commit" in rec["git"]
    assert calls[-1] == (12, 0, 0)
    manifest = store.manifest()
    assert manifest["config_hash"] == cfg.hash and len(manifest["runs"]) == 12


def test_a_rerun_skips_finished_records_and_retries_failed_ones(tmp_path):
    cfg = config(seeds=[0, 13])
    first = run_sweep(cfg, tmp_path, workers=0, run_fn=fake_run)
    assert sorted(first.failed) == sorted(
        f"{a}__{s}__seed13" for a in ("hold", "nominal") for s in ("nominal", "geometric")
    )
    rec = RunStore(tmp_path).load("hold__nominal__seed13")
    assert rec["status"] == "failed" and rec["metrics"] == {}
    assert rec["error"]["type"] == "RuntimeError"
    assert "deliberate failure of hold__nominal__seed13" in rec["error"]["traceback"]
    before = {p.name: p.stat().st_mtime_ns for p in RunStore(tmp_path).paths()}

    second = run_sweep(cfg, tmp_path, workers=0, run_fn=fake_run)
    assert second.skipped == 4 and second.done == 4  # the failed four are retried
    after = {p.name: p.stat().st_mtime_ns for p in RunStore(tmp_path).paths()}
    assert {k for k in after if after[k] != before[k]} == {f"{k}.json" for k in first.failed}

    third = run_sweep(cfg, tmp_path, workers=0, run_fn=fake_run, retry_failed=False)
    assert third.skipped == 8 and third.done == 0


def test_more_seeds_reuse_the_finished_runs(tmp_path):
    run_sweep(config(seeds=[0]), tmp_path, workers=0, run_fn=fake_run)
    summary = run_sweep(config(seeds=[0, 1]), tmp_path, workers=0, run_fn=fake_run)
    assert summary.skipped == 4 and summary.done == 4


def test_records_of_another_spec_are_refused_not_overwritten(tmp_path):
    run_sweep(config(), tmp_path, workers=0, run_fn=fake_run)
    before = comparable(RunStore(tmp_path))
    with pytest.raises(SweepError, match=r"(?s)12 record\(s\).*another spec.*--overwrite"):
        run_sweep(config(episode_seconds=2.0), tmp_path, workers=0, run_fn=fake_run)
    assert comparable(RunStore(tmp_path)) == before
    summary = run_sweep(
        config(episode_seconds=2.0), tmp_path, workers=0, run_fn=fake_run, overwrite=True
    )
    assert summary.done == 12


def test_one_sweep_a_directory_and_a_killed_ones_temporaries_are_removed(tmp_path):
    """A second sweep into a directory another one is writing is refused, naming its pid; once
    the directory is free, temporaries a killed sweep left half-written are removed (with the
    lock held no writer can own them)."""
    store = RunStore(tmp_path)
    with store.lock():
        with pytest.raises(RecordError, match=rf"another sweep \(pid {os.getpid()}\)"):
            run_sweep(config(), tmp_path, workers=0, run_fn=fake_run)
        assert not store.paths()  # nothing ran
    left = [tmp_path / ".hold__nominal__seed0.json.k2j4x9.tmp", tmp_path / "._sweep.json.a1.tmp"]
    for p in left:
        p.write_text('{"half": ')
    summary = run_sweep(config(), tmp_path, workers=0, run_fn=fake_run)
    assert summary.done == 12 and not any(p.exists() for p in left)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    run_sweep(config(), tmp_path, workers=0, run_fn=fake_run)  # the lock was released


def test_process_pool_gives_the_same_records_as_in_process(tmp_path):
    cfg = config(seeds=[0, 13, 1])
    a, b = tmp_path / "a", tmp_path / "b"
    run_sweep(cfg, a, workers=0, run_fn=fake_run)
    summary = run_sweep(cfg, b, workers=2, run_fn=fake_run)
    assert len(summary.failed) == 4  # failures do not stop the sweep
    ra, rb = comparable(RunStore(a)), comparable(RunStore(b))
    for rec in (*ra.values(), *rb.values()):  # tracebacks name the pool's frames; compare the rest
        if rec["error"]:
            rec["error"].pop("traceback")
    assert ra == rb


def pid_run(spec: RunSpec) -> dict:
    """A run that says which process ran it."""
    return {"metrics": {"rms_mm": 1.0, "max_mm": 1.0}, "pid": os.getpid()}


def test_a_worker_is_replaced_after_its_share_of_runs(tmp_path, monkeypatch):
    """A long sweep does not run every episode in one process (whose address space grows past
    the run's memory limit): after RUNS_PER_WORKER runs a fresh worker takes over."""
    import experiments.sweep as sweep

    monkeypatch.setattr(sweep, "RUNS_PER_WORKER", 2)
    summary = run_sweep(config(), tmp_path, workers=1, run_fn=pid_run)
    assert summary.done == 12 and not summary.failed
    pids = [load_record(p)["extra"]["pid"] for p in RunStore(tmp_path).paths()]
    counts = {p: pids.count(p) for p in set(pids)}
    assert max(counts.values()) <= 2 and len(counts) >= 6


# -- for real: the actual env and agents --------------------------------------------------------

TINY = """
name = "tiny"
seeds = [0]
episode_seconds = 1.0
settle_seconds = 0.5
metrics = ["rms_mm", "rms_settled_mm", "max_mm", "effort_rms", "calib_rms_mm", "diverged", "solve_time_median_ms"]
scenarios = ["nominal", "geometric"]
agents = [
    "hold",
    "nominal",
    { name = "tests.test_experiments_sweep:DampedHold", label = "damped", settings = { factor = 0.3 } },
]
[env]
trajectory = "circle"
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny real config and one sweep of it (two local processes)."""
    from experiments.config import load_config

    root = tmp_path_factory.mktemp("tiny")
    path = root / "tiny.toml"
    path.write_text(TINY)
    cfg = load_config(path)
    summary = run_sweep(cfg, root / "first", workers=2)
    assert not summary.failed, [
        load_record(root / "first" / f"{k}.json")["error"] for k in summary.failed
    ]
    return cfg, root


def test_real_tiny_sweep_twice_gives_identical_records_apart_from_timing(tiny):
    cfg, root = tiny
    run_sweep(cfg, root / "second", workers=1)
    a, b = comparable(RunStore(root / "first")), comparable(RunStore(root / "second"))
    assert len(a) == 6 and a == b
    rec = a["nominal__geometric__seed0.json"]
    assert rec["spec"]["env_kwargs"] == {"scenario": "geometric", "trajectory": "circle"}
    assert rec["episode"]["steps"] == 50 and len(rec["series"]["true_error_mm"]) == 50
    # the metric is the RMS of the recorded series: the record is self-consistent
    e = np.asarray(rec["series"]["true_error_mm"])
    assert rec["metrics"]["rms_mm"] == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)
    hold = a["hold__geometric__seed0.json"]["metrics"]["rms_mm"]
    assert rec["metrics"]["rms_mm"] < hold  # tracking beats holding still
    assert a["damped__geometric__seed0.json"]["report"] == {"steps": 50}


def test_dask_backend_gives_the_same_records_as_local_processes(tiny):
    distributed = pytest.importorskip("distributed")
    cfg, root = tiny
    first = comparable(RunStore(root / "first"))
    # a LocalCluster started by the sweep
    summary = run_sweep(cfg, root / "dask", backend="dask", workers=1, processes=False)
    assert summary.done == 6 and not summary.failed
    assert comparable(RunStore(root / "dask")) == first
    # an existing cluster, by its scheduler's address
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        summary = run_sweep(
            cfg, root / "dask-address", backend="dask", address=cluster.scheduler_address
        )
    assert summary.done == 6 and not summary.failed
    assert comparable(RunStore(root / "dask-address")) == first


def _sweep_cmd(config: Path, out: Path, workers: int = 1) -> list[str]:
    return [
        sys.executable,
        "-m",
        "experiments.cli",
        "sweep",
        str(config),
        "--out",
        str(out),
        "--workers",
        str(workers),
    ]


def _table(runs: Path) -> str:
    """The leaderboard CSV without the timing columns (those vary from run to run); whether the
    checkout running the test has local changes is not the point here."""
    lines = to_csv(build_leaderboard(runs, allow_dirty=True)).splitlines()
    header = lines[0].split(",")
    keep = [i for i, h in enumerate(header) if not h.startswith("solve_time")]
    return "\n".join(",".join(row.split(",")[i] for i in keep) for row in lines)


@pytest.fixture(scope="module")
def tiny_long(tiny):
    """The tiny config with two seeds (12 runs) and one whole sweep of it from the CLI: what a
    sweep killed and resumed must end with."""
    _, root = tiny
    config_path = root / "tiny-long.toml"
    config_path.write_text(TINY.replace("seeds = [0]", "seeds = [0, 1]"))
    whole = root / "whole"
    subprocess.run(
        _sweep_cmd(config_path, whole), cwd=ROOT, check=True, capture_output=True, timeout=300
    )
    return config_path, whole


@pytest.mark.slow
def test_killed_sweep_resumes_to_the_same_table(tiny_long, tmp_path):
    config_path, whole = tiny_long
    killed = tmp_path / "killed"
    proc = subprocess.Popen(
        _sweep_cmd(config_path, killed),
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own process group: the kill takes the workers too
    )
    deadline = time.monotonic() + 180
    try:
        while len(RunStore(killed).paths()) < 4:
            assert proc.poll() is None, "the sweep ended before it could be killed"
            assert time.monotonic() < deadline, "the sweep made no progress"
            time.sleep(0.01)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    done_before = {p.name: load_record(p) for p in RunStore(killed).paths()}
    assert 4 <= len(done_before) < 12, "killed too late to test a resume"

    resumed = subprocess.run(
        _sweep_cmd(config_path, killed), cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"({len(done_before)} already finished, 0 failed)" in resumed.stdout
    final = {p.name: load_record(p) for p in RunStore(killed).paths()}
    assert len(final) == 12
    for name, rec in done_before.items():  # nothing finished before the kill was redone
        assert final[name] == rec
    assert not [p for p in killed.iterdir() if p.name.startswith(".")]  # no temp files

    assert _table(killed) == _table(whole)
    assert (
        json.loads((killed / "_sweep.json").read_text())["config_hash"]
        == json.loads((whole / "_sweep.json").read_text())["config_hash"]
    )


# -- no process outlives its sweep ----------------------------------------------------------------


def _alive(procs) -> list:
    """The processes still running (a zombie waiting for its new parent to reap it is dead)."""
    import psutil

    out = []
    for p in procs:
        try:
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.NoSuchProcess:
            pass
    return out


@pytest.mark.slow
@pytest.mark.parametrize("sig", ["SIGKILL", "SIGTERM"])
def test_a_signalled_sweep_leaves_no_process_and_resumes_exactly(tiny_long, tmp_path, sig):
    """Only the sweep's own pid is signalled, its output read through pipes, as a caller does:
    within 5 s no process of its tree runs and the pipes are closed; the rerun finishes exactly
    the records an uninterrupted sweep writes, keeping those written before the signal."""
    psutil = pytest.importorskip("psutil")
    config_path, whole = tiny_long
    out = tmp_path / "runs"
    proc = subprocess.Popen(
        _sweep_cmd(config_path, out, workers=2),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    captured: dict[str, bytes] = {}
    readers = [
        threading.Thread(target=lambda k=k, f=f: captured.__setitem__(k, f.read()), daemon=True)
        for k, f in (("out", proc.stdout), ("err", proc.stderr))
    ]
    for r in readers:
        r.start()
    parent = psutil.Process(proc.pid)
    tree: dict[int, psutil.Process] = {}
    deadline = time.monotonic() + 180
    try:
        while len(RunStore(out).paths()) < 2:
            assert proc.poll() is None, "the sweep ended before it could be signalled"
            assert time.monotonic() < deadline, "the sweep made no progress"
            tree |= {c.pid: c for c in parent.children(recursive=True)}
            time.sleep(0.01)
        tree |= {c.pid: c for c in parent.children(recursive=True)}
        # two workers and multiprocessing's resource tracker
        assert len(_alive(tree.values())) >= 3, [c.cmdline() for c in tree.values()]
        os.kill(proc.pid, getattr(signal, sig))
        t0 = time.monotonic()
        proc.wait(timeout=5)
        psutil.wait_procs(_alive(tree.values()), timeout=max(0.0, 5 - (time.monotonic() - t0)))
        survivors = _alive(tree.values())
        assert not survivors, f"alive 5 s after {sig}: {[p.cmdline() for p in survivors]}"
        for r in readers:  # the pipes closed: a caller reading them does not hang
            r.join(timeout=max(0.1, 5 - (time.monotonic() - t0)))
            assert not r.is_alive(), f"the sweep's output pipe is still open 5 s after {sig}"
    finally:
        for p in [parent, *tree.values()]:
            with contextlib.suppress(psutil.NoSuchProcess):
                p.kill()
    err = captured["err"].decode()
    if sig == "SIGTERM":  # stops as on Ctrl-C: one line, the exit code of a shell
        assert proc.returncode == 128 + signal.SIGTERM, err
        assert "interrupted (SIGTERM)" in err and "Traceback" not in err, err
    else:
        assert proc.returncode == -signal.SIGKILL
    done_before = {p.name: load_record(p) for p in RunStore(out).paths()}
    assert 2 <= len(done_before) < 12, "signalled too late to test a resume"

    resumed = subprocess.run(
        _sweep_cmd(config_path, out, workers=2),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"({len(done_before)} already finished, 0 failed)" in resumed.stdout
    final = {p.name: load_record(p) for p in RunStore(out).paths()}
    for name, rec in done_before.items():  # nothing finished before the signal was redone
        assert final[name] == rec
    assert comparable(RunStore(out)) == comparable(RunStore(whole))  # no run lost or doubled
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temp files


def test_a_worker_exits_when_its_parent_dies_without_pdeathsig(tmp_path):
    """The portable half of the guard (a watchdog on the parent's pid), alone: a middle process
    starts a child that runs only the watchdog, then is SIGKILLed; the child must exit."""
    psutil = pytest.importorskip("psutil")
    child_code = (
        "import os, time; from experiments.sweep import _watch_parent; "
        "print(os.getpid(), flush=True); _watch_parent(os.getppid())"
    )
    middle_code = (
        "import subprocess, sys, time; "
        f"c = subprocess.Popen([sys.executable, '-c', {child_code!r}], stdout=sys.stdout); "
        "time.sleep(600)"
    )
    middle = subprocess.Popen(
        [sys.executable, "-c", middle_code], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    try:
        child = psutil.Process(int(middle.stdout.readline()))
        time.sleep(0.5)
        assert _alive([child]), "the watchdog ended its process while the parent lived"
        middle.kill()
        middle.wait()
        psutil.wait_procs([child], timeout=5)
        assert not _alive([child]), "the child outlived its parent by 5 s"
    finally:
        middle.kill()
        with contextlib.suppress(Exception):
            child.kill()


# -- every output place is checked before any work ------------------------------------------------


def _unwritable(tmp_path: Path, where: str, monkeypatch) -> Path:
    """An output folder where no file can be written: inside a file, below a file, or a folder
    that refuses new files (chmod, or for root, who ignores it, a probe that fails as the OS
    would)."""
    a_file = tmp_path / "a-file"
    a_file.write_text("not a folder\n")
    if where == "file":
        return a_file
    if where == "below a file":
        return a_file / "runs" / "quick"
    ro = tmp_path / "read-only"
    ro.mkdir()
    ro.chmod(0o555)
    if where == "read-only" and os.access(ro, os.W_OK):
        pytest.skip("this user writes in a read-only folder (root); see 'refusing'")
    if where == "refusing":

        def refuse(*args, **kwargs):
            raise PermissionError(13, "Permission denied")

        monkeypatch.setattr("tempfile.mkstemp", refuse)
    return ro / "runs"


@pytest.mark.parametrize("where", ["file", "below a file", "read-only", "refusing"])
def test_sweep_refuses_an_unwritable_out_in_one_line_before_any_run(tmp_path, where, monkeypatch):
    from typer.testing import CliRunner

    from experiments.cli import app

    config_path = tmp_path / "tiny.toml"
    config_path.write_text(TINY)
    out = _unwritable(tmp_path, where, monkeypatch)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    for extra in ([], ["--dry-run"]):
        res = CliRunner().invoke(app, ["sweep", str(config_path), "--out", str(out), *extra])
        assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.output
        text = " ".join(res.output.split())
        assert f"{out}: cannot write the sweep's records there" in text, res.output
        assert "running" not in text  # refused before the sweep started
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before  # nothing made
    with pytest.raises(Exception, match="cannot write the sweep's records there"):
        run_sweep(config(), out, workers=0, run_fn=fake_run)  # the Python API checks too


def test_leaderboard_refuses_an_unwritable_out_before_reading_the_records(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from experiments.cli import app

    runs = tmp_path / "runs"
    run_sweep(config(), runs, workers=0, run_fn=fake_run)
    for where in ("file", "below a file"):
        (tmp_path / where).mkdir()
        out = _unwritable(tmp_path / where, where, monkeypatch)
        res = CliRunner().invoke(app, ["leaderboard", str(runs), "--out", str(out)])
        assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.output
        assert f"{out}: cannot write the leaderboard there" in " ".join(res.output.split())


def test_local_changes_are_git_status_of_the_tracked_files(tmp_path):
    import subprocess

    from experiments.records import local_changes

    assert local_changes(tmp_path) is None  # not a checkout
    run = dict(cwd=tmp_path, check=True, capture_output=True)
    subprocess.run(["git", "init", "-q"], **run)
    (tmp_path / "a.py").write_text("x = 1\n")
    subprocess.run(["git", "add", "a.py"], **run)
    subprocess.run(
        ["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "a"], **run
    )
    (tmp_path / "untracked.txt").write_text("not a change of the tree\n")
    assert local_changes(tmp_path) == []
    (tmp_path / "a.py").write_text("x = 2\n")
    assert local_changes(tmp_path) == ["a.py"]


def test_a_sweep_from_a_changed_checkout_says_so_before_the_first_run(tmp_path, monkeypatch):
    """A user's records from a tree with local changes are refused by the leaderboard: the sweep
    says so first, naming the files, instead of only ending with `next: sixaxis leaderboard`."""
    from typer.testing import CliRunner

    from experiments.cli import app

    config_path = tmp_path / "tiny.toml"
    config_path.write_text(TINY)
    monkeypatch.setattr("experiments.records.local_changes", lambda root=None: ["results/x.json"])
    res = CliRunner().invoke(app, ["sweep", str(config_path), "--out", str(tmp_path / "runs")])
    text = " ".join(res.output.split())
    assert "has local changes (results/x.json)" in text, res.output
    assert "--allow-dirty" in text
    monkeypatch.setattr("experiments.records.local_changes", lambda root=None: [])
    res = CliRunner().invoke(app, ["sweep", str(config_path), "--out", str(tmp_path / "runs2")])
    assert res.exit_code == 0 and "next: sixaxis leaderboard" in res.output, res.output
    assert "local changes" not in res.output
