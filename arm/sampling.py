"""Random arms and poses from a seed: the "true" errors of a sampled arm (the typical
magnitudes of docs/format.md, parameter names) and measurement poses within the limits with
the tool point above the floor."""

from __future__ import annotations

import numbers
from collections.abc import Iterable

import numpy as np

from arm.description import RobotDescription
from arm.errormodel import ErrorModel
from arm.errors import SamplingError
from arm.kinematics import Chain, tool_points

__all__ = [
    "MAX_POSES",
    "MIN_TOOL_HEIGHT",
    "NEAR_MARGIN",
    "SamplingError",
    "check_count",
    "region_of",
    "rng_from",
    "sample_parameters",
    "sample_poses",
]

MIN_TOOL_HEIGHT = 0.15  # m: samplers keep the tool point above this plane (docs/format.md)
#: the most random poses drawn at once (a plan's candidates, a simulated campaign): 2.4 MB of joint
#: angles, hours of simulation; beyond, a count is a typo (``--n 2e12`` asked for 87 TiB)
MAX_POSES = 1_000_000
#: random poses tried per pose wanted (at least ``_MIN_TRIES`` in all) before concluding that the
#: arm never lifts its tool above the floor
_TRIES_PER_POSE, _MIN_TRIES = 1000, 100_000


def rng_from(seed: int | np.random.Generator | None, what: str = "seed") -> np.random.Generator:
    """A generator from ``seed`` (a non-negative integer; a generator is used as it is); a
    negative or non-integer seed is a :class:`SamplingError` naming ``what``."""
    if isinstance(seed, np.random.Generator):
        return seed
    if (
        isinstance(seed, bool)
        or not isinstance(seed, numbers.Integral | type(None))
        or (seed is not None and seed < 0)
    ):
        raise SamplingError(f"{what} must be a non-negative integer, got {seed!r}")
    return np.random.default_rng(seed)


def check_count(n: object, what: str = "n", limit: int = MAX_POSES) -> int:
    """``n`` as an int if it is a whole number from 1 to ``limit``, else a :class:`SamplingError`
    naming ``what`` and the bound."""
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or not 1 <= int(n) <= limit:
        raise SamplingError(f"{what} must be a whole number from 1 to {limit:,}, got {n!r}")
    return int(n)


def sample_parameters(
    model: ErrorModel,
    rng: np.random.Generator,
    scale: float = 1.0,
    level: str = "typical",
    only: Iterable[str] | None = None,
) -> np.ndarray:
    """A "true" parameter vector: nominal plus, for each parameter, a magnitude drawn from its
    effect's typical range (``level="low"`` takes the low end of it) times ``scale``, with a random
    sign unless the effect's sign is physical. ``only`` restricts the draw to some names."""
    p = model.nominal()
    wanted = None if only is None else set(only)
    for e in model.effects:
        sl = model.layout.slice(e.name)
        for k, name in zip(range(sl.start, sl.stop), model.layout.names[sl], strict=True):
            if wanted is not None and name not in wanted:
                continue
            rg = e.typical_range(name)
            if rg is None:
                continue
            lo, hi = rg
            mag = lo if level == "low" else rng.uniform(lo, hi)
            sign = 1.0 if e.positive else rng.choice((-1.0, 1.0))
            p[k] += sign * mag * scale
    return p


#: how far (rad) the poses planned for a program's region reach beyond its joints' range
NEAR_MARGIN = 0.1


def region_of(
    robot: RobotDescription, program: np.ndarray, margin: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """The joint region of a program's joints (P, 6): per joint, the range it covers widened by
    :data:`NEAR_MARGIN` on each side, within the limits (shrunk by ``margin``)."""
    q = np.asarray(program, dtype=float)
    if q.ndim != 2 or q.shape[1] != 6 or len(q) == 0 or not np.isfinite(q).all():
        raise SamplingError(
            f"a program's joints must be a non-empty (P, 6) array of finite angles, got shape "
            f"{q.shape}"
        )
    lo = np.maximum(q.min(axis=0) - NEAR_MARGIN, robot.lower + margin)
    hi = np.minimum(q.max(axis=0) + NEAR_MARGIN, robot.upper - margin)
    if np.any(lo > hi):
        bad = [j + 1 for j in np.flatnonzero(lo > hi)]
        raise SamplingError(
            f"the program's joints q{', q'.join(map(str, bad))} lie outside the arm's joint limits"
        )
    return lo, hi


def sample_poses(
    robot: RobotDescription,
    n: int,
    rng: np.random.Generator,
    min_height: float = MIN_TOOL_HEIGHT,
    margin: float = 0.05,
    near: np.ndarray | None = None,
) -> np.ndarray:
    """``n`` joint configurations uniform within the limits (shrunk by ``margin`` rad), keeping the
    nominal tool point above ``min_height`` (in the robot base frame). An arm that does not lift
    its tool above ``min_height`` in ``1000 n`` tries (an arm of zero lengths, lengths in mm read
    as m) is a :class:`SamplingError`, not an endless search.

    ``near`` (P, 6): the joints of a program; the poses are drawn from its region instead, the
    box of its joints widened by :data:`NEAR_MARGIN` rad on each side (:func:`region_of`)."""
    n = check_count(n, "the number of poses")
    lo, hi = robot.lower + margin, robot.upper - margin
    if near is not None:
        lo, hi = region_of(robot, near, margin)
    chain = Chain.from_description(robot)
    tool = robot.to_modified().tool_points[0]
    out = np.empty((0, 6))
    tried, budget, highest = 0, max(_TRIES_PER_POSE * n, _MIN_TRIES), -np.inf
    while len(out) < n:
        if tried >= budget:
            raise SamplingError(
                f"robot {robot.name!r}: {len(out)} of {tried:,} random poses within the limits "
                f"put the tool point above z = {min_height:g} m ({n} wanted; the highest reached "
                f"{highest:.3g} m): the arm's lengths cannot be right (every a and d zero? "
                'millimetres read as metres? say length_unit = "mm")'
            )
        m = min(max(2 * (n - len(out)), 16), budget - tried, 100_000)
        q = rng.uniform(lo, hi, size=(m, 6))
        tried += m
        z = tool_points(chain, q, tool)[:, 2]
        highest = max(highest, float(z.max()))
        out = np.vstack([out, q[z > min_height]])
    return out[:n]
