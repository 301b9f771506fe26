"""The agents' errors, all :class:`arm.errors.SixAxisError` s with their built-in parent.

The modules that raise them re-export them (``from agents.runner import AgentFailure`` still
works).
"""

from __future__ import annotations

from arm.errors import SixAxisError

__all__ = [
    "AgentError",
    "AgentFailure",
    "AgentStateError",
    "EpisodeError",
    "PolicyFileError",
    "TimeLimitExceeded",
    "TrainConfigError",
    "TrainingError",
    "UnsupportedEffectError",
]


class AgentError(SixAxisError, ValueError):
    """An unknown agent, bad settings, or a request it cannot carry out, naming what is wrong."""


class AgentStateError(SixAxisError, RuntimeError):
    """A call an agent cannot answer in its state (an action before ``reset``)."""


class UnsupportedEffectError(SixAxisError, ValueError):
    """An effect, or a compiled function, that the CasADi tool model cannot express."""


class AgentFailure(SixAxisError, RuntimeError):
    """The agent failed: it raised, returned an action that is not 6 finite numbers, or its
    process ended; the message names the agent, the call and the step. ``agent_traceback``:
    the agent's own traceback, when it ran in a process of its own."""

    agent_traceback: str = ""


class TimeLimitExceeded(SixAxisError, TimeoutError):
    """The run was still going at its time limit."""


class EpisodeError(SixAxisError, ValueError):
    """An episode that cannot run as asked (no phase, a phase longer than the episode)."""


class PolicyFileError(SixAxisError, ValueError):
    """A policy file that is missing, unsafe to load, or does not fit its description."""


class TrainConfigError(SixAxisError, ValueError):
    """A training config that cannot run, naming the file and the key."""


class TrainingError(SixAxisError, RuntimeError):
    """A training run that cannot go on (it ran out of its episode seeds)."""
