"""What the ``sixaxis`` commands print, shared by all of them: the consoles, the one-line error
exit, numbers as text, the command lines a user copies, and the rich tables of the lab's results
(fit, diagnosis, discovery, plan, compensation) and of the leaderboard.

The command modules (``cli_lab``, ``cli_sweep``, ``cli_agents``, ``cli_demo``) parse options, call
the library inside :func:`user_errors` and print with these; nothing here computes a result. Numbers
and units read as in every other place the lab shows them (:mod:`lab.text`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import shlex
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, NoReturn

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
    caught: tuple[type[BaseException], ...] = (SixAxisError, *extra)
    try:
        yield
    except caught as exc:
        fail(f"{prefix}{exc}")


Justify = Literal["left", "right"]


def _table(title: str, *columns: tuple[str, Justify]) -> Table:
    """A rich table titled on the left, with these (header, justification) columns."""
    table = Table(title=title, title_justify="left")
    for header, justify in columns:
        table.add_column(header, justify=justify)
    return table


# -- commands as text ------------------------------------------------------------------------------
def command_line(*words: object, **options: object) -> str:
    """The ``sixaxis`` command line that these words and (non-default) options spell: an option
    whose value is None, False or [] is left out, True is a bare flag, a list repeats the flag;
    a list among the words is its items (the data files of a command)."""
    out = ["sixaxis"]
    for w in words:
        out += map(str, w) if isinstance(w, list | tuple) else [str(w)]
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
    table = _table(
        f"identified parameters ({result.rank} of {result.n_parameters} fitted)",
        ("parameter", "left"),
        ("effect", "left"),
        ("nominal", "right"),
        ("error", "right"),
        ("std", "right"),
        ("unit", "left"),
    )
    for row in result.rows():
        cell = parameter_cells(row)
        error = "[dim]fixed[/dim]" if cell["fitted"] == "no" else cell["error"]
        table.add_row(
            cell["name"], cell["effect"], cell["nominal"], error, cell["std"], cell["unit"]
        )
    return table


def candidates_table(candidates: Sequence[Any]) -> Table:
    """A diagnosis's candidate effects, best first: RMS and held-out RMS after adding each, its
    p-value and whether it is significant."""
    table = _table(
        "candidate effects, best first (RMS after adding each)",
        ("candidate", "left"),
        ("RMS mm", "right"),
        ("held-out mm", "right"),
        ("p-value", "right"),
        ("significant", "left"),
    )
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
    table = _table(
        "what the residual depends on",
        ("variable", "left"),
        ("score (adjusted R^2)", "right"),
        ("p-value", "right"),
    )
    for h in hints:
        table.add_row(escape(h.variable), f"{h.score:.3f}", p_value_text(h.p_value))
    return table


def discovery_table(terms: Sequence[Any]) -> Table:
    """The terms a discovery found, refitted with the model: joint, expression, coefficient,
    standard error and parameter name."""
    table = _table(
        "discovered terms (refitted with the model)",
        ("joint", "right"),
        ("term", "left"),
        ("coefficient", "right"),
        ("std", "right"),
        ("parameter", "left"),
    )
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


def compensation_table(summary: dict[str, Any]) -> Table:
    """The calibrated arm's error at the targets, commanded the start's joint angles (the
    program's or the nominal inverse kinematics') and the compensated ones, with the joint change
    (``summary``: a compensation's ``to_dict()``)."""
    n = summary["n_targets"]
    table = Table(
        title=f"error of {summary['robot']!r} at {n} targets, through its model (mm)",
        title_justify="left",
    )
    table.add_column("joint angles commanded")
    table.add_column("RMS", justify="right")
    table.add_column("max", justify="right")
    table.add_column("joint change max / median (mrad)", justify="right")
    first = (
        "the program as it is"
        if summary["start"] == "program"
        else f"nominal inverse kinematics ({summary['nominal_robot']}, calibrated base and tool)"
    )
    table.add_row(
        first, mm_text(summary["start_rms_mm"]), mm_text(summary["start_max_mm"]), "0 / 0"
    )
    table.add_row(
        "compensated",
        mm_text(summary["rms_mm"], 6),
        mm_text(summary["max_mm"], 6),
        f"{summary['max_joint_change_mrad']:.3f} / {summary['median_joint_change_mrad']:.3f}",
    )
    return table


_ORIENTATION_SAID = {
    "program": "held from the program (q1..q6 through the calibrated model)",
    "targets": "the targets' own (their orientation columns)",
    "free": "free (--free-orientation: the tool point alone)",
}


def agents_table(specs: Sequence[Any]) -> Table:
    """The registered agents (``agents.registry.AgentSpec`` s): name, class, what it is."""
    table = _table(
        "agents (sixaxis evaluate AGENT, or an agent's name in a config)",
        ("name", "left"),
        ("class", "left"),
        ("what it is", "left"),
    )
    for spec in specs:
        made = ", ".join(f"{k}={v!r}" for k, v in spec.kwargs.items())
        table.add_row(spec.name, spec.entry_point + (f" ({made})" if made else ""), spec.summary)
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


# -- JSON -------------------------------------------------------------------------------------------
def _json_safe(obj: Any) -> Any:
    """Plain JSON: numpy scalars and arrays as numbers and lists, NaN and inf as null."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_safe(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    return obj


# -- cautions ---------------------------------------------------------------------------------------
class _Once(logging.Filter):
    """Lets a log record through once per command: a caution the lab gives at each of its fits
    (a poor pose set, at the screen's fit and at the refit) is said once."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: set[tuple[int, str]] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.levelno, record.getMessage())
        new = key not in self.seen
        self.seen.add(key)
        return new


_cautions: list[warnings.WarningMessage] | None = None


@contextlib.contextmanager
def cautions_recorded() -> Iterator[None]:
    """Within a lab command: every caution of the project (an :class:`arm.errors.SixAxisWarning`)
    is recorded for the JSON (:func:`with_cautions`), and each log record is said once."""
    global _cautions
    from arm.errors import SixAxisWarning

    # a filter per handler: a record goes through each (pytest's two among them)
    filters = [(h, _Once()) for h in logging.getLogger().handlers]
    for h, once in filters:
        h.addFilter(once)
    previous = _cautions
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SixAxisWarning)
        _cautions = caught
        try:
            yield
        finally:
            _cautions = previous
            for h, once in filters:
                h.removeFilter(once)


def record_cautions(caught: Sequence[warnings.WarningMessage]) -> None:
    """Add warnings that a reader caught (and said) itself to the command's record."""
    if _cautions is not None:
        _cautions.extend(caught)


def with_cautions(obj: dict) -> dict:
    """``obj`` with ``warnings``: every caution the command gave, once each, in order, as
    ``{"code": its class name, "message": ...}`` (docs/format.md, the lab's JSON output)."""
    seen: set[tuple[str, str]] = set()
    out = []
    for w in _cautions or ():
        key = (w.category.__name__, str(w.message))
        if key not in seen:
            seen.add(key)
            out.append({"code": key[0], "message": key[1]})
    return obj | {"warnings": out}


def json_text(obj: dict) -> str:
    """A result's JSON object as text (strict JSON: NaN and inf are null)."""
    return json.dumps(_json_safe(obj), indent=2, allow_nan=False)


def emit_json(obj: dict, as_json: bool, out: Path | None) -> None:
    """Write the JSON object to ``out`` (atomically), print it with ``as_json`` (stdout carries
    nothing else), else say where it went."""
    from arm.files import OutputError, atomic_write_text, is_stdout

    text = json_text(with_cautions(obj))
    if out is not None:
        try:
            atomic_write_text(out, text + "\n")
        except OutputError as exc:
            fail(str(exc))
        except OSError as exc:
            fail(f"{out}: cannot write ({exc.strerror or exc})")
    if as_json and not is_stdout(out):
        print(text)
    elif out is not None:
        say(f"wrote {out}")


def say(text: str) -> None:
    """One line of plain text (no markup, no highlighting, not wrapped)."""
    console.print(escape(text), highlight=False, soft_wrap=True)


# -- the lab's commands -----------------------------------------------------------------------------
def print_sessions(data: Any) -> None:
    """The sessions of several files joined (nothing for one file)."""
    if len(data.sessions) > 1:
        say("sessions: " + "; ".join(s.text() for s in data.sessions))


def print_fit(result: Any) -> None:
    console.print(fit_table(result))
    say(result.summary())


def print_left_out(duplicates: Sequence[Any], outliers: Sequence[Any], rule: Any, of: str) -> None:
    from lab.text import left_out_lines

    for text in left_out_lines(duplicates, outliers, rule, of=of):
        say(text)


def _verdict_line(d: Any, what: str, none_without_noise: str) -> str:
    colour = {"none": "green", "unexplained": "yellow", "noise": "yellow"}.get(d.verdict, "red")
    line = f"verdict: [bold {colour}]{escape(d.verdict)}[/bold {colour}]"
    if d.verdict == "none" and d.noise_mm is None:
        line += f" ({none_without_noise}; give --noise-mm to test the residual against the {what})"
    elif d.verdict == "none":
        line += " (the residual is consistent with the noise: nothing missing)"
    return line


def print_noise(obj: Any) -> None:
    """The noise floor's source (repeated poses) and, when only noise is left, what it implies."""
    from lab.repeatability import NoiseFloor

    text = NoiseFloor(obj.noise_mm, obj.noise_source, obj.repeatability).text()
    if text:
        say(text)
    if obj.noise_note:
        console.print(f"[yellow]{escape(obj.noise_note)}[/yellow]", highlight=False, soft_wrap=True)


def print_notes(notes: Sequence[str], title: str) -> None:
    for n in notes:
        say(f"{title}: {n}")


def discover_command(data: Path | list[Path], d: Any, context: dict[str, Any] | None = None) -> str:
    """The ``sixaxis lab discover`` command that continues an ``unexplained`` diagnosis: from
    the diagnosed model (not the catalogue's partial explanation, whose approximating terms would
    hide the form), with the options the diagnosis was given that discover takes (``context``:
    the instrument's noise as stated, not one measured from repeated poses, which discover
    measures again)."""
    effects = ",".join(d.effects)
    return command_line(
        "lab",
        "discover",
        data,
        **{"--effects": None if effects == "geometric" else effects, "-o": "discovered.py"},
        **(context or {}),
    )


def print_diagnosis(
    d: Any, data: Path | list[Path], next_steps: Mapping[str, dict[str, Any]] | None = None
) -> None:
    """A diagnosis for people; ``next_steps``: per command (``fit``, ``discover``), the flags
    that a printed step of it repeats."""
    steps_ = next_steps or {}
    floor = f", noise floor {d.noise_floor_mm:.4f} mm" if d.noise_floor_mm else ""
    console.print(
        f"model [bold]{escape(', '.join(d.effects))}[/bold] on {d.fit.n_points} points: RMS "
        f"{d.rms_mm:.4f} mm, held-out {d.cv_rms_mm:.4f} mm{floor}",
        highlight=False,
        soft_wrap=True,
    )
    print_noise(d)
    line = _verdict_line(d, "instrument's noise", "no catalogued effect is significant")
    if d.verdict == "noise":
        line += " (nothing is missing, but the noise is above the one the tests used)"
    elif d.verdict == "unexplained":
        line += " (the residual is above the noise and no catalogued effect explains it)"
    if d.suggestion:
        fit = steps_.get("fit", {})
        then = escape(command_line("lab", "fit", data, **{"--effects": d.suggestion}, **fit))
        if d.verdict == "unexplained":
            line += f"; the catalogue's best, which explains part: {then}"
        else:
            line += f"; next: {then}"
    console.print(line, highlight=False, soft_wrap=True)
    if d.resolution_note:
        say(d.resolution_note)
    if d.cyclic_orders:
        say(
            "cyclic errors, orders per turn: "
            + "; ".join(
                f"joint {j}: {', '.join(map(str, ks))}" for j, ks in d.cyclic_orders.items()
            )
        )
        for reading in d.readings:
            say(f"  {reading}")
    print_notes(d.notes, "cannot resolve")
    print_notes(d.implausible, "passed over as implausible")
    if d.verdict == "unexplained":
        say(
            "next: let the lab search for the missing term's form: "
            + discover_command(data, d, steps_.get("discover"))
        )
    print_left_out(d.fit.duplicates, d.outlier_list, d.outlier_rule, "the fit and the tests")
    lack: dict[str, list[str]] = {}  # what is missing -> the candidates that need it
    for label, why in d.skipped.items():
        if why.startswith("needs "):
            lack.setdefault(why[len("needs ") :], []).append(label)
    if lack:
        console.print(
            "[yellow]not tested[/yellow], for lack of data: "
            + escape("; ".join(f"{', '.join(k)} (needs {v})" for v, k in lack.items())),
            highlight=False,
            soft_wrap=True,
        )
    shown = d.candidates[:10]
    if shown:
        console.print(candidates_table(shown))
    if len(d.candidates) > len(shown):
        console.print(f"... and {len(d.candidates) - len(shown)} more (--json lists all)")
    if d.hints:
        console.print(hints_table(d.hints[:6]))


def print_discovery(
    d: Any,
    output: Path | None,
    data: Path | list[Path] | None = None,
    context: dict[str, Any] | None = None,
) -> None:
    """A discovery for people; ``context``: the options the next step printed repeats."""
    floor = f", noise floor {d.noise_floor_mm:.4f} mm" if d.noise_floor_mm else ""
    console.print(
        f"model [bold]{escape(', '.join(d.effects))}[/bold] on {d.base.n_points} points: RMS "
        f"{d.rms_mm:.4f} mm{floor}; {d.n_candidates} candidate terms (harmonics to order "
        f"{d.order} per turn, fewer where the sampling resolves fewer), family-wise "
        f"false-discovery rate {d.alpha:g}",
        highlight=False,
        soft_wrap=True,
    )
    print_noise(d)
    line = _verdict_line(d, "noise", "no term is significant")
    if d.verdict == "noise":
        line += " (no term is significant, but the noise is above the one the tests used)"
    elif d.verdict == "unexplained" and d.terms:
        line += " (the terms found explain part; the residual stays above the noise)"
    elif d.verdict == "unexplained":
        line += " (the residual is above the noise and no term of the library explains it)"
    console.print(line, highlight=False, soft_wrap=True)
    print_notes(d.notes, "cannot resolve")
    if not d.terms:
        return
    for f in d.formulas.values():
        console.print(f"  [bold]{escape(f)}[/bold]", highlight=False, soft_wrap=True)
    console.print(discovery_table(d.terms))
    for reading in dict.fromkeys(t.reading for t in d.terms):
        terms = ", ".join(t.expression for t in d.terms if t.reading == reading)
        say(f"  {terms}: {reading}")
    held = f", held-out {d.validation_rms_mm:.4f} mm" if d.validation_rms_mm is not None else ""
    say(f"with the terms: RMS {d.rms_after_mm:.4f} mm{held}")
    if output is not None:
        ctx = dict(context or {})
        modules = [*ctx.pop("--effect-module", []), str(output)]
        fit = command_line(
            "lab",
            "fit",
            data if data is not None else "DATA.csv",
            **{"--effect-module": modules, "--effects": d.suggestion},
            **ctx,
        )
        say(f"wrote the effect to {output}; fit it with: {fit}")


@contextlib.contextmanager
def steps(console_: Console | None = None) -> Iterator[Callable[[str | None], None]]:
    """A spinner for work done in named steps: ``step("fitting ...")`` says the last step done
    with its time and shows the next; ``step(None)`` ends."""
    import time

    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        TimeElapsedColumn(),
        console=console_ or console,
        transient=True,
    ) as bar:
        task = bar.add_task("starting", total=None)
        last: list[Any] = [None, time.perf_counter()]

        def step(message: str | None) -> None:
            now = time.perf_counter()
            if last[0] is not None:
                bar.console.print(
                    f"[green]done[/green] {escape(last[0])} ({now - last[1]:.2f} s)",
                    highlight=False,
                    soft_wrap=True,
                )
            last[:] = [message, now]
            if message is not None:
                bar.update(task, description=escape(message))

        yield step


