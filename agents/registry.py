"""Agents by name: ``make_agent("mpc", horizon=15)``, or a user's class by import path
``make_agent("my_package.controllers:MyAgent", gain=2.0)``.

| name           | what it is                                                                  |
|----------------|-----------------------------------------------------------------------------|
| `hold`         | zero velocity: the floor                                                    |
| `nominal`      | resolved-rate tracking on the nominal model, no measurements                |
| `feedforward`  | nominal tracking of the reference minus the last measured model error       |
| `calibrated`   | calibrate from a measurement phase (least squares), then track blind        |
| `mpc`          | kinematic MPC (QP, daqp) with online recursive least-squares calibration    |
| `mpc-ipopt`    | the same MPC as a nonlinear program solved by IPOPT                         |
| `mpc-oracle`   | the MPC given the plant's true model (needs the env's truth)                |
| `mpc-diagnose` | the MPC that diagnoses its own model with the lab and widens it             |
| `sac`          | the shipped plain SAC policy (stable-baselines3): joint velocities          |
| `ppo-residual` | the shipped residual PPO policy on top of ``feedforward`` (+-0.5 mm)        |
| `sac-residual` | the shipped residual SAC policy on top of ``feedforward`` (+-0.5 mm)        |

Every ``agents/policies/<name>.npz`` is registered as ``<name>``: a learned policy loads from that
file (weights as arrays, no unpickling) or from ``path``, another such file.

A class path (``package.module:Class``) imports that module: it runs the module's code, so name
only classes you trust.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from pathlib import Path
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


def _feedforward(**kw):
    from agents.reference import FeedforwardAgent

    return FeedforwardAgent(**kw)


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


#: the learned policies shipped in agents/policies/ (<name>.npz), each registered by its name
POLICIES = tuple(
    sorted(p.stem for p in (Path(__file__).resolve().parent / "policies").glob("*.npz"))
)


def _policy(name: str) -> Callable[..., Agent]:
    def make(**kw):
        from agents.policy import PolicyAgent

        return PolicyAgent(name, **kw)

    return make


AGENTS: dict[str, Callable[..., Agent]] = {
    "hold": _hold,
    "nominal": _nominal,
    "feedforward": _feedforward,
    "calibrated": _calibrated,
    "mpc": _mpc,
    "mpc-ipopt": _mpc_ipopt,
    "mpc-oracle": _mpc_oracle,
    "mpc-diagnose": _mpc_diagnose,
    **{name: _policy(name) for name in POLICIES},
}


def agent_names() -> list[str]:
    return list(AGENTS)


def resolve_agent(name: str) -> tuple[Callable[..., Agent], Callable[..., Any]]:
    """The factory of ``name`` and the callable whose signature its settings must fit."""
    if name in AGENTS:
        from agents import mpc, policy, reference, self_diagnosis

        cls = {
            "hold": reference.HoldAgent,
            "nominal": reference.NominalAgent,
            "feedforward": reference.FeedforwardAgent,
            "calibrated": reference.CalibratedAgent,
            "mpc": mpc.MPCAgent,
            "mpc-ipopt": mpc.MPCAgent,
            "mpc-oracle": mpc.MPCAgent,
            "mpc-diagnose": self_diagnosis.DiagnosingMPCAgent,
            **{p: policy.PolicyAgent for p in POLICIES},
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
    except (TypeError, ValueError) as exc:
        raise AgentError(f"agent {name!r}: bad settings {settings}: {exc}") from exc
    return agent
