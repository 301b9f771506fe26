"""``sixaxis train ppo|sac|td3 --config FILE``, ``sixaxis train ship RUN``, ``sixaxis evaluate
AGENT`` and ``sixaxis render AGENT``: thin layers over :mod:`agents.training` and
:mod:`agents.runner`."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from arm.constraints import declare
from experiments.cli_inputs import option_of
from experiments.cli_output import console, fail, user_errors

train_app = typer.Typer(help="Train learning agents.", no_args_is_help=True)


def _train(
    algo: str,
    config: Path | None,
    seed: int | None,
    timesteps: int | None,
    output: Path | None,
    ship: bool,
    resume: bool,
    stop_at: int | None = None,
    diagnostics: Path | None = None,
) -> None:
    from agents.training import load_train_config, ship_policy, train

    config = config or Path(f"experiments/configs/{algo}-residual.toml")
    with user_errors():
        cfg = load_train_config(
            config,
            seed=seed,
            total_timesteps=timesteps,
            output=None if output is None else str(output),
        )
    if cfg.algo != algo:
        fail(f"{config}: [train] algo is {cfg.algo!r}; use `sixaxis train {cfg.algo}`")
    console.print(
        f"training {algo.upper()} ({cfg.variant}, seed {cfg.seed}) for {cfg.total_timesteps:,} "
        f"steps on {', '.join(cfg.scenarios_unique())}; records in {cfg.output}"
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

        def update(n: int, total: int) -> None:
            bar.update(job, completed=n)

        with user_errors():
            out = train(
                cfg, progress=update, resume=resume, stop_at=stop_at, diagnostics=diagnostics
            )
    console.print(f"done in {time.perf_counter() - t0:.0f} s: {out}")
    if diagnostics is not None:
        console.print(f"SB3's diagnostics: {diagnostics / 'progress.csv'}")
    if ship:
        with console.status("evaluating the policy on the leaderboard's episodes..."):
            dst = ship_policy(out)
        console.print(f"shipped {dst} ({dst.stat().st_size / 1024:.0f} KB)")


_CONFIG_HELP = (
    "A TOML file with a [train] table (default: experiments/configs/<algo>-residual.toml)."
)


@dataclass(frozen=True)
class TrainInputs:
    """What ``sixaxis train ppo|sac|td3`` takes beside its config, each declared once
    (:func:`arm.constraints.declare`; the option made from it by
    :func:`~experiments.cli_inputs.option_of`)."""

    diagnostics: Path | None = declare(
        None,
        help="A folder for stable-baselines3's own logger: progress.csv of its standard scalars "
        "(PPO's KL, clip fraction, entropy, explained variance, losses; SAC's and TD3's losses), "
        "and TensorBoard event files where the tensorboard package is installed.",
        metavar="DIR",
    )


TRAIN_INPUTS = TrainInputs()
_RESUME_HELP = (
    "Continue the run in the output directory from its last checkpoint (SB3's own save, which "
    "unpickles: resume only runs you made)."
)


def _make_train_command(algo: str) -> None:
    @train_app.command(algo)
    def command(
        config: Annotated[Path | None, typer.Option("--config", "-c", help=_CONFIG_HELP)] = None,
        seed: Annotated[
            int | None,
            typer.Option(help="The training seed (network, exploration, episode seeds)."),
        ] = None,
        timesteps: Annotated[
            int | None, typer.Option(help="Override total_timesteps (e.g. a short trial run).")
        ] = None,
        output: Annotated[Path | None, typer.Option(help="Override the output directory.")] = None,
        ship: Annotated[
            bool,
            typer.Option(help="Copy the best policy into agents/policies/ when training ends."),
        ] = False,
        resume: Annotated[bool, typer.Option(help=_RESUME_HELP)] = False,
        stop_at: Annotated[
            int | None,
            typer.Option(
                min=1,
                help="Stop at this many steps (checkpoint written; --resume goes on), the "
                "config's total_timesteps unchanged.",
            ),
        ] = None,
        diagnostics: Annotated[
            Path | None, option_of(TrainInputs, "diagnostics")
        ] = TRAIN_INPUTS.diagnostics,
    ) -> None:
        _train(algo, config, seed, timesteps, output, ship, resume, stop_at, diagnostics)

    command.__doc__ = (
        f"Train {algo.upper()} (stable-baselines3) on SixAxisTrack-v0: evaluations (curve.csv), "
        "checkpoints and the policy (best.npz, final.npz) in the output directory."
    )


for _algo in ("ppo", "sac", "td3"):
    _make_train_command(_algo)


@train_app.command("ship")
def ship(
    run: Annotated[Path, typer.Argument(help="A training output directory (runs/...).")],
    which: Annotated[str, typer.Option(help="best or final.")] = "best",
    name: Annotated[
        str | None, typer.Option(help="The agent's name (default: the run's config name).")
    ] = None,
) -> None:
    """Copy a trained policy (.npz weights and .json) into agents/policies/ and record its
    deterministic leaderboard evaluation in the .json."""
    from agents.training import ship_policy

    with (
        user_errors(ValueError),
        console.status("evaluating the policy on the leaderboard's episodes..."),
    ):
        dst = ship_policy(run, which, name)
    meta = json.loads(dst.with_suffix(".json").read_text())
    console.print(f"shipped {dst} ({dst.stat().st_size / 1024:.0f} KB)")
    for sc, v in meta["leaderboard"]["episodes"].items():
        console.print(
            f"  {sc:13s} settled {sum(v['rms_settled_mm']) / len(v['rms_settled_mm']):.4f} mm"
        )


@train_app.command("record")
def record(
    names: Annotated[
        list[str] | None,
        typer.Argument(help="Shipped policies to re-evaluate (default: every one shipped)."),
    ] = None,
) -> None:
    """Evaluate shipped policies again on the public episodes and rewrite the evaluation their
    .json records (the weights are not touched), naming this checkout's commit, which must be
    clean."""
    from agents.policy import POLICY_DIR
    from agents.training import rerecord_policy
    from experiments.records import git_state

    state = git_state()
    if state["dirty"] or state["commit"] is None:
        raise typer.BadParameter(
            "commit your changes first: a policy's record names the clean commit that made it"
        )
    chosen = names or sorted(p.stem for p in POLICY_DIR.glob("*.npz"))
    for name in chosen:
        with user_errors(ValueError), console.status(f"evaluating {name}..."):
            dst = rerecord_policy(name, commit=state["commit"])
        console.print(f"recorded {dst.with_suffix('.json')} at {state['commit'][:10]}")


#: what ``evaluate`` reports: the leaderboard's three tracking metrics by the leaderboard's names
#: (``rms_settled_mm`` the ranking, ``rms_startup_mm`` the first second, ``rms_mm`` the whole
#: episode), the worst settled error, divergence and the agent's time per step
EVALUATE_METRICS = (
    "rms_settled_mm",
    "rms_startup_mm",
    "rms_mm",
    "max_settled_mm",
    "diverged",
    "solve_time_median_ms",
)
#: the table's column headers (the leaderboard's words: settled, start-up, whole)
EVALUATE_HEADERS = {
    "scenario": "scenario",
    "seed": "seed",
    "rms_settled_mm": "settled",
    "rms_startup_mm": "start-up",
    "rms_mm": "whole",
    "max_settled_mm": "max settled",
    "solve_time_median_ms": "ms/step",
}


def _evaluate_one(agent: str, settings: dict, scenario: str, seed: int, seconds: float):
    """One episode of ``agent``; a class path runs in a process of its own, as in a sweep."""
    from agents.registry import make_agent
    from agents.runner import run_episode

    env = {"scenario": scenario}
    if ":" not in agent:
        return run_episode(make_agent(agent, **settings), env, seed=seed, episode_seconds=seconds)
    from agents.isolation import IsolatedAgent

    with IsolatedAgent(agent, settings) as isolated:
        return run_episode(isolated, env, seed=seed, episode_seconds=seconds)


def evaluate(
    agent: Annotated[
        str,
        typer.Argument(
            help="An agent name, or package.module:Class (imports that module: its code runs)."
        ),
    ],
    scenario: Annotated[list[str], typer.Option(help="Scenario(s).")] = ["geometric"],  # noqa: B006
    seeds: Annotated[int, typer.Option(min=1, help="Seeds 0..N-1.")] = 3,
    settings: Annotated[
        str, typer.Option(help="Agent settings as JSON, e.g. '{\"horizon\": 15}'.")
    ] = "{}",
    episode_seconds: Annotated[
        float | None,
        typer.Option(help="The episode's length, s (default: the env's, 10 s)."),
    ] = None,
    settle: Annotated[
        float,
        typer.Option(
            min=0.0, help="The settled metrics count after this many seconds (< the episode)."
        ),
    ] = 2.0,
    output: Annotated[
        Path | None,
        typer.Option(
            "--output", "-o", help="Also write the rows to this file: .json, or .csv (one a line)."
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Run an agent on seeded episodes and print its true tracking error (mm) as the leaderboard
    names it: settled (after the settling time: the ranking), start-up (the first second) and
    whole (the episode), with the worst settled error and the time per step."""
    from arm.errors import SixAxisError
    from experiments.metrics import episode_metrics
    from experiments.records import jsonable

    kw = _agent_settings(agent, settings)
    known = _scenarios()
    for sc in scenario:
        if sc not in known:
            fail(f"--scenario: unknown scenario {sc!r}; known: {', '.join(known)}")
    episode_s = _episode_seconds() if episode_seconds is None else float(episode_seconds)
    if not (math.isfinite(episode_s) and episode_s >= 0.02):
        fail(f"--episode-seconds: expected at least one control step (0.02 s), got {episode_s:g}")
    if not settle < episode_s:
        fail(f"--settle: {settle:g} s leaves nothing of the {episode_s:g} s episode to measure")
    if output is not None:
        if output.suffix not in (".json", ".csv"):
            fail(f"--output {output}: write the rows as .json or .csv")
        from arm.files import check_output

        with user_errors():
            check_output(output, stdout_ok=False)
    rows = []
    with console.status("running episodes...") as status:
        for sc in scenario:
            for s in range(seeds):
                status.update(f"{agent} on {sc}, seed {s}")
                try:
                    r = _evaluate_one(agent, kw, sc, s, episode_s)
                except SixAxisError as exc:  # refused on purpose, or the agent failed: say why
                    status.stop()
                    fail(f"{agent} on {sc}, seed {s}: {exc}")
                m, timing = episode_metrics(r, EVALUATE_METRICS, settle_seconds=settle)
                rows.append({"scenario": sc, "seed": s} | m | timing)
    if output is not None:
        _write_rows(output, rows)
    if as_json:
        print(json.dumps(jsonable(rows), indent=2))
        return
    console.print(_evaluate_table(agent, kw, rows, settle, episode_s))
    diverged = [f"{r['scenario']} seed {r['seed']}" for r in rows if r["diverged"] == 1.0]
    if diverged:
        console.print(f"diverged: {', '.join(diverged)}", highlight=False)
    if output is not None:
        console.print(f"wrote {len(rows)} rows to {output}", highlight=False)


