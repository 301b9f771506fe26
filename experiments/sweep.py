"""The sweep runner: every agent x scenario x seed of a config, one record per run.

    config = load_config("experiments/configs/quick.toml")
    summary = run_sweep(config, workers=2)                    # local processes
    summary = run_sweep(config, backend="dask")               # a Dask LocalCluster
    summary = run_sweep(config, backend="dask", address="tcp://scheduler:8786")

Runs go to local processes (:class:`concurrent.futures.ProcessPoolExecutor`, spawned, one thread
each) or to a Dask distributed cluster (the optional ``cluster`` extra). Workers only compute: each
returns its outcome and this process writes the record atomically, so whatever the backend,
``runs/<config-name>/`` holds one whole file per finished run and nothing else. A rerun skips every
finished record whose spec is unchanged, so an interrupted sweep resumes where it stopped; failed
runs are retried (``retry_failed=False`` keeps them). A run that raises is recorded with its
traceback and the sweep goes on.

A record with the same run key but another spec (the config changed under the same output
directory) is refused before anything runs, unless ``overwrite=True``.

No process outlives its sweep. The local workers die with this process whatever ends it: on Linux
the kernel kills them when it dies (``PR_SET_PDEATHSIG``), everywhere a watchdog thread in each
worker exits when its parent's pid goes away; they ignore SIGINT, so that a Ctrl-C in a terminal
stops the sweep here and this process ends them. An interrupt (``KeyboardInterrupt``, or any
exception) ends the runs in flight at once instead of waiting for them; their records were never
written, so a rerun does them again. A LocalCluster's Dask workers watch their nanny the same way.

It is one module, longer than most, because planning, running on either backend and recording share
the record's layout and the rule that resumes a sweep.
"""

from __future__ import annotations

import contextlib
import ctypes
import datetime as _dt
import logging
import os
import secrets
import signal
import socket
import sys
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agents.isolation import THREAD_VARS
from experiments.config import ExperimentConfig, RunSpec
from experiments.errors import SweepError
from experiments.records import RECORD_SCHEMA, RunStore, environment_info, jsonable, repo_path

__all__ = [
    "SweepError",
    "SweepProgress",
    "SweepSummary",
    "build_record",
    "check_scheduler",
    "episode_seeds",
    "execute_run",
    "plan_sweep",
    "run_sweep",
]

log = logging.getLogger(__name__)

RunFn = Callable[[RunSpec], Mapping[str, Any]]


@dataclass
class SweepProgress:
    """Counts for a progress display: ``done`` includes ``failed``; ``skipped`` were finished
    before this sweep started."""

    total: int
    skipped: int
    done: int = 0
    failed: int = 0
    running: int = 0
    last: str = ""

    @property
    def remaining(self) -> int:
        return self.total - self.skipped - self.done


@dataclass
class SweepSummary:
    out_dir: Path
    total: int
    skipped: int
    done: int
    failed: list[str] = field(default_factory=list)
    wall_time_s: float = 0.0


# -- one run ------------------------------------------------------------------------------------


