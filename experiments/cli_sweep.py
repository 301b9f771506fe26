"""``sixaxis sweep CONFIG``, ``sixaxis leaderboard [RUNS_DIR]``, ``sixaxis reproduce RECORD``: thin
layers over :mod:`experiments.sweep`, :mod:`experiments.leaderboard` and :mod:`experiments.records`."""

from __future__ import annotations

import contextlib
import math
import signal
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from experiments.cli_output import (
    command_line,
    console,
    err_console,
    leaderboard_grid,
    user_errors,
)

#: how many pending runs ``--dry-run`` lists by name
DRY_RUN_LISTED = 200


@contextlib.contextmanager
def _stop_on_signals() -> Iterator[None]:
    """SIGTERM and SIGHUP (a closed terminal) stop the sweep like SIGINT: the runs in flight are
    ended, the finished records kept, the exit code 128 + the signal. A second signal ends the
    process at once (its workers still die with it)."""
    names = [n for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n)]
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread may set handlers
        return

    def handler(signum: int, frame: object) -> None:
        for n in names:
            signal.signal(getattr(signal, n), signal.SIG_DFL)
        stop = KeyboardInterrupt(signal.Signals(signum).name)  # what Ctrl-C raises, and which
        stop.signum = signum  # type: ignore[attr-defined]
        raise stop

    old = {n: signal.signal(getattr(signal, n), handler) for n in names}
    try:
        yield
    finally:
        for n, h in old.items():
            signal.signal(getattr(signal, n), h)


def sweep(
    config: Annotated[
        Path,
        typer.Argument(help="An experiment config (TOML), e.g. experiments/configs/quick.toml."),
    ],
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Records directory (default: runs/<config name>)."),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(
            "--workers",
            "-w",
            min=0,
            help="Parallel runs (default: the CPU count); 0 runs in this process.",
        ),
    ] = None,
    backend: Annotated[str, typer.Option(help="local (processes) or dask.")] = "local",
    address: Annotated[
        str | None, typer.Option(help="Dask scheduler address; none: start a LocalCluster.")
    ] = None,
    retry_failed: Annotated[
        bool, typer.Option("--retry-failed/--keep-failed", help="Rerun runs recorded as failed.")
    ] = True,
    overwrite: Annotated[
        bool, typer.Option(help="Replace records made by another spec of the same run.")
    ] = False,
    dry_run: Annotated[
        bool, typer.Option(help="Validate and list what would run, run nothing.")
    ] = False,
) -> None:
    """Run every agent x scenario x seed of CONFIG; finished runs are skipped, so rerunning resumes."""
    from experiments.config import load_config
    from experiments.records import RunStore
    from experiments.sweep import check_scheduler, plan_sweep, run_sweep

    with user_errors():
        cfg = load_config(config)
    out_dir = out if out is not None else Path("runs") / cfg.name
    with user_errors():  # every check before any work (and before the progress bar)
        store = RunStore(out_dir)
        store.check_writable()
        pending, finished = plan_sweep(cfg, store, retry_failed, overwrite)
        if backend == "dask" and address and not dry_run:
            check_scheduler(address)
    if dry_run:
        _print_plan(cfg, out_dir, pending, finished)
        return
    _warn_local_changes()

    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("running {task.fields[running]}  failed [red]{task.fields[failed]}[/red]"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
    )
    last = None
    with Progress(*columns, console=console, transient=False) as bar, _stop_on_signals():
        task = bar.add_task(f"sweep {cfg.name}", total=None, running=0, failed=0)

        def on_progress(state) -> None:
            nonlocal last
            last = state
            bar.update(
                task,
                total=state.total,
                completed=state.skipped + state.done,
                running=state.running,
                failed=state.failed,
            )

        try:
            with user_errors():
                summary = run_sweep(
                    cfg,
                    out_dir,
                    workers=workers,
                    backend=backend,
                    address=address,
                    retry_failed=retry_failed,
                    overwrite=overwrite,
                    command=command_line(
                        "sweep",
                        config,
                        **{
                            "--out": out,
                            "--workers": workers,
                            "--backend": None if backend == "local" else backend,
                            "--address": address,
                            "--keep-failed": not retry_failed,
                            "--overwrite": overwrite,
                        },
                    ),
                    progress=on_progress,
                )
        except KeyboardInterrupt as exc:
            signum = getattr(exc, "signum", signal.SIGINT)
            bar.stop()
            kept = "" if last is None else f"{last.skipped + last.done} of {last.total} runs "
            err_console.print(
                f"[yellow]interrupted[/yellow] ({signal.Signals(signum).name}): {kept}recorded "
                f"in {escape(str(out_dir))}, the runs in flight stopped; run the same command "
                "again to resume",
                highlight=False,
            )
            raise typer.Exit(128 + signum) from None
    _print_summary(summary)
    if summary.failed:
        raise typer.Exit(1)


