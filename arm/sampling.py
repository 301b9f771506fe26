"""Random arms and poses from a seed: the "true" errors of a sampled arm (the typical
magnitudes of docs/format.md, parameter names) and measurement poses within the limits with
the tool point above the floor."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from arm.description import RobotDescription
from arm.errormodel import ErrorModel
from arm.kinematics import Chain, tool_points

__all__ = ["MIN_TOOL_HEIGHT", "sample_parameters", "sample_poses"]

MIN_TOOL_HEIGHT = 0.15  # m: samplers keep the tool point above this plane (docs/format.md)


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


def sample_poses(
    robot: RobotDescription,
    n: int,
    rng: np.random.Generator,
    min_height: float = MIN_TOOL_HEIGHT,
    margin: float = 0.05,
) -> np.ndarray:
    """``n`` joint configurations uniform within the limits (shrunk by ``margin`` rad), keeping the
    nominal tool point above ``min_height`` (in the robot base frame)."""
    lo, hi = robot.lower + margin, robot.upper - margin
    chain = Chain.from_description(robot)
    tool = robot.to_modified().tool_points[0]
    out = np.empty((0, 6))
    while len(out) < n:
        q = rng.uniform(lo, hi, size=(max(2 * (n - len(out)), 16), 6))
        ok = tool_points(chain, q, tool)[:, 2] > min_height
        out = np.vstack([out, q[ok]])
    return out[:n]
