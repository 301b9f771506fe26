"""Agents by name: ``make_agent("mpc", horizon=15)``, or a user's class by import path
``make_agent("my_package.controllers:MyAgent", gain=2.0)``.

Every agent is one row of :data:`AGENTS`, an :class:`AgentSpec` (Gymnasium's ``EnvSpec`` is the
model): its name, the class that makes it, the settings it is made with, what it is.
``sixaxis agents`` lists them.

Every ``agents/policies/<name>.npz`` is registered as ``<name>``: a learned policy loads from that
file (weights as arrays, no unpickling). ``policy`` runs a policy file of your own, given as the
setting ``path`` (``agents.from_sb3`` writes one from a stable-baselines3 model).

A class path (``package.module:Class``) imports that module: it runs the module's code, so name
only classes you trust.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import inspect
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib.machinery import PathFinder
from pathlib import Path
from typing import Any

from agents.base import Agent
from agents.errors import AgentError
from arm.constraints import check, constraints_of

__all__ = [
    "AGENTS",
    "CROSS_CPU_RTOL",
    "POLICIES",
    "AgentError",
    "AgentSpec",
    "agent_module_source",
    "agent_names",
    "check_settings",
    "cross_cpu_rtol",
    "make_agent",
    "resolve_agent",
]


#: the relative tolerance within which an agent's leaderboard rows reproduce on another CPU,
#: unless its spec declares a larger one (README: ``sixaxis reproduce --rtol 1e-6``)
CROSS_CPU_RTOL = 1e-6
#: the QP MPCs' (results/perturbation.md): a few units in the last place of every observation
#: still grow past 1e-8 in two to five episodes of eight (up to 2.2e-5; the median episode 1e-9
#: to 7e-8), and a relative 1e-12 to 9e-5. The same MPC by IPOPT stays below 1e-9 and keeps 1e-6.
MPC_CROSS_CPU_RTOL = 1e-3


@dataclass(frozen=True)
class AgentSpec:
    """One registered agent, as Gymnasium's ``EnvSpec`` registers an environment: its ``name``,
    the class that makes it (``entry_point``, ``"package.module:Class"``, imported only when the
    agent is made), the ``kwargs`` it is made with before the user's settings, and one line of
    what it is; ``cross_cpu_rtol``, the relative tolerance its rows keep on another CPU (the
    largest a rounding difference grows to in its closed loop, measured by
    ``benchmarks/perturbation.py``: ``results/perturbation.md``)."""

    name: str
    entry_point: str
    summary: str
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    cross_cpu_rtol: float = CROSS_CPU_RTOL

    def load(self) -> type[Agent]:
        """The agent's class."""
        module, _, attr = self.entry_point.partition(":")
        return getattr(importlib.import_module(module), attr)

    def make(self, **settings: Any) -> Agent:
        return self.load()(**(dict(self.kwargs) | settings))


#: the learned policies shipped in agents/policies/ (<name>.npz), each registered by its name
POLICIES = tuple(
    sorted(p.stem for p in (Path(__file__).resolve().parent / "policies").glob("*.npz"))
)

#: every agent by name: the one table (``sixaxis agents`` lists it)
AGENTS: dict[str, AgentSpec] = {
    s.name: s
    for s in (
        AgentSpec("hold", "agents.reference:HoldAgent", "zero velocity: the floor"),
        AgentSpec(
            "nominal",
            "agents.reference:NominalAgent",
            "resolved-rate tracking on the nominal model, no measurements",
        ),
        AgentSpec(
            "feedforward",
            "agents.reference:FeedforwardAgent",
            "nominal tracking of the reference minus the last measured model error",
        ),
        AgentSpec(
            "calibrated",
            "agents.reference:CalibratedAgent",
            "calibrate from a measurement phase (least squares), then track blind",
        ),
        AgentSpec(
            "mpc",
            "agents.mpc:MPCAgent",
            "kinematic MPC (QP, daqp) with online recursive least-squares calibration",
            cross_cpu_rtol=MPC_CROSS_CPU_RTOL,
        ),
        AgentSpec(
            "mpc-ipopt",
            "agents.mpc:MPCAgent",
            "the same MPC as a nonlinear program solved by IPOPT",
            {"solver": "ipopt"},
        ),
        AgentSpec(
            "mpc-oracle",
            "agents.mpc:MPCAgent",
            "the MPC given the plant's true model (needs the env's truth)",
            {"oracle": True},
            cross_cpu_rtol=MPC_CROSS_CPU_RTOL,
        ),
        AgentSpec(
            "mpc-diagnose",
            "agents.self_diagnosis:DiagnosingMPCAgent",
            "the MPC that diagnoses its own model with the lab and widens it",
            cross_cpu_rtol=MPC_CROSS_CPU_RTOL,
        ),
        AgentSpec(
            "policy",
            "agents.policy:PolicyAgent",
            "a policy file of your own (settings: path, e.g. runs/ppo-seed1/best.npz; "
            "agents.from_sb3 writes one from any SB3 model)",
        ),
        *(
            AgentSpec(
                p,
                "agents.policy:PolicyAgent",
                f"the shipped learned policy agents/policies/{p}.npz",
                {"policy": p},
            )
            for p in POLICIES
        ),
    )
}


