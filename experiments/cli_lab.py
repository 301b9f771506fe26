"""``sixaxis lab ...``: the model lab's commands (fit, diagnose, report, plan, collect, export,
compensate). Work in progress: commands are added as the lab lands."""

from __future__ import annotations

import typer

app = typer.Typer(
    help="The model lab: compare the model with measurements, find what it misses.",
    no_args_is_help=True,
)