def _warn_local_changes() -> None:
    """Say before the first run that the records will come from a tree with local changes,
    which no commit reproduces (the leaderboard refuses them unless --allow-dirty)."""
    from experiments.records import local_changes, source_root

    changed = local_changes()
    if not changed:
        return
    shown = ", ".join(changed[:3]) + (f" and {len(changed) - 3} more" if len(changed) > 3 else "")
    err_console.print(
        f"[yellow]warning[/yellow]: the checkout {escape(str(source_root()))} has local changes "
        f"({escape(shown)}): these runs' records will say so, no commit reproduces them, and "
        "`sixaxis leaderboard` refuses them unless --allow-dirty; commit or stash first "
        "(git stash) to publish them",
        highlight=False,
    )


def _print_plan(cfg: Any, out_dir: Path, pending: Sequence[Any], finished: Sequence[Any]) -> None:
    """What a sweep would run (--dry-run)."""
    drawn = (
        f" (episode seeds drawn from [2**32, 2**63) when the sweep starts, kept in "
        f"{out_dir / '_sweep.json'})"
        if cfg.draw_seeds
        else ""
    )
    console.print(
        f"{cfg.name}: {len(cfg.agents)} agents x {len(cfg.scenarios)} scenarios x "
        f"{cfg.n_seeds} seeds = {len(pending) + len(finished)} runs{drawn}; "
        f"{len(finished)} finished in {out_dir}, {len(pending)} to run; time limit "
        f"{cfg.time_limit_s:g} s a run, memory limit {cfg.memory_limit_mb} MiB a worker.",
        highlight=False,
    )
    for spec in pending[:DRY_RUN_LISTED]:
        console.print(f"  {spec.run_key}", highlight=False)
    if len(pending) > DRY_RUN_LISTED:
        console.print(f"  ... and {len(pending) - DRY_RUN_LISTED} more", highlight=False)


def _print_summary(summary: Any) -> None:
    """What a sweep ran, where its records are, which failed and what comes next."""
    console.print(
        f"{summary.done} runs in {summary.wall_time_s:.1f} s ({summary.skipped} already finished, "
        f"{len(summary.failed)} failed); records in {summary.out_dir}"
    )
    if summary.failed:
        for key in summary.failed[:10]:
            console.print(
                f"  [red]failed[/red] {summary.out_dir / (key + '.json')}", highlight=False
            )
        if len(summary.failed) > 10:
            console.print(f"  ... and {len(summary.failed) - 10} more")
    console.print(f"next: sixaxis leaderboard {summary.out_dir}", highlight=False)


