"""The ``sixaxis`` command line: a thin layer over the Python API.

Each command group lives in its own module (``cli_lab``, ``cli_agents``, ``cli_sweep``) and is
mounted here; library code logs with :mod:`logging`, the CLI prints with rich.
"""

from __future__ import annotations

import logging
import warnings

import typer
from rich.console import Console
from rich.logging import RichHandler

from experiments import cli_agents, cli_demo, cli_lab, cli_sweep
from lab.errors import LabWarning

app = typer.Typer(
    name="sixaxis",
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


def main() -> None:
    app()


if __name__ == "__main__":
    main()
