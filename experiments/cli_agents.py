"""Commands of the ``sixaxis`` CLI for agents. Work in progress: commands are added as they land."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Mount this module's commands on the main app."""
