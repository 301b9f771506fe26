"""Experiment configs: a TOML file names the agents (with their settings), the scenarios, the seeds,
the episode and the metrics; :func:`load_config` parses it and refuses anything wrong *before* a
single run starts, naming the file and the key.

    name = "quick"                       # optional (default: the file's stem); runs/<name>/
    description = "a few minutes on 2 cores"
    env_id = "SixAxisTrack-v0"           # optional
    seeds = 20                           # a count: episode seeds drawn when the sweep starts
                                         # (or a list of fixed seeds, [0, 1, 2]; >= 3: see below)
    episode_seconds = 6.0                # one judged phase of this length (unless [[phases]])
    settle_seconds = 2.0                 # the settled metrics count after this much of the episode
    converge_mm = 0.25                   # converge_s: when the true error stays below this (mm)
    metrics = ["rms_mm", "rms_settled_mm", "converge_s", "max_settled_mm", "effort_rms"]
    rank_by = "rms_settled_mm"           # the ranking metric (default: rms_settled_mm if listed)
    time_limit_s = 600                   # a run still going after this is recorded as failed
    memory_limit_mb = 4096               # each run's address space (where the platform has one)
    isolate = "class-path"               # agents in a process of their own: class-path, all, none
    scenarios = ["nominal", "geometric", { name = "stiff", scenario = "compliance", env = {...} }]

    [env]                                # keyword arguments of gym.make for every run
    trajectory = "circle"

    [[agents]]
    name = "mpc"                         # a registered agent, or "package.module:Class"
                                         # (a class path imports its module: that code runs)
    label = "mpc-h20"                    # optional: how it shows in records and the leaderboard
                                         # ("ppo@s3": agent ppo's training seed 3; the
                                         # leaderboard ranks ppo over its seeds)
    settings = { horizon = 20 }          # keyword arguments of the agent
    scenario_settings = { backlash = { effects = "geometric,backlash" } }   # per scenario, on top
    env = { preview_steps = 20 }         # optional env overrides for this agent

    campaign = { kind = "workspace", judge_posture = "reach" }   # or: phases of a named campaign

    [[phases]]                           # optional: e.g. calibrate, then run blind
    name = "calibration"
    seconds = 10.0
    judged = false
    env = { trajectory = "spline" }

Seeds. A count draws that many episode seeds when the sweep starts, from [2**32, 2**63) (never a
training or evaluation seed of the shipped policies), the same for every agent and scenario (the
comparisons are paired); the sweep keeps them in its manifest, so a resumed sweep reuses them, and
each record's spec carries its seed, which ``sixaxis reproduce`` reads. Its runs are named
``agent__scenario__epK`` (the K-th episode). A list gives fixed seeds (``agent__scenario__seedS``):
for tests and development, not for published tables, since anyone can rebuild a public seed's
arm. At most :data:`MAX_SEEDS` seeds and :data:`MAX_RUNS` runs.

Limits. ``time_limit_s`` (default 600 s) bounds each run's wall time: a run still going then is
recorded as failed ("TimeLimitExceeded") and the sweep goes on. ``memory_limit_mb`` (default
4096) caps each run's address space where the platform allows it (Linux, macOS: ``RLIMIT_AS``
of the worker process and of an isolated agent's process); a run that exhausts it fails with a
``MemoryError``. ``isolate`` says which agents run in a process of their own
(:class:`agents.isolation.IsolatedAgent`): ``"class-path"`` (the default: every agent named as
``package.module:Class``), ``"all"`` or ``"none"``.

An agent may also be given as a bare string in ``agents = ["hold", "nominal"]``. The env keyword
arguments of a run are ``[env] | scenario.env | agent.env | {"scenario": ...}``, in that order.

The judged episode is measured whole (``rms_mm``, ``converge_s``) and after a settling time
(``rms_settled_mm``, ``max_settled_mm``). ``settle_seconds`` defaults to 2 s: past the servo's
start-up, and *unlike* any shipped agent's calibration window (``calibrated`` calibrates at 3 s).
A settling time equal to an agent's calibration window would leave out exactly the phase in which
that agent tracks uncalibrated, its worst; the loader warns when a setting ``calibration_seconds``
equals it, and refuses a settling time as long as the judged episode (nothing would be left).
With fewer than 3 seeds the leaderboard shows the minimum and maximum over seeds instead of a
Student-t interval (the loader warns): give at least 3.

A config expands into :class:`RunSpec` s, one per agent x scenario x seed: plain data that says
everything a run needs, so a record that carries it can be rerun anywhere.

It is one module, longer than most, because the config's schema and every check of it belong
together: whoever reads an error message finds the rule beside the key it names.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import json
import logging
import re
import tomllib
import typing
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from arm.constraints import (
    AnyOf,
    Constraint,
    Interval,
    OneOf,
    TypeOf,
    expectation,
    from_annotation,
    type_name,
)
from arm.files import input_problem
from experiments.errors import ConfigError, MissingSeedsError
from experiments.metrics import (
    DEFAULT_CONVERGE_MM,
    DEFAULT_METRICS,
    DEFAULT_SETTLE_SECONDS,
    METRICS,
    MIN_VALUES_FOR_CI,
)

__all__ = [
    "DEFAULT_MEMORY_LIMIT_MB",
    "DEFAULT_TIME_LIMIT_S",
    "ISOLATE",
    "MAX_RUNS",
    "MAX_SEEDS",
    "AgentEntry",
    "ConfigError",
    "ExperimentConfig",
    "PhaseEntry",
    "RunSpec",
    "ScenarioEntry",
    "canonical_json",
    "known_scenarios",
    "load_config",
    "parse_config",
    "short_hash",
    "spec_problems",
    "split_train_seed",
]

log = logging.getLogger(__name__)

#: the env's control period (s): no episode or phase may be shorter
CONTROL_DT = 0.02

DEFAULT_ENV_ID = "SixAxisTrack-v0"
#: each run's wall-time limit (s) unless a config sets ``time_limit_s``
DEFAULT_TIME_LIMIT_S = 600.0
#: each run's address-space limit (MiB) unless a config sets ``memory_limit_mb``
DEFAULT_MEMORY_LIMIT_MB = 4096
#: which agents run in a process of their own (``isolate``)
ISOLATE = ("class-path", "all", "none")
#: the most episode seeds a config may ask for, and the most runs
MAX_SEEDS = 10_000
MAX_RUNS = 200_000
#: drawn episode seeds come from [DRAWN_SEED_LOW, 2**63): above every training (10_000 +
#: 100_000 k) and evaluation (900_000 +) seed of the shipped policies
DRAWN_SEED_LOW = 2**32
DRAWN_SEED_HIGH = 2**63
LABEL_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")
#: an agent's label may end in ``@s<training seed>``: one network of a learned agent trained
#: with several seeds (``ppo@s3``: agent ``ppo``, seed 3), ranked with its other seeds
TRAIN_SEED_MARK = "@s"
AGENT_LABEL_RE = re.compile(r"^(?P<agent>[A-Za-z0-9][A-Za-z0-9_.+-]*)(@s(?P<seed>[0-9]+))?$")


def split_train_seed(label: str) -> tuple[str, int | None]:
    """The agent an agent label ranks as and its training seed: ``"ppo@s3"`` is ``("ppo",
    3)``, ``"ppo"`` is ``("ppo", None)`` (one network, or an agent that is not learned)."""
    m = AGENT_LABEL_RE.match(label)
    if m is None or m["seed"] is None:
        return label, None
    return m["agent"], int(m["seed"])


def canonical_json(obj: Any) -> str:
    """One spelling of a JSON value (sorted keys, no spaces): what hashes are taken of."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True)


