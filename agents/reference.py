"""Reference controllers: the floor (``hold``), the textbook (``nominal``), the no-learning
measurement feed-forward (``feedforward``) and the calibration engineer's (``calibrated``).

* ``hold`` commands zero velocity: the floor any agent must beat.
* ``nominal``: resolved-rate tracking with the nominal kinematic model and no measurements,
  ``v = J^+ ((r_1 - r_0) / dt + gain (r_0 - x(q)) / dt)``, J^+ a damped pseudo-inverse, scaled
  into the velocity limits and the acceleration limits, stopped at joint limits.
* ``feedforward``: the same tracking law, its target shifted by the model error that the last
  tracker measurement revealed, ``e = y - x_nom(q at y's instant)``: it tracks ``r - e``, so the
  true tool point (about ``x_nom + e``) lands on ``r``. No learning, no model identification: the
  reference that learned residual policies must beat.
* ``calibrated``: the same tracking law on a model identified from measurements. It records
  every tracker measurement (with the encoder reading and columns of its instant) while tracking
  with the nominal model; at ``calibration_seconds`` (or, with ``None``, at the start of every new
  phase) it identifies the model with the lab (:func:`lab.fit`) and from then on tracks with the
  identified model, blind.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from agents.base import Agent, measurement_columns, refuse_settings, solve_time_stats
from agents.errors import AgentError
from agents.tool_model import cached_tool_model
from arm.constraints import NON_NEGATIVE, Constraint, Interval
from arm.errormodel import ErrorModel
from envs.task import Observation, TaskInfo, Truth

__all__ = [
    "CalibratedAgent",
    "FeedforwardAgent",
    "HoldAgent",
    "NominalAgent",
    "fit_measurements",
]

log = logging.getLogger(__name__)

#: what the reference controllers' settings may be (:mod:`arm.constraints`): the fraction of the
#: error removed per step, and when the calibrated agent fits (s from the episode's start)
REFERENCE_SETTINGS: dict[str, Constraint] = {
    "gain": Interval(float, 0.0, 1.0, closed="right"),
    "calibration_seconds": NON_NEGATIVE,
}


class HoldAgent(Agent):
    """Commands zero joint velocity."""

    name = "hold"

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task = task

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        return np.zeros(6)

    def report(self) -> dict[str, float | list]:
        return {"tracker_points_used": 0}


class NominalAgent(Agent):
    """Resolved-rate tracking of the reference with a kinematic model (nominal by default).

    ``gain`` (0..1] is the fraction of the current error removed per step, ``damping`` (m) the
    damped pseudo-inverse's regularisation, ``effects`` the model (its parameters stay nominal
    unless a subclass identifies them).
    """

    name = "nominal"

    def __init__(
        self, gain: float = 0.5, damping: float = 1e-3, effects: str | Sequence[str] = "geometric"
    ) -> None:
        super().__init__()
        refuse_settings(REFERENCE_SETTINGS, gain=gain)
        self.gain = float(gain)
        self.damping = float(damping)
        self.effects = effects

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self.task = task
        self.model = ErrorModel(task.robot, self.effects)
        self.p = self.model.nominal()
        self.tm = cached_tool_model(self.model)
        self._cache: tuple[bytes, np.ndarray, np.ndarray] | None = None
        self._times: list[float] = []
        self._start_phase()

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        self.task = task
        self._start_phase()

    def _start_phase(self) -> None:
        self.v_prev = np.zeros(6)
        self.dirs = np.zeros(6)
        self.payload = float(self.task.robot.payload)

    def _columns(self, o: Observation, info: Mapping[str, Any]) -> dict[str, float]:
        mc = measurement_columns(info)
        if "payload" in mc and np.isfinite(mc["payload"]):
            self.payload = mc["payload"]
        if o.payload is not None:
            self.payload = o.payload
        cols = {"temperature": o.temperature, "payload": self.payload}
        cols.update({f"dir{i + 1}": float(self.dirs[i]) for i in range(6)})
        return cols

    def point_dq(
        self, q: np.ndarray, cols: Mapping[str, float] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The model's tool point and its derivative by q at ``q`` (remembered for the last ``q``
        and columns: a residual policy's features and the command ask for the same pose)."""
        cvec = self.tm.column_vector(cols)
        key = np.asarray(q, dtype=float).tobytes() + self.p.tobytes() + cvec.tobytes()
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, *self.tm.point_dq(q, self.p, cvec))
        return self._cache[1], self._cache[2]

    def command(self, o: Observation, cols: Mapping[str, float]) -> np.ndarray:
        """The joint velocity (rad/s) of the resolved-rate law at observation ``o``."""
        task = self.task
        dt = float(task.dt)
        x, J = self.point_dq(o.q, cols)
        r0 = o.ref
        r1 = o.references(1)[0]
        xd = (r1 - r0) / dt + self.gain * (r0 - x) / dt
        lam2 = self.damping**2
        v = J.T @ np.linalg.solve(J @ J.T + lam2 * np.eye(3), xd)
        v_max = np.asarray(task.v_max, dtype=float)
        scale = np.max(np.abs(v) / v_max)
        if scale > 1.0:
            v = v / scale
        da = np.asarray(task.a_max, dtype=float) * dt
        v = self.v_prev + np.clip(v - self.v_prev, -da, da)
        # do not drive into a joint limit
        q_next = o.q + dt * v
        v = np.where(
            (q_next < np.asarray(task.q_lower)) & (v < 0)
            | (q_next > np.asarray(task.q_upper)) & (v > 0),
            0.0,
            v,
        )
        return v

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        t0 = time.perf_counter()
        out = self.track(Observation.parse(self.task, obs), info)
        self.last_solve_time = time.perf_counter() - t0
        self._times.append(self.last_solve_time)
        return out

    def track(
        self, o: Observation, info: Mapping[str, Any], offset: np.ndarray | None = None
    ) -> np.ndarray:
        """One step of the tracking law towards the reference shifted by ``offset`` (3,) m (none:
        the reference itself); updates the controller's state and returns the normalised
        command."""
        cols = self._columns(o, info)
        if offset is not None:
            o = o.shifted(offset)
        v = self.command(o, cols)
        moving = np.abs(v) > 1e-6
        self.dirs[moving] = np.sign(v[moving])
        self.v_prev = v
        return np.clip(v / np.asarray(self.task.v_max, dtype=float), -1.0, 1.0)

    def report(self) -> dict[str, float | list]:
        return solve_time_stats(self._times) | {"tracker_points_used": 0}


