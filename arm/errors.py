"""The one base of sixaxis-track's own errors and cautions.

Every error the project raises on purpose (bad input, an impossible request, a failed sweep)
derives from :class:`SixAxisError`, and keeps the built-in parent it always had (``ValueError``
for bad input, ``RuntimeError`` for a failed sweep), so ``except ValueError`` still catches it.
A front end catches ``SixAxisError`` alone to tell a user's mistake from a bug.

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

__all__ = ["SixAxisError", "SixAxisWarning", "collected_warnings", "warn"]


class SixAxisError(Exception):
    """Base of every error sixaxis-track raises on purpose: the message names what is wrong and
    where (file, row, column, parameter or key)."""


class SixAxisWarning(UserWarning):
    """Base of every caution sixaxis-track gives a user: the message says what and where."""


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