def execute_run(spec: RunSpec) -> dict[str, Any]:
    """Run one spec for real: make the agent, run the episode, compute the metrics.

    Returns the outcome part of a record: ``metrics``, ``timing_metrics``, ``report``, ``series``
    (time, true error, judged per step), ``calibration``, ``episode``."""
    from agents.registry import agent_module_source, make_agent
    from agents.runner import Phase, run_episode
    from experiments.metrics import (
        calibration_error_mm,
        episode_metrics,
        parameter_errors,
        reports_model,
    )

    module = agent_module_source(spec.agent)  # a user's class: its file and hash, before it runs
    deadline = time.monotonic() + spec.time_limit_s
    if spec.isolate:
        from agents.isolation import IsolatedAgent

        agent: Any = IsolatedAgent(
            spec.agent, spec.settings, deadline=deadline, memory_limit_mb=spec.memory_limit_mb
        )
    else:
        agent = make_agent(spec.agent, **spec.settings)
    _limit_threads()  # the agent may have imported torch
    phases = None
    if spec.phases:
        phases = [
            Phase(p["name"], float(p["seconds"]), dict(p.get("env", {})), bool(p["judged"]))
            for p in spec.phases
        ]
    try:
        result = run_episode(
            agent,
            spec.env_kwargs,
            seed=spec.seed,
            episode_seconds=None if phases else spec.episode_seconds,
            phases=phases,
            env_id=spec.env_id,
            deadline=deadline,
        )
    finally:
        if spec.isolate:
            agent.close()
    report = dict(result.report or {})
    calib_mm = None
    calibration: dict[str, Any] = {}
    if reports_model(report):
        calibration["parameter_errors"] = parameter_errors(report, result.truth_parameters)
        if "calib_rms_mm" in spec.metrics:
            try:
                truth = _truth(spec)
                calib_mm = calibration_error_mm(
                    truth.model,
                    truth.params,
                    report["parameter_names"],
                    report["parameters"],
                    est_model=getattr(agent, "model", None),
                )
            except Exception as exc:  # a metric that cannot be computed is missing, not fatal
                log.warning("%s: no calibration error: %s", spec.run_key, exc)
                calibration["calib_rms_error"] = f"{type(exc).__name__}: {exc}"
    metrics, timing_metrics = episode_metrics(
        result,
        spec.metrics,
        settle_seconds=spec.settle_seconds,
        calib_rms_mm=calib_mm,
        converge_mm=spec.converge_mm,
    )
    timed = {k: v for k, v in report.items() if "time" in k}
    return {
        "oracle": bool(result.oracle),  # read before the episode started
        "isolated": bool(spec.isolate),
        "agent_module": module,
        "metrics": metrics,
        "timing_metrics": timing_metrics | {"report": timed},
        "report": {k: v for k, v in report.items() if k not in timed},
        "calibration": calibration,
        "series": {
            "time": result.time,
            "true_error_mm": result.true_error_mm,
            "judged": result.judged,
        },
        "episode": {"steps": len(result.time), "diverged": bool(result.diverged)},
    }


def _truth(spec: RunSpec):
    """The plant's truth for this spec and seed (a fresh env, reset with the run's seed)."""
    from agents.runner import make_env

    env = make_env(spec.env_id, spec.env_kwargs, None)
    try:
        env.reset(seed=int(spec.seed))
        return env.unwrapped.truth
    finally:
        env.close()


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def _limit_threads() -> None:
    """One thread per run: two workers on two cores must not fight over BLAS or torch threads, and
    a fixed thread count keeps torch's sums in the same order, run after run."""
    for var in THREAD_VARS:
        os.environ.setdefault(var, "1")
    torch = sys.modules.get("torch")  # never import it here: agents that use it already have
    if torch is not None and torch.get_num_threads() != 1:
        torch.set_num_threads(1)


@contextlib.contextmanager
def _child_thread_env() -> Iterator[None]:
    """Children inherit the environment when spawned: one BLAS thread each."""
    saved = {v: os.environ.get(v) for v in THREAD_VARS}
    for v in THREAD_VARS:
        os.environ[v] = "1"
    try:
        yield
    finally:
        for v, old in saved.items():
            if old is None:
                os.environ.pop(v, None)
            else:
                os.environ[v] = old


#: how often a worker's watchdog looks for its parent (s): the longest a worker outlives it
PARENT_POLL_SECONDS = 0.2
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def _worker_init(parent_pid: int, memory_limit_mb: int | None = None) -> None:
    """A pool worker's initializer: it dies with the sweep (:func:`_die_with_parent`) and its
    address space is capped (:func:`agents.isolation.limit_memory`)."""
    from agents.isolation import limit_memory

    _die_with_parent(parent_pid)
    limit_memory(memory_limit_mb)


