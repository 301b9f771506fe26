"""An MPC that diagnoses its own model: ``mpc-diagnose``.

It tracks with the geometric model (:class:`~agents.mpc.MPCAgent`) and keeps its tracker points
with their inputs (:class:`~agents.online_calibration.MeasurementBuffer`: q, the point, the
commanded direction of each joint, the declared payload, the temperature sensor; the gravity
torques follow from q and the payload). Everything it uses is what a real controller has: no
truth, no scenario name.

**When.** After ``first_points`` tracker points it runs the lab's diagnosis
(:func:`lab.diagnose`, with the instrument's noise and a family-wise level ``alpha``) on the
buffer. If the model is adequate (verdict ``none``) it stops and watches its innovations; if not,
it tries again on 30 % more points (15, 20, 26, 34, ... by default), so that a short buffer
that cannot yet separate an effect gets more data, at a cost that grows slowly; after widening it
looks again at the wider model. It
diagnoses again when the innovations say the model has become insufficient (a payload change,
say): the last ``monitor_points`` innovations, normalised by the noise, beyond their chi-square
level ``monitor_p``.

**What it uses.** The diagnosis's explanation (its ``suggestion``), also when the verdict is
``unexplained`` (on backlash the catalogue explains part of the residual only: the plant's gap
closes over time, the model flips it at once). Each effect of it, in the order the diagnosis
chose them, must pass a **held-out test** against spurious extras (a compliance term beside
backlash, a gear-ratio term where compliance is): the model with and without it is fitted on the
buffer but its last ``holdout`` fraction, and the effect is kept only if it predicts those later
points better (RMS at most ``guard`` of the model without it). The lab already confirms each
effect on left-out poses; later points are the stricter test on a trajectory, where neighbouring
poses resemble each other. (``test_first=False`` takes the first effect on the lab's word.)

**How it widens.** When it adds an effect it also asks whether one it added earlier is still
needed: an effect whose removal leaves the held-out points predicted about as well (``prune``)
goes; on a campaign over the workspace a load-backlash or gear term taken early, before the
compliance that explains the postures appeared, otherwise stays and extrapolates badly to a new
region. The model, the MPC and the estimator take the resulting effects; the estimator
continues from the one re-run over the buffer (``relearn``, default), which is what an estimator
told the effects from the start would have learned from the same points: the geometric
parameters that had absorbed the missing effect are re-estimated with it. (With
``relearn=False`` it widens the running estimator, keeping its estimates and information and
starting the new parameters from their prior; the old information then anchors the geometric
parameters at values that compensated for the missing effect, and on ``backlash`` the error
stays about 15 % higher.)

**Timing.** A diagnosis starts at a fixed step, runs in a worker thread (off the control path:
the control step's own time, ``last_solve_time``, never includes it) and is adopted at a fixed
later step, ``lag_steps`` after it started, waiting for it there if it is late: the same seed
always gives the same numbers. Its cost per call (the worker's CPU time) is in the report, beside
the control path's step times, with the number of diagnoses that did not finish within their lag
in real time (``lag_steps * dt``).

The record (``report()``) lists every diagnosis: when (step, time, points), the verdict, the
suggestion, what the held-out test kept and the ratios, and the effects it ended with.

It is one module, longer than most, because the schedule of diagnoses, the worker that runs them and
the held-out test that adopts their result share the agent's buffer and step count.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from agents.mpc import MPCAgent, Widening
from agents.online_calibration import RecursiveLeastSquares, merge_effects
from arm.errormodel import ErrorModel
from arm.measurements import MeasurementSet
from envs.task import TaskInfo, Truth

__all__ = ["DiagnosingMPCAgent", "DiagnosisRecord"]

log = logging.getLogger(__name__)

#: the fewest poses the lab fits the geometric model to (33 parameters, 3 equations a pose)
MIN_FIT_POINTS = 12

#: the worker threads' names start with this; their lab warnings (a short buffer is a "poor pose
#: set" by the lab's standard, and it says so) are the agent's business, not the user's
WORKER = "mpc-diagnose"


class _QuietWorkers(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not (
            record.levelno <= logging.WARNING and (record.threadName or "").startswith(WORKER)
        )


for _name in ("lab.identifiability", "lab.identification", "lab.diagnosis"):
    logging.getLogger(_name).addFilter(_QuietWorkers())


@dataclass
class DiagnosisRecord:
    """One diagnosis of the agent's model: when it started and was adopted, on how many points,
    the lab's verdict and suggestion, the effects it kept (with the held-out RMS ratio, with over
    without, of each extra effect tried), and the model's effects after it."""

    step: int
    time_s: float
    points: int
    effects_before: list[str]
    adopt_step: int = -1
    verdict: str = ""
    suggestion: str | None = None
    chi2_p_value: float | None = None
    tried: dict[str, float] = field(default_factory=dict)
    kept: list[str] = field(default_factory=list)
    dropped: list[str] = field(default_factory=list)
    effects_after: list[str] = field(default_factory=list)
    reason: str = "start"
    error: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "step": self.step,
            "time_s": self.time_s,
            "points": self.points,
            "adopt_step": self.adopt_step,
            "reason": self.reason,
            "verdict": self.verdict,
            "suggestion": self.suggestion,
            "chi2_p_value": self.chi2_p_value,
            "tried": dict(self.tried),
            "kept": list(self.kept),
            "dropped": list(self.dropped),
            "effects_before": list(self.effects_before),
            "effects_after": list(self.effects_after),
            "error": self.error,
        }


