"""The episode loop: one agent, one seeded arm, one or more phases, arrays out.

    result = run_episode(make_agent("mpc"), {"scenario": "geometric"}, seed=3)
    result.rms_mm(start=3.0)                      # tracking RMS after the first 3 s, mm

A *phase* is a stretch of the same arm under different env settings: the must-show "calibrate,
then run blind on a new trajectory" is two phases,

    run_episode(agent, {"scenario": "compliance"}, seed=0,
                phases=calibrate_then_blind(10.0, 10.0, judge_trajectory="lemniscate"))

Each phase makes the env with ``env_kwargs | phase.overrides`` and resets it with the same seed, so
the truth (the sampled arm) is the same (checked: a phase whose truth differs is refused); the agent
is told with ``next_phase`` and keeps what it learned. Only ``judged`` phases count in the metrics.

Because every phase is reset with the same seed, phases that differ only in trajectory kind draw
their paths around the same random posture; :func:`workspace_campaign` sets each phase's
``posture`` so that calibration covers the workspace and the judged region is a new one.

What the agent is given is what a real controller has: the observation, the env's ``task`` (which
does not name the scenario) and, of each step's ``info``, only :data:`envs.task.CONTROLLER_INFO_KEYS`
(the tracker's measurement, the reference, the time, the divergence flag). The true tool point and
error, the reward's parts and the plant's exact temperature and payload stay here, for the
metrics. The plant's truth (:class:`envs.task.Truth`) is handed to agents that declare
``needs_truth = True`` (oracles) and to no other.

No agent is given the episode's seed: the plant's truth is a function of it and the public code.
An agent that wants randomness gets ``reset(task, seed=agent_seed)``, a number derived from the
episode seed by a cryptographic hash (:func:`agent_seed`), which gives nothing away about it. An
agent's oracle status is read once, when the episode starts, before ``reset``: an agent that says
``needs_truth = False`` later is still recorded as an oracle (``EpisodeResult.oracle``), and one
that says ``True`` only later gets no truth.

An agent that raises, or returns an action that is not 6 finite numbers, ends the episode with
:class:`AgentFailure` (naming the agent, the call and the step); an episode still running at its
``deadline`` (a :func:`time.monotonic` time) ends with :class:`TimeLimitExceeded`.

Deterministic: the same agent settings, env settings and seed give the same arrays (timings
aside). Inputs and outputs are plain data, so runs can be farmed out to other processes.
"""

from __future__ import annotations

import hashlib
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from agents.base import Agent
from agents.errors import AgentFailure, EpisodeError, TimeLimitExceeded
from envs.task import Truth, controller_info

__all__ = [
    "ENV_ID",
    "JUDGE_POSTURES",
    "WORKSPACE_POSTURES",
    "AgentFailure",
    "EpisodeError",
    "EpisodeResult",
    "Phase",
    "TimeLimitExceeded",
    "agent_seed",
    "calibrate_then_blind",
    "calibration_campaign",
    "make_env",
    "run_episode",
    "workspace_campaign",
]

log = logging.getLogger(__name__)

ENV_ID = "SixAxisTrack-v0"


def agent_seed(episode_seed: int) -> int:
    """The seed an agent is given for an episode: 63 bits of SHA-256 of the episode seed. It
    gives the agent reproducible randomness and nothing of the episode seed (the hash cannot be
    inverted, and the published seeds are drawn from 2**63 values)."""
    digest = hashlib.sha256(f"sixaxis-agent-seed:{int(episode_seed)}".encode()).digest()
    return int.from_bytes(digest[:8], "big") >> 1


@dataclass(frozen=True)
class Phase:
    """``seconds`` of the episode with ``overrides`` of the env settings (e.g. a new
    ``trajectory``, ``measurements=False``); ``judged`` phases count in the metrics."""

    name: str = "track"
    seconds: float | None = None
    overrides: Mapping[str, Any] = field(default_factory=dict)
    judged: bool = True


