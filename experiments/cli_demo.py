"""``sixaxis demo``: the whole story on built-in defaults, what ``make demo`` runs.

1. The lab's loop: the simulated MuJoCo arm, with elastic joints that it does not advertise,
   is measured like a laser-tracker campaign; the geometric-only calibration leaves an error well
   above the noise floor; the diagnosis names the missing effect; the fit with it brings the
   held-out error down to the floor.
2. The quick benchmark sweep and its leaderboard.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer
from rich.panel import Panel
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from experiments.cli_output import console, fail, p_value_text

NOISE_MM = 0.015  # per axis, a good laser tracker


def _collect(n: int, scenario: str, seed: int, truth, label: str):
    from envs.collect import collect_measurements

    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task(label, total=n)
        return collect_measurements(
            truth=truth,
            n=n,
            scenario=scenario,
            noise_mm=NOISE_MM,
            seed=seed,
            progress=lambda i, _n: bar.update(task, completed=i),
        )


def lab_story(
    scenario: str = "compliance", n: int = 200, seed: int = 7, out: Path | None = None
) -> dict:
    """Run the lab's loop on a simulated campaign; returns the numbers it printed."""
    import numpy as np

    from arm.description import seed_robot
    from envs.scenarios import draw_truth
    from lab import diagnose, fit, screen

    # one arm, measured twice: the calibration campaign and a held-out one
    truth = draw_truth(scenario, seed_robot(), np.random.default_rng(seed))
    console.rule(
        f"[bold]1. The model lab: an arm with a hidden effect ({n} poses, tracker noise {NOISE_MM * 1e3:.0f} µm)"
    )
    train = _collect(n, scenario, seed, truth, "measuring the calibration poses")
    held_out = _collect(n // 2, scenario, seed + 1000, truth, "measuring held-out poses")
    if out is not None:
        from arm.files import make_folders
        from arm.measurements import write_measurements

        make_folders(out)
        write_measurements(train, out / "calibration.csv")
        write_measurements(held_out, out / "validation.csv")
        console.print(f"data written to {out}/calibration.csv and {out}/validation.csv")

    floor = NOISE_MM * math.sqrt(3.0)
    rows = screen(train, "seed", "geometric", noise_mm=NOISE_MM)  # which rows count, once
    geo = fit(rows, validate=held_out)
    d = diagnose(rows)  # tests what this fit misses, no refit
    suggestion = d.suggestion or "geometric"
    full = fit(train, "seed", suggestion, validate=held_out)

    table = Table(title="calibration of the simulated arm (3-D errors, mm)", title_justify="left")
    table.add_column("model")
    table.add_column("train RMS", justify="right")
    table.add_column("held-out RMS", justify="right")
    table.add_column("held-out / noise floor", justify="right")
    table.add_row("nominal (uncalibrated)", f"{1e3 * geo.initial_rms:.3f}", "", "")
    for name, r in (("geometric", geo), (suggestion, full)):
        held = r.validation_rms_mm
        assert held is not None  # both fits were validated on the held-out poses
        table.add_row(name, f"{r.rms_mm:.4f}", f"{held:.4f}", f"{held / floor:.2f}x")
    console.print(table)

    diag = Table(
        title=f"diagnosis of the geometric model: verdict [bold]{d.verdict}[/]",
        title_justify="left",
    )
    diag.add_column("candidate")
    diag.add_column("RMS after adding (mm)", justify="right")
    diag.add_column("p-value", justify="right")
    diag.add_column("significant")
    for c in d.candidates[:5]:
        diag.add_row(
            c.label, f"{c.rms_mm:.4f}", p_value_text(c.p_value), "yes" if c.significant else "no"
        )
    console.print(diag)
    console.print(
        "where the geometric model fails (residual explained by each measured variable): "
        + ", ".join(f"{h.variable} {h.score:.2f}" for h in d.hints[:5])
    )
    console.print(
        Panel.fit(
            f"The plant's hidden effect was [bold]{scenario}[/]; the lab's verdict is "
            f"[bold]{d.verdict}[/].\nHeld-out error: geometric {geo.validation_rms_mm:.4f} mm -> "
            f"{suggestion} {full.validation_rms_mm:.4f} mm (noise floor {floor:.4f} mm).",
            title="the error falls",
        )
    )
    return {
        "verdict": d.verdict,
        "suggestion": suggestion,
        "geometric_validation_rms_mm": geo.validation_rms_mm,
        "full_validation_rms_mm": full.validation_rms_mm,
        "noise_floor_mm": floor,
    }


def register(app: typer.Typer) -> None:
    """Mount ``sixaxis demo`` on the main app."""

    @app.command()
    def demo(
        scenario: Annotated[
            str, typer.Option(help="The hidden effect of the simulated arm.")
        ] = "compliance",
        poses: Annotated[int, typer.Option(help="Calibration poses to measure.")] = 200,
        seed: Annotated[int, typer.Option(help="Seed of the simulated arm and campaign.")] = 7,
        out: Annotated[Path, typer.Option(help="Where the demo writes its data and runs.")] = Path(
            "runs/demo"
        ),
        sweep: Annotated[
            bool, typer.Option(help="Run the quick benchmark sweep after the lab.")
        ] = True,
    ) -> None:
        """The lab's loop on a simulated arm with a hidden effect, then the quick benchmark."""
        from envs.scenarios import SCENARIOS

        if scenario not in SCENARIOS:
            fail(f"--scenario: unknown scenario {scenario!r}; known: " + ", ".join(SCENARIOS))
        lab_story(scenario, poses, seed, out)
        if sweep:
            _quick_sweep(out)


def _quick_sweep(out: Path) -> None:
    console.rule("[bold]2. The benchmark: controllers on SixAxisTrack-v0 (quick sweep)")
    from experiments.cli_sweep import leaderboard, sweep

    config = Path(__file__).resolve().parent / "configs" / "quick.toml"
    sweep(config, out=out / "quick")  # resumes: a second demo reruns nothing
    # the demo runs from whatever tree it is in: its table is a demonstration, marked if dirty
    leaderboard(out / "quick", out=out / "leaderboard", allow_dirty=True)
