"""An agent in a process of its own, so that nothing of the episode's truth exists where it runs.

    agent = IsolatedAgent("mypkg.controllers:MyAgent", {"gain": 2.0})
    result = run_episode(agent, {"scenario": "geometric"}, seed=7)    # as any agent
    agent.close()

The agent's class is imported, made and run in a fresh Python process (not a fork: nothing of
this process's memory is copied into it). This process keeps the env, the plant and its truth,
and sends the agent, over a pipe, only what a controller is given: the task at ``reset`` and
``next_phase``, then at each step the observation and the controllers' part of ``info``
(:func:`envs.task.controller_info`); an oracle (an agent whose ``needs_truth`` is set when it is
made) also gets a copy of the truth at ``reset`` and the plant's exact conditions at each step.
No env, truth or runner object exists in the agent's process, so walking its garbage collector
or its stack finds none.

The pipe's two directions differ. What this process sends is pickled (it comes from us); what
the agent's process sends back is JSON only (the action as numbers, the report as plain data),
so nothing the agent's process sends can run code here.

What it covers: accidents and casual peeking. It does not cover a hostile process running as the
same user, which can read any file that user can (the run directory with other runs' records
among them) and, where the system allows, other processes' memory. Run agents you do not trust
as another user, or in a container with only the code mounted (docs/benchmark.md).

Time and memory. Every call waits at most until ``deadline`` (a :func:`time.monotonic` time);
an agent that does not answer by then is killed and :class:`~agents.runner.TimeLimitExceeded` is
raised, so a hanging ``act`` cannot hang a sweep. ``memory_limit_mb`` caps the agent process's
address space (``RLIMIT_AS``, where the platform has it): an agent that exhausts it fails with a
``MemoryError`` that names it. An exception in the agent is raised here as
:class:`~agents.runner.AgentFailure` with the agent's own traceback in its message.

The numbers are the same as in one process: the action comes back as the agent returned it
(JSON writes a float exactly), and the agent's randomness, if any, is seeded the same way
(``tests/test_agents_isolation.py``; the cost per step is in ``results/benchmarks.md``).
"""

from __future__ import annotations

import contextlib
import copy
import json
import logging
import os
import pickle
import select
import struct
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Mapping
from typing import Any

import numpy as np

from agents.base import Agent
from agents.runner import AgentFailure, TimeLimitExceeded
from envs.task import TaskInfo, Truth

__all__ = ["THREAD_VARS", "IsolatedAgent", "limit_memory", "plain_data"]

log = logging.getLogger(__name__)

#: how long a new agent process may take to import and make its agent (s), unless the run's
#: deadline comes first
START_SECONDS = 120.0
#: the largest message the agent's process may send back (bytes)
MAX_REPLY_BYTES = 64 << 20
_HEADER = struct.Struct("!Q")
#: the thread-count variables of the numerical libraries: one thread each for an agent's process
THREAD_VARS = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
)