def _evaluate_table(agent: str, kw: dict, rows: list[dict], settle: float, episode_s: float):
    """The rows as a table that fits 80 columns, with the mean over seeds of each scenario."""
    from rich import box

    table = Table(
        title=f"{agent} {json.dumps(kw) if kw else ''}\ntrue tracking RMS (mm): settled after "
        f"{settle:g} s, start-up 0-1 s, whole 0-{episode_s:g} s",
        box=box.SIMPLE_HEAD,
        pad_edge=False,
    )
    for k, header in EVALUATE_HEADERS.items():
        table.add_column(header, justify="left" if k == "scenario" else "right", no_wrap=True)

    def cells(row: dict) -> list[str]:
        out = []
        for k in EVALUATE_HEADERS:
            v = row.get(k, "")
            if k == "solve_time_median_ms":
                out.append(f"{v:.2f}" if isinstance(v, float) else str(v))
            else:
                out.append(f"{v:.4f}" if isinstance(v, float) else str(v))
        return out

    for sc in dict.fromkeys(r["scenario"] for r in rows):
        mine = [r for r in rows if r["scenario"] == sc]
        for row in mine:
            table.add_row(*cells(row))
        if len(mine) > 1:
            mean = {k: float(np.nanmean([r[k] for r in mine])) for k in EVALUATE_METRICS}
            table.add_row(*cells({"scenario": sc, "seed": "mean"} | mean), style="bold")
            table.add_section()
    return table