def short_hash(obj: Any, n: int = 16) -> str:
    return hashlib.sha256(canonical_json(obj).encode()).hexdigest()[:n]


# -- the parsed config ------------------------------------------------------------------------


@dataclass(frozen=True)
class AgentEntry:
    label: str
    agent: str
    settings: dict[str, Any] = field(default_factory=dict)
    env: dict[str, Any] = field(default_factory=dict)
    scenario_settings: dict[str, dict[str, Any]] = field(default_factory=dict)

    def settings_for(self, scenario_label: str) -> dict[str, Any]:
        """The agent's settings on one scenario: ``settings``, then that scenario's own."""
        return dict(self.settings) | dict(self.scenario_settings.get(scenario_label, {}))


@dataclass(frozen=True)
class ScenarioEntry:
    label: str
    scenario: str
    env: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class PhaseEntry:
    name: str
    seconds: float
    judged: bool = True
    env: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "seconds": self.seconds, "judged": self.judged, "env": self.env}


@dataclass(frozen=True)
class RunSpec:
    """Everything one run needs: agent and settings, env id and keyword arguments, seed, phases,
    metrics. ``run_hash`` is taken over all of it except the config's name, so the same run in two
    configs is the same run."""

    config_name: str
    agent_label: str
    agent: str
    settings: dict[str, Any]
    scenario_label: str
    scenario: str
    env_id: str
    env_kwargs: dict[str, Any]
    seed: int
    episode_seconds: float
    settle_seconds: float
    phases: tuple[dict[str, Any], ...]
    metrics: tuple[str, ...]
    converge_mm: float = DEFAULT_CONVERGE_MM
    #: the episode's index when its seed was drawn at sweep time (None: a fixed seed)
    episode: int | None = None
    time_limit_s: float = DEFAULT_TIME_LIMIT_S
    memory_limit_mb: int | None = DEFAULT_MEMORY_LIMIT_MB
    isolate: bool = False

    @property
    def run_key(self) -> str:
        if self.episode is not None:
            return f"{self.agent_label}__{self.scenario_label}__ep{self.episode}"
        return f"{self.agent_label}__{self.scenario_label}__seed{self.seed}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "config_name": self.config_name,
            "agent_label": self.agent_label,
            "agent": self.agent,
            "settings": dict(self.settings),
            "scenario_label": self.scenario_label,
            "scenario": self.scenario,
            "env_id": self.env_id,
            "env_kwargs": dict(self.env_kwargs),
            "seed": self.seed,
            "episode_seconds": self.episode_seconds,
            "settle_seconds": self.settle_seconds,
            "phases": [dict(p) for p in self.phases],
            "metrics": list(self.metrics),
            "converge_mm": self.converge_mm,
            **({} if self.episode is None else {"episode": self.episode}),
            "time_limit_s": self.time_limit_s,
            "memory_limit_mb": self.memory_limit_mb,
            "isolate": self.isolate,
        }

    #: what changes how a run is run, not what it computes: not in its hash
    RUN_OPTIONS = ("time_limit_s", "memory_limit_mb", "isolate")

    @property
    def run_hash(self) -> str:
        d = self.to_dict()
        d.pop("config_name")
        for k in self.RUN_OPTIONS:
            d.pop(k)
        return short_hash(d)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> RunSpec:
        return cls(
            config_name=str(d["config_name"]),
            agent_label=str(d["agent_label"]),
            agent=str(d["agent"]),
            settings=dict(d["settings"]),
            scenario_label=str(d["scenario_label"]),
            scenario=str(d["scenario"]),
            env_id=str(d["env_id"]),
            env_kwargs=dict(d["env_kwargs"]),
            seed=int(d["seed"]),
            episode_seconds=float(d["episode_seconds"]),
            settle_seconds=float(d["settle_seconds"]),
            phases=tuple(dict(p) for p in d.get("phases", ())),
            metrics=tuple(d["metrics"]),
            converge_mm=float(d.get("converge_mm", DEFAULT_CONVERGE_MM)),
            episode=None if d.get("episode") is None else int(d["episode"]),
            time_limit_s=float(d.get("time_limit_s", DEFAULT_TIME_LIMIT_S)),
            memory_limit_mb=(
                None
                if d.get("memory_limit_mb", DEFAULT_MEMORY_LIMIT_MB) is None
                else int(d.get("memory_limit_mb", DEFAULT_MEMORY_LIMIT_MB))
            ),
            isolate=bool(d.get("isolate", False)),
        )