def _die_with_parent(parent_pid: int) -> None:
    """A pool worker's initializer: this process ends when ``parent_pid`` (the sweep) ends.

    A spawned worker blocks on a queue whose other end it holds itself, so it would never see the
    sweep die, and it keeps the sweep's stdout open (a caller reading it through a pipe would
    hang). Linux kills it with the parent (``PR_SET_PDEATHSIG``); everywhere, a daemon thread
    exits the process once its parent pid changes (the orphan was adopted). SIGINT is ignored: a
    Ctrl-C reaches the whole process group, and the sweep decides what stops."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
                log.debug("prctl(PR_SET_PDEATHSIG) failed: errno %d", ctypes.get_errno())
        except (OSError, AttributeError) as exc:  # no libc symbol: the watchdog still works
            log.debug("no PR_SET_PDEATHSIG: %s", exc)
    if os.getppid() != parent_pid:  # the parent died before the guard was in place
        os._exit(1)
    threading.Thread(
        target=_watch_parent, args=(parent_pid,), name="sixaxis-parent-watchdog", daemon=True
    ).start()


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_SECONDS)
    os._exit(1)  # nothing to save: a worker only computes, the parent writes every record


def _stop_pool(pool: Any) -> None:
    """End a process pool's workers now (their runs are lost, not recorded) and reap them.
    ``shutdown(wait=True)`` would wait for every run in flight, minutes for a long episode."""
    procs = dict(getattr(pool, "_processes", None) or {})  # terminate_workers() in Python 3.14
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs.values():
        with contextlib.suppress(ValueError, OSError):  # closed or already gone
            if p.is_alive():
                p.terminate()
    for p in procs.values():
        with contextlib.suppress(ValueError, OSError):
            p.join(timeout=5)
            if p.is_alive():
                p.kill()
                p.join(timeout=5)


class _WarningCollector(logging.Handler):
    """Keeps the warnings a run logs, for its record, instead of letting workers print them over
    the parent's progress bar."""

    def __init__(self) -> None:
        super().__init__(level=logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(f"{record.name}: {record.getMessage()}")


@contextlib.contextmanager
def _collect_warnings() -> Iterator[list[str]]:
    """The run's logged warnings and its Python warnings (the lab's cautions are
    ``SixAxisWarning`` s), once each, for its record instead of the workers' stderr."""
    # A spawned worker's root logger has no handler, so without this one logging's last resort
    # would print each warning to stderr; in this process the caller's handlers still see them.
    import warnings

    root = logging.getLogger()
    collector = _WarningCollector()
    root.addHandler(collector)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield collector.messages
    finally:
        root.removeHandler(collector)
        for w in caught:
            text = f"{w.category.__name__}: {w.message}"
            if text not in collector.messages:
                collector.messages.append(text)


@contextlib.contextmanager
def _alarm(seconds: float) -> Iterator[list[bool]]:
    """Raise :class:`~agents.runner.TimeLimitExceeded` in this thread after ``seconds`` (SIGALRM:
    the main thread of a POSIX process only; elsewhere it only yields). Python code that hangs
    is stopped; a hang no signal stops (inside C code) is ended by the sweep, which ends the
    worker. Yields a list whose one item says whether the alarm rang (code that wraps every
    exception it sees, as the env's option checks do, cannot hide the reason)."""
    rang = [False]
    if (
        not hasattr(signal, "setitimer")
        or threading.current_thread() is not threading.main_thread()
    ):
        yield rang
        return
    from agents.runner import TimeLimitExceeded

    def ring(signum: int, frame: object) -> None:
        rang[0] = True
        raise TimeLimitExceeded(f"the run was still going after its time limit ({seconds:g} s)")

    old = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, max(seconds, 1e-3))
    try:
        yield rang
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _error(exc: BaseException, tb: str) -> dict[str, Any]:
    """A failed run's ``error``: the type, one line of what happened, the traceback (with the
    agent's own, when the agent ran in a process of its own)."""
    message = str(exc)
    if isinstance(exc, MemoryError):
        message = message or "out of memory (the run's memory limit, memory_limit_mb)"
    own = getattr(exc, "agent_traceback", "")
    return {
        "type": type(exc).__name__,
        "message": message,
        "traceback": tb + (f"\nin the agent's process:\n{own}" if own else ""),
    }


def run_in_worker(run_fn: RunFn, spec_dict: dict[str, Any]) -> dict[str, Any]:
    """What a worker does with one run: call ``run_fn``, never raise, time it. Returns the
    outcome, the status (ok/failed with the reason and traceback), the warnings it logged and
    where and when it ran. A run still going after the spec's ``time_limit_s`` is stopped and
    failed (:func:`_alarm`)."""
    _limit_threads()
    spec = RunSpec.from_dict(spec_dict)
    started = _now()
    t0 = time.perf_counter()
    warnings_logged: list[str] = []
    rang = [False]
    try:
        with _collect_warnings() as warnings_logged, _alarm(spec.time_limit_s) as rang:
            outcome = dict(run_fn(spec))
        status, error = "ok", None
    except Exception as exc:
        log.info("run %s failed: %s: %s", spec.run_key, type(exc).__name__, exc)
        outcome = {}
        status = "failed"
        error = _error(exc, traceback.format_exc())
        if rang[0]:  # whatever the exception became on its way up
            error["type"] = "TimeLimitExceeded"
            error["message"] = (
                f"the run was still going after its time limit ({spec.time_limit_s:g} s)"
            )
    wall = time.perf_counter() - t0
    env = environment_info()
    return jsonable(
        {
            "status": status,
            "error": error,
            "outcome": outcome,
            "warnings": warnings_logged,
            "versions": env["versions"],
            "git": env["git"],
            "timing": {
                "started": started,
                "finished": _now(),
                "wall_time_s": wall,
                "host": socket.gethostname(),
                "pid": os.getpid(),
            },
        }
    )