def leaderboard(
    runs_dir: Annotated[Path, typer.Argument(help="A sweep's records directory.")] = Path(
        "runs/full"
    ),
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Where leaderboard.md/.csv and the PNGs go.")
    ] = Path("results"),
    rank_by: Annotated[
        str | None, typer.Option(help="The headline metric (default: the config's rank_by).")
    ] = None,
    plots: Annotated[bool, typer.Option(help="Draw the PNG plots.")] = True,
    allow_dirty: Annotated[
        bool,
        typer.Option(
            help="Accept records made from a tree with local changes (no commit reproduces "
            "them); their rows are marked."
        ),
    ] = False,
    reference: Annotated[
        str | None,
        typer.Option(help="The agent the aggregates compare with (default: feedforward)."),
    ] = None,
    readme: Annotated[
        Path | None,
        typer.Option(
            help="Also rewrite the leaderboard section of this README (between its "
            "'leaderboard:begin' and 'leaderboard:end' markers) from the new leaderboard.json."
        ),
    ] = None,
) -> None:
    """Build results/leaderboard.md, .json and .csv (ranked by the settled RMS; the start-up and
    the whole episode beside it; 95 % bootstrap intervals over episodes; which orderings the
    paired intervals resolve; aggregates against a reference; what each hidden effect costs; the
    compute budget), leaderboard_runs.csv (every run, its seed and commit), leaderboard_pairs.csv
    and the plots. Records from a tree with local changes are refused unless --allow-dirty."""
    from experiments.leaderboard import (
        analysis_cell,
        build_leaderboard,
        ordering_text,
        readme_block,
        to_json,
        update_readme,
        write_leaderboard,
    )
    from experiments.records import check_writable_dir

    with user_errors():
        check_writable_dir(out, "the leaderboard")
        board = build_leaderboard(
            runs_dir, rank_by=rank_by, allow_dirty=allow_dirty, reference=reference
        )
    command = command_line(
        "leaderboard",
        runs_dir,
        **{
            "--out": None if out == Path("results") else out,
            "--rank-by": rank_by,
            "--no-plots": not plots,
            "--allow-dirty": allow_dirty,
            "--reference": reference,
            "--readme": readme,
        },
    )
    paths = write_leaderboard(board, out, command=command, plots=plots)
    m = board.rank_by
    console.print(
        leaderboard_grid(
            board,
            f"{m}: geometric mean over episodes (bold: best contender; intervals in "
            f"{out / 'leaderboard.md'})",
            lambda r: analysis_cell(board, r, m, spread=False),
        )
    )
    for s in board.scenarios:
        console.print(f"{s}: {ordering_text(board.analysis, s)}", highlight=False)
    if board.failed:
        console.print(f"[red]{len(board.failed)} failed run(s)[/red] (listed in the markdown)")
    if readme is not None:
        with user_errors():
            update_readme(readme, readme_block(to_json(board, command)))
        console.print(f"updated the leaderboard section of {readme}", highlight=False)
    for p in paths.values():
        console.print(f"wrote {p}", highlight=False)


