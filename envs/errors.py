"""The environment's own error classes (each a :class:`arm.errors.SixAxisError`, keeping its
built-in parent); the env's option and state errors live beside the env
(:mod:`envs.sixaxis_track_v0`)."""

from __future__ import annotations

from arm.errors import SixAxisError

__all__ = ["InterfaceError"]


class InterfaceError(SixAxisError, ValueError):
    """An option of an interface wrapper (:mod:`envs.wrappers`) it cannot take, named."""