class FeedforwardAgent(NominalAgent):
    """The nominal tracking law plus the last measured model error as a feed-forward offset.

    At every tracker measurement ``y`` (with the encoder reading ``q_y`` of its instant,
    ``info["measurement_q"]``) the model error is ``e = y - x_nom(q_y)``; the controller then
    tracks ``r - e``. The offset is held between measurements and through a blind phase (the last
    one seen); measurements older than ``max_age`` seconds (a delivery delay) are still used.
    No learning and no identification: the baseline learned residual policies are built on.
    """

    name = "feedforward"

    def __init__(self, gain: float = 0.5, damping: float = 1e-3) -> None:
        super().__init__(gain=gain, damping=damping, effects="geometric")

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        super().reset(task, seed, truth)
        self.error = np.zeros(3)  # m, the model error at the last measurement
        self.error_change = np.zeros(3)  # m, how much the last measurement changed it
        self.n_measurements = 0
        self.last_measurement_time = -np.inf
        self.measured_dirs = np.zeros(6)  # the joints' directions of motion at the last one

    def observe(self, o: Observation, info: Mapping[str, Any]) -> bool:
        """Update the model error from a new measurement in ``info``; True if there was one."""
        if not info.get("measurement_valid", False):
            return False
        y = np.asarray(info.get("measurement"), dtype=float).reshape(-1)
        q_y = info.get("measurement_q")
        q_y = o.q if q_y is None else np.asarray(q_y, dtype=float).reshape(-1)
        if (
            y.shape != (3,)
            or q_y.shape != (6,)
            or not (np.isfinite(y).all() and np.isfinite(q_y).all())
        ):
            return False
        e = y - self.tm.point(q_y, self.p)
        cols = measurement_columns(info)
        self.measured_dirs = np.array(
            [cols.get(f"dir{i + 1}", self.dirs[i]) for i in range(6)], dtype=float
        )
        self.error_change = e - self.error if self.n_measurements else np.zeros(3)
        self.error = e
        self.n_measurements += 1
        t = info.get("measurement_time", info.get("time"))
        self.last_measurement_time = float(t) if t is not None else self.last_measurement_time
        return True

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        t0 = time.perf_counter()
        o = Observation.parse(self.task, obs)
        self.observe(o, info)
        out = self.track(o, info, -self.error)
        self.last_solve_time = time.perf_counter() - t0
        self._times.append(self.last_solve_time)
        return out

    def report(self) -> dict[str, float | list]:
        out = super().report()
        out["measurements_used"] = self.n_measurements
        out["tracker_points_used"] = self.n_measurements
        return out


