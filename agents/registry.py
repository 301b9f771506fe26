"""Agents by name: ``make_agent("mpc", horizon=15)``, or a user's class by import path
``make_agent("my_package.controllers:MyAgent", gain=2.0)``.

| name           | what it is                                                                  |
|----------------|-----------------------------------------------------------------------------|
| `hold`         | zero velocity: the floor                                                    |
| `nominal`      | resolved-rate tracking on the nominal model, no measurements                |
| `calibrated`   | calibrate from a measurement phase (least squares), then track blind        |
| `mpc`          | kinematic MPC (QP, daqp) with online recursive least-squares calibration    |
| `mpc-ipopt`    | the same MPC as a nonlinear program solved by IPOPT                         |
| `mpc-oracle`   | the MPC given the plant's true model (needs the env's truth)                |
| `mpc-diagnose` | the MPC that diagnoses its own model with the lab and widens it             |
| `ppo`          | the shipped PPO policy (stable-baselines3)                                  |
| `ppo-residual` | the shipped residual PPO policy on top of the nominal controller            |
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from typing import Any

from agents.base import Agent
from arm.errors import SixAxisError

__all__ = ["AGENTS", "AgentError", "agent_names", "check_settings", "make_agent", "resolve_agent"]


class AgentError(SixAxisError, ValueError):
    """An unknown agent or bad settings, with the name at fault."""


def _hold(**kw):
    from agents.reference import HoldAgent

    return HoldAgent(**kw)


def _nominal(**kw):
    from agents.reference import NominalAgent

    return NominalAgent(**kw)


def _calibrated(**kw):
    from agents.reference import CalibratedAgent

    return CalibratedAgent(**kw)


def _mpc(**kw):
    from agents.mpc import MPCAgent

    return MPCAgent(**kw)


def _mpc_ipopt(**kw):
    from agents.mpc import MPCAgent

    return MPCAgent(**({"solver": "ipopt"} | kw))


def _mpc_oracle(**kw):
    from agents.mpc import MPCAgent

    return MPCAgent(**({"oracle": True} | kw))


def _mpc_diagnose(**kw):
    from agents.self_diagnosis import DiagnosingMPCAgent

    return DiagnosingMPCAgent(**kw)


def _ppo(**kw):
    from agents.ppo import PPOAgent

    return PPOAgent(**kw)


def _ppo_residual(**kw):
    from agents.ppo import PPOAgent

    return PPOAgent(**({"variant": "residual"} | kw))


AGENTS: dict[str, Callable[..., Agent]] = {
    "hold": _hold,
    "nominal": _nominal,
    "calibrated": _calibrated,
    "mpc": _mpc,
    "mpc-ipopt": _mpc_ipopt,
    "mpc-oracle": _mpc_oracle,
    "mpc-diagnose": _mpc_diagnose,
    "ppo": _ppo,
    "ppo-residual": _ppo_residual,
}


def agent_names() -> list[str]:
    return list(AGENTS)


def resolve_agent(name: str) -> tuple[Callable[..., Agent], Callable[..., Any]]:
    """The factory of ``name`` and the callable whose signature its settings must fit."""
    if name in AGENTS:
        from agents import mpc, ppo, reference, self_diagnosis

        cls = {
            "hold": reference.HoldAgent,
            "nominal": reference.NominalAgent,
            "calibrated": reference.CalibratedAgent,
            "mpc": mpc.MPCAgent,
            "mpc-ipopt": mpc.MPCAgent,
            "mpc-oracle": mpc.MPCAgent,
            "mpc-diagnose": self_diagnosis.DiagnosingMPCAgent,
            "ppo": ppo.PPOAgent,
            "ppo-residual": ppo.PPOAgent,
        }[name]
        return AGENTS[name], cls
    if ":" in name:
        module, _, attr = name.partition(":")
        try:
            mod = importlib.import_module(module)
        except ImportError as exc:
            raise AgentError(f"agent {name!r}: cannot import module {module!r}: {exc}") from exc
        found = getattr(mod, attr, None)
        if found is None:
            raise AgentError(f"agent {name!r}: module {module!r} has no {attr!r}")
        if not (isinstance(found, type) and issubclass(found, Agent)):
            raise AgentError(f"agent {name!r}: {attr} is not a subclass of agents.base.Agent")
        return found, found
    raise AgentError(
        f"unknown agent {name!r}; known: {', '.join(AGENTS)}, or a class as 'package.module:Class'"
    )


def check_settings(name: str, settings: dict[str, Any]) -> None:
    """Refuse settings that the agent does not take, before any run starts."""
    _, cls = resolve_agent(name)
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
    except TypeError as exc:
        raise AgentError(f"agent {name!r}: bad settings {settings}: {exc}") from exc
    return agent