def build_record(
    spec: RunSpec, result: Mapping[str, Any], config: ExperimentConfig | None = None
) -> dict[str, Any]:
    """A record from a spec and what :func:`run_in_worker` returned."""
    outcome = dict(result.get("outcome") or {})
    timing = dict(result.get("timing") or {})
    timing |= dict(outcome.pop("timing_metrics", {}) or {})
    return jsonable(
        {
            "schema": RECORD_SCHEMA,
            "run_key": spec.run_key,
            "run_hash": spec.run_hash,
            "config_name": spec.config_name,
            "config_hash": config.hash if config is not None else None,
            "config_path": repo_path(config.path) if config is not None else None,
            "spec": spec.to_dict(),
            "status": result.get("status", "failed"),
            "oracle": bool(outcome.pop("oracle", False)),
            "isolated": bool(outcome.pop("isolated", spec.isolate)),
            # a class-path agent's module: {module, file, root, sha256} (None: registered agent)
            "agent_module": outcome.pop("agent_module", None),
            "error": result.get("error"),
            "metrics": outcome.pop("metrics", {}),
            "report": outcome.pop("report", {}),
            "calibration": outcome.pop("calibration", {}),
            "episode": outcome.pop("episode", {}),
            "warnings": list(result.get("warnings") or []),
            "series": outcome.pop("series", {}),
            "extra": outcome,
            "versions": result.get("versions", {}),
            "git": result.get("git", {}),
            "timing": timing,
        }
    )


def _failed_outcome(exc: BaseException, note: str) -> dict[str, Any]:
    env = environment_info()
    return {
        "status": "failed",
        "error": {
            "type": type(exc).__name__,
            "message": f"{note}: {exc}",
            "traceback": "".join(traceback.format_exception(exc)),
        },
        "outcome": {},
        "versions": env["versions"],
        "git": env["git"],
        "timing": {"started": _now(), "finished": _now(), "wall_time_s": 0.0},
    }


# -- the sweep ---------------------------------------------------------------------------------


def episode_seeds(config: ExperimentConfig, store: RunStore) -> tuple[int, ...] | None:
    """The episode seeds of a config that draws them (None for fixed seeds): those the sweep's
    manifest in ``store`` keeps, then new ones drawn from the operating system's randomness in
    [2**32, 2**63) for the rest. Nothing is written here (:func:`run_sweep` keeps them)."""
    if not config.draw_seeds:
        return None
    from experiments.config import DRAWN_SEED_HIGH, DRAWN_SEED_LOW

    man = store.manifest() or {}
    kept = man.get("episode_seeds") or []
    if not isinstance(kept, list) or not all(
        isinstance(x, int) and not isinstance(x, bool) and DRAWN_SEED_LOW <= x < DRAWN_SEED_HIGH
        for x in kept
    ):
        raise SweepError(
            f"{store.root / '_sweep.json'}: episode_seeds: expected a list of integers in "
            f"[2**32, 2**63), got {str(kept)[:80]}"
        )
    seeds = list(kept)
    draw = secrets.SystemRandom()
    while len(seeds) < config.draw_seeds:
        x = draw.randrange(DRAWN_SEED_LOW, DRAWN_SEED_HIGH)
        if x not in seeds:
            seeds.append(x)
    return tuple(seeds)