@dataclass(frozen=True)
class ExperimentConfig:
    """A validated experiment config; :meth:`runs` expands it into agent x scenario x seed."""

    name: str
    description: str
    env_id: str
    seeds: tuple[int, ...]
    episode_seconds: float
    settle_seconds: float
    metrics: tuple[str, ...]
    rank_by: str
    env: dict[str, Any]
    agents: tuple[AgentEntry, ...]
    scenarios: tuple[ScenarioEntry, ...]
    phases: tuple[PhaseEntry, ...] = ()
    path: str | None = None
    converge_mm: float = DEFAULT_CONVERGE_MM
    #: how many episode seeds the sweep draws (0: the fixed ``seeds``)
    draw_seeds: int = 0
    time_limit_s: float = DEFAULT_TIME_LIMIT_S
    memory_limit_mb: int | None = DEFAULT_MEMORY_LIMIT_MB
    isolate: str = "class-path"

    @property
    def n_seeds(self) -> int:
        return self.draw_seeds or len(self.seeds)

    def to_dict(self) -> dict[str, Any]:
        """The normalised config (what its hash is taken of; the file's path is not in it)."""
        return {
            "name": self.name,
            "description": self.description,
            "env_id": self.env_id,
            "seeds": self.draw_seeds if self.draw_seeds else list(self.seeds),
            "time_limit_s": self.time_limit_s,
            "memory_limit_mb": self.memory_limit_mb,
            "isolate": self.isolate,
            "episode_seconds": self.episode_seconds,
            "settle_seconds": self.settle_seconds,
            "converge_mm": self.converge_mm,
            "metrics": list(self.metrics),
            "rank_by": self.rank_by,
            "env": dict(self.env),
            "agents": [
                {"label": a.label, "name": a.agent, "settings": a.settings, "env": a.env}
                | ({"scenario_settings": a.scenario_settings} if a.scenario_settings else {})
                for a in self.agents
            ],
            "scenarios": [
                {"label": s.label, "scenario": s.scenario, "env": s.env} for s in self.scenarios
            ],
            "phases": [p.to_dict() for p in self.phases],
        }

    @property
    def hash(self) -> str:
        return short_hash(self.to_dict())

    def isolated(self, agent: str) -> bool:
        """Whether the agent ``agent`` (a name or class path) runs in a process of its own."""
        return self.isolate == "all" or (self.isolate == "class-path" and ":" in agent)

    def runs(self, episode_seeds: Sequence[int] | None = None) -> list[RunSpec]:
        """Every run, in a fixed order: agents, then scenarios, then seeds. A config that draws
        its seeds needs them (``episode_seeds``, as many as it draws: the sweep's manifest keeps
        them)."""
        if self.draw_seeds:
            if episode_seeds is None or len(episode_seeds) < self.draw_seeds:
                raise MissingSeedsError(
                    f"config {self.name}: its {self.draw_seeds} episode seeds are drawn when the "
                    "sweep starts; pass them (episode_seeds)"
                )
            seeds: list[tuple[int | None, int]] = list(
                enumerate(int(x) for x in episode_seeds[: self.draw_seeds])
            )
        else:
            seeds = [(None, s) for s in self.seeds]
        out = []
        for a in self.agents:
            isolate = self.isolated(a.agent)
            for s in self.scenarios:
                env_kwargs = self.env | s.env | a.env | {"scenario": s.scenario}
                for episode, seed in seeds:
                    out.append(
                        RunSpec(
                            config_name=self.name,
                            agent_label=a.label,
                            agent=a.agent,
                            settings=a.settings_for(s.label),
                            scenario_label=s.label,
                            scenario=s.scenario,
                            env_id=self.env_id,
                            env_kwargs=dict(sorted(env_kwargs.items())),
                            seed=seed,
                            episode_seconds=self.episode_seconds,
                            settle_seconds=self.settle_seconds,
                            phases=tuple(p.to_dict() for p in self.phases),
                            metrics=self.metrics,
                            converge_mm=self.converge_mm,
                            episode=episode,
                            time_limit_s=self.time_limit_s,
                            memory_limit_mb=self.memory_limit_mb,
                            isolate=isolate,
                        )
                    )
        return out

    def spec_for(self, agent_label: str, scenario_label: str, seed: int, episode: int | None):
        """The run of this config for one agent, scenario and seed (``episode``: its index, for a
        config that draws its seeds), or None if the config has no such agent or scenario."""
        n = max(self.n_seeds, (episode or 0) + 1)
        seeds = [seed] * n if self.draw_seeds else None
        if not self.draw_seeds and seed not in self.seeds:
            return None
        for spec in self.runs(seeds):
            if (
                spec.agent_label == agent_label
                and spec.scenario_label == scenario_label
                and spec.seed == seed
                and spec.episode == episode
            ):
                return spec
        return None


# -- parsing and validation -------------------------------------------------------------------

# every top-level key and what it takes, declared (arm.constraints): its kind is checked first
# (a config of the wrong shape is refused before anything else), its range with the rest
_TOP: dict[str, Constraint] = {
    "name": TypeOf(str),
    "description": TypeOf(str),
    "env_id": TypeOf(str),
    # a count (1 to MAX_SEEDS) or an array of distinct seeds >= 0: judged item by item
    "seeds": AnyOf((TypeOf(list), Interval(int))),
    "episode_seconds": Interval(float),  # at least one control step: checked with the phases
    "settle_seconds": Interval(float, 0.0, None),
    "converge_mm": Interval(float, 0.0, None, closed="neither"),
    "metrics": TypeOf(list),
    "rank_by": TypeOf(str),
    "env": TypeOf(dict),
    "agents": TypeOf(list),
    "scenarios": TypeOf(list),
    "phases": TypeOf(list),
    "campaign": TypeOf(dict),
    "time_limit_s": Interval(float, 0.0, 10**7, closed="neither", why="seconds"),
    "memory_limit_mb": Interval(int, 256, None, why="MiB"),
    "isolate": OneOf(ISOLATE),
}
_REQUIRED = ("seeds", "agents", "scenarios")
_AGENT_KEYS = {"name", "label", "settings", "env", "scenario_settings"}
_SCENARIO_KEYS = {"name", "scenario", "env"}
_PHASE_KEYS = {"name", "seconds", "judged", "env"}