def print_report(rep: Any, output: Path, seconds: float) -> None:
    print_left_out(rep.duplicates, rep.outliers, rep.outlier_rule, "every model and every test")
    for run in rep.runs:
        verdict = f", verdict {run.diagnosis.verdict}" if run.diagnosis is not None else ""
        held = (
            f", held-out {run.validation_rms_mm:.4f} mm"
            if run.validation_rms_mm is not None
            else ""
        )
        say(f"  {run.label:<28} RMS {run.rms_mm:.4f} mm{held}{verdict}")
    size = "" if str(output) == "-" else f" ({output.stat().st_size / 1024:.0f} KB)"
    say(f"wrote {output}{size} in {seconds:.1f} s")


def print_plan(p: Any, criterion: str, output: Path, angle_unit: str, poses: bool = False) -> None:
    console.print(plan_table(p, criterion))
    ident = p.identifiability
    say(
        f"{ident.rank} of {ident.n_parameters} parameters identifiable, condition number "
        f"{p.condition_number:.3g}"
    )
    if ident.unidentifiable:
        what = "poses" if poses else "positions"  # an instrument of orientations too, or not
        say(f"not identifiable from {what} (fixed): " + "; ".join(ident.unidentifiable))
    say(f"wrote {output} (q1..q6 in {angle_unit})")