def plan_sweep(
    config: ExperimentConfig,
    store: RunStore,
    retry_failed: bool = True,
    overwrite: bool = False,
    seeds: Sequence[int] | None = None,
) -> tuple[list[RunSpec], list[RunSpec]]:
    """``(pending, finished)``: the runs still to do and those whose record is already there.
    A config that draws its seeds uses ``seeds``, or :func:`episode_seeds`.

    Raises :class:`SweepError` when a record under a run key has another spec (unless
    ``overwrite``): the config changed, and mixing the two would lose or mislabel results."""
    if seeds is None:
        seeds = episode_seeds(config, store)
    pending, finished, conflicts = [], [], []
    for spec in config.runs(seeds):
        rec = store.load(spec.run_key)
        if rec is None:
            pending.append(spec)
        elif rec.get("run_hash") != spec.run_hash:
            if overwrite:
                pending.append(spec)
            else:
                conflicts.append(store.path(spec.run_key))
        elif rec.get("status") == "ok" or not retry_failed:
            finished.append(spec)
        else:
            pending.append(spec)
    if conflicts:
        shown = "\n".join(f"  {p}" for p in conflicts[:5])
        more = f"\n  ... and {len(conflicts) - 5} more" if len(conflicts) > 5 else ""
        raise SweepError(
            f"{len(conflicts)} record(s) in {store.root} were made by another spec of the same "
            f"run (the config changed):\n{shown}{more}\nUse another output directory, or "
            "overwrite them (--overwrite)."
        )
    return pending, finished


def run_sweep(
    config: ExperimentConfig,
    out_dir: str | Path | None = None,
    *,
    workers: int | None = None,
    backend: str = "local",
    address: str | None = None,
    processes: bool = True,
    run_fn: RunFn | None = None,
    retry_failed: bool = True,
    overwrite: bool = False,
    command: str | None = None,
    progress: Callable[[SweepProgress], None] | None = None,
) -> SweepSummary:
    """Run every pending run of ``config``; see the module docstring.

    ``workers``: local processes (default: the CPU count; 0 runs in this process, one after
    another), or the workers of a Dask LocalCluster. ``address``: an existing Dask scheduler.
    ``processes=False`` makes the LocalCluster's workers threads of this process. ``run_fn``
    replaces :func:`execute_run` (it must be picklable: a module-level function)."""
    if backend not in ("local", "dask"):
        raise SweepError(f"unknown backend {backend!r}; use 'local' or 'dask'")
    if workers is not None and (
        isinstance(workers, bool) or int(workers) != workers or workers < 0
    ):
        raise SweepError(f"workers must be an integer >= 0, got {workers!r}")
    run_fn = run_fn or execute_run
    store = RunStore(out_dir if out_dir is not None else Path("runs") / config.name)
    store.check_writable()  # before any run: a read-only place fails now, in one line
    if backend == "dask" and address:
        check_scheduler(address)  # before anything is written
    with store.lock():  # one sweep a directory; what a killed one left half-written goes
        seeds = episode_seeds(config, store)
        pending, finished = plan_sweep(config, store, retry_failed, overwrite, seeds)
        t0 = time.perf_counter()
        store.write_manifest(
            {
                "config_name": config.name,
                "config_hash": config.hash,
                "config_path": repo_path(config.path),
                "command": command,
                "config": config.to_dict(),
                "runs": {s.run_key: s.run_hash for s in config.runs(seeds)},
            }
            | ({} if seeds is None else {"episode_seeds": list(seeds)})
        )
        state = SweepProgress(total=len(pending) + len(finished), skipped=len(finished))
        failed: list[str] = []
        log.info(
            "sweep %s: %d runs, %d already finished, %d to run (%s backend)",
            config.name,
            state.total,
            state.skipped,
            len(pending),
            backend,
        )

        def report(spec: RunSpec, result: Mapping[str, Any]) -> None:
            rec = build_record(spec, result, config)
            store.write(rec)
            state.done += 1
            state.last = spec.run_key
            if rec["status"] != "ok":
                state.failed += 1
                failed.append(spec.run_key)
                err = rec.get("error") or {}
                log.warning("%s failed: %s: %s", spec.run_key, err.get("type"), err.get("message"))

        def tick(running: int) -> None:
            state.running = running
            if progress is not None:
                progress(state)

        tick(0)
        if pending:
            if backend == "dask":
                _run_dask(pending, run_fn, workers, address, processes, report, tick)
            elif workers == 0:
                for spec in pending:
                    tick(1)
                    report(spec, run_in_worker(run_fn, spec.to_dict()))
                tick(0)
            else:
                n = workers if workers is not None else (os.cpu_count() or 1)
                _run_local(pending, run_fn, max(1, n), report, tick, config.memory_limit_mb)
        return SweepSummary(
            out_dir=store.root,
            total=state.total,
            skipped=state.skipped,
            done=state.done,
            failed=failed,
            wall_time_s=time.perf_counter() - t0,
        )