def fit_measurements(
    model: ErrorModel,
    q: np.ndarray,
    xyz: np.ndarray,
    columns: Mapping[str, np.ndarray] | None = None,
    p0: np.ndarray | None = None,
    loss: str = "soft_l1",
    noise: float = 15e-6,
) -> tuple[np.ndarray, list[str]]:
    """Identify ``model`` from measured points ``xyz`` (N, 3) at encoder readings ``q`` (N, 6):
    the parameters these poses determine are fitted, the rest stay nominal. Returns the full
    parameter vector (laid out by ``model.layout``) and the names fitted.

    The lab's identification (:func:`lab.fit`: identifiability, Levenberg-Marquardt with the
    analytic Jacobian, a robust loss against outliers) when the lab is installed; otherwise
    scipy's ``least_squares`` with the error model's analytic Jacobian and the same robust loss
    on the identifiable parameters."""
    q = np.asarray(q, dtype=float).reshape(-1, 6)
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    columns = {k: np.asarray(v, dtype=float) for k, v in (columns or {}).items()}
    try:
        from lab import ContaminatedError, LabOptions, fit
    except ImportError:
        return _fit_scipy(model, q, xyz, columns, p0, loss, noise)
    from arm.measurements import MeasurementSet

    data = MeasurementSet(q, xyz, columns, source="calibration phase")
    start = None if p0 is None else model.layout.as_dict(p0)
    # the poses of a calibration phase determine what they do: no campaign to refuse
    options = LabOptions(loss=loss, noise_mm=noise * 1e3, min_identified=0.0)  # type: ignore[arg-type]
    try:
        res = fit(data, model.robot, model.effects, options=options, start=start)
    except ContaminatedError as exc:
        # More poses far off than the lab leaves out (an effect the model lacks, such as
        # backlash, sets a group of poses apart): the lab's own advice, every pose fitted with
        # the robust loss, rather than no calibration at all
        log.info("%s; fitting every pose with the %s loss", exc, loss)
        keep = dataclasses.replace(options, outliers="keep")
        res = fit(data, model.robot, model.effects, options=keep, start=start)
    p = model.nominal() if p0 is None else np.array(p0, dtype=float)
    fitted = [n for n, ok in zip(res.names, res.identifiable, strict=True) if ok]
    values = res.parameters()
    for n in model.layout.names:
        p[model.layout.index(n)] = values[n]
    return p, fitted


def _fit_scipy(model, q, xyz, columns, p0, loss, noise) -> tuple[np.ndarray, list[str]]:
    from scipy.optimize import least_squares

    from agents.online_calibration import identifiable_parameters, prior_scales

    p0 = model.nominal() if p0 is None else np.asarray(p0, dtype=float)
    inputs = model.inputs(q, columns)
    free = identifiable_parameters(model, q, columns, p=p0, noise=noise)
    if 3 * len(q) < len(free) or not free:
        raise AgentError(
            f"{len(q)} measurements cannot determine {len(free)} parameters of {model!r}"
        )
    idx = model.layout.indices(free)
    s = prior_scales(model)[idx]

    def residual(z):
        p = p0.copy()
        p[idx] += s * z
        return (model.predict(inputs, p) - xyz).reshape(-1)

    def jac(z):
        p = p0.copy()
        p[idx] += s * z
        _, J = model.predict(inputs, p, jacobian=True)
        return J[:, :, idx].reshape(-1, len(idx)) * s

    sol = least_squares(
        residual, np.zeros(len(idx)), jac=jac, loss=loss, f_scale=3 * noise, x_scale=1.0
    )
    p = p0.copy()
    p[idx] += s * sol.x
    return p, free


