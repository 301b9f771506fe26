"""The experiments' errors, all :class:`arm.errors.SixAxisError` s with their built-in parent.

The modules that raise them re-export them (``from experiments.config import ConfigError`` still
works). One class stays where it is: ``experiments.cli_inputs.DeclaredError``, a command-line
option's refused value, derives from ``typer.BadParameter``, and this module imports no typer
(the configs, sweeps and records are used without the command line).
"""

from __future__ import annotations

from collections.abc import Sequence

from arm.errors import SixAxisError

__all__ = [
    "ConfigError",
    "MetricError",
    "MissingSeedsError",
    "RecordError",
    "ReproduceError",
    "SweepError",
    "UnknownMetricError",
    "VideoError",
]


class ConfigError(SixAxisError, ValueError):
    """A config that cannot run: the message names the file and every key at fault."""

    def __init__(self, source: str, problems: Sequence[str]) -> None:
        self.source = source
        self.problems = list(problems)
        lines = "\n".join(f"  - {p}" for p in self.problems)
        super().__init__(f"{source}: bad experiment config:\n{lines}")


class MissingSeedsError(SixAxisError, ValueError):
    """A config that draws its episode seeds asked for its runs without them."""


class SweepError(SixAxisError, RuntimeError):
    """A sweep that cannot start (e.g. records of another spec under the same run keys)."""


class RecordError(SixAxisError, ValueError):
    """A record file that cannot be read, naming the file."""


class ReproduceError(SixAxisError, ValueError):
    """A summary that cannot be read, a row that cannot be rerun (dirty, unknown commit, missing
    config), naming the file, row and column."""


class MetricError(SixAxisError, ValueError):
    """A metric that cannot be computed from what it was given (parameters of no model)."""


class UnknownMetricError(SixAxisError, KeyError):
    """A metric asked for by a name that is not one of ``experiments.metrics.METRICS``."""


class VideoError(SixAxisError, ValueError):
    """Video settings that cannot be written (frame size, rate), or no video writer installed."""
