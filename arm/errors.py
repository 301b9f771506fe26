"""The one base of sixaxis-track's own errors.

Every error the project raises on purpose (bad input, an impossible request, a failed sweep)
derives from :class:`SixAxisError`, and keeps the built-in parent it always had (``ValueError``
for bad input, ``RuntimeError`` for a failed sweep), so ``except ValueError`` still catches it.
A front end catches ``SixAxisError`` alone to tell a user's mistake from a bug.
"""

from __future__ import annotations

__all__ = ["SixAxisError"]


class SixAxisError(Exception):
    """Base of every error sixaxis-track raises on purpose: the message names what is wrong and
    where (file, row, column, parameter or key)."""