#: the least grace (s) past a run's time limit before the sweep ends its worker
OVERDUE_GRACE_S = 30.0

#: runs a worker process does before a fresh one replaces it. A run's address-space limit
#: (``memory_limit_mb``) counts all a long-lived worker holds: the leaderboard's full sweep at
#: 295022a, 2,160 runs a worker, had 11 runs refused memory after some 1,700 each, its envs kept
#: alive by a reference cycle until the cyclic collector ran (about 12-16 MiB each; the env no
#: longer makes that cycle). A fresh process (its imports: about 2 s) bounds any such growth.
RUNS_PER_WORKER = 200


def _overdue_after(spec: RunSpec) -> float:
    """How long after its start the sweep ends a run's worker (s): its time limit, which the
    worker enforces itself, and a grace for a hang no signal can stop (inside C code)."""
    return spec.time_limit_s + max(OVERDUE_GRACE_S, 0.25 * spec.time_limit_s)


def _run_local(
    pending: Sequence[RunSpec],
    run_fn: RunFn,
    workers: int,
    report: Callable[[RunSpec, Mapping[str, Any]], None],
    tick: Callable[[int], None],
    memory_limit_mb: int | None = None,
) -> None:
    """A bounded queue over a spawned process pool: at most ``workers`` runs in flight, so the
    progress bar's "running" is true and an interrupt loses at most those. A run whose worker
    does not answer well past its time limit (:func:`_overdue_after`) is recorded as failed and
    the pool is ended and replaced (the other runs in flight are run again)."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    from agents.runner import TimeLimitExceeded

    queue = deque(pending)
    ctx = mp.get_context("spawn")  # no forked copies of MuJoCo, CasADi or torch state
    with _child_thread_env():
        while queue:
            pool = ProcessPoolExecutor(
                max_workers=workers,
                mp_context=ctx,
                initializer=_worker_init,
                initargs=(os.getpid(), memory_limit_mb),
                max_tasks_per_child=RUNS_PER_WORKER,
            )
            try:
                inflight: dict[Any, tuple[RunSpec, float]] = {}
                broken = False
                while (queue or inflight) and not broken:
                    while queue and len(inflight) < workers:
                        spec = queue.popleft()
                        fut = pool.submit(run_in_worker, run_fn, spec.to_dict())
                        inflight[fut] = (spec, time.monotonic())
                    tick(len(inflight))
                    due = min(t0 + _overdue_after(sp) for sp, t0 in inflight.values())
                    done, _ = wait(
                        inflight,
                        timeout=max(0.0, due - time.monotonic()),
                        return_when=FIRST_COMPLETED,
                    )
                    if not done:
                        _end_overdue(pool, inflight, queue, report, TimeLimitExceeded)
                        broken = True
                        break
                    for fut in done:
                        spec, _ = inflight.pop(fut)
                        try:
                            result = fut.result()
                        except BrokenProcessPool as exc:
                            broken = True
                            result = _failed_outcome(
                                exc,
                                "a worker process died while this run was in flight (this run "
                                "or another one in flight crashed it, or ran out of memory)",
                            )
                        except Exception as exc:  # e.g. an outcome that cannot be pickled
                            result = _failed_outcome(exc, "the run's result did not come back")
                        report(spec, result)
                if broken and inflight:  # the pool is unusable: every run in flight died with it
                    for fut, (spec, _) in inflight.items():
                        err = fut.exception() if fut.done() else BrokenProcessPool("pool broken")
                        report(spec, _failed_outcome(err, "a worker process died"))
                    inflight.clear()
                    log.warning("a worker process died; starting a new pool")
            except BaseException:  # an interrupt, or a record that cannot be written
                _stop_pool(pool)
                raise
            if broken:
                _stop_pool(pool)
            else:
                pool.shutdown(wait=True)
    tick(0)


def _end_overdue(
    pool: Any,
    inflight: dict[Any, tuple[RunSpec, float]],
    queue: deque,
    report: Callable[[RunSpec, Mapping[str, Any]], None],
    timeout_error: type[Exception],
) -> None:
    """End the pool whose worker hangs: the overdue runs are recorded as failed, runs that
    finished meanwhile as they came back, and the others go back to the front of the queue."""
    now = time.monotonic()
    _stop_pool(pool)
    for fut, (spec, t0) in list(inflight.items()):
        if fut.done() and not fut.cancelled() and fut.exception() is None:
            report(spec, fut.result())
        elif now >= t0 + _overdue_after(spec) - 1e-3:
            exc = timeout_error(
                f"the run did not end within its time limit ({spec.time_limit_s:g} s) and its "
                "worker did not answer after it; the worker was ended"
            )
            log.warning("%s: over its time limit; its worker was ended", spec.run_key)
            report(spec, _failed_outcome(exc, "time limit"))
        else:
            queue.appendleft(spec)
    inflight.clear()


#: how long to wait for a Dask scheduler to answer (s)
SCHEDULER_TIMEOUT_S = 5.0


def check_scheduler(address: str) -> None:
    """Refuse at once an address where no scheduler listens (a TCP connection is tried first:
    Dask's own client would retry for its whole timeout)."""
    from urllib.parse import urlsplit

    url = urlsplit(address if "://" in address else f"tcp://{address}")
    if url.scheme not in ("tcp", "tls"):  # inproc://, ucx://...: Dask's client judges them
        return
    try:
        host, port = url.hostname, url.port
    except ValueError:
        host, port = None, None
    if not host or port is None:
        raise SweepError(
            f"--address {address!r}: not a scheduler address (tcp://HOST:PORT, e.g. "
            "tcp://127.0.0.1:8786)"
        )
    try:
        with socket.create_connection((host, port), timeout=SCHEDULER_TIMEOUT_S):
            pass
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        raise SweepError(f"--address {address}: no Dask scheduler answers there ({why})") from None


def _run_dask(
    pending: Sequence[RunSpec],
    run_fn: RunFn,
    workers: int | None,
    address: str | None,
    processes: bool,
    report: Callable[[RunSpec, Mapping[str, Any]], None],
    tick: Callable[[int], None],
) -> None:
    """The same bounded queue over a Dask cluster (an existing scheduler, or a LocalCluster)."""
    try:
        from distributed import Client, LocalCluster, wait
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        raise SweepError(
            "the Dask backend needs the 'cluster' extra: pip install 'sixaxis-track[cluster]'"
        ) from exc

    if not log.isEnabledFor(logging.INFO):  # Dask's own chatter only when asked for (-v)
        for name in ("distributed", "dask"):
            logging.getLogger(name).setLevel(logging.WARNING)
    with contextlib.ExitStack() as stack:
        if address:
            check_scheduler(address)
            try:
                client = stack.enter_context(Client(address, timeout=SCHEDULER_TIMEOUT_S))
            except (OSError, TimeoutError, ValueError) as exc:
                raise SweepError(
                    f"--address {address}: cannot connect to a Dask scheduler there: "
                    f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
                ) from None
        else:
            n = workers if workers else (os.cpu_count() or 1)
            with _child_thread_env():
                cluster = stack.enter_context(
                    LocalCluster(
                        n_workers=n,
                        threads_per_worker=1,
                        processes=processes,
                        dashboard_address=None,
                    )
                )
            client = stack.enter_context(Client(cluster))
        slots = max(1, sum(client.nthreads().values()))
        log.info("dask: %s with %d worker threads", client.scheduler.address, slots)
        queue = deque(pending)
        inflight: dict[Any, RunSpec] = {}
        while queue or inflight:
            while queue and len(inflight) < slots:
                spec = queue.popleft()
                fut = client.submit(
                    run_in_worker,
                    run_fn,
                    spec.to_dict(),
                    pure=False,
                    key=f"sixaxis-run-{spec.run_key}-{os.urandom(4).hex()}",
                )
                inflight[fut] = spec
            tick(len(inflight))
            done, _ = wait(list(inflight), return_when="FIRST_COMPLETED")
            for fut in done:
                spec = inflight.pop(fut)
                try:
                    result = fut.result()
                except Exception as exc:  # a killed worker, a lost connection
                    result = _failed_outcome(exc, "the Dask task failed")
                report(spec, result)
                fut.release()
    tick(0)
