"""Terms that transfer: blocked cross-validation across sessions or tracker stations.

    col = block_column(data)                  # "session", else "station", else None
    rms = blocked_rms(data, robot, "geometric,compliance", options)
    kept, table = confirm_groups(data, robot, base, groups, options)

A random split of one campaign tells whether a term predicts poses like the ones it was fitted
on. A user calibrates once and uses the result in other sessions, from other stations, elsewhere
in the workspace. Where the data say which rows belong together (a ``session`` column, else a
``station`` column) in at least :data:`MIN_BLOCKS` blocks (or two, asked with
``across_blocks=True``), the diagnosis and the discovery keep a term only if it helps on a block
it was not fitted on:

* **blocked RMS**: each block is left out in turn, the model fitted to the others (the rows the
  screen kept, none left out again, plausibility not judged: a fold is not a result) and validated
  on it as ``--validate`` does (a station the fit has not seen has its base registered rigidly;
  outside the fitted domain terms that do not hold are left out, :mod:`lab.domain`): the 3-D RMS
  of each block;
* **confirmation**, backward: with the candidate groups in, and with each left out in turn; the
  group whose absence raises the held-out RMS least on average over the blocks (the mean of the
  log ratios, so that a fold that cannot predict its block at all neither decides nor drowns
  the others) goes if it does not raise it, and the others are judged again. The diagnosis's groups are its chosen effects (a cyclic effect's orders together), the
  discovery's its discovered effect.

This confirms a selection made by the lab's own tests; it never adds a term, so the diagnosis's
and the discovery's false-alarm guarantees (:mod:`lab.diagnosis`, :mod:`lab.discovery`) hold as
they are. Its cost is up to (groups + 1) x blocks fits a round.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from arm.description import RobotDescription
from arm.effects import Effect
from arm.measurements import MeasurementSet
from lab.errors import FitError, LabWarning
from lab.folds import Fold, fold
from lab.identification import fit
from lab.options import LabOptions

__all__ = [
    "BLOCK_COLUMNS",
    "MIN_BLOCKS",
    "block_column",
    "blocked_folds",
    "blocked_rms",
    "blocked_text",
    "confirm_groups",
    "rms_of",
    "use_blocks",
]

log = logging.getLogger(__name__)

#: the columns that say which rows belong together, in the order they are looked for
BLOCK_COLUMNS = ("session", "station")
#: blocks the diagnosis and discovery need before they confirm by them unasked: with two, each
#: fold fits one block alone, in its own region of the workspace, and terms that transfer when
#: fitted on two sessions look useless there (the UR10's series, leaving one out: the
#: discovery's path predicted it to 0.19 / 0.23 / 0.32 mm unconfirmed, 0.53 / 0.45 / 0.35 mm
#: confirmed on the two sessions left; docs/lab.md)
MIN_BLOCKS = 3

Effects = str | Sequence[str | Effect]


def block_column(data: MeasurementSet) -> str | None:
    """``session`` where the data have that column with two or more ids, else ``station`` so,
    else None."""
    for c in BLOCK_COLUMNS:
        if c in data.columns and len(np.unique(data.columns[c])) >= 2:
            return c
    return None


def use_blocks(data: MeasurementSet, across: bool | None) -> bool:
    """Whether to confirm by blocks: ``across`` if given (True needs two blocks at least), else
    where the data have :data:`MIN_BLOCKS` blocks."""
    col = block_column(data)
    if col is None or across is False:
        return False
    return bool(across) or len(np.unique(data.columns[col])) >= MIN_BLOCKS


def blocked_folds(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: Effects,
    options: LabOptions,
    *,
    plausible: bool = False,
) -> dict[float, Fold | None]:
    """{block id: the model fitted to the other blocks, and its residuals on the block's rows}
    (the module docstring); None where a fold cannot be fitted. ``plausible``: a fold whose
    parameters the lab would refuse as a result (beyond the plausible bound of their kind,
    unless ``options.accept_large``) is one that cannot be fitted either: fitted on one session,
    terms that two sessions identify can be absorbed into millimetres that cancel in that session
    and not in the next (the UR10, a fold of series B alone: 3374 mrad, 772 mm on series D)."""
    col = block_column(data)
    if col is None:
        raise FitError(f"{data.source}: no session or station column of two or more ids")
    accept = options.accept_large if plausible else True
    opts = replace(options, outliers="keep", accept_large=accept)
    # a held-out station's frame from its own rows: every model alike
    return {
        float(b): fold(
            data,
            data.columns[col] == b,
            lambda train: fit(train, robot, effects, options=opts),
            register=True,
            ignore=LabWarning,
        )
        for b in np.unique(data.columns[col])
    }


def blocked_rms(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: Effects,
    options: LabOptions,
    *,
    plausible: bool = False,
) -> dict[float, float]:
    """{block id: the 3-D RMS (m) of its rows predicted by the model fitted to the other blocks}
    (:func:`blocked_folds`); infinite where a fold cannot be fitted."""
    folds = blocked_folds(data, robot, effects, options, plausible=plausible)
    return rms_of(folds)


def rms_of(folds: dict[float, Fold | None]) -> dict[float, float]:
    """Each block's RMS (m) of :func:`blocked_folds`; infinite where its fold was not fitted."""
    return {b: math.inf if f is None else f.rms for b, f in folds.items()}


def _gain(with_: dict[float, float], without: dict[float, float]) -> float:
    """How much a group helps where it was not fitted: the mean over blocks of
    log(RMS without / RMS with); above 0 it helps. A block whose fold could not be fitted either
    way says nothing."""
    logs = [
        math.log(without[b] / with_[b])
        for b in with_
        if math.isfinite(with_[b]) and math.isfinite(without[b]) and with_[b] > 0
    ]
    if any(math.isfinite(without[b]) and not math.isfinite(with_[b]) for b in with_):
        return -math.inf  # with the group a fold cannot be fitted
    return float(np.mean(logs)) if logs else 0.0


def confirm_groups(
    data: MeasurementSet,
    robot: RobotDescription,
    build: Callable[[list[int]], Effects],
    labels: Sequence[str],
    options: LabOptions,
) -> tuple[list[int], list[dict]]:
    """Which of the candidate groups help on blocks they were not fitted on. ``build(keep)``
    gives the model's effects with the groups ``keep`` (indices) in; ``labels`` names the
    groups. Backward elimination: with the groups kept so far, each left out in turn; the one
    whose absence raises the held-out RMS least on average over the blocks (the mean of the log
    ratios: a fold whose fit cannot predict its block at all, millimetres off with or without
    the group, neither decides nor drowns the others) goes if it does not raise it, and the
    rest are judged again without it (groups that share what they explain cover for each other
    one at a time). Returns the groups kept and one row per model tried: ``{"without": label,
    or None for the model with ``of`` the groups then kept, "blocked_rms_mm": {block: RMS},
    "gain": mean log ratio}``."""
    kept = list(range(len(labels)))
    table: list[dict] = []
    while kept:  # backward: the group that helps least goes, until every one left helps
        full = blocked_rms(data, robot, build(kept), options)
        table.append(
            {"without": None, "of": [labels[k] for k in kept], "blocked_rms_mm": _mm(full)}
        )
        gains = {}
        for g in kept:
            without = blocked_rms(data, robot, build([k for k in kept if k != g]), options)
            gains[g] = _gain(full, without)
            table.append({"without": labels[g], "blocked_rms_mm": _mm(without), "gain": gains[g]})
        worst = min(gains, key=lambda g: gains[g])
        if gains[worst] > 0:
            break
        kept.remove(worst)
    log.info(
        "blocked cross-validation by %s: kept %s of %s",
        block_column(data),
        [labels[k] for k in kept],
        list(labels),
    )
    return kept, table


def _mm(rms: dict[float, float]) -> dict[str, float | None]:
    return {f"{b:g}": (1e3 * v if math.isfinite(v) else None) for b, v in rms.items()}


def blocked_text(blocked: dict) -> str:
    """One line for people: what the blocked cross-validation kept and dropped."""
    rows = blocked["models"]

    def cells(r: dict) -> str:
        return "/".join("-" if v is None else f"{v:.4f}" for v in r["blocked_rms_mm"].values())

    last = [r for r in rows if r["without"] is None][-1]
    dropped = blocked["dropped"]
    return (
        f"across {blocked['column']}s {'/'.join(last['blocked_rms_mm'])}, each left out in "
        f"turn: held-out RMS {cells(last)} mm with {', '.join(last['of']) or 'the model alone'}"
        + (f"; dropped, no help where not fitted: {', '.join(dropped)}" if dropped else "")
    )