def _write_rows(path: Path, rows: list[dict]) -> None:
    """``evaluate``'s rows as JSON (a list of objects) or CSV, atomically."""
    import csv
    import io

    from arm.files import atomic_write_text
    from experiments.records import jsonable

    if path.suffix == ".json":
        text = json.dumps(jsonable(rows), indent=2) + "\n"
    else:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
        text = buf.getvalue()
    with user_errors():
        atomic_write_text(path, text)


def render(
    agent: Annotated[str, typer.Argument(help="An agent name or package.module:Class.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="The video file (MP4).")] = Path(
        "run.mp4"
    ),
    scenario: Annotated[str, typer.Option(help="The scenario.")] = "geometric",
    seed: Annotated[int, typer.Option(help="The episode's seed.")] = 0,
    seconds: Annotated[
        float,
        typer.Option(
            "--episode-seconds",
            "--seconds",
            help="The episode's length, s (the name evaluate and sweep configs use).",
        ),
    ] = 10.0,
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
    from arm.files import check_output
    from experiments.video import render_episode

    if output.suffix.lower() != ".mp4":
        fail(f"--output {output}: the video is written as MP4; give a file ending in .mp4")
    with user_errors():
        check_output(output, stdout_ok=False)
    a = make_agent(agent, **_agent_settings(agent, settings))
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


def _agent_settings(agent: str, settings: str) -> dict:
    """``--settings`` as a dict the agent takes (it is made once to check), or a one-line error."""
    from agents.registry import AgentError, make_agent

    try:
        kw = json.loads(settings)
    except json.JSONDecodeError as exc:
        fail(f"--settings: not JSON: {exc}")
    if not isinstance(kw, dict):
        fail(f"--settings: expected a JSON object of name: value, got {settings!r}")
    try:
        make_agent(agent, **kw)
    except AgentError as exc:
        fail(str(exc))
    except (TypeError, ValueError) as exc:  # a setting the agent itself refuses
        fail(f"--settings: agent {agent!r} refuses {kw}: {exc}")
    return kw


def _scenarios() -> tuple[str, ...]:
    from envs.scenarios import SCENARIOS

    return tuple(SCENARIOS)


def _episode_seconds() -> float:
    """The length of ``evaluate``'s episodes: SixAxisTrack-v0's default ``episode_seconds``
    (its TimeLimit follows it)."""
    import inspect

    from envs.sixaxis_track_v0 import SixAxisTrackEnv

    return float(inspect.signature(SixAxisTrackEnv).parameters["episode_seconds"].default)


def agents() -> None:
    """List the registered agents: name, class and what each is."""
    from agents.registry import AGENTS
    from experiments.cli_output import agents_table

    console.print(agents_table(list(AGENTS.values())))


def register(app: typer.Typer) -> None:
    """Mount this module's commands on the main app."""
    app.command("agents")(agents)
    app.add_typer(train_app, name="train")
    app.command("evaluate")(evaluate)
    app.command("render")(render)
