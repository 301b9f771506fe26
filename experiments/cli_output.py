"""What the ``sixaxis`` commands print, shared by all of them: the consoles, the one-line error
exit, numbers as text, the command lines a user copies, and the rich tables of the lab's results
(fit, diagnosis, discovery, plan, compensation) and of the leaderboard.

The command modules (``cli_lab``, ``cli_sweep``, ``cli_agents``, ``cli_demo``) parse options, call
the library inside :func:`user_errors` and print with these; nothing here computes a result. Numbers
and units read as in every other place the lab shows them (:mod:`lab.text`).
"""

from __future__ import annotations

import contextlib
import shlex
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NoReturn

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from arm.errors import SixAxisError
from lab.text import mm_text, p_value_text, parameter_cells, signed_text

__all__ = [
    "candidates_table",
    "command_line",
    "compensation_table",
    "console",
    "discovery_table",
    "err_console",
    "fail",
    "fit_table",
    "hints_table",
    "leaderboard_grid",
    "mm_text",
    "p_value_text",
    "plan_table",
    "signed_text",
    "user_errors",
]

console = Console()
err_console = Console(stderr=True, soft_wrap=True)


def fail(message: object) -> NoReturn:
    """Print ``error: message`` on stderr and exit with code 2 (bad input, not a bug)."""
    err_console.print(f"[red]error:[/red] {escape(str(message))}", highlight=False)
    raise typer.Exit(2)


@contextlib.contextmanager
def user_errors(*extra: type[BaseException], prefix: str = "") -> Iterator[None]:
    """The project's own errors (:class:`~arm.errors.SixAxisError`: bad input, with the file,
    line, column, key or parameter named) and ``extra`` become one line ``error: {prefix}...``
    and exit code 2; anything else is a bug and keeps its traceback."""
    try:
        yield
    except (SixAxisError, *extra) as exc:
        fail(f"{prefix}{exc}")


# -- commands as text ------------------------------------------------------------------------------
def command_line(*words: object, **options: object) -> str:
    """The ``sixaxis`` command line that these words and (non-default) options spell: an option
    whose value is None, False or [] is left out, True is a bare flag, a list repeats the flag."""
    out = ["sixaxis", *map(str, words)]
    for flag, value in options.items():
        if value is None or value is False or value == []:
            continue
        for v in value if isinstance(value, list) else [value]:
            out.append(flag)
            if v is not True:
                out.append(str(v))
    return shlex.join(out)


# -- the lab's results ------------------------------------------------------------------------------
def fit_table(result: Any) -> Table:
    """The paper's Table 3 and more: nominal, identified error and its standard error per
    parameter of a :class:`lab.FitResult` (lengths in mm; angles: nominal in deg, errors in
    mrad)."""
    table = Table(
        title=f"identified parameters ({result.rank} of {result.n_parameters} fitted)",
        title_justify="left",
    )
    for c, j in (
        ("parameter", "left"),
        ("effect", "left"),
        ("nominal", "right"),
        ("error", "right"),
        ("std", "right"),
        ("unit", "left"),
    ):
        table.add_column(c, justify=j)
    for row in result.rows():
        c = parameter_cells(row)
        error = "[dim]fixed[/dim]" if c["fitted"] == "no" else c["error"]
        table.add_row(c["name"], c["effect"], c["nominal"], error, c["std"], c["unit"])
    return table


def candidates_table(candidates: Sequence[Any]) -> Table:
    """A diagnosis's candidate effects, best first: RMS and held-out RMS after adding each, its
    p-value and whether it is significant."""
    table = Table(
        title="candidate effects, best first (RMS after adding each)", title_justify="left"
    )
    for c, j in (
        ("candidate", "left"),
        ("RMS mm", "right"),
        ("held-out mm", "right"),
        ("p-value", "right"),
        ("significant", "left"),
    ):
        table.add_column(c, justify=j)
    for c in candidates:
        sig = "[bold]yes[/bold]" if c.significant else "no"
        table.add_row(
            escape(c.label), mm_text(c.rms_mm), mm_text(c.cv_rms_mm), p_value_text(c.p_value), sig
        )
    if candidates:
        table.columns[0].min_width = max(len(c.label) for c in candidates)
    return table


def hints_table(hints: Sequence[Any]) -> Table:
    """The measured variables the residual still depends on, with their scores and p-values."""
    table = Table(title="what the residual depends on", title_justify="left")
    table.add_column("variable")
    table.add_column("score (adjusted R^2)", justify="right")
    table.add_column("p-value", justify="right")
    for h in hints:
        table.add_row(escape(h.variable), f"{h.score:.3f}", p_value_text(h.p_value))
    return table


def discovery_table(terms: Sequence[Any]) -> Table:
    """The terms a discovery found, refitted with the model: joint, expression, coefficient,
    standard error and parameter name."""
    table = Table(title="discovered terms (refitted with the model)", title_justify="left")
    for c, j in (
        ("joint", "right"),
        ("term", "left"),
        ("coefficient", "right"),
        ("std", "right"),
        ("parameter", "left"),
    ):
        table.add_column(c, justify=j)
    for t in terms:
        table.add_row(
            str(t.joint),
            escape(t.expression),
            f"{t.coefficient:.4g}",
            "-" if t.std is None else f"{t.std:.2g}",
            t.name,
        )
    return table


def plan_table(plan: Any, criterion: str) -> Table:
    """A pose plan's O1 and O4 beside those of random pose sets of the same size."""
    table = Table(title=f"{plan.n_poses} poses chosen by {criterion.upper()}", title_justify="left")
    table.add_column("", style="bold")
    table.add_column("planned", justify="right")
    table.add_column(f"{plan.n_poses} random poses (mean of 20)", justify="right")
    table.add_row("O1", f"{plan.o1:.4g}", f"{plan.random_o1:.4g}")
    table.add_row("O4", f"{plan.o4:.4g}", f"{plan.random_o4:.4g}")
    return table


def compensation_table(calibrated: str, nominal: str, n: int, summary: dict[str, Any]) -> Table:
    """The error of the ``calibrated`` arm at ``n`` targets, commanded by the ``nominal`` arm's
    inverse kinematics and compensated (``summary``: a compensation's ``to_dict()``)."""
    table = Table(title=f"error of {calibrated!r} at {n} targets (mm)", title_justify="left")
    table.add_column("joint angles commanded")
    table.add_column("RMS", justify="right")
    table.add_column("max", justify="right")
    table.add_row(
        f"nominal inverse kinematics ({nominal})",
        mm_text(summary["nominal_rms_mm"]),
        mm_text(summary["nominal_max_mm"]),
    )
    table.add_row("compensated", mm_text(summary["rms_mm"], 6), mm_text(summary["max_mm"], 6))
    return table


# -- the leaderboard --------------------------------------------------------------------------------
def leaderboard_grid(board: Any, title: str, cell: Callable[[Any], str]) -> Table:
    """One row per agent, one column per scenario, ``cell(row)`` in each; the best of each
    scenario in bold green."""
    table = Table(title=title)
    table.add_column("agent", style="bold")
    for s in board.scenarios:
        table.add_column(s, justify="right")
    for a in board.agents:
        rows = [board.row(a, s) for s in board.scenarios]
        cells = []
        for r in rows:
            c = "" if r is None else cell(r)
            cells.append(f"[bold green]{c}[/bold green]" if r is not None and r.best else c)
        table.add_row(next(r for r in rows if r is not None).display, *cells)
    return table
