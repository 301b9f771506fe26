"""The ``sixaxis`` command line: a thin layer over the Python API.

Each command group lives in its own module (``cli_lab``, ``cli_agents``, ``cli_sweep``) and is
mounted here; library code logs with :mod:`logging`, the CLI prints with rich.
"""

from __future__ import annotations

import logging
import os
import sys
import warnings
from typing import Any

import typer
from rich.console import Console
from rich.logging import RichHandler

from arm.errors import SixAxisError
from experiments import cli_agents, cli_demo, cli_lab, cli_sweep
from experiments.cli_inputs import OneLineErrors
from experiments.cli_output import fail
from lab.errors import LabWarning


class _Commands(OneLineErrors):
    """The ``sixaxis`` group: an error the project raises on purpose (:class:`SixAxisError`: bad
    input, named) that a command did not turn into its own line still ends as one line
    ``error: ...`` and exit code 2, never a traceback; so does an exception raised in a user's
    ``--effect-module``, named by its file and line, and a refused option value
    (:class:`~experiments.cli_inputs.OneLineErrors`). Anything else is a bug and keeps its
    traceback."""

    def invoke(self, ctx: Any) -> Any:
        try:
            return super().invoke(ctx)
        except SixAxisError as exc:
            fail(exc)
        except Exception as exc:  # a user's effect module's own failure is theirs, not a bug
            from arm.effects import user_module_failure

            where = user_module_failure(exc)
            if where is None:
                raise
            fail(where)


app = typer.Typer(
    name="sixaxis",
    cls=_Commands,
    help="sixaxis-track: calibrate a six-axis arm, find what its model misses, benchmark controllers.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)
app.add_typer(cli_lab.app, name="lab")
cli_agents.register(app)
cli_sweep.register(app)
cli_demo.register(app)


@app.callback()
def _main(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log library messages."),
) -> None:
    # the lab's cautions are warnings besides their log record: the log (on stderr) says them
    # once here
    warnings.simplefilter("ignore", LabWarning)
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="%(message)s",
        handlers=[
            # stderr: a warning must never break a command's --json on stdout
            RichHandler(console=Console(stderr=True), show_path=False, rich_tracebacks=False)
        ],
    )
    # a folder an output needed, made (arm.files.make_folders): one line, without --verbose too
    logging.getLogger("arm.files").setLevel(logging.INFO)


def main() -> None:
    """The ``sixaxis`` console script. The working folder is importable, as ``python -m`` makes
    it: an agent ``mypkg.myagent:MyAgent`` of a package beside the user's config is found by
    ``sweep``, ``evaluate`` and ``reproduce`` without ``PYTHONPATH`` (a console script's
    ``sys.path`` starts at its own folder, not the working one)."""
    cwd = os.getcwd()
    if "" not in sys.path and cwd not in sys.path:
        sys.path.insert(0, cwd)
    app()


if __name__ == "__main__":
    main()
