"""Which of ``lumped_compliance``'s parameters a fit frees, decided from the fitted rows alone.

The effect's base set (:mod:`arm.effects.lumped`) has 24 to 30 products on a 6R arm. On real
arms most of them fit the training rows' systematic residue rather than gravity, and a held-out
series is then worse than with ``compliance`` and the arm's masses (the UR10's series A and B
left out: 7 % and 12 % worse); an F-test cannot tell, as the residue is significant over
thousands of poses. Its first group (:func:`arm.effects.lumped.first_group`: the long links'
moments along their length, 3 on a UR) does as well as ``compliance`` there, but misses a heavy
arm's payload and wrist moments, off its links' lines.

So the rest of the base set enters only where the rows say it predicts better: a blocked
cross-validation, each block fitted on the others and predicted, with and without the rest.
The blocks are the tracker stations when the rows come from several (a held-out station is
registered on its own rows, as a left-out series is checked), else :data:`BLOCKS` consecutive
runs of rows (a drift or a session's change is not averaged over). The rest is freed only when
it lowers the blocked RMS by at least :data:`REST_GAIN`, and held at zero when the rows are too
few for blocks of :data:`MIN_BLOCK_ROWS` (no fair check: the first group alone).

Judged on folds its design never saw (``benchmarks/lumped_heldout.py``): with any gain taken,
the UR10's series B alone freed the rest for a 1.6 % lower blocked RMS (its five runs of rows
share the session's residue), and the fit then missed series A and D by 2.1x and 2.9x the first
group's error; with too few rows to judge (the Rokae's 29) it freed all of them. (On the UR5's
20 random poses the fit is refused either way: the parameter count, held ones included, exceeds
the equations.) A heavy arm's payload and wrist moments, where the rest is
the law, lowered it by 38 % and more where it was freed in the first twelve of
``benchmarks/heavy_arm.py``'s campaigns.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from arm.description import RobotDescription
from arm.effects import Effect
from arm.effects.lumped import LumpedCompliance, first_group, parameter_name
from arm.measurements import MeasurementSet
from lab.estimation import fit_rows
from lab.folds import fold
from lab.options import LabOptions

__all__ = ["held_rest"]

log = logging.getLogger(__name__)

#: consecutive blocks of rows measured from one station
BLOCKS = 5
#: fewer rows than this per block hold the rest at zero (no fair check)
MIN_BLOCK_ROWS = 20
#: the share by which the rest must lower the blocked RMS to be freed: its 24 to 30 parameters
#: buying less fit one session's residue, which another session does not share
REST_GAIN = 0.10


def held_rest(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: Sequence[Effect],
    options: LabOptions,
    fixed: Sequence[str] = (),
) -> tuple[str, ...]:
    """The names of ``lumped_compliance``'s parameters beyond its first group to hold at zero in
    a fit of ``data`` (the module docstring): all of them unless the rest lowers the blocked
    RMS by :data:`REST_GAIN`; () when the effect is not fitted or names its own parameters."""
    rest = _rest(robot, effects, fixed)
    if not rest:
        return ()
    blocks, stations = _blocks(data)
    if blocks is None:
        log.info(
            "lumped_compliance: %d rows, too few for %d blocks of %d: the rest held at zero",
            len(data),
            BLOCKS,
            MIN_BLOCK_ROWS,
        )
        return rest
    sub = options.replace(accept_large=True, outliers="keep")
    free = _blocked_sse(data, robot, effects, sub, tuple(fixed), blocks, stations)
    first = _blocked_sse(data, robot, effects, sub, tuple(fixed) + rest, blocks, stations)
    held = not free < first * (1.0 - REST_GAIN) ** 2  # an infinite (refused) fit frees nothing
    log.info(
        "lumped_compliance: blocked cross-validation over %d blocks, RMS %.4g mm with its first "
        "group, %.4g mm with all %d more: %s",
        len(blocks),
        1e3 * np.sqrt(first / len(data)),
        1e3 * np.sqrt(free / len(data)),
        len(rest),
        "the rest held at zero" if held else "all free",
    )
    return rest if held else ()


def _rest(
    robot: RobotDescription, effects: Sequence[Effect], fixed: Sequence[str]
) -> tuple[str, ...]:
    lumped = [e for e in effects if isinstance(e, LumpedCompliance) and e.fixed is None]
    if not lumped:
        return ()
    first = set(first_group(robot))
    names = [parameter_name(j, t) for e in lumped for j, t in e.columns_of(robot)]
    rest = tuple(n for n in names if n not in first and n not in fixed)
    return rest if len(rest) < len(names) else ()  # no first group on this arm: nothing to test


def _blocks(data: MeasurementSet) -> tuple[list[np.ndarray] | None, bool]:
    """(the blocks of rows, whether they are stations), or None when too few rows."""
    station = data.columns.get("station")
    if station is not None and len(np.unique(station)) > 1:
        blocks = [np.flatnonzero(station == s) for s in np.unique(station)]
        stations = True
    else:
        blocks = np.array_split(np.arange(len(data)), BLOCKS)
        stations = False
    if min(len(b) for b in blocks) < MIN_BLOCK_ROWS:
        return None, stations
    return blocks, stations


def _blocked_sse(
    data: MeasurementSet,
    robot: RobotDescription,
    effects: Sequence[Effect],
    options: LabOptions,
    fixed: tuple[str, ...],
    blocks: list[np.ndarray],
    stations: bool,
) -> float:
    """Sum of the squared 3-D errors (m^2) of every block predicted by a fit of the others;
    infinite when a fit is refused."""
    total = 0.0
    for b in blocks:
        f = fold(
            data,
            b,
            lambda train: fit_rows(train, robot, effects, options, fixed=fixed),
            register=stations,
        )
        if f is None:
            return float("inf")
        total += float(np.sum(f.residuals**2))
    return total