def agent_names() -> list[str]:
    return list(AGENTS)


def cross_cpu_rtol(name: str) -> float:
    """The relative tolerance within which the rows of agent ``name`` reproduce on another CPU:
    its spec's (:attr:`AgentSpec.cross_cpu_rtol`), or :data:`CROSS_CPU_RTOL` for a user's class,
    whose sensitivity nobody measured."""
    spec = AGENTS.get(name)
    return spec.cross_cpu_rtol if spec is not None else CROSS_CPU_RTOL


def resolve_agent(name: str) -> tuple[Callable[..., Agent], Callable[..., Any]]:
    """The factory of ``name`` and the callable whose signature its settings must fit."""
    if name in AGENTS:
        spec = AGENTS[name]
        return spec.make, spec.load()
    if ":" in name:
        module, _, attr = name.partition(":")
        try:
            mod = importlib.import_module(module)
        except ImportError as exc:
            raise AgentError(
                f"agent {name!r}: cannot import module {module!r}: {exc} (searched: the working "
                f"folder {os.getcwd()}, PYTHONPATH and the installed packages; run sixaxis from "
                "the folder that holds the package, or install it)"
            ) from exc
        found = getattr(mod, attr, None)
        if found is None:
            raise AgentError(f"agent {name!r}: module {module!r} has no {attr!r}")
        if not (isinstance(found, type) and issubclass(found, Agent)):
            raise AgentError(f"agent {name!r}: {attr} is not a subclass of agents.base.Agent")
        return found, found
    raise AgentError(
        f"unknown agent {name!r}; known: {', '.join(AGENTS)}, or a class as 'package.module:Class'"
    )


def agent_module_source(name: str) -> dict[str, Any] | None:
    """Where a class-path agent's module is and what it holds: ``{"module", "file", "root",
    "sha256"}`` (``file`` absolute; ``root`` the folder on ``sys.path`` it is imported from;
    ``sha256`` of the file's bytes), found as ``import`` would find it but without running it.
    None for a registered agent (the commit holds its code) or a module with no file."""
    if name in AGENTS or ":" not in name:
        return None
    module = name.partition(":")[0]
    parts = module.split(".")
    spec = None
    search: list[str] | None = None
    for i in range(len(parts)):
        dotted = ".".join(parts[: i + 1])
        loaded = sys.modules.get(dotted)
        spec = getattr(loaded, "__spec__", None) or PathFinder.find_spec(dotted, search)
        if spec is None:
            return None
        search = list(spec.submodule_search_locations or [])
    origin = getattr(spec, "origin", None)
    if not origin or not os.path.isfile(origin):
        return None
    path = Path(origin).resolve()
    up = len(parts) - (0 if path.stem == "__init__" else 1)
    root = path.parent
    for _ in range(up):
        root = root.parent
    return {
        "module": module,
        "file": str(path),
        "root": str(root),
        "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
    }


def check_settings(name: str, settings: dict[str, Any]) -> None:
    """Refuse settings that the agent does not take, before any run starts; an agent that
    declares its settings (a dataclass ``Settings`` with :mod:`arm.constraints`, as
    ``mpc-diagnose``) has every bad value named at once."""
    _, cls = resolve_agent(name)
    declared = getattr(cls, "Settings", None)
    if dataclasses.is_dataclass(declared) and isinstance(declared, type):
        bad = check(settings, constraints_of(declared))
        if bad:
            raise AgentError(f"agent {name!r}: " + "; ".join(bad))
    sig = inspect.signature(cls.__init__)
    params = sig.parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    unknown = sorted(set(settings) - set(params) - {"self"})
    if unknown:
        allowed = [p for p in params if p != "self"]
        raise AgentError(
            f"agent {name!r}: unknown setting(s) {', '.join(unknown)}; "
            f"it takes: {', '.join(allowed) or 'none'}"
        )


def make_agent(name: str, **settings: Any) -> Agent:
    """An agent by registered name or ``package.module:Class`` with its settings."""
    factory, _ = resolve_agent(name)
    check_settings(name, settings)
    try:
        agent = factory(**settings)
    except (TypeError, ValueError) as exc:
        raise AgentError(f"agent {name!r}: bad settings {settings}: {exc}") from exc
    return agent
