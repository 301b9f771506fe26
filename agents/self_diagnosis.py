"""An MPC that diagnoses its own model: ``mpc-diagnose``.

It tracks with the geometric model (:class:`~agents.mpc.MPCAgent`) and keeps its tracker points
with their inputs (:class:`~agents.online_calibration.MeasurementBuffer`: q, the point, the
commanded direction of each joint, the declared payload, the temperature sensor; the gravity
torques follow from q and the payload). Everything it uses is what a real controller has: no
truth, no scenario name. Two tests look for what its model misses, each in a worker thread of
its own.

**The sequential test** (:mod:`agents.model_selection`, default ``select=True``) decides as soon
as the evidence suffices. Shadow estimators of the current model and of the model with each
candidate effect family of the catalogue (on every joint) take every tracker point; before taking
it each predicts it, and the sum of the log predictive densities of a candidate minus the
current model's is its log Bayes factor. A family is selected when that reaches ``log(K /
select_alpha)`` (``K`` candidates) against the current model and against every other candidate,
and against a *drift*: the current model with a short memory (forgetting ``drift``), which wins
when the arm changed (a payload that is not declared yet) rather than lacked an effect. Under the
current model each Bayes factor is a martingale, so the chance of any false selection over the
whole episode is at most ``select_alpha`` (Ville's inequality): the false-alarm discipline of the
lab's family-wise level, for a test that looks at every point. On ``backlash`` it selects within a
few points of a joint's reversal (0.7-3.2 s on seeds 0-4), where a batch diagnosis needs 20-70
points to see the gap. The first ``burn_in`` points train the shadows without counting. A job
starts every ``select_every`` steps on the points not yet taken and is adopted ``select_lag``
steps later; a new selection (after a widening) first replays the buffer, ``replay_chunk`` points
a job, without deciding.

**The lab's diagnosis** (:func:`lab.diagnose`) runs on the buffer after ``first_points`` tracker
points, with the instrument's noise and a family-wise level ``alpha``. If the model is adequate
(verdict ``none``) it stops and watches its innovations; if not, it tries again on 30 % more points
(15, 20, 26, 34, ... by default); after any widening it looks again at the wider model. It
diagnoses again when the innovations say the model has become insufficient (a payload change,
say): the last ``monitor_points`` innovations, normalised by the noise, beyond their chi-square
level ``monitor_p``. It uses the diagnosis's explanation (its ``suggestion``), also when the
verdict is ``unexplained`` (the catalogue explains part of the residual only). Each effect of it,
in the order the diagnosis chose them, must pass a **held-out test** against spurious extras: the
model with and without it is fitted on the buffer but its last ``holdout`` fraction, and the
effect is kept only if it predicts those later points better (RMS at most ``guard`` of the model
without it). (``test_first=False`` takes the first effect on the lab's word.) The diagnosis
names effects per joint (``backlash[1]``: the joints the buffer shows); the estimator takes the
first effect found on every joint, as the sequential test adds it, so that a joint that moves
later is already modelled (its parameters stay at their prior until then); an extra keeps the
joints the held-out test checked (on a campaign over the workspace, an extra on every joint
extrapolates worse to a region it has not seen: 1.27x the oracle against 1.10x). The lab's plausibility bound
is off inside the agent (``accept_large``): on a short buffer a parameter that the points barely
determine may take any value, and the held-out test, not the bound, judges the model.

**Extras.** An effect added to a model that has one already, by either test, must pass the
held-out test; on a campaign over the workspace it checks that the effect carries over to the
latest postures, which the prequential evidence (points like the ones before them) does not.
When it adds an effect it also asks whether one added earlier is still needed: an effect whose
removal leaves the held-out points predicted about as well (``prune``) goes.

**How it widens.** The model, the MPC and the estimator take the resulting effects; the estimator
continues from the one re-run over the buffer (``relearn``, default), which is what an estimator
told the effects from the start would have learned from the same points: the geometric
parameters that had absorbed the missing effect are re-estimated with it. (With
``relearn=False`` it widens the running estimator, keeping its estimates and information and
starting the new parameters from their prior; the old information then anchors the geometric
parameters at values that compensated for the missing effect, and on ``backlash`` the error
stays about 15 % higher.)

**Timing.** Each job starts at a fixed step, runs in its worker thread (off the control path:
the control step's own time, ``last_solve_time``, never includes it) and is adopted at a fixed
later step, waiting for it there if it is late: the same seed always gives the same numbers.
A result prepared for a model that the other test has widened meanwhile is dropped (and the
question asked again of the wider model). The costs per call (the workers' CPU time) are in the
report, beside the control path's step times, with the number of jobs that did not finish within
their lag in real time.

The record (``report()``) lists every diagnosis and selection: which test (``method``), when
(step, time, points), the verdict (the lab's, or the family selected), the suggestion, the log
Bayes factors (``evidence``), what the held-out test kept and the ratios, and the effects it
ended with.

It is one module, longer than most, because the two tests share the buffer, the held-out test,
the widening and the fixed-step schedule that keeps them reproducible.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from scipy import stats

from agents.errors import AgentError
from agents.model_selection import SequentialSelection, candidate_families
from agents.mpc import MPCAgent, Widening
from agents.online_calibration import MeasurementBuffer, RecursiveLeastSquares, merge_effects
from arm.constraints import Interval, declare, problems, refuse
from arm.effects import make_effect
from arm.errormodel import ErrorModel
from arm.errors import SixAxisWarning, collected_warnings, warn
from arm.measurements import MeasurementSet
from envs.task import TaskInfo, Truth

if TYPE_CHECKING:
    from lab.options import LabOptions

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


def _quiet_the_lab_in_workers() -> None:
    """The filter on every module of the lab (a logger's filter sees only its own records, not
    its children's): the fit's plausibility and outliers, the domain's excursions... of a short
    buffer as well as the diagnosis's."""
    import pkgutil

    import lab

    for info in pkgutil.iter_modules(lab.__path__):
        logging.getLogger(f"lab.{info.name}").addFilter(_QuietWorkers())


_quiet_the_lab_in_workers()


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
    method: str = "lab"
    evidence: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
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
            "evidence": dict(self.evidence),
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
    selection: SequentialSelection | None = None  # the selection to continue with
    fed: int = 0  # buffer points (by number) the selection has taken
    live_from: int = 0  # buffer points numbered below this were a replay (no decisions)
    warnings: list[tuple[str, type[SixAxisWarning]]] = field(default_factory=list)  # the lab's


class Deferred:
    """One kind of background job: started in a worker thread at a control step, its result
    adopted ``lag`` control steps later whatever the work really took (so that the same seed gives
    the same episode on any machine), with the thread time each job cost and how many cost more
    than their lag (``late``). The agent runs two: the lab's diagnosis and the sequential test."""

    def __init__(self, lag: int, label: str) -> None:
        self.lag, self.label = int(lag), label
        self.job: _Outcome | None = None
        self.thread: threading.Thread | None = None
        self.started = -1
        self.costs: list[float] = []
        self.late = 0

    @property
    def running(self) -> bool:
        return self.thread is not None

    def due(self, step: int) -> bool:
        """Whether the running job's result is to be adopted at control step ``step``."""
        return self.thread is not None and step >= self.started + self.lag

    def start(self, step: int, job: _Outcome, work: Callable[..., None], *args: Any) -> None:
        """Run ``work(job, *args)`` in a worker thread from control step ``step``; the lab's
        warnings it gives are kept with the job (:meth:`finish` issues them)."""
        self.job, self.started = job, step

        def run() -> None:
            with collected_warnings() as caught:
                job.warnings = caught
                work(job, *args)

        self.thread = threading.Thread(
            target=run, name=f"{WORKER} {self.label}step {step}", daemon=True
        )
        self.thread.start()

    def join(self) -> float:
        """Wait for the running job (if any); returns the wall time waited."""
        if self.thread is None:
            return 0.0
        t0 = time.perf_counter()
        self.thread.join()
        return time.perf_counter() - t0

    def finish(self, dt: float) -> tuple[_Outcome, float]:
        """The finished job (waited for) and the wall time waited; its cost is recorded, late if
        it cost more than its lag of ``dt`` steps."""
        waited = self.join()
        job, self.thread, self.job = self.job, None, None
        assert job is not None
        # issued here, in the thread that adopts the job: a worker's stack holds no caller to
        # point a warning at but threading.py; here it points at the code that ran the episode
        for message, category in job.warnings:
            warn(f"{WORKER} {self.label}at step {self.started}: {message}", category)
        self.costs.append(job.cost_s)
        if job.cost_s > self.lag * dt:
            self.late += 1
        return job, waited


def _in(low: float, high: float, closed: Literal["both", "neither"] = "neither") -> Interval:
    return Interval(float, low, high, closed=closed)


@dataclass(frozen=True)
class DiagnosisSettings:
    """The diagnosing agent's own settings (beyond :class:`~agents.mpc.MPCAgent`'s), each with
    what it takes declared beside it (:mod:`arm.constraints`): a bad value is refused with every
    other bad one, in one error, and a config names them before any run. See
    :class:`DiagnosingMPCAgent` for what each does."""

    first_points: int = declare(15, Interval(int, MIN_FIT_POINTS, None))
    growth: float = declare(1.3, Interval(float, 1.0, None, closed="neither"))
    lag_steps: int = declare(25, Interval(int, 1, None))
    alpha: float = declare(0.02, _in(0.0, 1.0))
    guard: float = declare(0.95, _in(0.0, 1.0))
    holdout: float = declare(0.3, _in(0.1, 0.5, "both"))
    window: int = declare(1000, Interval(int, 1, None))
    monitor_points: int = declare(10, Interval(int, 1, None))
    monitor_p: float = declare(1e-4, _in(0.0, 1.0))
    candidates: tuple[str, ...] | None = None
    relearn: bool = True
    test_first: bool = True
    prune: bool = True
    select: bool = True
    select_alpha: float = declare(0.02, _in(0.0, 1.0))
    burn_in: int = declare(5, Interval(int, 0, None))
    select_every: int = declare(5, Interval(int, 1, None))
    select_lag: int = declare(5, Interval(int, 1, None))
    replay_chunk: int = declare(50, Interval(int, 1, None))
    drift: float | None = declare(0.95, _in(0.0, 1.0))

    def __post_init__(self) -> None:
        if self.candidates is not None and not isinstance(self.candidates, tuple):
            object.__setattr__(self, "candidates", tuple(self.candidates))
        found = problems(self)
        if not found and self.window < self.first_points:
            found.append(
                f"window ({self.window}) must be at least first_points ({self.first_points})"
            )
        refuse(found, AgentError)


class DiagnosingMPCAgent(MPCAgent):
    """The MPC that diagnoses its own model; see the module docstring.

    Settings beyond :class:`~agents.mpc.MPCAgent`'s: ``first_points`` (tracker points before the
    first diagnosis), ``growth`` (each retry waits for this factor more points), ``lag_steps``
    (control steps from a diagnosis's start to its adoption), ``alpha`` (the lab's family-wise
    false-alarm level per diagnosis), ``guard`` and ``holdout`` (the held-out test: the RMS
    ratio an effect must reach on the buffer's last ``holdout`` fraction), ``window`` (the most
    recent points a diagnosis uses; re-learning uses all the buffer holds), ``monitor_points``
    and ``monitor_p`` (the innovation test that starts a new diagnosis), ``candidates`` (effects
    to test; default the lab's: every catalogued effect and the scan of cyclic errors, which a
    list without ``"cyclic"`` leaves out), ``relearn`` (re-run the widened estimator over the
    buffer), ``test_first`` (the held-out test for the first effect too, not only the extras),
    ``prune`` (drop effects added earlier that a later, wider model no longer needs; with
    ``relearn`` only); for the sequential test ``select`` (on/off), ``select_alpha`` (its
    false-selection level over the episode), ``burn_in`` (points that train without counting),
    ``select_every`` and ``select_lag`` (steps between its jobs, and from a job's start to its
    adoption), ``replay_chunk`` (points a job replays into a new selection) and ``drift`` (the
    forgetting of the drifting competitor; None: none).
    """

    name = "mpc-diagnose"

    Settings = DiagnosisSettings

    def __init__(
        self,
        settings: DiagnosisSettings | None = None,
        *,
        buffer: int = 5000,
        effects: str | Sequence[str] = "geometric",
        name: str | None = None,
        **settings_and_mpc: Any,
    ) -> None:
        own = {f.name for f in dataclasses.fields(DiagnosisSettings)}
        given = {k: settings_and_mpc.pop(k) for k in list(settings_and_mpc) if k in own}
        if settings is not None and given:
            raise AgentError(f"give the settings once: settings= and {', '.join(given)}")
        if settings_and_mpc.get("oracle"):
            raise AgentError("mpc-diagnose is not an oracle: it diagnoses its own model")
        st = settings if settings is not None else DiagnosisSettings(**given)
        if buffer < st.window:
            raise AgentError(f"buffer ({buffer}) must hold the window ({st.window} points)")
        super().__init__(effects=effects, buffer=buffer, name=name, **settings_and_mpc)
        self.settings = st

    # -- episode ----------------------------------------------------------------------------------
    def reset(self, task: TaskInfo, seed: int | None = None, truth: Truth | None = None) -> None:
        for worker in (getattr(self, "_diagnosis", None), getattr(self, "_selecting", None)):
            if worker is not None:
                worker.join()
        super().reset(task, seed, truth)
        self._k = 0  # control steps since the episode's start, over every phase
        self._next_points = self.settings.first_points
        self._adequate = False  # the last diagnosis found nothing to add
        self._since_diagnosis = 0
        self._innov: deque[float] = deque(maxlen=self.settings.monitor_points)
        self._diagnosis = Deferred(self.settings.lag_steps, "")
        self.records: list[DiagnosisRecord] = []
        self._waits: list[float] = []
        self._service: list[float] = []
        # the sequential test (agents.model_selection), in a worker of its own
        self._sel: SequentialSelection | None = (
            self._selection_for(self.model) if self.settings.select else None
        )
        self._sel_fed = 0  # buffer points (by number, rejected ones too) the selection has taken
        self._sel_live_from = 0  # the points before this one are replayed, without decisions
        self._selecting = Deferred(self.settings.select_lag, "selection ")

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
        if self._selecting.due(self._k):
            self._adopt_selection()
        if self._diagnosis.due(self._k):
            self._adopt()
        elif not self._diagnosis.running and self._due():
            self._start()
        if (
            self.settings.select
            and not self._selecting.running
            and self._k % self.settings.select_every == 0
        ):
            self._start_selection()
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
        if (
            len(self._innov) < self.settings.monitor_points
            or self._since_diagnosis < self.settings.monitor_points
        ):
            return None
        # chi-square with 3 degrees of freedom per point when the model is right (the
        # estimate's own uncertainty makes it a little larger: the level is strict)
        s = float(np.sum(self._innov))
        if stats.chi2.sf(s, 3 * len(self._innov)) < self.settings.monitor_p:
            return "innovations"
        return None

    def _start(self) -> None:
        reason = self._due() or "more data"
        assert self.buffer is not None and self.model is not None
        since = max(self.buffer.total - self.settings.window, 0)
        data = self.buffer.to_measurements(since=since, source="mpc-diagnose buffer")
        rec = DiagnosisRecord(
            step=self._k,
            time_s=self._k * float(self.task.dt),
            points=len(data),
            effects_before=list(self.model.effect_names),
            reason=reason,
        )
        self._since_diagnosis = 0
        self._innov.clear()
        # everything the buffer holds, for re-learning (the diagnosis takes the window)
        held = self.buffer.to_measurements(since=self.buffer.first, source="mpc-diagnose buffer")
        self._diagnosis.start(
            self._k, _Outcome(rec), self._work, data, held, self.model, self.buffer.total
        )

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
        from lab import FitError

        t0 = time.thread_time()
        try:
            self._diagnose(job, data, held, model, total)
        except FitError as exc:  # the lab refuses to judge these points (too few, too poor):
            # no verdict yet, and another try on more points; reported, not a warning
            log.info("mpc-diagnose: no verdict at step %d: %s", job.record.step, exc)
            job.record.error = f"{type(exc).__name__}: {exc}"
            job.widening = job.estimator = None
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
            options=self._lab_options(),
            alpha=self.settings.alpha,
            # by default the lab's: every catalogued effect and the scan of cyclic errors
            candidates=self.settings.candidates,
        )
        rec.verdict, rec.suggestion, rec.chi2_p_value = d.verdict, d.suggestion, d.chi2_p_value
        if not d.explanation:
            return
        # the first effect chosen is significant and predicts left-out poses (the lab's
        # confirmation); each further one must also predict the buffer's last points from a fit
        # on the points before them (the held-out test against spurious extras)
        first, *extras = d.explanation
        kept: list[str] = [] if self.settings.test_first else [first.label]
        tested = list(d.explanation) if self.settings.test_first else extras
        cut = round(len(data) * (1.0 - self.settings.holdout))
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
                rec.tried[c.label] = rms / base_rms if 0 < base_rms < math.inf else math.inf
                if math.isfinite(rms) and rms <= self.settings.guard * base_rms:
                    kept.append(c.label)
                    base_rms = rms
        if not kept:
            return
        rec.kept = kept
        labels = merge_effects(model, kept)
        if self.settings.prune and self.settings.relearn and cut >= MIN_FIT_POINTS:
            labels = self._pruned(model, labels, train, test, rec)
        if len(model.effects) == 1:
            # the first effect found goes on every joint, as the sequential test adds it: the
            # joints the buffer has not moved yet stay at their prior until they do
            labels = [
                e if e in model.effect_names or make_effect(e).scan_only else make_effect(e).name
                for e in labels
            ]  # (a cyclic error keeps its joints and orders: it has no "every joint")
        job.widening = self._prepare(model, labels)
        if self.settings.relearn:
            job.estimator = self._relearned(job.widening.model, held)
        job.replayed = total

    def _lab_options(self) -> LabOptions:
        """The lab's options for this agent's fits and diagnoses: the task's tracker noise,
        large values accepted (an arm far off its nominal is for the lab to describe here), and
        whatever its poses identify fitted (an episode's path is no campaign to refuse)."""
        from lab import LabOptions

        return LabOptions(noise_mm=float(self.task.noise_mm), accept_large=True, min_identified=0.0)

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
            if math.isfinite(rms) and rms <= full / self.settings.guard:
                rec.dropped.append(e)
                labels, full = trial, min(rms, full)
        return labels

    def _prepare(self, model: ErrorModel, labels: list[str]) -> Widening:
        """The model, tool model and MPC of exactly ``labels`` (wider, or pruned)."""
        from agents.tool_model import cached_tool_model

        if set(labels) >= set(model.effect_names) and not self.settings.relearn:
            return self.prepare_widening(labels)
        new = ErrorModel(model.robot, labels, targets=model.targets)
        tm = cached_tool_model(new)
        return Widening(new, tm, self._make_mpc(tm), None)

    def _held_out_rms(
        self, model: ErrorModel, added: list[str], train: MeasurementSet, test: MeasurementSet
    ) -> float:
        """RMS (mm) on ``test`` of the model with ``added`` effects fitted on ``train``; infinite
        when the lab cannot fit it from ``train`` (a parameter that these points do not determine,
        or an implausible value): such a model predicts nothing, and is not kept."""
        from lab import FitError, fit

        spec = merge_effects(model, added)
        try:
            res = fit(
                train,
                model.robot,
                spec,
                options=self._lab_options(),
                validate=test,
                accept_other_frame=True,  # its own arm's rows, held out on purpose
            )
        except FitError as exc:
            log.debug("mpc-diagnose: held-out fit of %s refused: %s", ",".join(spec), exc)
            return math.inf
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
    def _adopt(self) -> None:
        job, waited = self._diagnosis.finish(float(self.task.dt))
        assert self.model is not None
        self._waits.append(waited)
        rec = job.record
        rec.adopt_step = self._k
        if job.widening is not None and list(self.model.effect_names) != rec.effects_before:
            # the sequential test widened the model while the lab worked on the old one
            rec.error = "superseded: the model was widened meanwhile"
            job.widening = job.estimator = None
        elif job.widening is not None and list(job.widening.model.effect_names) == list(
            self.model.effect_names
        ):
            job.widening = job.estimator = None  # nothing new
        if job.widening is not None:
            if self.settings.relearn and job.estimator is not None and self.buffer is not None:
                est = job.estimator
                # the points that arrived while the worker ran
                rows = self.buffer.to_measurements(since=job.replayed)
                cols = _rows(rows)
                for k in range(len(rows)):
                    est.update(rows.q[k], rows.xyz[k], cols[k])
                self._adopt_relearned(job.widening, est)
            else:
                self.adopt_widening(job.widening)
            self._sel_outdated()
            self._adequate = False  # look again with the wider model
            self._next_points = (
                self.buffer.count() + self.settings.first_points if self.buffer else 0
            )
        elif rec.verdict == "none" or (rec.error and rec.error.startswith("superseded")):
            self._adequate = rec.verdict == "none"
            if not self._adequate and self.buffer is not None:
                self._next_points = self.buffer.count() + self.settings.first_points
        else:
            self._adequate = False
            points = self.buffer.count() if self.buffer is not None else 0
            self._next_points = max(math.ceil(rec.points * self.settings.growth), points + 1)
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
    # -- the sequential test ----------------------------------------------------------------------
    def _sel_outdated(self) -> None:
        """The model changed under the selection (the lab widened it): the next selection job
        builds one for the new model and replays the buffer into it."""
        self._sel = None

    def _start_selection(self) -> None:
        """A job of the sequential test: the points not yet taken, oldest first, at most
        ``replay_chunk`` of them (a new selection catches up on the buffer over a few jobs:
        each job's work is bounded)."""
        assert self.buffer is not None and self.model is not None
        total = self.buffer.total
        sel = self._sel
        fed, live_from = self._sel_fed, self._sel_live_from
        if sel is None:  # a new selection (the model changed): it replays what the buffer holds
            fed, live_from = self.buffer.first, total
        elif fed >= total:
            return
        fed = max(fed, self.buffer.first)  # (a buffer full for long drops its oldest points)
        until = min(total, fed + self.settings.replay_chunk)
        rec = DiagnosisRecord(
            step=self._k,
            time_s=self._k * float(self.task.dt),
            points=until,
            effects_before=list(self.model.effect_names),
            reason="sequential test",
            method="sequential",
        )
        job = _Outcome(rec, selection=sel, fed=fed)
        new = self.buffer.to_measurements(since=fed, until=until, accepted_only=False)
        held = self.buffer.to_measurements(since=self.buffer.first, until=until)
        self._selecting.start(
            self._k, job, self._select_work, new, held, self.model, until, live_from
        )

    def _select_work(
        self,
        job: _Outcome,
        new: MeasurementSet,
        held: MeasurementSet,
        model: ErrorModel,
        until: int,
        live_from: int,
    ) -> None:
        """Feed the points to the selection (built first if the model changed; points numbered
        below ``live_from`` add evidence without deciding); on a selection, test it (an extra),
        prepare the widening and the estimator re-learned over the buffer (in the worker thread:
        it reads the agent's settings only)."""
        t0 = time.thread_time()
        try:
            sel = job.selection
            if sel is None:
                sel = job.selection = self._selection_for(model)
            job.live_from = live_from
            chosen = None
            if sel is not None:
                cols = _rows(new)
                for k in range(len(new)):
                    live = job.fed + k >= live_from
                    chosen = sel.feed(new.q[k], new.xyz[k], cols[k], decide=live) or chosen
            job.fed = until
            rec = job.record
            if chosen is not None and sel is not None:
                rec.verdict = chosen
                rec.evidence = sel.evidence()
                labels = merge_effects(model, [chosen])
                rec.suggestion = ",".join(labels)
                if len(model.effects) > 1:  # an extra: the held-out test and pruning, as the lab's
                    tested = self._tested_extra(model, chosen, held, rec)
                    if tested is None:
                        sel.veto(chosen, math.ceil(sel.n_points * self.settings.growth))
                        chosen = None
                    labels = tested or labels
            if chosen is not None:
                rec.kept = [chosen]
                w = self._prepare(model, labels)
                job.widening = w
                job.estimator = self._relearned(w.model, held)
                job.replayed = until
        except Exception as exc:  # a failed selection changes nothing: it is reported
            log.warning("mpc-diagnose: selection at step %d failed: %s", job.record.step, exc)
            job.record.error = f"{type(exc).__name__}: {exc}"
            job.widening = job.estimator = None
        job.cost_s = time.thread_time() - t0

    def _tested_extra(
        self, model: ErrorModel, chosen: str, held: MeasurementSet, rec: DiagnosisRecord
    ) -> list[str] | None:
        """The effects after adding ``chosen`` to a model that has effects already: only if it
        predicts the buffer's last ``holdout`` points better from a fit on the points before them
        (the lab path's test of extras), then pruned of effects it makes unnecessary; None: it
        fails, or the buffer is too short to test it."""
        data = held.subset(np.arange(max(len(held) - self.settings.window, 0), len(held)))
        cut = round(len(data) * (1.0 - self.settings.holdout))
        if cut < MIN_FIT_POINTS:
            rec.error = (
                f"not tested: the held-out test needs {MIN_FIT_POINTS} points before the last"
            )
            return None
        train, test = data.subset(np.arange(cut)), data.subset(np.arange(cut, len(data)))
        base = self._held_out_rms(model, [], train, test)
        rms = self._held_out_rms(model, [chosen], train, test)
        rec.tried[chosen] = rms / base if 0 < base < math.inf else math.inf
        if not (math.isfinite(rms) and rms <= self.settings.guard * base):
            return None
        labels = merge_effects(model, [chosen])
        if self.settings.prune and self.settings.relearn:
            labels = self._pruned(model, labels, train, test, rec)
        return labels

    def _selection_for(self, model: ErrorModel | None) -> SequentialSelection | None:
        """A selection for ``model``: its null and a shadow per candidate family (their CasADi
        builds are cached per process)."""
        assert self.rls is not None and model is not None
        fams = candidate_families(model, self.settings.candidates, MeasurementBuffer.COLUMNS)
        if not fams:
            return None
        return SequentialSelection(
            model,
            fams,
            self.rls.sigma,
            alpha=self.settings.select_alpha,
            burn_in=self.settings.burn_in,
            forgetting=self.rls.forgetting,
            drift=self.settings.drift,
        )

    def _adopt_selection(self) -> None:
        job, waited = self._selecting.finish(float(self.task.dt))
        assert self.model is not None
        rec = job.record
        if list(self.model.effect_names) != rec.effects_before:
            return  # the lab widened the model meanwhile: the next job starts afresh
        self._sel, self._sel_fed, self._sel_live_from = job.selection, job.fed, job.live_from
        self._waits.append(waited)
        if job.widening is None or job.estimator is None:
            if rec.error or rec.verdict:  # a failure, or a selection the held-out test refused
                rec.adopt_step = self._k
                rec.effects_after = list(self.model.effect_names)
                self.records.append(rec)
            return
        rec.adopt_step = self._k
        assert self.buffer is not None
        est = job.estimator
        rows = self.buffer.to_measurements(since=job.replayed)
        cols = _rows(rows)
        for k in range(len(rows)):
            est.update(rows.q[k], rows.xyz[k], cols[k])
        self._adopt_relearned(job.widening, est)
        self._sel_outdated()  # the next job starts the selection of the wider model
        rec.effects_after = list(self.model.effect_names)
        self.records.append(rec)
        log.info(
            "mpc-diagnose at %.2f s (%d points): the sequential test selects %s",
            rec.time_s,
            rec.points,
            rec.verdict,
        )
        if not self._diagnosis.running:  # the lab looks again at the wider model
            self._adequate = False
            self._next_points = self.buffer.count() + self.settings.first_points

    def report(self) -> dict[str, float | list]:
        self._diagnosis.join()
        self._selecting.join()
        out = super().report()
        out["diagnoses"] = [r.to_dict() for r in self.records]
        out["diagnosis_verdicts"] = [r.verdict for r in self.records]
        out["diagnosed_effects"] = list(self.model.effect_names) if self.model is not None else []
        widened = [r for r in self.records if r.kept]
        out["widened_at_s"] = (
            [r.adopt_step * float(self.task.dt) for r in widened] if self._task is not None else []
        )
        out["diagnosis_cost_time_s"] = list(self._diagnosis.costs)
        out["diagnosis_wait_time_s"] = list(self._waits)
        out["diagnosis_late"] = self._diagnosis.late
        out["selection_cost_time_s"] = list(self._selecting.costs)
        out["selection_late"] = self._selecting.late
        if self._sel is not None:
            out["selection_evidence"] = [
                {"family": f, "log_bf": v} for f, v in self._sel.evidence().items()
            ]
        if self._service:
            out["diagnosis_service_time_max_s"] = float(np.max(self._service))
        return out


def _rows(data: MeasurementSet) -> list[dict[str, float]]:
    """The per-point columns of a measurement set as the estimator takes them."""
    names = list(data.columns)
    arr = np.column_stack([data.columns[c] for c in names]) if names else np.empty((len(data), 0))
    return [dict(zip(names, map(float, row), strict=True)) for row in arr]