class CalibratedAgent(NominalAgent):
    """Calibrate from measurements, then track blind with the identified model.

    ``calibration_seconds``: a single fit at this time (s from the episode's start, over all
    phases), after which measurements are ignored; ``None`` (or ``"each_phase"``, as a config
    file spells it): collect every measurement and refit at the start of each new phase (a
    multi-phase calibration, then a blind phase).
    ``effects``: what the identified model expresses; ``min_measurements``: below this many the
    model stays as it was.
    """

    name = "calibrated"

    def __init__(
        self,
        calibration_seconds: float | str | None = 3.0,
        effects: str | Sequence[str] = "geometric",
        gain: float = 0.5,
        damping: float = 1e-3,
        min_measurements: int = 10,
    ) -> None:
        super().__init__(gain=gain, damping=damping, effects=effects)
        if isinstance(calibration_seconds, str):
            if calibration_seconds != "each_phase":
                raise AgentError(
                    f"calibration_seconds must be seconds, None or 'each_phase', got "
                    f"{calibration_seconds!r}"
                )
            calibration_seconds = None
        refuse_settings(REFERENCE_SETTINGS, calibration_seconds=calibration_seconds)
        self.calibration_seconds = calibration_seconds
        self.min_measurements = int(min_measurements)

    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        super().reset(task, seed, truth)
        self._q: list[np.ndarray] = []
        self._xyz: list[np.ndarray] = []
        self._cols: list[dict[str, float]] = []
        self.fitted: list[str] = []
        self.n_fits = 0
        self.final = False  # the one-shot fit is done: measurements are no longer used
        self.fit_time_s = 0.0
        self._t0 = 0.0  # episode time at the start of the phase
        self._t = 0.0

    def next_phase(self, task: TaskInfo, truth: Truth | None = None) -> None:
        if not self.final and self.calibration_seconds is None and len(self._q) > 0:
            self.calibrate()
        self._t0 = self._t
        super().next_phase(task, truth)

    def _record(self, info: Mapping[str, Any]) -> None:
        if not info.get("measurement_valid", False):
            return
        y = np.asarray(info.get("measurement"), dtype=float)
        qm = np.asarray(info.get("measurement_q"), dtype=float)
        if not (np.all(np.isfinite(y)) and np.all(np.isfinite(qm))):
            return
        self._q.append(qm)
        self._xyz.append(y)
        self._cols.append(measurement_columns(info))

    def calibrate(self) -> None:
        """Fit the model to every measurement recorded so far."""
        n = len(self._q)
        if n < self.min_measurements:
            log.info("calibrated: only %d measurements, the model stays nominal", n)
            return
        need = self.model.required_columns() | {"payload"}
        cols = {}
        for c in need:
            default = self.task.robot.payload if c == "payload" else 0.0
            cols[c] = np.array([d.get(c, default) for d in self._cols], dtype=float)
        t0 = time.perf_counter()
        sigma = max(self.task.noise_mm * 1e-3, 2e-6)
        try:
            self.p, self.fitted = fit_measurements(
                self.model, np.array(self._q), np.array(self._xyz), cols, noise=sigma
            )
            self.n_fits += 1
        except ValueError as exc:  # lab.FitError is a ValueError
            log.warning("calibrated: fit failed (%s); the model stays as it was", exc)
        self.fit_time_s = time.perf_counter() - t0

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        t = info.get("time")
        self._t = self._t0 + float(t) if t is not None else self._t + float(self.task.dt)
        if not self.final:
            self._record(info)
            if self.calibration_seconds is not None and self._t >= self.calibration_seconds:
                self.calibrate()
                self.final = True  # one shot, even if too few measurements came
        return super().act(obs, info)

    def report(self) -> dict[str, float | list]:
        out = super().report()
        out["calibration_measurements"] = len(self._q)
        out["tracker_points_used"] = len(self._q)
        out["calibration_fits"] = self.n_fits
        out["calibration_fit_time_s"] = self.fit_time_s
        out["parameter_names"] = list(self.model.layout.names)
        out["parameters"] = [float(v) for v in self.p]
        out["fitted"] = list(self.fitted)
        return out