def calibrate_then_blind(
    calibration_seconds: float = 10.0,
    judge_seconds: float = 10.0,
    judge_trajectory: str | None = "lemniscate",
    calibration_trajectory: str | None = None,
) -> list[Phase]:
    """A calibration phase with measurements (not judged), then blind tracking (measurements
    off) on another trajectory (judged)."""
    cal = {} if calibration_trajectory is None else {"trajectory": calibration_trajectory}
    blind: dict[str, Any] = {"measurements": False}
    if judge_trajectory is not None:
        blind["trajectory"] = judge_trajectory
    return [
        Phase("calibration", calibration_seconds, cal, judged=False),
        Phase("blind", judge_seconds, blind, judged=True),
    ]


def calibration_campaign(
    kinds: Sequence[str] = ("circle", "lines", "spline"),
    payloads: Sequence[float] | None = (0.0, 3.0),
    seconds: float = 10.0,
    judge_trajectory: str = "lemniscate",
    judge_payload: float | None = 1.5,
    judge_seconds: float = 10.0,
) -> list[Phase]:
    """A calibration campaign, then blind tracking on a trajectory not seen before.

    One measured phase per trajectory kind (each drawn in its own region of the workspace) and,
    with ``payloads``, per payload mass (kg, constant through the phase: the ``payload``
    scenario's schedule overridden); then the judged phase, measurements off, on
    ``judge_trajectory`` with ``judge_payload``. Load contrast is what separates the joints'
    compliance from the geometry: at a fixed load, gravity torques vary too little along the
    env's trajectories for a geometric model to fail where it was not calibrated."""

    def load(m):
        return {} if m is None else {"overrides": {"payload": {"payload0": m, "payload1": m}}}

    phases = [
        Phase(
            f"calibration-{k}" + ("" if m is None else f"-{m:g}kg"),
            seconds,
            {"trajectory": k} | load(m),
            judged=False,
        )
        for k in kinds
        for m in (payloads if payloads is not None else (None,))
    ]
    phases.append(
        Phase(
            "blind",
            judge_seconds,
            {"trajectory": judge_trajectory, "measurements": False} | load(judge_payload),
        )
    )
    return phases


#: Calibration postures of the seed arm (joint angles, rad) spread over its workspace: the arm
#: raised and leaning back (the shoulder's gravity torque about -40 N m), upright, half and far
#: out (about 0 to 90 N m), the wrist turned different ways, the base at different angles. Each
#: is the centre of one calibration trajectory (``posture`` of the env). Nine rather than six:
#: with six, the wrist's and elbow's compliance stayed poorly determined and the compliant model
#: was up to 1.6x the oracle's blind error (median 1.2x); with nine, at most 1.15x (no forgetting, judged at
#: ``reach``, 10 seeds).
WORKSPACE_POSTURES: tuple[tuple[float, ...], ...] = (
    (-0.6, -1.9, -0.6, 0.5, 0.6, 0.0),
    (0.5, -1.2, 0.3, -0.5, -0.5, 0.0),
    (0.0, -1.6, 0.9, 0.0, 0.8, 0.0),
    (0.8, -2.1, 0.2, 0.8, -0.3, 0.0),
    (-0.3, -1.4, -0.5, -0.8, 0.4, 0.0),
    (0.3, -1.0, 0.6, 0.3, -0.7, 0.0),
    (-0.9, -1.7, 0.4, -1.0, -0.6, 0.0),
    (0.6, -1.8, 1.2, 1.1, 0.7, 0.0),
    (-0.7, -1.25, -0.1, 0.9, -0.8, 0.0),
)

#: Judged regions of the seed arm that no posture of :data:`WORKSPACE_POSTURES` visits:
#: ``reach`` far out and low (1.08 m from the base axis, 0.38 m high: shoulder torque about
#: 103 N m, above any calibration posture's), ``raised`` up and back (about -90 N m, below any),
#: ``inside`` between calibration postures (about 40 N m, 20 N m at the elbow).
JUDGE_POSTURES: dict[str, tuple[float, ...]] = {
    "reach": (-0.2, -0.9, -0.3, 0.4, 0.5, 0.0),
    "raised": (0.2, -2.3, -0.2, 0.5, 0.3, 0.0),
    "inside": (-0.5, -1.5, 0.1, -0.3, -0.4, 0.0),
}