def reproduce(
    record: Annotated[
        Path,
        typer.Argument(
            help="A run record (runs/<config>/<run-key>.json) or a per-run summary "
            "(results/leaderboard_runs.csv)."
        ),
    ],
    rtol: Annotated[
        float,
        typer.Option(
            help="Relative tolerance of the comparison (0: exact, as on the machine that made "
            "the rows; 1e-6 on another CPU, which rounds differently: the learned policies "
            "infer in float64 and tests/test_policy_reproducibility.py keeps this promise). "
            "Above 0, an agent that declares a larger cross-CPU tolerance (the MPCs: "
            "results/perturbation.md) is compared within its own."
        ),
    ] = 0.0,
    run: Annotated[
        list[str] | None,
        typer.Option(
            "--run",
            help="A summary's row by run key (agent__scenario__epK for drawn seeds, agent__scenario__seedN for listed ones); repeatable.",
        ),
    ] = None,
    line: Annotated[
        list[int] | None,
        typer.Option("--line", help="A summary's row by its line in the file; repeatable."),
    ] = None,
    every: Annotated[bool, typer.Option("--all", help="Every row of the summary.")] = False,
    isolated: Annotated[
        bool,
        typer.Option(
            help="Rerun in an export of the row's commit even when this checkout is at it."
        ),
    ] = False,
) -> None:
    """Rerun a run and compare its metrics with the recorded ones.

    A record (JSON) is rerun with the code of this checkout. A row of a per-run summary (CSV) is
    rerun from the config and the commit it names: in this checkout when it is at that commit
    without local changes, else in an export of the commit (git archive) to a temporary
    directory. Rows made with local changes are refused."""
    from experiments.cli_output import fail

    if not (math.isfinite(rtol) and rtol >= 0):
        fail(f"--rtol: a relative tolerance must be >= 0, got {rtol:g}")
    if record.suffix.lower() == ".csv":
        _reproduce_rows(record, run or [], line or [], every, rtol, isolated)
        return
    from experiments.reproduce import row_rtol
    from experiments.sweep import build_record, execute_run, run_in_worker

    rec, spec = _rerunnable(record)
    _note_environment(rec)
    console.print(f"rerunning {spec.run_key} ({spec.agent} on {spec.scenario}, seed {spec.seed})")
    t0 = time.perf_counter()
    new = build_record(spec, run_in_worker(execute_run, spec.to_dict()))
    if new["status"] != "ok":
        err = new.get("error") or {}
        err_console.print(f"[red]the rerun failed:[/red] {err.get('traceback') or err}")
        raise typer.Exit(1)
    if rec.get("status") != "ok":
        console.print(
            f"the record is a failed run ({(rec.get('error') or {}).get('type')}); the rerun succeeded"
        )
    title = f"{spec.run_key}: recorded vs reproduced ({time.perf_counter() - t0:.1f} s)"
    own = row_rtol(rtol, spec.agent)
    if own > rtol:
        console.print(f"{spec.agent}: compared within its cross-CPU tolerance {own:g}")
    table, differ = _compared(rec, new, own, title)
    console.print(table)
    old_t, new_t = rec.get("timing") or {}, new.get("timing") or {}
    for k in ("wall_time_s", "solve_time_median_ms"):
        if k in old_t and k in new_t:
            console.print(
                f"timing {k}: recorded {_show(old_t[k])}, now {_show(new_t[k])} (not compared)"
            )
    if differ:
        err_console.print(f"[red]not reproduced:[/red] {', '.join(differ)} differ")
        raise typer.Exit(1)
    console.print("[green]reproduced:[/green] every metric and the error series are the same")


def _rerunnable(record: Path) -> tuple[dict[str, Any], Any]:
    """A record and its run's spec, refused where the spec cannot be rerun or the record was
    edited (its spec does not hash to its run_hash)."""
    from experiments.config import RunSpec, spec_problems
    from experiments.records import RecordError, load_record

    with user_errors():
        rec = load_record(record)
        spec = RunSpec.from_dict(rec["spec"])
        problems = spec_problems(spec)
        if problems:
            raise RecordError(f"{record}: cannot rerun: " + "; ".join(problems))
        if rec.get("run_hash") != spec.run_hash:
            raise RecordError(
                f"{record}: its spec hashes to {spec.run_hash}, not its run_hash "
                f"{rec.get('run_hash')!r}: the record was edited, it is not the run it names"
            )
    return rec, spec


def _note_environment(rec: Mapping[str, Any]) -> None:
    """Say where this checkout's versions and commit differ from the record's."""
    from experiments.records import environment_info

    here = environment_info()
    for key in ("versions", "git"):
        mine, theirs = here[key], rec.get(key) or {}
        for k in sorted(set(mine) | set(theirs)):
            if k == "dirty":
                continue
            if mine.get(k) != theirs.get(k):
                console.print(
                    f"[yellow]note:[/yellow] {key}.{k} was {theirs.get(k)}, is {mine.get(k)}",
                    highlight=False,
                )


