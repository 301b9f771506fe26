"""The simulated world's errors, all :class:`arm.errors.SixAxisError` s with their built-in parent.

The modules that raise them re-export them (``from envs.scenarios import ScenarioError`` still
works). Plain classes: importing this module loads no MuJoCo.
"""

from __future__ import annotations

from gymnasium.error import ResetNeeded

from arm.errors import SixAxisError

__all__ = [
    "ActionError",
    "CollectError",
    "DivergedError",
    "EnvOptionError",
    "EnvStateError",
    "InstrumentError",
    "ObservationError",
    "PlantError",
    "ScenarioError",
    "SimulatorError",
    "TrajectoryError",
]


class SimulatorError(SixAxisError, RuntimeError):
    """MuJoCo cannot start or render (the GL backend that ``MUJOCO_GL`` names)."""


class PlantError(SixAxisError, ValueError):
    """A plant configuration that cannot be built or applied."""


class DivergedError(SixAxisError, RuntimeError):
    """The simulation diverged (a joint state that is not finite); the message names the pose."""


class ScenarioError(SixAxisError, ValueError):
    """An unknown scenario, or an override that names an unknown effect or parameter."""


class InstrumentError(SixAxisError, ValueError):
    """An instrument setting out of range."""


class TrajectoryError(SixAxisError, ValueError):
    """An unknown trajectory kind, or no reachable trajectory found."""


class CollectError(SixAxisError, ValueError):
    """Poses or payloads that cannot be measured: a wrong shape, NaN, outside the joint limits."""


class EnvOptionError(SixAxisError, ValueError):
    """Keyword arguments, reset options or wrapper settings the env does not take."""


class ActionError(SixAxisError, ValueError):
    """An action of the wrong shape, not numbers, NaN or inf (the env's or the tool interface's)."""


class EnvStateError(SixAxisError, ResetNeeded, RuntimeError):
    """A call the env (or a wrapper) cannot answer in its state (``step`` before ``reset``)."""


class ObservationError(SixAxisError, KeyError):
    """An observation asked for a part its task does not lay out (``envs.task``)."""