def workspace_campaign(
    postures: Sequence[Sequence[float | None]] = WORKSPACE_POSTURES,
    kinds: Sequence[str] = ("circle", "lines", "spline"),
    seconds: float = 10.0,
    judge_posture: str | Sequence[float | None] = "reach",
    judge_trajectory: str = "lemniscate",
    judge_seconds: float = 10.0,
) -> list[Phase]:
    """A calibration campaign over the workspace at one load, then blind tracking in a region it
    did not visit.

    One measured phase per posture of ``postures`` (the env's ``posture``: the trajectory is
    drawn around it), the trajectory kinds taken in turn from ``kinds``; then the judged phase,
    measurements off, on ``judge_trajectory`` around ``judge_posture`` (a name of
    :data:`JUDGE_POSTURES` or joint angles). Gravity torques differ from posture to posture, so
    the joints' compliance is what separates the regions: a geometric-only model fitted over
    them is a compromise that leaves an error where the arm is judged, and an online estimator
    with forgetting cannot adapt to the judged region, which it never measures. The default
    postures are the seed arm's; another arm needs its own (a posture outside its joint limits is
    refused by the env)."""
    if not postures:
        raise EpisodeError("workspace_campaign needs at least one calibration posture")
    if not kinds:
        raise EpisodeError("workspace_campaign needs at least one trajectory kind")
    if isinstance(judge_posture, str):
        try:
            judge_posture = JUDGE_POSTURES[judge_posture]
        except KeyError:
            raise EpisodeError(
                f"unknown judge_posture {judge_posture!r}; known: {', '.join(JUDGE_POSTURES)}, "
                "or 6 joint angles"
            ) from None
    phases = [
        Phase(
            f"calibration-{i + 1}-{kinds[i % len(kinds)]}",
            seconds,
            {"trajectory": kinds[i % len(kinds)], "posture": list(p)},
            judged=False,
        )
        for i, p in enumerate(postures)
    ]
    phases.append(
        Phase(
            "blind",
            judge_seconds,
            {
                "trajectory": judge_trajectory,
                "posture": list(judge_posture),
                "measurements": False,
            },
        )
    )
    return phases


@dataclass
class EpisodeResult:
    """Per-step arrays of one episode (all phases concatenated) and what the agent reported.

    ``time`` (s, continuing across phases, at the end of each step), ``phase`` (index into
    ``phases``), ``judged`` (bool), ``true_error_mm`` (against the plant's true tool point),
    ``actions`` (T, 6) in [-1, 1], ``measurement`` (T, 3) the tracker point delivered at that step
    (NaN if none), ``solve_time_s`` (the agent's computation per step), ``diverged``; ``oracle``:
    whether the agent was given the truth (its ``needs_truth`` when the episode started).
    """

    agent: str
    seed: int
    env_id: str
    env_kwargs: dict
    phases: list[dict]
    time: np.ndarray
    phase: np.ndarray
    judged: np.ndarray
    true_error_mm: np.ndarray
    actions: np.ndarray
    measurement: np.ndarray
    solve_time_s: np.ndarray
    diverged: bool
    report: dict
    truth_parameters: dict[str, float] = field(default_factory=dict)
    wall_time_s: float = 0.0
    oracle: bool = False

    def _mask(self, start: float = 0.0, judged_only: bool = True) -> np.ndarray:
        m = np.ones(len(self.time), dtype=bool)
        if judged_only:
            m &= self.judged
        if start:
            # ``start`` counts from the beginning of the first judged phase
            t0 = self.time[self.judged][0] - self._dt() if judged_only and self.judged.any() else 0
            m &= self.time - t0 > start + 1e-9
        return m

    def _dt(self) -> float:
        return float(self.time[1] - self.time[0]) if len(self.time) > 1 else 0.0

    def rms_mm(self, start: float = 0.0, judged_only: bool = True) -> float:
        """Tracking RMS (mm) over the judged steps after ``start`` seconds into them."""
        e = self.true_error_mm[self._mask(start, judged_only)]
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")

    def max_mm(self, start: float = 0.0, judged_only: bool = True) -> float:
        e = self.true_error_mm[self._mask(start, judged_only)]
        return float(e.max()) if e.size else float("nan")

    def to_dict(self) -> dict:
        """Plain lists and numbers (for JSON records)."""
        out = asdict(self)
        for k, v in out.items():
            if isinstance(v, np.ndarray):
                out[k] = v.tolist()
        return out