def _is(v: Any, types_: type | tuple[type, ...]) -> bool:
    """isinstance, except that a bool is not an int (TOML keeps them apart, so do we)."""
    types_ = types_ if isinstance(types_, tuple) else (types_,)
    if isinstance(v, bool):
        return bool in types_
    return isinstance(v, types_)


def load_config(path: str | Path, check_agents: bool = True) -> ExperimentConfig:
    """Read and validate an experiment config file; :class:`ConfigError` names every problem."""
    p = Path(path)
    why = input_problem(p, "config")  # a FIFO would wait for ever, /dev/zero never end
    if why and "not found" not in why:
        raise ConfigError(str(p), [why])
    try:
        raw = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(str(p), ["no such file"]) from None
    except OSError as exc:
        raise ConfigError(str(p), [f"cannot read: {exc}"]) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(p), [f"not valid TOML: {exc}"]) from None
    except UnicodeDecodeError as exc:
        raise ConfigError(str(p), [f"not UTF-8 text: {exc}"]) from None
    return parse_config(raw, source=str(p), default_name=p.stem, check_agents=check_agents)


def parse_config(
    raw: Mapping[str, Any],
    source: str = "<config>",
    default_name: str = "experiment",
    check_agents: bool = True,
) -> ExperimentConfig:
    """Validate a config given as a mapping (what TOML parses to). ``check_agents=False`` skips
    making each agent once (which catches bad setting values, at the cost of importing them).

    The steps: the keys and their kinds (a config of the wrong shape is refused before anything
    else), each key's declared range, the seeds, the metrics, the env options, the scenarios,
    agents and phases, then what they must agree on; every problem is named at once."""
    problems: list[str] = []
    bad = problems.append
    _check_keys(raw, bad)
    if problems:
        raise ConfigError(source, problems)

    name = raw.get("name", default_name)
    if not LABEL_RE.match(name):
        bad(f"name: {name!r} must be letters, digits and _ . + - (it names the runs directory)")
    env_id = raw.get("env_id", DEFAULT_ENV_ID)
    seeds, draw = _parse_seeds(raw["seeds"], bad)
    n_seeds = draw or len(seeds)
    if 0 < n_seeds < MIN_VALUES_FOR_CI:
        log.warning(
            "%s: seeds: %d seed(s); the leaderboard shows min-max, not a confidence interval, "
            "with fewer than %d",
            source,
            n_seeds,
            MIN_VALUES_FOR_CI,
        )
    out_of_range = _check_ranges(raw, bad)
    time_limit_s = raw.get("time_limit_s", DEFAULT_TIME_LIMIT_S)
    memory_limit_mb = raw.get("memory_limit_mb", DEFAULT_MEMORY_LIMIT_MB)
    isolate = raw.get("isolate", "class-path")
    episode_seconds = float(raw.get("episode_seconds", 10.0))
    if "episode_seconds" not in out_of_range and not episode_seconds >= CONTROL_DT - 1e-12:
        bad(
            f"episode_seconds: {episode_seconds:g} s is shorter than one control step "
            f"({CONTROL_DT:g} s)"
        )
    settle_seconds = float(raw.get("settle_seconds", DEFAULT_SETTLE_SECONDS))
    converge_mm = float(raw.get("converge_mm", DEFAULT_CONVERGE_MM))
    metrics, rank_by = _parse_metrics(raw, bad)

    env_info = _env_signature(env_id, bad)
    env = dict(raw.get("env", {}))
    if "scenario" in env:
        bad("env.scenario: scenarios are chosen by the top-level 'scenarios' list")
    _check_env_kwargs(env, "env", env_info, bad)
    scenarios = _parse_scenarios(raw["scenarios"], known_scenarios(env_id), env_info, bad)
    scenario_labels = {s.label for s in scenarios}
    agents = [
        ae
        for _, where, a in _entries(raw["agents"], "agents", _AGENT_KEYS, bad, "an agent")
        if (ae := _agent_entry(a, where, env_info, scenario_labels, check_agents, bad)) is not None
    ]
    _no_repeats([a.label for a in agents], "agents", "label", "give one a 'label'", bad)
    if not raw["agents"]:
        bad("agents: empty")
    phases = _parse_phases(raw, env_info, bad)
    if phases:
        episode_seconds = float(sum(p.seconds for p in phases if p.judged))
    _check_settling(source, settle_seconds, episode_seconds, agents, bad)
    _check_lengths(env, scenarios, agents, phases, episode_seconds, raw, env_info, bad)
    _check_env_options(env_id, env, scenarios, agents, phases, raw, problems)

    n_runs = len(agents) * len(scenarios) * n_seeds
    if n_runs > MAX_RUNS:
        bad(
            f"seeds: {len(agents)} agents x {len(scenarios)} scenarios x {n_seeds} seeds = "
            f"{n_runs} runs; at most {MAX_RUNS}"
        )
    if problems:
        raise ConfigError(source, problems)
    return ExperimentConfig(
        name=name,
        description=raw.get("description", ""),
        env_id=env_id,
        seeds=tuple(seeds),
        episode_seconds=episode_seconds,
        settle_seconds=settle_seconds,
        converge_mm=converge_mm,
        metrics=tuple(metrics),
        rank_by=rank_by,
        env=dict(sorted(env.items())),
        agents=tuple(agents),
        scenarios=tuple(scenarios),
        phases=tuple(phases),
        path=source,
        draw_seeds=draw,
        time_limit_s=float(time_limit_s),
        memory_limit_mb=int(memory_limit_mb),
        isolate=str(isolate),
    )