def plain_data(x: Any) -> Any:
    """``x`` as JSON-able plain data: arrays and numpy scalars as lists and numbers, tuples and
    sets as lists, mapping keys as strings; anything else as its ``repr``."""
    if isinstance(x, Mapping):
        return {str(k): plain_data(v) for k, v in x.items()}
    if isinstance(x, np.ndarray):
        return plain_data(x.tolist())
    if isinstance(x, (list, tuple, set, frozenset)):
        return [plain_data(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    return repr(x)


def _error_text(err: Mapping[str, Any]) -> str:
    return f"{err.get('type', 'Error')}: {err.get('message', '')}"


class IsolatedAgent(Agent):
    """An agent (registered name or ``package.module:Class``) made and run in its own process;
    see the module docstring. Its ``needs_truth`` is what the agent said when it was made, and
    does not change after."""

    def __init__(
        self,
        name: str,
        settings: Mapping[str, Any] | None = None,
        *,
        deadline: float | None = None,
        memory_limit_mb: int | None = None,
    ) -> None:
        super().__init__()
        self.agent_spec = name
        self.deadline = deadline
        self.memory_limit_mb = memory_limit_mb
        self._truth: Truth | None = None
        self._model_desc: dict[str, Any] | None = None
        self._proc: subprocess.Popen | None = None
        self._stderr = tempfile.TemporaryFile()
        parent_r, child_w = os.pipe()
        child_r, parent_w = os.pipe()
        env = dict(os.environ) | {v: "1" for v in THREAD_VARS}
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "agents.isolation", str(child_r), str(child_w)],
                pass_fds=(child_r, child_w),
                stdin=subprocess.DEVNULL,
                stdout=self._stderr,
                stderr=self._stderr,
                env=env,
                cwd=tempfile.gettempdir(),
                close_fds=True,
            )
        finally:
            os.close(child_r)
            os.close(child_w)
        self._rfd, self._wfd = parent_r, parent_w
        ready = self._call(
            {
                "op": "init",
                "name": name,
                "settings": dict(settings or {}),
                "sys_path": [os.path.abspath(p) if p else os.getcwd() for p in sys.path],
                "memory_limit_mb": memory_limit_mb,
            },
            what="start",
            limit=START_SECONDS,
        )
        self.name = str(ready.get("name", name))
        self.needs_truth = bool(ready.get("needs_truth", False))
        self.class_name = str(ready.get("class", ""))

    # -- the agent's interface -------------------------------------------------------------
    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task = task
        self._truth = truth if self.needs_truth else None
        self._model_desc = None
        self._call({"op": "reset", "task": task, "seed": seed, "truth": _snapshot(self._truth)})

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        self.task = task
        self._truth = truth if self.needs_truth else None
        self._call({"op": "next_phase", "task": task, "truth": _snapshot(self._truth)})

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        msg: dict[str, Any] = {"op": "act", "obs": obs, "info": dict(info)}
        if self._truth is not None:
            msg["conditions"] = dict(self._truth.conditions())
        reply = self._call(msg, what="act")
        self.last_solve_time = float(reply.get("solve", 0.0))
        return np.asarray(reply.get("action"), dtype=float)

    def report(self) -> dict[str, float | list]:
        reply = self._call({"op": "report"}, what="report")
        self._model_desc = reply.get("model")
        rep = reply.get("report")
        return dict(rep) if isinstance(rep, dict) else {}

    @property
    def model(self) -> Any:
        """The agent's error model, rebuilt here from its effects (for the calibration error),
        or None when it has none or it cannot be rebuilt."""
        desc = self._model_desc
        if not desc or self._task is None:
            return None
        from arm.errormodel import ErrorModel

        try:
            return ErrorModel(self.task.robot, list(desc["effects"]), desc["targets"])
        except Exception as exc:  # an effect of the user's own: no model here
            log.debug("cannot rebuild the agent's model %s: %s", desc, exc)
            return None

    # -- the process ------------------------------------------------------------------------
    def close(self) -> None:
        """End the agent's process (asked first, then killed)."""
        proc = self._proc
        if proc is None:
            return
        self._proc = None
        if proc.poll() is None:
            with contextlib.suppress(OSError):
                _send(self._wfd, pickle.dumps({"op": "close"}))
            try:
                proc.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for fd in (self._rfd, self._wfd):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._stderr.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    def __enter__(self) -> IsolatedAgent:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _kill(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()

    def _stderr_tail(self, n: int = 2000) -> str:
        with contextlib.suppress(OSError, ValueError):
            self._stderr.seek(0, os.SEEK_END)
            size = self._stderr.tell()
            self._stderr.seek(max(0, size - n))
            return self._stderr.read().decode("utf-8", "replace").strip()
        return ""

    def _call(
        self, msg: dict[str, Any], what: str | None = None, limit: float | None = None
    ) -> dict[str, Any]:
        """Send ``msg``, wait for the reply (until the deadline), raise what went wrong."""
        what = what or str(msg["op"])
        if self._proc is None:
            raise AgentFailure(f"agent {self.agent_spec}: its process was closed")
        try:
            _send(self._wfd, pickle.dumps(msg, protocol=pickle.HIGHEST_PROTOCOL))
        except OSError:  # the process is gone: its exit says why (below)
            pass
        timeout = None if self.deadline is None else self.deadline - time.monotonic()
        if limit is not None:
            timeout = limit if timeout is None else min(timeout, limit)
        try:
            raw = _receive(self._rfd, timeout)
        except TimeoutError:
            self._kill()
            if limit is not None and (
                self.deadline is None or time.monotonic() < self.deadline - 1e-3
            ):
                raise AgentFailure(
                    f"agent {self.agent_spec}: its process did not start within {limit:g} s"
                ) from None
            raise TimeLimitExceeded(
                f"agent {self.agent_spec}: {what} did not return within the run's time limit"
            ) from None
        except EOFError:
            code = self._proc.wait() if self._proc is not None else None
            how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit {code}"
            tail = self._stderr_tail()
            raise AgentFailure(
                f"agent {self.agent_spec}: its process ended during {what} ({how})"
                + (f"; it wrote: {tail.splitlines()[-1]}" if tail else "")
            ) from None
        try:
            reply = json.loads(raw)
        except (ValueError, UnicodeDecodeError):
            self._kill()
            raise AgentFailure(
                f"agent {self.agent_spec}: its process sent something that is not JSON"
            ) from None
        if not isinstance(reply, dict):
            self._kill()
            raise AgentFailure(f"agent {self.agent_spec}: its process sent {type(reply).__name__}")
        if "error" in reply:
            err = reply["error"] if isinstance(reply["error"], dict) else {}
            exc = AgentFailure(f"agent {self.agent_spec}: {what} raised {_error_text(err)}")
            exc.agent_traceback = str(err.get("traceback", ""))
            if what in ("start", "init"):
                self.close()
            raise exc
        return reply


def _snapshot(truth: Truth | None) -> Truth | None:
    """A copy of the truth to send: without its live view of the plant (the agent's process
    gets the plant's conditions with each step instead)."""
    if truth is None:
        return None
    snap = copy.copy(truth)
    if getattr(snap, "_live", None) is not None:
        object.__setattr__(snap, "_live", None)
    return snap


# -- the wire ------------------------------------------------------------------------------------


def _send(fd: int, payload: bytes) -> None:
    data = _HEADER.pack(len(payload)) + payload
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


def _read_exact(fd: int, n: int, deadline: float | None) -> bytes:
    chunks, got = [], 0
    while got < n:
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                raise TimeoutError
        chunk = os.read(fd, min(n - got, 1 << 20))
        if not chunk:
            raise EOFError
        chunks.append(chunk)
        got += len(chunk)
    return b"".join(chunks)


def _receive(fd: int, timeout: float | None, limit: int = MAX_REPLY_BYTES) -> bytes:
    deadline = None if timeout is None else time.monotonic() + max(0.0, timeout)
    (n,) = _HEADER.unpack(_read_exact(fd, _HEADER.size, deadline))
    if n > limit:
        raise EOFError
    return _read_exact(fd, n, deadline)


# -- the agent's process ------------------------------------------------------------------------


def _model_desc(agent: Agent) -> dict[str, Any] | None:
    model = getattr(agent, "model", None)
    names = getattr(model, "effect_names", None)
    targets = getattr(model, "targets", None)
    if names is None or targets is None:
        return None
    return {"effects": [str(n) for n in names], "targets": [int(t) for t in targets]}


class _Conditions:
    """The plant's conditions as the last step sent them (an oracle's truth reads them)."""

    def __init__(self) -> None:
        self.now: dict[str, float] = {}

    def __call__(self) -> dict[str, float]:
        return dict(self.now)


def _serve(rfd: int, wfd: int) -> int:  # noqa: C901  (one loop: a branch per message of the pipe)
    """The agent process's loop: one request, one JSON reply, until ``close`` or EOF."""

    def reply(obj: dict[str, Any]) -> None:
        _send(wfd, json.dumps(obj, allow_nan=True).encode())

    def failure(exc: BaseException) -> dict[str, Any]:
        return {
            "error": {
                "type": type(exc).__name__,
                "message": str(exc).splitlines()[0][:500] if str(exc) else "",
                "traceback": traceback.format_exc()[-8000:],
            }
        }

    agent: Agent | None = None
    live = _Conditions()
    while True:
        try:
            msg = pickle.loads(_receive(rfd, None, limit=1 << 40))
        except EOFError:
            return 0
        op = msg.get("op")
        try:
            if op == "init":
                sys.path[:] = list(msg["sys_path"])
                limit_memory(msg.get("memory_limit_mb"))
                from agents.registry import make_agent

                agent = make_agent(msg["name"], **msg["settings"])
                torch = sys.modules.get("torch")
                if torch is not None:
                    torch.set_num_threads(1)
                reply(
                    {
                        "name": str(agent.name),
                        "class": f"{type(agent).__module__}:{type(agent).__qualname__}",
                        "needs_truth": bool(agent.needs_truth),
                    }
                )
            elif op == "close":
                return 0
            elif agent is None:
                reply({"error": {"type": "RuntimeError", "message": "no agent made yet"}})
            elif op in ("reset", "next_phase"):
                truth = msg.get("truth")
                if truth is not None and hasattr(truth, "bind"):
                    truth.bind(live)
                if op == "reset":
                    agent.reset(msg["task"], seed=msg["seed"], truth=truth)
                else:
                    agent.next_phase(msg["task"], truth=truth)
                reply({"ok": True})
            elif op == "act":
                if "conditions" in msg:
                    live.now = dict(msg["conditions"])
                action = agent.act(msg["obs"], msg["info"])
                values = np.asarray(action, dtype=float).ravel().tolist()
                reply({"action": values, "solve": float(getattr(agent, "last_solve_time", 0.0))})
            elif op == "report":
                reply({"report": plain_data(agent.report()), "model": _model_desc(agent)})
            else:
                reply({"error": {"type": "ValueError", "message": f"unknown request {op!r}"}})
        except (Exception, SystemExit) as exc:  # the agent's failure, told to the runner
            agent_failed = failure(exc)
            try:
                reply(agent_failed)
            except MemoryError:
                reply({"error": {"type": "MemoryError", "message": "out of memory"}})
            if op == "init":
                return 1


def limit_memory(mb: int | None) -> None:
    """Cap this process's address space at ``mb`` MiB (``RLIMIT_AS``, where the platform has
    it): code that needs more fails with a ``MemoryError`` instead of taking the machine."""
    if not mb:
        return
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return
    _soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = int(mb) << 20
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    try:
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    except (ValueError, OSError) as exc:  # pragma: no cover - a platform that refuses
        log.debug("no memory limit: %s", exc)


def _die_with_parent() -> None:
    """End this process when the one that started it ends, even inside a hanging ``act``:
    Linux kills it with its parent (``PR_SET_PDEATHSIG``); everywhere, a daemon thread exits
    once the parent pid changes. SIGINT is ignored: the runner decides what stops."""
    import ctypes
    import signal
    import threading

    parent = os.getppid()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.2)
        os._exit(1)

    threading.Thread(target=watch, name="sixaxis-agent-watchdog", daemon=True).start()


def _main(argv: list[str]) -> int:
    rfd, wfd = int(argv[1]), int(argv[2])
    _die_with_parent()
    # the agent's prints go to the log file, never into the pipe
    sys.stdout.flush()
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    return _serve(rfd, wfd)


if __name__ == "__main__":  # pragma: no cover - the agent's process
    sys.exit(_main(sys.argv))