def make_env(env_id: str, kwargs: Mapping[str, Any], steps: int | None):
    """``gym.make(env_id, **kwargs)`` with SixAxisTrack-v0 registered; ``steps`` replaces the
    registered episode limit."""
    import gymnasium as gym

    import envs  # noqa: F401  (registers SixAxisTrack-v0)

    kw = dict(kwargs)
    if steps is not None:
        kw["max_episode_steps"] = steps
    return gym.make(env_id, **kw)


def _truth_parameters(truth: Truth | None) -> dict[str, float]:
    return {} if truth is None else truth.model.layout.as_dict(truth.params)


def run_episode(
    agent: Agent,
    env_kwargs: Mapping[str, Any] | None = None,
    seed: int = 0,
    episode_seconds: float | None = None,
    phases: Sequence[Phase] | None = None,
    env_id: str = ENV_ID,
    on_step: Callable[[Any], None] | None = None,
    deadline: float | None = None,
) -> EpisodeResult:
    """Run ``agent`` on one seeded episode; see the module docstring. ``on_step(env)`` is called
    after every step (e.g. to render a frame: give ``render_mode`` in ``env_kwargs``);
    ``deadline`` (a :func:`time.monotonic` time) ends the episode with
    :class:`TimeLimitExceeded` if it is still running then."""
    env_kwargs = dict(env_kwargs or {})
    if phases is None:
        phases = [Phase("track", episode_seconds, {}, judged=True)]
    if not phases:
        raise EpisodeError("run_episode needs at least one phase")
    cols: dict[str, list] = {
        k: [] for k in ("time", "phase", "judged", "err", "act", "meas", "solve")
    }
    diverged = False
    truth0: Truth | None = None
    t_offset = 0.0
    wall0 = time.perf_counter()
    oracle = bool(agent.needs_truth)  # fixed now, before reset: what the record says
    name = str(agent.name)
    for k, ph in enumerate(phases):
        kw = env_kwargs | dict(ph.overrides)
        env = None
        try:
            # the phase's length is counted here, so lift the registered time limit
            env = make_env(env_id, kw, None if ph.seconds is None else 10**9)
            obs, info = env.reset(seed=int(seed))
            task = env.unwrapped.task
            dt = float(task.dt)
            steps = None if ph.seconds is None else max(1, round(ph.seconds / dt))
            truth = env.unwrapped.truth
            given = truth if oracle else None
            if k == 0:
                truth0 = truth
                _call(name, "reset", 0, agent.reset, task, seed=agent_seed(seed), truth=given)
            else:
                if not _same_truth(truth0, truth):
                    raise EpisodeError(
                        f"phase {ph.name!r}: overrides {dict(ph.overrides)} change the sampled "
                        "arm; a phase must keep the truth of the episode"
                    )
                _call(name, "next_phase", len(cols["time"]), agent.next_phase, task, truth=given)
            n = 0
            while True:
                step = len(cols["time"])
                if deadline is not None and time.monotonic() > deadline:
                    raise TimeLimitExceeded(
                        f"the episode was still running at its time limit (step {step}, "
                        f"{step * dt:g} s of simulated time)"
                    )
                action = _checked_action(
                    name, step, _call(name, "act", step, agent.act, obs, controller_info(info))
                )
                solve = float(getattr(agent, "last_solve_time", 0.0))
                obs, _, terminated, truncated, info = env.step(action)
                n += 1
                cols["time"].append(t_offset + float(info.get("time", n * dt)))
                cols["phase"].append(k)
                cols["judged"].append(ph.judged)
                cols["err"].append(float(info.get("true_error_mm", np.nan)))
                cols["act"].append(action)
                m = info.get("measurement")
                valid = bool(info.get("measurement_valid", False)) and m is not None
                cols["meas"].append(np.asarray(m, dtype=float) if valid else np.full(3, np.nan))
                cols["solve"].append(solve)
                if on_step is not None:
                    on_step(env)
                if info.get("diverged", False):
                    diverged = True
                if truncated and not terminated and steps is not None and n < steps:
                    raise EpisodeError(
                        f"phase {ph.name!r}: {ph.seconds:g} s asked, but the env's episode "
                        f"ends after {n * dt:g} s (its episode_seconds); give episode_seconds "
                        f"= {ph.seconds:g} in its options"
                    )
                if terminated or truncated or diverged or (steps is not None and n >= steps):
                    break
            t_offset = cols["time"][-1] if cols["time"] else t_offset
        finally:
            if env is not None:
                env.close()
        if diverged:
            log.warning("episode diverged in phase %r (seed %s)", ph.name, seed)
            break
    report = _call(name, "report", len(cols["time"]), agent.report)
    return EpisodeResult(
        agent=name,
        seed=int(seed),
        env_id=env_id,
        env_kwargs=env_kwargs,
        phases=[
            {
                "name": p.name,
                "seconds": p.seconds,
                "overrides": dict(p.overrides),
                "judged": p.judged,
            }
            for p in phases
        ],
        time=np.asarray(cols["time"], dtype=float),
        phase=np.asarray(cols["phase"], dtype=int),
        judged=np.asarray(cols["judged"], dtype=bool),
        true_error_mm=np.asarray(cols["err"], dtype=float),
        actions=np.asarray(cols["act"], dtype=float).reshape(-1, 6),
        measurement=np.asarray(cols["meas"], dtype=float).reshape(-1, 3),
        solve_time_s=np.asarray(cols["solve"], dtype=float),
        diverged=diverged,
        report=report,
        truth_parameters=_truth_parameters(truth0),
        wall_time_s=time.perf_counter() - wall0,
        oracle=oracle,
    )