@contextlib.contextmanager
def counted(description: str, total: int) -> Iterator[Callable[[int, int], None]]:
    """A progress bar of ``total`` items; yields ``progress(done, total)``."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=console,
    ) as bar:
        task = bar.add_task(description, total=total)
        yield lambda i, _n: bar.update(task, completed=i)


def print_compensation(comp: Any, summary: dict[str, Any], output: Path) -> None:
    console.print(compensation_table(summary))
    say(
        f"orientation {_ORIENTATION_SAID[summary['orientation']]}; the compensated joints "
        f"differ from the {'program' if summary['start'] == 'program' else 'nominal solution'} "
        f"by at most {summary['max_joint_change_mrad']:.3f} mrad; {summary['converged']} of "
        f"{comp.n} reached"
    )
    if summary["far_from_start"]:
        console.print(
            "[yellow]joints moved more than 200 mrad (near a singularity, where a small change "
            "of the pose turns the joints a lot):[/yellow] rows "
            f"{', '.join(str(i + 1) for i in summary['far_from_start'][:20])}",
            highlight=False,
            soft_wrap=True,
        )
    for kind, rows in summary["singular"].items():
        console.print(
            f"[yellow]singular poses ({kind}: the point solved alone, the start's split of "
            "the joints kept, the orientation held as near as that allows):[/yellow] rows "
            f"{', '.join(str(i + 1) for i in rows[:20])}",
            highlight=False,
            soft_wrap=True,
        )
    if summary["unreachable"]:
        console.print(
            f"[yellow]not reached (out of reach, or only beyond the joint limits):[/yellow] rows "
            f"{', '.join(str(i + 1) for i in summary['unreachable'][:20])}",
            highlight=False,
            soft_wrap=True,
        )
    say(f"wrote {output}")