def _check_keys(raw: Mapping[str, Any], bad: Callable[[str], None]) -> None:
    """Every top-level key known, of its declared kind; the required ones there."""
    for key in raw:
        if key not in _TOP:
            bad(f"{key}: unknown key; known: {', '.join(_TOP)}")
    for key, constraint in _TOP.items():
        if key in raw and not constraint.kind_holds(raw[key]):
            bad(f"{key}: {expectation(constraint, raw[key])}")
    for key in _REQUIRED:
        if key not in raw:
            bad(f"{key}: missing (required)")


def _check_ranges(raw: Mapping[str, Any], bad: Callable[[str], None]) -> set[str]:
    """Every top-level value given against its declared constraint (its kind is known to hold);
    the keys out of range."""
    out = set()
    for key, constraint in _TOP.items():
        if key in raw and (why := expectation(constraint, raw[key])) is not None:
            bad(f"{key}: {why}")
            out.add(key)
    return out


def _parse_seeds(seeds_raw: Any, bad: Callable[[str], None]) -> tuple[list[int], int]:
    """The fixed seeds, or how many seeds to draw (a count)."""
    seeds: list[int] = []
    draw = 0
    if _is(seeds_raw, int):
        if seeds_raw < 1:
            bad(f"seeds: a count must be at least 1, got {seeds_raw}")
        elif seeds_raw > MAX_SEEDS:
            bad(f"seeds: {seeds_raw} episodes per agent and scenario; at most {MAX_SEEDS}")
        else:
            draw = seeds_raw
    elif len(seeds_raw) > MAX_SEEDS:
        bad(f"seeds: {len(seeds_raw)} seeds; at most {MAX_SEEDS}")
    else:
        for i, s in enumerate(seeds_raw):
            if not _is(s, int) or s < 0:
                bad(f"seeds[{i}]: expected a non-negative integer, got {type_name(s)} {s!r}")
            else:
                seeds.append(s)
        if not seeds_raw:
            bad("seeds: empty")
        if len(set(seeds)) != len(seeds):
            bad(f"seeds: repeated seeds in {seeds_raw}")
    return seeds, draw


def _parse_metrics(raw: Mapping[str, Any], bad: Callable[[str], None]) -> tuple[list[Any], Any]:
    """The metrics (a metric's companion, e.g. never_converged of converge_s, comes with it) and
    the one that ranks."""
    metrics = list(raw.get("metrics", list(DEFAULT_METRICS)))
    for i, m in enumerate(metrics):
        if not isinstance(m, str):
            bad(f"metrics[{i}]: expected a string, got {type_name(m)} {m!r}")
        elif m not in METRICS:
            bad(f"metrics[{i}]: unknown metric {m!r}; known: {', '.join(METRICS)}")
    if len(set(map(str, metrics))) != len(metrics):
        bad(f"metrics: repeated names in {metrics}")
    for m in list(metrics):
        companion = METRICS[m].companion if isinstance(m, str) and m in METRICS else None
        if companion is not None and companion not in metrics:
            metrics.insert(metrics.index(m) + 1, companion)
    rank_by = raw.get("rank_by", "rms_settled_mm" if "rms_settled_mm" in metrics else "rms_mm")
    if rank_by not in metrics:
        bad(f"rank_by: {rank_by!r} is not one of the metrics {metrics}")
    return metrics, rank_by


def _parse_scenarios(
    items: Sequence[Any], known: Any, env_info: Any, bad: Callable[[str], None]
) -> list[ScenarioEntry]:
    """The scenarios list: each entry, no label twice, not empty."""
    scenarios = [
        e
        for _, where, s in _entries(items, "scenarios", _SCENARIO_KEYS, bad, "a scenario")
        if (e := _scenario_entry(s, where, known, env_info, bad)) is not None
    ]
    _no_repeats([s.label for s in scenarios], "scenarios", "name", "give one a different name", bad)
    if not items:
        bad("scenarios: empty")
    return scenarios


def _parse_phases(
    raw: Mapping[str, Any], env_info: Any, bad: Callable[[str], None]
) -> list[PhaseEntry]:
    """The episode's phases: the [[phases]] tables, or those a [campaign] makes; at least one
    judged, each at least one control step."""
    phases = [
        _phase_entry(ph, f"phase{i}", where, env_info, bad)
        for i, where, ph in _entries(raw.get("phases", []), "phases", _PHASE_KEYS, bad)
    ]
    if "campaign" in raw and _is(raw["campaign"], dict):
        if raw.get("phases"):
            bad("campaign: give either campaign or [[phases]], not both")
        else:
            phases = _campaign_phases(raw["campaign"], bad)
            for i, ph in enumerate(phases):
                _check_env_kwargs(ph.env, f"campaign (phase {i}: {ph.name}).env", env_info, bad)
    if phases and not any(p.judged for p in phases):
        bad("phases: no phase is judged; mark at least one 'judged = true'")
    if phases and "episode_seconds" in raw:
        bad("episode_seconds: give either episode_seconds or [[phases]], not both")
    for i, ph in enumerate(phases):
        if not ph.seconds >= CONTROL_DT - 1e-12:
            bad(
                f"phases[{i}].seconds: {ph.seconds:g} s is shorter than one control step "
                f"({CONTROL_DT:g} s)"
            )
    return phases


def _check_settling(
    source: str,
    settle_seconds: float,
    episode_seconds: float,
    agents: Sequence[AgentEntry],
    bad: Callable[[str], None],
) -> None:
    """The settling time leaves steps for the settled metrics; an agent that calibrates at it
    is warned of."""
    if episode_seconds > 0 and settle_seconds >= episode_seconds:
        bad(
            f"settle_seconds: {settle_seconds:g} s is not shorter than the judged episode "
            f"({episode_seconds:g} s): no step would be left for the settled metrics"
        )
    for a in agents:
        if a.settings.get("calibration_seconds") == settle_seconds:
            log.warning(
                "%s: agent %s calibrates at %g s, the settling time: its uncalibrated phase, its "
                "worst, is left out of every settled metric; rms_mm and converge_s still count it",
                source,
                a.label,
                settle_seconds,
            )