def _call(name: str, what: str, step: int, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any:
    """Call one of the agent's methods; what it raises becomes :class:`AgentFailure` naming the
    agent, the call and the step (the time limit passes through)."""
    try:
        return fn(*args, **kw)
    except TimeLimitExceeded:
        raise
    except AgentFailure as exc:  # from an agent's own process: say when
        if exc.args and "(step " not in str(exc.args[0]):
            exc.args = (f"{exc.args[0]} (step {step})", *exc.args[1:])
        raise
    except Exception as exc:
        text = str(exc).splitlines()[0] if str(exc) else ""
        raise AgentFailure(
            f"agent {name}: {what} raised {type(exc).__name__}: {text} (step {step})"
        ) from exc


def _checked_action(name: str, step: int, action: Any) -> np.ndarray:
    """The agent's action as 6 finite floats, or :class:`AgentFailure` saying what it was."""
    try:
        a = np.asarray(action, dtype=float)
    except (TypeError, ValueError):
        raise AgentFailure(
            f"agent {name}: act returned {type(action).__name__}, not 6 numbers (step {step})"
        ) from None
    if a.shape != (6,):
        a = a.reshape(-1) if a.size == 6 else a
    if a.shape != (6,):
        raise AgentFailure(
            f"agent {name}: act returned an array of shape {a.shape}, not (6,) (step {step})"
        )
    if not np.all(np.isfinite(a)):
        bad = [int(i) + 1 for i in np.flatnonzero(~np.isfinite(a))]
        raise AgentFailure(
            f"agent {name}: act returned a non-finite action (joint(s) {bad}: {a.tolist()}) "
            f"at step {step}"
        )
    return a


def _same_truth(a: Truth | None, b: Truth | None) -> bool:
    if a is None or b is None:
        return True
    return np.array_equal(np.asarray(a.params), np.asarray(b.params))
