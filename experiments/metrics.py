"""What a run is judged by: metrics of one episode (an :class:`agents.runner.EpisodeResult`) and
their summary over seeds (mean with a 95 % bootstrap confidence interval from three seeds on,
:mod:`experiments.statistics`, which never reaches below zero for a positive quantity; the
minimum and maximum with fewer).

The leaderboard ranks by the settled RMS (``rms_settled_mm``: after ``settle_seconds``), what an
agent's calibration and control decide. The start-up is its own column (``rms_startup_mm``: the
first second, before the first tracker points have told anyone anything, where 86-89 % of a
non-oracle agent's whole-episode squared error falls on ``geometric``); ``rms_mm`` counts both.
``converge_s`` is kept for configs that ask for it, but the path decides it as much as the agent
(a fast stretch late in the episode takes even the oracle above the threshold), so the shipped
configs no longer list it.

| metric                 | unit | what it is                                                            |
|------------------------|------|-----------------------------------------------------------------------|
| `rms_mm`               | mm   | RMS of the true tool-point error over the judged steps (whole episode) |
| `max_mm`               | mm   | its maximum (mostly the starting offset)                              |
| `rms_settled_mm`       | mm   | RMS after the first ``settle_seconds`` of the judged steps            |
| `max_settled_mm`       | mm   | the maximum after the first ``settle_seconds``                        |
| `rms_startup_mm`       | mm   | RMS over the first second of the judged steps (the start-up)          |
| `tracker_points`       | 1    | tracker points the agent used (every phase): what it says it used (``tracker_points_used`` in its report), else every point delivered to it |
| `converge_s`           | s    | the time (from the start of the judged steps) after which the true error stays below ``converge_mm`` to the end; missing (null) when it never does |
| `never_converged`      | 1    | 1 if the error never stayed below ``converge_mm`` (the leaderboard counts it over seeds) |
| `effort_rms`           | 1    | RMS of the normalised joint-velocity commands (1: every joint at full speed) |
| `effort_rate_rms`      | 1/s  | RMS of the commands' rate of change (normalised units per second)     |
| `calib_rms_mm`         | mm   | calibration error: RMS over 64 fixed poses of the distance between the tool point the agent's model (with what it identified) predicts and the true one; only for agents that report their model's parameters |
| `calib_params`         | 1    | how many parameters the agent identified                              |
| `diverged`             | 1    | 1 if the simulation diverged (the leaderboard sums it over seeds)     |
| `solve_time_median_ms` | ms   | median computation time of the agent per step (a timing field)        |
| `solve_time_p95_ms`    | ms   | its 95th percentile (a timing field)                                  |

Timing metrics vary from run to run; records keep them apart (``record["timing"]``) so that
everything else in a record is reproducible bit for bit.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from experiments.errors import MetricError, UnknownMetricError

__all__ = [
    "DEFAULT_CONVERGE_MM",
    "DEFAULT_METRICS",
    "DEFAULT_SETTLE_SECONDS",
    "METRICS",
    "MIN_VALUES_FOR_CI",
    "Metric",
    "Summary",
    "calibration_error_mm",
    "convergence_time",
    "episode_metrics",
    "parameter_errors",
    "reports_model",
    "summarize",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Metric:
    name: str
    unit: str
    description: str
    timing: bool = False  # varies with the machine: kept out of the reproducible part
    aggregate: str = "mean"  # "mean" (with a CI over seeds) or "sum" (a count over seeds)
    #: a metric recorded with this one, which says why a value is missing (``converge_s`` is
    #: null where the error never converged, and ``never_converged`` is then 1)
    companion: str | None = None


METRICS: dict[str, Metric] = {
    m.name: m
    for m in (
        Metric("rms_mm", "mm", "tracking RMS of the true tool-point error (judged steps)"),
        Metric("max_mm", "mm", "maximum true tool-point error (judged steps)"),
        Metric("rms_settled_mm", "mm", "tracking RMS after the settling time"),
        Metric("max_settled_mm", "mm", "maximum true tool-point error after the settling time"),
        Metric("rms_startup_mm", "mm", "tracking RMS over the first second (start-up)"),
        Metric("tracker_points", "1", "tracker points the agent used"),
        Metric(
            "converge_s",
            "s",
            "time after which the true error stays below the convergence threshold (the path "
            "decides it as much as the agent)",
            companion="never_converged",
        ),
        Metric(
            "never_converged",
            "1",
            "episodes whose error never stayed below the convergence threshold",
            aggregate="sum",
        ),
        Metric("effort_rms", "1", "RMS of the normalised joint-velocity commands"),
        Metric("effort_rate_rms", "1/s", "RMS rate of change of the normalised commands"),
        Metric(
            "calib_rms_mm", "mm", "tool-point error of the agent's identified model at 64 poses"
        ),
        Metric("calib_params", "1", "number of parameters identified"),
        Metric("diverged", "1", "episodes in which the simulation diverged", aggregate="sum"),
        Metric("solve_time_median_ms", "ms", "median computation per step", timing=True),
        Metric("solve_time_p95_ms", "ms", "95th percentile computation per step", timing=True),
    )
}

DEFAULT_METRICS = (
    "rms_settled_mm",
    "rms_startup_mm",
    "rms_mm",
    "max_mm",
    "max_settled_mm",
    "effort_rms",
    "calib_rms_mm",
    "diverged",
    "solve_time_median_ms",
    "solve_time_p95_ms",
)

#: the convergence threshold (mm) unless a config sets ``converge_mm``: well above the tracker's
#: noise floor (0.026 mm RMS in 3-D), well below the nominal arm's errors (about 2.5 mm)
DEFAULT_CONVERGE_MM = 0.25
#: the settling time (s) unless a config sets ``settle_seconds``; see experiments.config
DEFAULT_SETTLE_SECONDS = 2.0
#: the start-up (s) of ``rms_startup_mm``: the judged steps' first second
STARTUP_SECONDS = 1.0

CALIBRATION_POSES = 64
CALIBRATION_POSE_SEED = 20240611  # fixed: every agent and run is judged at the same poses


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def convergence_time(t: np.ndarray, err: np.ndarray, threshold_mm: float, t0: float = 0.0) -> float:
    """The time (s, from ``t0``) after which ``err`` stays below ``threshold_mm`` to the end:
    the end time ``t`` of the last step at or above it (a NaN, a diverged step, counts as above),
    0 if no step is; ``inf`` if the last step is (never converged) or there is no step."""
    t = np.asarray(t, dtype=float)
    err = np.asarray(err, dtype=float)
    if err.size == 0:
        return math.inf
    above = ~(err < threshold_mm)  # NaN is above
    if above[-1]:
        return math.inf
    hits = np.flatnonzero(above)
    return 0.0 if hits.size == 0 else float(t[hits[-1]] - t0)


def episode_metrics(
    result: Any,
    names: Iterable[str],
    settle_seconds: float = DEFAULT_SETTLE_SECONDS,
    calib_rms_mm: float | None = None,
    converge_mm: float = DEFAULT_CONVERGE_MM,
) -> tuple[dict[str, float], dict[str, float]]:
    """The metrics ``names`` of one episode, split into ``(reproducible, timing)``.

    ``result`` is an :class:`agents.runner.EpisodeResult` (or anything with its arrays);
    ``calib_rms_mm`` comes from :func:`calibration_error_mm` (it needs the truth's model);
    ``converge_mm`` is the threshold of ``converge_s``. A metric's companion (``never_converged``
    of ``converge_s``) is returned with it. ``converge_s`` is NaN (null in a record) when the error
    never converged."""
    names = list(names)
    unknown = [n for n in names if n not in METRICS]
    if unknown:
        raise UnknownMetricError(f"unknown metric(s) {unknown}; known: {', '.join(METRICS)}")
    names += [c for n in names if (c := METRICS[n].companion) is not None and c not in names]
    judged = np.asarray(result.judged, dtype=bool)
    t = np.asarray(result.time, dtype=float)
    err = np.asarray(result.true_error_mm, dtype=float)
    act = np.asarray(result.actions, dtype=float).reshape(-1, 6)
    dt = float(t[1] - t[0]) if len(t) > 1 else float("nan")
    e = err[judged]
    # the settling time counts from the start of the first judged phase
    if judged.any():
        t0 = t[judged][0] - (dt if np.isfinite(dt) else 0.0)
        settled = err[judged & (t - t0 > settle_seconds + 1e-9)]
        startup = err[judged & (t - t0 <= STARTUP_SECONDS + 1e-9)]
    else:
        t0 = 0.0
        settled = startup = np.empty(0)
    converge = convergence_time(t[judged], e, converge_mm, t0) if e.size else math.nan
    a = act[judged]
    rate = np.diff(act, axis=0)[judged[1:]] / dt if len(act) > 1 else np.empty((0, 6))
    solve = np.asarray(result.solve_time_s, dtype=float)
    solve = solve[judged] if solve.shape == judged.shape else solve
    values: dict[str, float] = {
        "rms_mm": _rms(e),
        "max_mm": float(np.max(e)) if e.size else float("nan"),
        "rms_settled_mm": _rms(settled),
        "max_settled_mm": float(np.max(settled)) if settled.size else float("nan"),
        "rms_startup_mm": _rms(startup),
        "converge_s": converge if math.isfinite(converge) else float("nan"),
        "never_converged": math.nan if math.isnan(converge) else float(math.isinf(converge)),
        "effort_rms": _rms(a),
        "effort_rate_rms": _rms(rate),
        "diverged": 1.0 if bool(result.diverged) else 0.0,
        "solve_time_median_ms": float(np.median(solve)) * 1e3 if solve.size else float("nan"),
        "solve_time_p95_ms": float(np.percentile(solve, 95)) * 1e3 if solve.size else float("nan"),
    }
    report = getattr(result, "report", {}) or {}
    values["calib_params"] = float(len(identified_names(report)))
    used = report.get("tracker_points_used")
    if isinstance(used, (int, float)) and not isinstance(used, bool):
        values["tracker_points"] = float(used)
    else:
        meas = np.asarray(getattr(result, "measurement", np.empty((0, 3))), dtype=float)
        values["tracker_points"] = float(np.isfinite(meas).all(axis=-1).sum()) if meas.size else 0.0
    values["calib_rms_mm"] = float("nan") if calib_rms_mm is None else float(calib_rms_mm)
    out: dict[str, float] = {}
    timing: dict[str, float] = {}
    for n in names:
        (timing if METRICS[n].timing else out)[n] = values[n]
    return out, timing


def identified_names(report: Mapping[str, Any]) -> list[str]:
    """The parameters an agent says it identified: its ``fitted`` or ``rls_free`` list when it
    gives one (possibly empty: it identified nothing yet), else every parameter it reports; none if
    it reports no parameters."""
    names = report.get("parameter_names")
    if not names or "parameters" not in report:
        return []
    for key in ("fitted", "rls_free"):
        if key in report:
            return [str(n) for n in report[key]]
    return [str(n) for n in names]


def reports_model(report: Mapping[str, Any]) -> bool:
    """Whether the agent reports the parameters of its model (``parameter_names``, ``parameters``)."""
    return bool(report.get("parameter_names")) and "parameters" in report


def parameter_errors(report: Mapping[str, Any], truth: Mapping[str, float]) -> dict[str, float]:
    """identified - true, for every identified parameter that the truth also has (SI units)."""
    names = report.get("parameter_names") or []
    values = report.get("parameters") or []
    est = dict(zip(names, values, strict=False))
    return {
        n: float(est[n]) - float(truth[n])
        for n in identified_names(report)
        if n in truth and n in est
    }


def calibration_error_mm(
    truth_model: Any,
    truth_params: np.ndarray,
    names: Sequence[str],
    values: Sequence[float],
    est_model: Any = None,
    n_poses: int = CALIBRATION_POSES,
) -> float:
    """RMS (mm) over ``n_poses`` fixed poses of |x_est(q) - x_true(q)|: the tool point predicted by
    the identified parameters (``names``, ``values``) against the truth's.

    The estimate is evaluated with ``est_model`` (an :class:`arm.errormodel.ErrorModel` whose
    layout has ``names``) when given, else with the truth's model (its other parameters nominal),
    which needs ``names`` to be among the truth's. Poses come from a fixed seed; columns an effect
    needs are set to reference conditions (temperature 20 degC, the arm's payload, every joint
    approached from +)."""
    from arm.sampling import sample_poses

    names = list(names)
    vals = np.asarray(values, dtype=float)
    if est_model is not None and tuple(est_model.layout.names) == tuple(names):
        model, p_est = est_model, vals
    else:
        missing = [n for n in names if n not in truth_model.layout]
        if missing:
            raise MetricError(
                f"the identified parameters {missing} are not in the truth's model and no model "
                "of the estimate was given"
            )
        model = truth_model
        p_est = truth_model.nominal()
        for n, v in zip(names, vals, strict=True):
            p_est[truth_model.layout.index(n)] = v
    robot = truth_model.robot
    q = sample_poses(robot, n_poses, np.random.default_rng(CALIBRATION_POSE_SEED))

    def cols(m):
        base = {
            "temperature": np.full(len(q), 20.0),
            "payload": np.full(len(q), float(getattr(robot, "payload", 0.0) or 0.0)),
            "t": np.zeros(len(q)),
        }
        base |= {f"dir{i}": np.ones(len(q)) for i in range(1, 7)}
        return {c: base[c] for c in m.required_columns() | {"payload"} if c in base}

    x_true = truth_model.predict(truth_model.inputs(q, cols(truth_model)), np.asarray(truth_params))
    x_est = model.predict(model.inputs(q, cols(model)), p_est)
    return float(np.sqrt(np.mean(np.sum((x_est - x_true) ** 2, axis=1)))) * 1e3


#: fewer finite values than this and a summary shows the minimum and maximum, not an interval
MIN_VALUES_FOR_CI = 3


@dataclass(frozen=True)
class Summary:
    """A metric over seeds: mean, its 95 % bootstrap confidence interval ``[lo, hi]``
    (:func:`experiments.statistics.mean_interval`: BCa; for a positive quantity it never reaches
    below zero), ``ci95`` its half-width (``(hi - lo) / 2``, for a column of numbers), standard
    deviation, count of finite values, their sum, minimum and maximum. :attr:`has_ci` says whether
    the interval is worth showing."""

    mean: float
    ci95: float
    std: float
    n: int
    total: float
    min: float = float("nan")
    max: float = float("nan")
    lo: float = float("nan")
    hi: float = float("nan")

    @property
    def has_ci(self) -> bool:
        """Enough values (:data:`MIN_VALUES_FOR_CI`) for the interval to be shown."""
        return self.n >= MIN_VALUES_FOR_CI and math.isfinite(self.lo) and math.isfinite(self.hi)

    @property
    def low(self) -> float:
        return self.lo

    @property
    def high(self) -> float:
        return self.hi


def summarize(values: Iterable[float], interval: bool = True) -> Summary:
    """Mean and bootstrap confidence interval of the finite ``values`` (``interval=False``:
    the mean, spread and range only, for metrics no table shows an interval of)."""
    from experiments.statistics import mean_interval

    x = np.asarray([v for v in values if v is not None], dtype=float)
    x = x[np.isfinite(x)]
    n = int(x.size)
    if n == 0:
        return Summary(float("nan"), float("nan"), float("nan"), 0, float("nan"))
    mean = float(np.mean(x))
    total = float(np.sum(x))
    lo, hi = float(np.min(x)), float(np.max(x))
    if n < 2:
        return Summary(mean, float("nan"), float("nan"), n, total, lo, hi)
    std = float(np.std(x, ddof=1))
    if not interval:
        return Summary(mean, float("nan"), std, n, total, lo, hi)
    ci = mean_interval(x)
    return Summary(mean, (ci.hi - ci.lo) / 2, std, n, total, lo, hi, ci.lo, ci.hi)