# -- the entries of the scenarios, agents and phases lists ------------------------------------
def _entries(
    items: Sequence[Any], section: str, keys: Iterable[str], bad, shorthand: str | None = None
) -> Iterator[tuple[int, str, dict[str, Any]]]:
    """Each table of a config list with its index and where it is (``agents[2]``); a bare string
    stands for ``{name = "..."}`` where ``shorthand`` says what it names. Entries that are not
    tables, and unknown keys, are reported to ``bad``; the former are skipped."""
    known = sorted(keys)
    for i, item in enumerate(items):
        where = f"{section}[{i}]"
        if shorthand is not None and isinstance(item, str):
            item = {"name": item}
        if not _is(item, dict):
            if shorthand is None:
                bad(f"{where}: expected a table, got {type_name(item)}")
            else:
                bad(
                    f"{where}: expected {shorthand} name or a table, got {type_name(item)} {item!r}"
                )
            continue
        for k in item:
            if k not in known:
                bad(f"{where}.{k}: unknown key; known: {', '.join(known)}")
        yield i, where, item


def _entry_env(
    entry: Mapping[str, Any], where: str, env_info, bad, scenario: str | None = None
) -> dict[str, Any]:
    """The entry's ``env`` table, checked against the env's keyword arguments; ``scenario``: why
    it may not set the scenario (None: it may)."""
    env = entry.get("env", {})
    if not _is(env, dict):
        bad(f"{where}.env: expected a table, got {type_name(env)}")
        env = {}
    if scenario is not None and "scenario" in env:
        bad(f"{where}.env.scenario: {scenario}")
    _check_env_kwargs(env, f"{where}.env", env_info, bad)
    return dict(env)


def _no_repeats(labels: Sequence[str], section: str, noun: str, remedy: str, bad) -> None:
    for dup in sorted({x for x in labels if labels.count(x) > 1}):
        bad(f"{section}: the {noun} {dup!r} appears twice ({remedy})")


def _scenario_entry(
    s: Mapping[str, Any], where: str, known: tuple[str, ...] | None, env_info, bad
) -> ScenarioEntry | None:
    label = s.get("name")
    scen = s.get("scenario", label)
    if not isinstance(label, str):
        bad(f"{where}.name: expected a string, got {type_name(label)} {label!r}")
        return None
    if not isinstance(scen, str):
        bad(f"{where}.scenario: expected a string, got {type_name(scen)} {scen!r}")
        return None
    if not LABEL_RE.match(label):
        bad(f"{where}.name: {label!r} must be letters, digits and _ . + -")
    if known is not None and scen not in known:
        key = "scenario" if "scenario" in s else "name"
        bad(f"{where}.{key}: unknown scenario {scen!r}; known: {', '.join(known)}")
    env = _entry_env(s, where, env_info, bad, f"give the scenario as {where}.scenario")
    return ScenarioEntry(label, scen, env)


def _agent_entry(
    a: Mapping[str, Any],
    where: str,
    env_info,
    scenario_labels: set[str],
    construct: bool,
    bad,
) -> AgentEntry | None:
    agent = a.get("name")
    if not isinstance(agent, str):
        bad(
            f"{where}.name: expected a string (an agent name or 'package.module:Class'), got {type_name(agent)} {agent!r}"
        )
        return None
    label = a.get("label", agent.rpartition(":")[2] if ":" in agent else agent)
    if not isinstance(label, str) or not AGENT_LABEL_RE.match(label):
        bad(
            f"{where}.label: {label!r} must be letters, digits and _ . + -, optionally ending "
            "in @s<training seed> (ppo@s3)"
        )
        return None
    settings = a.get("settings", {})
    if not _is(settings, dict):
        bad(f"{where}.settings: expected a table, got {type_name(settings)}")
        settings = {}
    env = _entry_env(a, where, env_info, bad)
    per = a.get("scenario_settings", {})
    if not _is(per, dict) or not all(_is(v, dict) for v in per.values()):
        bad(f"{where}.scenario_settings: expected a table of tables (scenario -> settings)")
        per = {}
    for sc in per:
        if sc not in scenario_labels:
            bad(
                f"{where}.scenario_settings.{sc}: not a scenario of this config "
                f"({', '.join(sorted(scenario_labels))})"
            )
    ok = _check_agent(agent, settings, where, bad, construct=construct)
    for sc, extra in per.items():
        ok = (
            _check_agent(
                agent,
                dict(settings) | dict(extra),
                f"{where}.scenario_settings.{sc}",
                bad,
                construct=construct,
            )
            and ok
        )
    if not ok:
        return None
    return AgentEntry(label, agent, dict(settings), env, {k: dict(v) for k, v in per.items()})


def _phase_entry(ph: Mapping[str, Any], default_name: str, where: str, env_info, bad) -> PhaseEntry:
    pname = ph.get("name", default_name)
    secs = ph.get("seconds")
    judged = ph.get("judged", True)
    if not isinstance(pname, str):
        bad(f"{where}.name: expected a string, got {type_name(pname)}")
    if isinstance(secs, bool) or not isinstance(secs, int | float) or secs <= 0:
        bad(f"{where}.seconds: expected a positive number, got {type_name(secs)} {secs!r}")
        secs = 1.0
    if not _is(judged, bool):
        bad(f"{where}.judged: expected a boolean, got {type_name(judged)} {judged!r}")
    env = _entry_env(ph, where, env_info, bad, "a phase keeps the episode's scenario")
    return PhaseEntry(str(pname), float(secs), bool(judged), env)


# -- checks against the env and the agents ----------------------------------------------------


def _env_class(env_id: str):
    import gymnasium as gym

    import envs  # noqa: F401  (registers SixAxisTrack-v0)

    spec = gym.spec(env_id)
    ep = spec.entry_point
    if not callable(ep):
        module, _, attr = str(ep).partition(":")
        ep = getattr(importlib.import_module(module), attr)
    # a factory (SixAxisTrack-v0's wraps the env in a TimeLimit of its own length) names its class
    return getattr(ep, "env_class", ep)


