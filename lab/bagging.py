"""One calibration from many draws of the poses: the lab's path (screen, diagnose, discover, fit)
run on each draw, and the models averaged (bagging, Breiman 1996).

    bag = lab.bag("sessions.csv", "ur10_robot", bags=10, poses=1000, noise_mm=0.015)
    bag.result             # a FitResult: validate, export, compensate it as any fit
    bag.write_module("bagged.py")   # the discovered terms of every draw, one effect module
    bag.effects            # what it fitted: the union of the draws' effects

Which terms the diagnosis and the discovery keep depends on which poses a campaign happened to
measure: on the UR10's three sessions, drawing another 1,000 poses per series moved the
held-out RMS of a left-out session by up to 0.1 mm (``results/real_data.md``). An average of
models chosen on different draws keeps what they share and shrinks what one draw alone took
up, which is the variance of the selection. Each draw takes at most ``poses`` poses of each
block (the ``session``, else ``station``, column; the whole set is one block without either), so
that a session of 12,000 poses does not outweigh one of 600 as if its poses were independent
evidence: the poses of one session share its errors (its tracker station, its temperature, its
region of the workspace), and over the draws the bag still sees most of them.

The average is one model of the union of the draws' effects: a cyclic order or a joint's
effect that a draw did not choose counts as zero there, and the discovered terms of every
draw join in one discovered effect. Its parameters are the means of the draws' parameters by
name, held; only each station's base is fitted again on the whole data, so that the result
stands where the data do. Outside the fitted domain (:mod:`lab.domain`) the terms that do not
hold are left out as for any fit, by the mean of the draws' fits without them.
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Unpack

import numpy as np

from arm.description import RobotDescription, as_robot
from arm.effects import parse_effects, union_of
from arm.errors import warn
from arm.measurements import MeasurementSet, as_measurements
from arm.params import parse_parameter_name
from lab.diagnosis import diagnose
from lab.discovery import Discovery, discover
from lab.errors import FitError, LabWarning
from lab.estimation import model_of
from lab.identification import fit
from lab.options import LabOptions, OptionFields, resolve
from lab.result import FitResult
from lab.screening import screen
from lab.transfer import block_column

__all__ = ["Bag", "bag", "union_effects"]

log = logging.getLogger(__name__)

#: draws of the poses, and the poses each draw takes of a session (or station) at most
BAGS = 10
POSES = 1000


def union_effects(specs: Sequence[str]) -> str:
    """The union of effects strings, in the order first met, each effect as its label writes it:
    ``compliance[2]`` and ``compliance[3]`` give ``compliance[2,3]``, the orders of ``cyclic``
    are joined per joint (runs of three or more as ranges)."""
    return ",".join(e.label for e in union_of(e for spec in specs for e in parse_effects(spec)))


@dataclass
class Draw:
    """One draw's path: its rows (indices into the data), what the diagnosis chose, what the
    discovery found, and the fit of both."""

    rows: np.ndarray
    choice: str
    discovery: Discovery | None
    result: FitResult


@dataclass
class Bag:
    """What :func:`bag` made: ``result``, the averaged model; ``effects``, its catalogue effects
    (a string) and ``discovered``, the discovered terms of every draw as one effect (None when
    no draw found any); ``draws``, each draw's path; ``refused``, the draws whose path the lab
    refused (a fit beyond the plausible bounds on those poses), left out of the mean."""

    result: FitResult
    effects: str
    discovered: Discovery | None
    draws: list[Draw] = field(repr=False)
    # the draws whose path the lab refused (at most half), each with why: left out of the mean
    refused: list[str] = field(default_factory=list)

    @property
    def suggestion(self) -> str:
        """The ``--effects`` string of the averaged model (with the discovered effect's name)."""
        if self.discovered is None:
            return self.effects
        return f"{self.effects},{self.discovered.effect_name}"

    @property
    def bags(self) -> int:
        """The draws made (the mean's and the refused)."""
        return len(self.draws) + len(self.refused)

    def write_module(self, path: str | Path) -> Path:
        """The discovered effect's module, as :meth:`lab.Discovery.write_module` writes it."""
        if self.discovered is None:
            raise FitError("no draw discovered a term: there is no effect module to write")
        return self.discovered.write_module(path)


def _draw_rows(data: MeasurementSet, poses: int, rng: np.random.Generator) -> np.ndarray:
    col = block_column(data)
    ids = data.columns[col] if col is not None else np.zeros(len(data))
    rows = []
    for b in np.unique(ids):
        idx = np.flatnonzero(ids == b)
        rows.append(idx if len(idx) <= poses else rng.choice(idx, poses, replace=False))
    return np.sort(np.concatenate(rows))


def _path(
    data: MeasurementSet, robot: RobotDescription, opts: LabOptions, name: str
) -> tuple[str, Discovery | None, FitResult]:
    """The lab's path on one draw: the diagnosis's choice, then the discovery on top of it."""
    s = screen(data, robot, "geometric", options=opts)
    choice = diagnose(s).suggestion or "geometric"
    try:
        disc = discover(data, robot, choice, options=opts, name=name)
    except FitError as exc:  # on top of the choice it failed: from geometric, as the CLI says
        log.info("draw %s: discover --effects %s refused (%s); from geometric", name, choice, exc)
        choice = "geometric"
        disc = discover(s, name=name)
    if disc.terms and disc.suggestion:
        effects = [*parse_effects(choice), disc.effect_class()()]
        return choice, disc, fit(data, robot, effects, options=opts)
    return choice, None, fit(data, robot, choice, options=opts)


def _values(res: FitResult, params: np.ndarray | None = None) -> dict[str, float]:
    p = res.params if params is None else params
    return dict(zip(res.model.layout.names, map(float, p), strict=True))


def _mean(values: list[dict[str, float]], names: Sequence[str]) -> dict[str, float]:
    """Each name's mean over the draws; a draw without it (an effect it did not choose) counts
    zero, except the base and tool, which every draw has."""
    return {n: float(np.mean([v.get(n, 0.0) for v in values])) for n in names}


@contextlib.contextmanager
def _quiet_draws() -> Iterator[None]:
    """The lab's log records below errors silenced, but this module's: a draw's cautions (a poor
    pose set, that draw's outliers) are not the calibration's; its fit on the whole gives
    those once."""
    lab_log = logging.getLogger("lab")
    level, own = lab_log.level, log.level
    log.setLevel(log.getEffectiveLevel())
    lab_log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        lab_log.setLevel(level)
        log.setLevel(own)


def bag(
    data: MeasurementSet | str | Path,
    robot: RobotDescription | str | Path | None = None,
    *,
    bags: int = BAGS,
    poses: int = POSES,
    seed: int = 0,
    name: str = "bagged",
    options: LabOptions | None = None,
    **keywords: Unpack[OptionFields],
) -> Bag:
    """The lab's path on ``bags`` draws of at most ``poses`` poses per session (or station),
    and their models averaged (the module docstring). ``seed`` draws the poses; ``name`` is the
    discovered effect's; the options are :class:`lab.LabOptions`."""
    if not (isinstance(bags, int) and bags >= 1):
        raise FitError(f"bags must be an integer >= 1, got {bags!r}")
    if not (isinstance(poses, int) and poses >= 12):
        raise FitError(f"poses (per session) must be an integer >= 12, got {poses!r}")
    opts = resolve(options, **keywords)
    data, robot = as_measurements(data), as_robot(robot)
    col = block_column(data)
    largest = np.unique(data.columns[col], return_counts=True)[1].max() if col else len(data)
    if bags > 1 and largest <= poses:  # each draw takes every pose: one path, the same
        where = f"every {col}" if col else "the data (one session)"
        text = (
            f"{data.source}: {where} has at most {poses} poses: every draw would take all of "
            f"them, the same path; one path, not {bags} draws (fewer poses per draw, "
            "poses= or --poses, make the draws differ)"
        )
        log.warning("%s", text)
        warn(text, LabWarning)
        bags = 1
    rng = np.random.default_rng(seed)
    draws: list[Draw] = []
    refused: list[str] = []
    for k in range(bags):
        rows = _draw_rows(data, poses, rng)
        with warnings.catch_warnings(), _quiet_draws():
            warnings.simplefilter("ignore", LabWarning)  # each draw's cautions: the whole's below
            try:
                choice, disc, res = _path(data.subset(rows), robot, opts, f"{name}_{k}")
            except FitError as exc:  # this draw's path refused: the others average without it
                refused.append(f"draw {k + 1} of {bags} ({len(rows)} poses): {exc}")
                log.warning("%s; left out of the average", refused[-1])
                continue
        draws.append(Draw(rows, choice, disc, res))
        log.info("draw %d of %d: %s", k + 1, bags, res.effects)
    if len(refused) * 2 > bags:
        raise FitError(
            f"{len(refused)} of {bags} draws refused, the first: {refused[0]}; a draw of more "
            "poses per session (poses=, --poses) identifies more"
        )
    effects = union_effects([d.choice for d in draws])
    found = [d.discovery for d in draws if d.discovery is not None]
    discovered = None
    if found:
        terms = {t.name: t for d in found for t in d.terms}
        selected = {t.name: t for d in found for t in d.selected}
        discovered = replace(
            found[0],
            terms=list(terms.values()),
            selected=list(selected.values()),
            effect_name=name,
            effect_module=None,
        )
    model = parse_effects(effects)
    if discovered is not None:
        model.append(discovered.effect_class()())
    union, _ = model_of(data, robot, model, opts.measured, opts.instrument)
    names = list(union.layout.names)
    values = [_values(d.result) for d in draws]
    mean = _mean(values, names)
    # each session's own (its base, its zero offsets) refitted; the rest the draws' mean
    own = ("base", "rehome")
    free = {n for n in names if (p := parse_parameter_name(n)) is not None and p.kind in own}
    result = fit(
        data, robot, model, options=opts, start=mean, fixed=[n for n in names if n not in free]
    )

    def refit(left_out: Sequence[str]) -> np.ndarray:
        """The mean of the draws' fits without ``left_out`` (each its own), in the union's
        layout."""
        without = []
        with warnings.catch_warnings(), _quiet_draws():  # the draws' cautions, as above
            warnings.simplefilter("ignore", LabWarning)
            for d, v in zip(draws, values, strict=True):
                own = [n for n in left_out if n in v]
                p = d.result.refit(own) if own and d.result.refit is not None else None
                without.append(v if p is None else _values(d.result, p))
        m = _mean(without, names) | {n: 0.0 for n in left_out}
        return result.model.layout.vector(m)

    # identified where a draw identified it: the domain's rules judge those terms (lab.domain)
    seen = {
        n
        for d in draws
        for n, i in zip(d.result.model.layout.names, d.result.identifiable, strict=True)
        if i
    }
    identified = result.identifiable | np.array([n in seen for n in names])
    return Bag(
        replace(result, refit=refit, identifiable=identified), effects, discovered, draws, refused
    )
