"""The one base of sixaxis-track's own errors and cautions, and the arm model's errors.

Every error the project raises on purpose (bad input, an impossible request, a failed sweep)
derives from :class:`SixAxisError`, and keeps the built-in parent it always had (``ValueError``
for bad input, ``RuntimeError`` for a failed sweep), so ``except ValueError`` still catches it.
A front end catches ``SixAxisError`` alone to tell a user's mistake from a bug.
``tests/test_error_tree.py`` holds every package to it: no bare ``raise ValueError(...)``, and
every exception class under this root.

The classes live in one ``errors`` module per package, as ``gymnasium/error.py`` keeps its own:
this one (the arm model's), :mod:`lab.errors` (under :class:`lab.errors.LabError`),
:mod:`envs.errors`, :mod:`agents.errors` and :mod:`experiments.errors`. The modules that raise
them re-export them (``from arm.measurements import MeasurementError`` still works).

A caution to the user (a poor pose set, rows left out of a fit, a value accepted beyond its
plausible bound) is a :class:`SixAxisWarning`, issued with :func:`warn` *besides* the log record:
a user can filter it (``warnings.simplefilter("ignore", SixAxisWarning)``), turn it into an
error, or assert it in a test (``pytest.warns``).
"""

from __future__ import annotations

import contextlib
import sys
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path

__all__ = [
    "DescriptionError",
    "EffectError",
    "IKError",
    "InputFileError",
    "MeasurementError",
    "MeasurementWarning",
    "ModelError",
    "NoiseError",
    "OutputError",
    "SamplingError",
    "SixAxisError",
    "SixAxisWarning",
    "UnknownNameError",
    "UrdfError",
    "collected_warnings",
    "warn",
]


class SixAxisError(Exception):
    """Base of every error sixaxis-track raises on purpose: the message names what is wrong and
    where (file, row, column, parameter or key)."""


class SixAxisWarning(UserWarning):
    """Base of every caution sixaxis-track gives a user: the message says what and where."""


# -- the arm model's errors (re-exported by the modules that raise them) --------------------------
class DescriptionError(SixAxisError, ValueError):
    """A robot description that cannot be used, with the file and key at fault."""


class UrdfError(SixAxisError, ValueError):
    """A URDF that cannot be read as a six-axis arm: the message names the file, joint or link."""


class EffectError(SixAxisError, ValueError):
    """An unknown effect, a bad effect specification or a missing measured column."""


class ModelError(SixAxisError, ValueError):
    """An error model given the wrong number of parameters, q not (N, 6), or a name twice."""


class UnknownNameError(SixAxisError, KeyError):
    """A parameter, effect or declared choice asked for by a name the model does not have."""


class IKError(SixAxisError, ValueError):
    """Bad input to an inverse-kinematics function (shapes, unknown tool)."""


class SamplingError(SixAxisError, ValueError):
    """A seed or a count that cannot be drawn from, or an arm whose poses cannot be sampled."""


class MeasurementError(SixAxisError, ValueError):
    """Bad measurement input; the message names the file, the line and the column."""


class NoiseError(SixAxisError, ValueError):
    """A noise setting out of range, or a data set whose uncertainty is not stated."""


class InputFileError(SixAxisError, ValueError):
    """An input that is not a regular file, is too large, or cannot be read."""


class OutputError(SixAxisError, ValueError):
    """An output path that would replace an input or something that is not a regular file, or
    that cannot be written."""


class MeasurementWarning(SixAxisWarning):
    """A measurement file the lab reads, with something the user should know: a column that no
    catalogued effect reads (kept for custom effects), a name close to a known one."""


# the project's packages: a warning points at the first frame outside them (the user's call)
_PACKAGES = tuple(
    str(Path(__file__).resolve().parents[1] / p) for p in ("arm", "lab", "envs", "agents")
)


# per thread: where warn() puts its warnings inside collected_warnings(), else None
_collecting = threading.local()


@contextlib.contextmanager
def collected_warnings() -> Iterator[list[tuple[str, type[SixAxisWarning]]]]:
    """Within the block, in this thread only, :func:`warn` appends ``(message, category)`` to the
    list it yields instead of issuing the warning. For work run in a worker thread: its stack
    holds no caller of the user's (a warning would point at ``threading.py``), so the thread
    that adopts the work's result issues them with :func:`warn`, at its own caller.
    (``warnings.catch_warnings`` would not do: it changes every thread's filters.)"""
    previous = getattr(_collecting, "sink", None)
    sink: list[tuple[str, type[SixAxisWarning]]] = []
    _collecting.sink = sink
    try:
        yield sink
    finally:
        _collecting.sink = previous


def warn(message: str, category: type[SixAxisWarning] = SixAxisWarning) -> None:
    """Issue ``message`` as a warning of ``category``, attributed to the caller's code (the first
    frame outside the project's library packages), as ``skip_file_prefixes`` does in 3.12.
    Inside :func:`collected_warnings` (in its thread), the warning is collected instead."""
    sink = getattr(_collecting, "sink", None)
    if sink is not None:
        sink.append((message, category))
        return
    level, frame = 2, sys._getframe(1)
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGES):
        level, frame = level + 1, frame.f_back  # type: ignore[assignment]
    warnings.warn(message, category, stacklevel=level)