def known_scenarios(env_id: str = DEFAULT_ENV_ID) -> tuple[str, ...] | None:
    """The env's scenario names: ``SCENARIOS`` of the env class, of its module, or (for
    SixAxisTrack-v0) of :mod:`envs.scenarios`; None when the env names none (not checked then)."""
    try:
        cls = _env_class(env_id)
    except Exception as exc:
        log.warning("cannot import the env class of %s to check scenarios: %s", env_id, exc)
        cls = None
    found = None
    if cls is not None:
        found = getattr(cls, "SCENARIOS", None)
        if found is None:
            found = getattr(importlib.import_module(cls.__module__), "SCENARIOS", None)
    if found is None and env_id == DEFAULT_ENV_ID:
        from envs.scenarios import SCENARIOS

        found = SCENARIOS
    return None if found is None else tuple(found)


def _env_signature(env_id: str, bad) -> dict[str, tuple[inspect.Parameter, Any]] | None:
    """The env constructor's keyword parameters (None: cannot tell, so env keys are not checked)."""
    try:
        import gymnasium as gym

        import envs  # noqa: F401

        gym.spec(env_id)
    except Exception as exc:
        bad(f"env_id: unknown environment {env_id!r} ({exc})")
        return None
    try:
        cls = _env_class(env_id)
    except Exception as exc:
        log.warning("cannot import the env class of %s to check env keys: %s", env_id, exc)
        return None
    params = dict(inspect.signature(cls.__init__).parameters)
    params.pop("self", None)
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return None
    try:
        hints = typing.get_type_hints(cls.__init__)
    except Exception:
        hints = {}
    return {k: (v, hints.get(k)) for k, v in params.items()}


_CAMPAIGN_KEYS = {"kind", "judge_posture", "judge_trajectory", "seconds", "judge_seconds"}


def _campaign_phases(raw: dict[str, Any], bad) -> list[PhaseEntry]:
    """``campaign = { kind = "workspace", judge_posture = "reach" }``: the phases of
    :func:`agents.runner.workspace_campaign` (calibration over the workspace, then blind tracking
    in a region it did not visit), which TOML cannot spell by hand (free joints are None)."""
    for k in raw:
        if k not in _CAMPAIGN_KEYS:
            bad(f"campaign.{k}: unknown key; known: {', '.join(sorted(_CAMPAIGN_KEYS))}")
    kind = raw.get("kind", "workspace")
    if kind != "workspace":
        bad(f"campaign.kind: unknown campaign {kind!r}; known: workspace")
        return []
    from agents.runner import workspace_campaign

    kwargs = {k: v for k, v in raw.items() if k in _CAMPAIGN_KEYS and k != "kind"}
    try:
        phases = workspace_campaign(**kwargs)
    except (TypeError, ValueError) as exc:
        bad(f"campaign: {exc}")
        return []
    return [
        PhaseEntry(p.name, float(p.seconds or 0.0), bool(p.judged), dict(p.overrides))
        for p in phases
    ]


def _check_lengths(env, scenarios, agents, phases, episode_seconds, raw, env_info, bad) -> None:
    """An episode (or phase) may not outlast the env's reference trajectory (its own
    ``episode_seconds`` option, when it has one)."""
    if env_info is None or "episode_seconds" not in env_info:
        return
    default = env_info["episode_seconds"][0].default
    runs = phases or [PhaseEntry("episode", episode_seconds, True, {})]
    seen = set()
    for s in scenarios:
        for a in agents:
            base = env | s.env | a.env
            for i, ph in enumerate(runs):
                limit = (base | ph.env).get("episode_seconds", default)
                if not _is(limit, (int, float)) or ph.seconds <= limit + 1e-9:
                    continue
                key = f"phases[{i}].seconds" if phases else "episode_seconds"
                if key in seen:
                    continue
                seen.add(key)
                bad(
                    f"{key}: {ph.seconds:g} s is longer than the env's reference trajectory "
                    f"({limit:g} s); set env.episode_seconds = {ph.seconds:g}"
                )


def _check_env_options(env_id, env, scenarios, agents, phases, raw, problems) -> None:
    """Every run's env options as the env itself judges them (its ``check_options``: a noise
    below zero, an unknown trajectory, a sampling period of 0, overrides the scenario does not
    have), so that a config the env would refuse fails here and not in every run. A problem is
    named by the key where the config sets the value, once."""
    try:
        check = getattr(_env_class(env_id), "check_options", None)
    except Exception:  # an env that cannot be imported: reported by the checks above
        return
    if check is None:
        return
    s_where = {}
    for i, s in enumerate(raw.get("scenarios") or []):
        s_where[s if isinstance(s, str) else s.get("name") if _is(s, dict) else None] = (
            f"scenarios[{i}]"
        )
    a_where = {}
    for i, a in enumerate(raw.get("agents") or []):
        a = {"name": a} if isinstance(a, str) else a
        if _is(a, dict) and _is(a.get("name"), str):
            a_where[a.get("label", a["name"].rpartition(":")[2])] = f"agents[{i}]"
    if raw.get("phases"):
        p_where = [f"phases[{i}]" for i in range(len(phases))]
    else:
        p_where = [f"campaign (phase {i}: {ph.name})" for i, ph in enumerate(phases)]
    runs: list[tuple[PhaseEntry | None, str | None]] = [*zip(phases, p_where, strict=True)]
    runs = runs or [(None, None)]
    seen, checked = set(), set()
    for s in scenarios:
        for a in agents:
            for ph, ph_where in runs:
                layers = [
                    (ph.env if ph else {}, f"{ph_where}.env"),
                    (a.env, f"{a_where.get(a.label, 'agents')}.env"),
                    (s.env, f"{s_where.get(s.label, 'scenarios')}.env"),
                    (env, "env"),
                ]
                kwargs = env | s.env | a.env | (ph.env if ph else {}) | {"scenario": s.scenario}
                key = canonical_json({k: repr(v) for k, v in kwargs.items()})
                if key in checked:
                    continue
                checked.add(key)
                for k, why in check(**kwargs).items():
                    if k == "scenario":  # the scenario names are checked on their own
                        continue
                    where = next((w for layer, w in layers if k in layer), None)
                    if where is None:  # a default the other options do not fit
                        where = f"env.{k} (scenario {s.label}, agent {a.label})"
                    else:
                        where = f"{where}.{k}"
                    if where in seen or any(p.startswith(f"{where}:") for p in problems):
                        continue
                    seen.add(where)
                    problems.append(f"{where}: {why}")