@dataclass
class _Outcome:
    """What the worker hands back: the filled-in record, and the prepared widening with the
    estimator re-run over the buffer (None when nothing is kept)."""

    record: DiagnosisRecord
    widening: Widening | None = None
    estimator: RecursiveLeastSquares | None = None
    replayed: int = 0  # buffer points (by number) the estimator has seen
    cost_s: float = 0.0


class DiagnosingMPCAgent(MPCAgent):
    """The MPC that diagnoses its own model; see the module docstring.

    Settings beyond :class:`~agents.mpc.MPCAgent`'s: ``first_points`` (tracker points before the
    first diagnosis), ``growth`` (each retry waits for this factor more points), ``lag_steps``
    (control steps from a diagnosis's start to its adoption), ``alpha`` (the lab's family-wise
    false-alarm level per diagnosis), ``guard`` and ``holdout`` (the held-out test: the RMS
    ratio an effect must reach on the buffer's last ``holdout`` fraction), ``window`` (the most
    recent points a diagnosis uses; re-learning uses all the buffer holds), ``monitor_points``
    and ``monitor_p`` (the innovation test that starts a new diagnosis), ``candidates`` (effects
    to test; default the lab's catalogue), ``relearn`` (re-run the widened estimator over the
    buffer), ``test_first`` (the held-out test for the first effect too, not only the extras),
    ``prune`` (drop effects added earlier that a later, wider model no longer needs; with
    ``relearn`` only).
    """

    name = "mpc-diagnose"

    def __init__(
        self,
        first_points: int = 15,
        growth: float = 1.3,
        lag_steps: int = 25,
        alpha: float = 0.02,
        guard: float = 0.95,
        holdout: float = 0.3,
        window: int = 1000,
        monitor_points: int = 10,
        monitor_p: float = 1e-4,
        candidates: Sequence[str] | None = None,
        relearn: bool = True,
        test_first: bool = True,
        prune: bool = True,
        buffer: int = 5000,
        effects: str | Sequence[str] = "geometric",
        name: str | None = None,
        **mpc_settings: Any,
    ) -> None:
        if mpc_settings.get("oracle"):
            raise ValueError("mpc-diagnose is not an oracle: it diagnoses its own model")
        super().__init__(effects=effects, buffer=buffer, name=name, **mpc_settings)
        if first_points < MIN_FIT_POINTS:
            raise ValueError(f"first_points must be >= 12, got {first_points}")
        if growth <= 1.0:
            raise ValueError(f"growth must be > 1, got {growth}")
        if lag_steps < 1:
            raise ValueError(f"lag_steps must be >= 1, got {lag_steps}")
        if not 0.0 < alpha < 1.0:
            raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
        if not 0.0 < guard < 1.0:
            raise ValueError(f"guard must lie in (0, 1), got {guard}")
        if window < first_points:
            raise ValueError(f"window ({window}) must be at least first_points ({first_points})")
        if buffer < window:
            raise ValueError(f"buffer ({buffer}) must hold the window ({window} points)")
        self.first_points = int(first_points)
        self.growth = float(growth)
        self.lag_steps = int(lag_steps)
        self.alpha = float(alpha)
        self.guard = float(guard)
        if not 0.1 <= holdout <= 0.5:
            raise ValueError(f"holdout must lie in [0.1, 0.5], got {holdout}")
        self.holdout = float(holdout)
        self.window = int(window)
        self.monitor_points = int(monitor_points)
        self.monitor_p = float(monitor_p)
        self.candidates = None if candidates is None else list(candidates)
        self.relearn = bool(relearn)
        self.test_first = bool(test_first)
        self.prune = bool(prune)

    # -- episode ----------------------------------------------------------------------------------
    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        self._join_worker()
        super().reset(task, seed, truth)
        self._k = 0  # control steps since the episode's start, over every phase
        self._next_points = self.first_points
        self._adequate = False  # the last diagnosis found nothing to add
        self._since_diagnosis = 0
        self._innov: deque[float] = deque(maxlen=self.monitor_points)
        self._job: _Outcome | None = None
        self._thread: threading.Thread | None = None
        self._job_start = -1
        self.records: list[DiagnosisRecord] = []
        self._costs: list[float] = []
        self._waits: list[float] = []
        self._service: list[float] = []
        self._late = 0

    def act(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        n_before = self.buffer.total if self.buffer is not None else 0
        action = super().act(obs, info)  # times itself: last_solve_time is the control path
        t0 = time.perf_counter()
        self._k += 1
        if self.buffer is not None and self.buffer.total > n_before:
            self._since_diagnosis += 1
            e = self.rls.last_innovation if self.rls is not None else None
            if e is not None and np.all(np.isfinite(e)) and self.rls is not None:
                self._innov.append(float(e @ e) / self.rls.sigma**2)
        if self._thread is not None and self._k >= self._job_start + self.lag_steps:
            self._adopt()
        elif self._thread is None and self._due():
            self._start()
        self._service.append(time.perf_counter() - t0)
        return action

    # -- when ---------------------------------------------------------------------------------------
    def _due(self) -> str | None:
        """Why a diagnosis should start now (None: it should not)."""
        if self.buffer is None or self.rls is None:
            return None
        points = self.buffer.count()
        if not self._adequate:
            return "more data" if points >= self._next_points else None
        if len(self._innov) < self.monitor_points or self._since_diagnosis < self.monitor_points:
            return None
        # chi-square with 3 degrees of freedom per point when the model is right (the
        # estimate's own uncertainty makes it a little larger: the level is strict)
        s = float(np.sum(self._innov))
        if stats.chi2.sf(s, 3 * len(self._innov)) < self.monitor_p:
            return "innovations"
        return None

    def _start(self) -> None:
        reason = self._due() or "more data"
        assert self.buffer is not None and self.model is not None
        since = max(self.buffer.total - self.window, 0)
        data = self.buffer.to_measurements(since=since, source="mpc-diagnose buffer")
        rec = DiagnosisRecord(
            step=self._k,
            time_s=self._k * float(self.task.dt),
            points=len(data),
            effects_before=list(self.model.effect_names),
            reason=reason,
        )
        self._job = _Outcome(rec)
        self._job_start = self._k
        self._since_diagnosis = 0
        self._innov.clear()
        job, model, total = self._job, self.model, self.buffer.total
        # everything the buffer holds, for re-learning (the diagnosis takes the window)
        held = self.buffer.to_measurements(since=self.buffer.first, source="mpc-diagnose buffer")
        self._thread = threading.Thread(
            target=self._work,
            args=(job, data, held, model, total),
            name=f"{WORKER} step {self._k}",
            daemon=True,
        )
        self._thread.start()

    # -- the worker ---------------------------------------------------------------------------------
    def _work(
        self,
        job: _Outcome,
        data: MeasurementSet,
        held: MeasurementSet,
        model: ErrorModel,
        total: int,
    ) -> None:
        """The diagnosis, the held-out test and the builds of the widening (in the worker
        thread; reads the agent's settings only, changes nothing the control path uses)."""
        t0 = time.thread_time()
        try:
            self._diagnose(job, data, held, model, total)
        except Exception as exc:  # a failed diagnosis changes nothing: it is reported
            log.warning("mpc-diagnose: diagnosis at step %d failed: %s", job.record.step, exc)
            job.record.error = f"{type(exc).__name__}: {exc}"
            job.widening = job.estimator = None
        job.cost_s = time.thread_time() - t0

    def _diagnose(
        self,
        job: _Outcome,
        data: MeasurementSet,
        held: MeasurementSet,
        model: ErrorModel,
        total: int,
    ) -> None:
        from lab import diagnose

        assert self.rls is not None
        rec = job.record
        d = diagnose(
            data,
            model.robot,
            list(model.effect_names),
            noise_mm=float(self.task.noise_mm),
            alpha=self.alpha,
            candidates=self.candidates,
        )
        rec.verdict, rec.suggestion, rec.chi2_p_value = d.verdict, d.suggestion, d.chi2_p_value
        if not d.explanation:
            return
        # the first effect chosen is significant and predicts left-out poses (the lab's
        # confirmation); each further one must also predict the buffer's last points from a fit
        # on the points before them (the held-out test against spurious extras)
        first, *extras = d.explanation
        kept: list[str] = [] if self.test_first else [first.label]
        tested = list(d.explanation) if self.test_first else extras
        cut = round(len(data) * (1.0 - self.holdout))
        train, test = data.subset(np.arange(cut)), data.subset(np.arange(cut, len(data)))
        if tested and cut < MIN_FIT_POINTS:  # too few points to fit without the held-out ones
            rec.error = (
                f"not tested: the held-out test needs {MIN_FIT_POINTS} points before the last"
            )
            tested = []
        if tested:
            base_rms = self._held_out_rms(model, kept, train, test)
            for c in tested:
                rms = self._held_out_rms(model, [*kept, c.label], train, test)
                rec.tried[c.label] = rms / base_rms if base_rms > 0 else math.inf
                if rms <= self.guard * base_rms:
                    kept.append(c.label)
                    base_rms = rms
        if not kept:
            return
        rec.kept = kept
        labels = merge_effects(model, kept)
        if self.prune and self.relearn and cut >= MIN_FIT_POINTS:
            labels = self._pruned(model, labels, train, test, rec)
        job.widening = self._prepare(model, labels)
        if self.relearn:
            job.estimator = self._relearned(job.widening.model, held)
        job.replayed = total

    def _pruned(
        self,
        model: ErrorModel,
        labels: list[str],
        train: MeasurementSet,
        test: MeasurementSet,
        rec: DiagnosisRecord,
    ) -> list[str]:
        """Drop effects added earlier that the wider model no longer needs: each in turn, if the
        model without it predicts the held-out points about as well (RMS at most 1 / guard of the
        model's with it), it goes (the estimator is re-learned over the buffer anyway)."""
        # the model's first effect (the geometric one) is never dropped
        old = [e for e in model.effect_names[1:] if e in labels[1:]]
        base = ErrorModel(model.robot, labels[:1], targets=model.targets)
        full = self._held_out_rms(base, labels[1:], train, test)
        for e in old:
            trial = [x for x in labels if x != e]
            rms = self._held_out_rms(base, trial[1:], train, test)
            if rms <= full / self.guard:
                rec.dropped.append(e)
                labels, full = trial, min(rms, full)
        return labels

    def _prepare(self, model: ErrorModel, labels: list[str]) -> Widening:
        """The model, tool model and MPC of exactly ``labels`` (wider, or pruned)."""
        from agents.tool_model import cached_tool_model

        if set(labels) >= set(model.effect_names) and not self.relearn:
            return self.prepare_widening(labels)
        new = ErrorModel(model.robot, labels, targets=model.targets)
        tm = cached_tool_model(new)
        return Widening(new, tm, self._make_mpc(tm), None)

    def _held_out_rms(
        self, model: ErrorModel, added: list[str], train: MeasurementSet, test: MeasurementSet
    ) -> float:
        """RMS (mm) on ``test`` of the model with ``added`` effects fitted on ``train``."""
        from lab import fit

        spec = merge_effects(model, added)
        res = fit(train, model.robot, spec, noise_mm=float(self.task.noise_mm), validate=test)
        return float(res.validation_rms_mm or math.inf)

    def _relearned(self, model: ErrorModel, data: MeasurementSet) -> RecursiveLeastSquares:
        """An estimator of ``model`` run over ``data`` from its prior: what an estimator told
        the effects from the start would have learned from these points."""
        from agents.online_calibration import cached_identifiable
        from agents.tool_model import cached_tool_model

        assert self.rls is not None
        est = RecursiveLeastSquares(
            model,
            free=cached_identifiable(model),
            sigma=self.rls.sigma,
            forgetting=self.rls.forgetting,
            tool_model=cached_tool_model(model),
        )
        rows = _rows(data)
        for k in range(len(data)):
            est.update(data.q[k], data.xyz[k], rows[k])
        return est

    # -- adoption -------------------------------------------------------------------------------------
    def _join_worker(self) -> float:
        th = getattr(self, "_thread", None)
        if th is None:
            return 0.0
        t0 = time.perf_counter()
        th.join()
        return time.perf_counter() - t0

    def _adopt(self) -> None:
        waited = self._join_worker()
        job = self._job
        self._thread, self._job = None, None
        assert job is not None and self.model is not None
        self._waits.append(waited)
        self._costs.append(job.cost_s)
        if job.cost_s > self.lag_steps * float(self.task.dt):
            self._late += 1
        rec = job.record
        rec.adopt_step = self._k
        if job.widening is not None:
            if self.relearn and job.estimator is not None and self.buffer is not None:
                est = job.estimator
                # the points that arrived while the worker ran
                rows = self.buffer.to_measurements(since=job.replayed)
                cols = _rows(rows)
                for k in range(len(rows)):
                    est.update(rows.q[k], rows.xyz[k], cols[k])
                self._adopt_relearned(job.widening, est)
            else:
                self.adopt_widening(job.widening)
            self._adequate = False  # look again with the wider model
            self._next_points = self.buffer.count() + self.first_points if self.buffer else 0
        elif rec.verdict == "none":
            self._adequate = True
        else:
            self._adequate = False
            points = self.buffer.count() if self.buffer is not None else 0
            self._next_points = max(math.ceil(rec.points * self.growth), points + 1)
        rec.effects_after = list(self.model.effect_names)
        self.records.append(rec)
        log.info(
            "mpc-diagnose at %.2f s (%d points): %s, suggestion %s, kept %s",
            rec.time_s,
            rec.points,
            rec.verdict,
            rec.suggestion,
            rec.kept or "nothing",
        )

    def _adopt_relearned(self, w: Widening, est: RecursiveLeastSquares) -> None:
        w.mpc.plan = self.mpc.plan.copy()
        w.mpc.n_fail, w.mpc.n_constrained = self.mpc.n_fail, self.mpc.n_constrained
        self.model, self.tm, self.mpc = w.model, w.tm, w.mpc
        self.rls = est
        self.p = est.params

    # -- record -------------------------------------------------------------------------------------
    def report(self) -> dict[str, float | list]:
        self._join_worker()
        out = super().report()
        out["diagnoses"] = [r.to_dict() for r in self.records]
        out["diagnosis_verdicts"] = [r.verdict for r in self.records]
        out["diagnosed_effects"] = list(self.model.effect_names) if self.model is not None else []
        widened = [r for r in self.records if r.kept]
        out["widened_at_s"] = (
            [r.adopt_step * float(self.task.dt) for r in widened] if self._task is not None else []
        )
        out["diagnosis_cost_time_s"] = list(self._costs)
        out["diagnosis_wait_time_s"] = list(self._waits)
        out["diagnosis_late"] = self._late
        if self._service:
            out["diagnosis_service_time_max_s"] = float(np.max(self._service))
        return out


def _rows(data: MeasurementSet) -> list[dict[str, float]]:
    """The per-point columns of a measurement set as the estimator takes them."""
    names = list(data.columns)
    arr = np.column_stack([data.columns[c] for c in names]) if names else np.empty((len(data), 0))
    return [dict(zip(names, map(float, row), strict=True)) for row in arr]
