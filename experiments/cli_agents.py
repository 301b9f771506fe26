"""``sixaxis train ppo --config FILE`` and ``sixaxis evaluate AGENT``: thin layers over
:mod:`agents.ppo` and :mod:`agents.runner`."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from experiments.cli_output import console, user_errors

train_app = typer.Typer(help="Train learning agents.", no_args_is_help=True)


@train_app.command("ppo")
def train_ppo(
    config: Annotated[
        Path, typer.Option("--config", "-c", help="A TOML file with a [ppo] table.")
    ] = Path("experiments/configs/ppo.toml"),
    timesteps: Annotated[
        int | None, typer.Option(help="Override total_timesteps (e.g. a short trial run).")
    ] = None,
    output: Annotated[Path | None, typer.Option(help="Override the output directory.")] = None,
    variant: Annotated[str | None, typer.Option(help="Override the variant.")] = None,
    ship: Annotated[
        bool,
        typer.Option(help="Copy the best policy into agents/policies/ when training ends."),
    ] = False,
    resume: Annotated[
        Path | None,
        typer.Option(help="Continue a previous run's final policy for --timesteps more steps."),
    ] = None,
) -> None:
    """Train PPO on SixAxisTrack-v0: checkpoints, evaluations and CSV logs in the output dir."""
    from agents.ppo import load_config, ship_policy, train

    with user_errors():
        cfg = load_config(config)
    if timesteps is not None:
        cfg.total_timesteps = int(timesteps)
    if output is not None:
        cfg.output = str(output)
    if variant is not None:
        cfg.variant = variant
        cfg.__post_init__()
    console.print(
        f"training PPO ({cfg.variant}) for {cfg.total_timesteps:,} steps on "
        f"{', '.join(sorted(set(cfg.scenarios)))}; logs in {cfg.output}"
    )
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    t0 = time.perf_counter()
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
    ) as bar:
        job = bar.add_task("steps", total=cfg.total_timesteps)
        start = [None]

        def update(n, total):
            start[0] = n if start[0] is None else start[0]
            bar.update(job, completed=n - start[0])

        out = train(cfg, progress=update, resume=resume)
    console.print(f"done in {time.perf_counter() - t0:.0f} s: {out / 'model.zip'}")
    if ship:
        dst = ship_policy(out, cfg.variant)
        console.print(f"shipped {dst} ({dst.stat().st_size / 1024:.0f} KB)")


@train_app.command("ship")
def ship(
    run: Annotated[Path, typer.Argument(help="A training output directory (runs/ppo-...).")],
    variant: Annotated[str, typer.Option(help="residual or plain.")] = "residual",
    which: Annotated[str, typer.Option(help="best, final, or a checkpoint's step count.")] = "best",
) -> None:
    """Copy a trained policy into agents/policies/ and record its deterministic leaderboard
    evaluation next to it (ppo-<variant>.json)."""
    from agents.ppo import ship_policy

    with console.status("evaluating the policy on the leaderboard's episodes..."):
        dst = ship_policy(run, variant, which)
    meta = json.loads(dst.with_suffix(".json").read_text())
    console.print(f"shipped {dst} ({dst.stat().st_size / 1024:.0f} KB)")
    for sc, v in meta["leaderboard"]["rms_mm"].items():
        console.print(f"  {sc:13s} {v:.4f} mm")


EVALUATE_METRICS = (
    "rms_mm",
    "rms_settled_mm",
    "converge_s",
    "max_settled_mm",
    "diverged",
    "solve_time_median_ms",
)


def evaluate(
    agent: Annotated[str, typer.Argument(help="An agent name or package.module:Class.")],
    scenario: Annotated[list[str], typer.Option(help="Scenario(s).")] = ["geometric"],  # noqa: B006
    seeds: Annotated[int, typer.Option(help="Seeds 0..N-1.")] = 3,
    settings: Annotated[
        str, typer.Option(help="Agent settings as JSON, e.g. '{\"horizon\": 15}'.")
    ] = "{}",
    settle: Annotated[
        float, typer.Option(help="The settled metrics count after this many seconds.")
    ] = 2.0,
    converge_mm: Annotated[
        float, typer.Option(help="converge_s: when the true error stays below this, mm.")
    ] = 0.25,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Run an agent on seeded episodes and print its tracking error (mm, true tool point): over
    the whole episode, after the settling time, and when it converged (as the leaderboard)."""
    from agents.registry import make_agent
    from agents.runner import run_episode
    from experiments.metrics import episode_metrics
    from experiments.records import jsonable

    with user_errors(json.JSONDecodeError):
        kw = json.loads(settings)
        make_agent(agent, **kw)
    rows = []
    with console.status("running episodes...") as status:
        for sc in scenario:
            for s in range(seeds):
                status.update(f"{agent} on {sc}, seed {s}")
                r = run_episode(make_agent(agent, **kw), {"scenario": sc}, seed=s)
                m, timing = episode_metrics(
                    r,
                    EVALUATE_METRICS,
                    settle_seconds=settle,
                    converge_mm=converge_mm,
                )
                rows.append({"scenario": sc, "seed": s} | m | timing)
    if as_json:
        print(json.dumps(jsonable(rows), indent=2))  # NaN (e.g. never converged) as null
        return
    table = Table(
        title=f"{agent} {kw or ''}: settled after {settle:g} s, converged below {converge_mm:g} mm"
    )
    for k in rows[0]:
        table.add_column(k)
    for row in rows:
        cells = []
        for k, v in row.items():
            if k == "converge_s" and row.get("never_converged") == 1.0:
                cells.append("never")
            else:
                cells.append(f"{v:.4f}" if isinstance(v, float) else str(v))
        table.add_row(*cells)
    console.print(table)