def spec_problems(spec: RunSpec) -> list[str]:
    """What would make a run spec (a record's, to rerun it) fail before its episode starts: the
    agent and its settings, the env's options in every phase, as a config is checked at load."""
    problems: list[str] = []
    info = _env_signature(spec.env_id, problems.append)
    _check_agent(
        spec.agent,
        dict(spec.settings),
        "spec",
        lambda m: problems.append(m.replace("spec.name:", "spec.agent:", 1)),
        construct=False,
    )
    phases = spec.phases or ({"env": {}},)
    for i, ph in enumerate(phases):
        where = f"spec.phases[{i}].env" if spec.phases else "spec.env_kwargs"
        kwargs = dict(spec.env_kwargs) | dict(ph.get("env") or {})
        _check_env_kwargs(
            {k: v for k, v in kwargs.items() if k != "scenario"}, where, info, problems.append
        )
        if problems:
            break
        try:
            check = getattr(_env_class(spec.env_id), "check_options", None)
        except Exception:
            check = None
        if check is not None:
            problems += [f"{where}.{k}: {why}" for k, why in check(**kwargs).items()]
    return problems


def _check_env_kwargs(env: Mapping[str, Any], where: str, info, bad) -> None:
    if info is None:
        return
    for k, v in env.items():
        if k == "render_mode":
            bad(f"{where}.{k}: sweeps do not render")
            continue
        if k not in info:
            known = ", ".join(n for n in info if n not in ("render_mode",))
            bad(f"{where}.{k}: unknown env option; the env takes: {known}")
            continue
        param, hint = info[k]
        msg = _type_problem(v, hint, param.default)
        if msg:
            bad(f"{where}.{k}: {msg}")


#: checks a class-path agent in a process of its own: the problems as a JSON list on stdout
_CHECK_DRIVER = r"""
import json, sys
from experiments.config import check_agent_in_process
args = json.loads(sys.stdin.read())
problems = []
ok = check_agent_in_process(args["agent"], args["settings"], args["where"], problems.append,
                       args["construct"])
print(json.dumps({"ok": ok, "problems": problems}))
"""


def _check_agent(agent: str, settings: dict, where: str, bad, construct: bool) -> bool:
    """Whether an agent and its settings can run, reporting what is wrong to ``bad``. A class
    path is imported (and made) in a process of its own: its module's code never runs in the
    sweep's process, where the runs' envs and truths will be."""
    if ":" not in agent:
        return check_agent_in_process(agent, settings, where, bad, construct)
    import os
    import subprocess
    import sys

    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) if p else os.getcwd() for p in sys.path)
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _CHECK_DRIVER],
            input=json.dumps(
                {"agent": agent, "settings": settings, "where": where, "construct": construct}
            ),
            capture_output=True,
            text=True,
            timeout=300,
            env=env,
            check=False,
        )
        answer = json.loads(proc.stdout.strip().splitlines()[-1])
    except (OSError, subprocess.SubprocessError, ValueError, IndexError) as exc:
        tail = ""
        if isinstance(exc, (ValueError, IndexError)):
            lines = (proc.stderr or "").strip().splitlines()
            tail = f": {lines[-1]}" if lines else f" (exit {proc.returncode})"
        bad(f"{where}.name: agent {agent!r} cannot be checked in a process of its own{tail}")
        return False
    for msg in answer["problems"]:
        bad(str(msg))
    return bool(answer["ok"])


def check_agent_in_process(agent: str, settings: dict, where: str, bad, construct: bool) -> bool:
    from agents.registry import AgentError, check_settings, make_agent, resolve_agent

    try:
        _, cls = resolve_agent(agent)
    except AgentError as exc:
        bad(f"{where}.name: {exc}")
        return False
    except Exception as exc:  # the agent's module itself fails to import
        bad(f"{where}.name: agent {agent!r} cannot be loaded: {type(exc).__name__}: {exc}")
        return False
    try:
        check_settings(agent, settings)
    except AgentError as exc:
        bad(f"{where}.settings: {exc}")
        return False
    params = inspect.signature(cls.__init__).parameters
    try:
        hints = typing.get_type_hints(cls.__init__)
    except Exception:
        hints = {}
    ok = True
    for k, v in settings.items():
        p = params.get(k)
        if p is None:  # taken by **kwargs
            continue
        msg = _type_problem(v, hints.get(k), p.default)
        if msg:
            bad(f"{where}.settings.{k}: {msg}")
            ok = False
    if ok and construct:
        try:
            make_agent(agent, **settings)
        except Exception as exc:
            bad(
                f"{where}.settings: agent {agent!r} refuses {settings}: {type(exc).__name__}: {exc}"
            )
            ok = False
    return ok


def _type_problem(value: Any, hint: Any, default: Any) -> str | None:
    """Why ``value`` does not fit a parameter annotated ``hint`` (default ``default``), by the
    constraints the annotation declares (:func:`arm.constraints.from_annotation`), or None. An
    annotation that says nothing checkable (a class, ``Any``) lets the value through: the agent or
    env judges it."""
    if hint is None:
        if default is inspect.Parameter.empty or default is None:
            return None
        hint = type(default)
    constraints, none_ok = from_annotation(hint)
    if not constraints or (value is None and none_ok):
        return None
    return expectation(constraints[0], value)