def _compared(
    rec: Mapping[str, Any], new: Mapping[str, Any], rtol: float, title: str
) -> tuple[Table, list[str]]:
    """The recorded and the reproduced metrics side by side, and what differs (a metric, or the
    error series, report, calibration or episode beyond ``rtol``)."""
    from experiments.reproduce import same_value

    table = Table(title=title)
    for c in ("metric", "recorded", "reproduced", "difference", ""):
        table.add_column(c, justify="right" if c not in ("metric", "") else "left")
    differ = []
    old_m, new_m = rec.get("metrics") or {}, new.get("metrics") or {}
    for k in sorted(set(old_m) | set(new_m)):
        a, b = old_m.get(k), new_m.get(k)
        same = same_value(a, b, rtol)
        if not same:
            differ.append(k)
        diff = "" if a is None or b is None else f"{b - a:+.3g}"
        table.add_row(
            k, _show(a), _show(b), diff, "[green]same[/green]" if same else "[red]DIFFERS[/red]"
        )
    for k in ("series", "report", "calibration", "episode"):
        if rec.get(k) != new.get(k) and not _close_tree(rec.get(k), new.get(k), rtol):
            differ.append(k)
            table.add_row(k, "", "", "", "[red]DIFFERS[/red]")
    return table, differ


def _reproduce_rows(
    path: Path, runs: list[str], lines: list[int], every: bool, rtol: float, isolated: bool
) -> None:
    from experiments.reproduce import check_row, read_runs_csv, reproduce_rows, select_rows

    with user_errors():
        picked = select_rows(read_runs_csv(path), runs, lines, every, source=str(path))
        for i, row in picked:  # every row named is checked before any is rerun
            check_row(row, path, i)
        console.print(f"rerunning {len(picked)} row(s) of {path} from the commits they name...")
        t0 = time.perf_counter()
        with console.status("rerunning..."):
            outcomes = reproduce_rows(picked, path, rtol=rtol, isolated=isolated)
    table = Table(title=f"{path}: recorded vs reproduced ({time.perf_counter() - t0:.1f} s)")
    for c in ("run", "metric", "recorded", "reproduced", "difference", ""):
        table.add_column(
            c, justify="right" if c in ("recorded", "reproduced", "difference") else "left"
        )
    failed = []
    for o in outcomes:
        if o.error is not None:
            failed.append(o.run_key)
            table.add_row(o.run_key, "", "", "", "", f"[red]{o.error}[/red]")
            continue
        bad = o.differences()
        if bad:
            failed.append(o.run_key)
        for m, a in o.recorded.items():
            b = o.reproduced.get(m)
            diff = "" if a is None or b is None else f"{b - a:+.3g}"
            mark = "[red]DIFFERS[/red]" if m in bad else "[green]same[/green]"
            table.add_row(o.run_key, m, _show(a), _show(b), diff, mark)
        table.add_section()
    console.print(table)
    for o in outcomes:
        where = "not rerun" if o.where == "not rerun" else f"rerun in {o.where}"
        within = (
            f"; compared within {o.row['agent_name']}'s cross-CPU tolerance {o.rtol:g}"
            if o.rtol > rtol
            else ""
        )
        console.print(f"{o.run_key} (line {o.line}): {where}{within}", highlight=False)
    if failed:
        err_console.print(f"[red]not reproduced:[/red] {', '.join(failed)}", highlight=False)
        raise typer.Exit(1)
    console.print(f"[green]reproduced:[/green] every metric of {len(outcomes)} row(s) is the same")


def _show(v) -> str:
    return "–" if v is None else f"{v:.9g}" if isinstance(v, float) else str(v)


def _close_tree(a, b, rtol: float) -> bool:
    if rtol == 0:
        return a == b
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close_tree(a[k], b[k], rtol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close_tree(x, y, rtol) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=rtol)
    return a == b


def register(app: typer.Typer) -> None:
    """Mount this module's commands on the main app."""
    app.command("sweep")(sweep)
    app.command("leaderboard")(leaderboard)
    app.command("reproduce")(reproduce)