def render(
    agent: Annotated[str, typer.Argument(help="An agent name or package.module:Class.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="The video file (MP4).")] = Path(
        "run.mp4"
    ),
    scenario: Annotated[str, typer.Option(help="The scenario.")] = "geometric",
    seed: Annotated[int, typer.Option(help="The episode's seed.")] = 0,
    seconds: Annotated[float, typer.Option(help="Episode length, s.")] = 10.0,
    every: Annotated[
        int, typer.Option(help="One frame every N control steps (50 / N frames per second).")
    ] = 1,
    width: Annotated[int, typer.Option(help="Frame width, pixels (even).")] = 640,
    height: Annotated[int, typer.Option(help="Frame height, pixels (even).")] = 480,
    settings: Annotated[
        str, typer.Option(help="Agent settings as JSON, e.g. '{\"horizon\": 15}'.")
    ] = "{}",
    trajectory: Annotated[
        str | None, typer.Option(help="circle, lemniscate, lines or spline (default: drawn).")
    ] = None,
) -> None:
    """Write a video of AGENT's episode: the arm, the reference path (green), the true tool path
    (blue) and the tracker's measured points (red), in real time."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    from agents.registry import make_agent
    from experiments.video import render_episode

    with user_errors(json.JSONDecodeError):
        a = make_agent(agent, **json.loads(settings))
    env = {} if trajectory is None else {"trajectory": trajectory}
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
    ) as bar:
        job = bar.add_task(f"{agent} on {scenario}, seed {seed}", total=None)
        with user_errors():
            info = render_episode(
                a,
                scenario,
                seed,
                output,
                seconds=seconds,
                every=every,
                width=width,
                height=height,
                env_kwargs=env,
                progress=lambda n, total: bar.update(job, completed=n, total=total),
            )
    console.print(
        f"wrote {info.path}: {info.frames} frames, {info.seconds:.2f} s at {info.fps:g} fps, "
        f"{info.width}x{info.height}",
        highlight=False,
    )


def register(app: typer.Typer) -> None:
    """Mount this module's commands on the main app."""
    app.add_typer(train_app, name="train")
    app.command("evaluate")(evaluate)
    app.command("render")(render)
