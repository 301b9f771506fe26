"""mpc-diagnose: the controller that diagnoses its own model. It widens to backlash on the
backlash scenario and widens nothing on clean (geometric) data, over 20 seeds each; the same
seed gives the same numbers although the diagnosis runs in a worker thread; what it found is in
its record; it takes nothing but what a real controller has."""

from __future__ import annotations

import numpy as np
import pytest

from agents.registry import make_agent
from agents.runner import run_episode
from arm.effects import candidate_effects

SEEDS = range(20)
EPISODE_S = 8.0


def _run(scenario: str, seed: int, seconds: float = EPISODE_S, **settings):
    agent = make_agent("mpc-diagnose", **settings)
    return agent, run_episode(agent, {"scenario": scenario}, seed=seed, episode_seconds=seconds)


def test_same_seed_same_numbers_and_a_record_of_what_it_found():
    a1, r1 = _run("backlash", 1, seconds=4.0)
    _, r2 = _run("backlash", 1, seconds=4.0)
    np.testing.assert_array_equal(r1.true_error_mm, r2.true_error_mm)
    np.testing.assert_array_equal(r1.actions, r2.actions)
    assert r1.report["diagnoses"] == r2.report["diagnoses"]
    rep = r1.report
    assert not a1.needs_truth
    assert rep["diagnoses"], "it diagnosed"
    lab = [d for d in rep["diagnoses"] if d["method"] == "lab"]
    first = lab[0]
    assert first["points"] == 15 and first["step"] * 0.02 == pytest.approx(first["time_s"])
    assert first["adopt_step"] == first["step"] + 25
    assert {"verdict", "suggestion", "kept", "effects_before", "effects_after"} <= set(first)
    widened = [d for d in rep["diagnoses"] if d["kept"]]
    assert widened and any("backlash" in k for k in widened[0]["kept"])
    # on backlash the sequential test decides first, within 2 s: a selection adopted 5 steps
    # after its job started, with the log Bayes factors of every candidate (and of a drift)
    seq = widened[0]
    assert seq["method"] == "sequential" and seq["time_s"] < 2.0
    assert seq["adopt_step"] == seq["step"] + 5
    assert seq["evidence"]["backlash"] == max(seq["evidence"].values())
    assert {"compliance", "thermal", "drift"} <= set(seq["evidence"])
    assert rep["diagnosed_effects"] == widened[-1]["effects_after"]
    assert rep["diagnosed_effects"][0] == "geometric" and len(rep["diagnosed_effects"]) > 1
    # their cost is reported per call, off the control path's step times
    assert len(rep["diagnosis_cost_time_s"]) == len(lab)
    assert all(c > 0 for c in rep["diagnosis_cost_time_s"])
    assert rep["selection_cost_time_s"] and all(c > 0 for c in rep["selection_cost_time_s"])


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="first_points"):
        make_agent("mpc-diagnose", first_points=5)
    with pytest.raises(ValueError, match="oracle"):
        make_agent("mpc-diagnose", oracle=True)
    with pytest.raises(ValueError, match="guard"):
        make_agent("mpc-diagnose", guard=1.5)
    with pytest.raises(ValueError, match="select_alpha"):
        make_agent("mpc-diagnose", select_alpha=0.0)
    with pytest.raises(ValueError, match="drift"):
        make_agent("mpc-diagnose", drift=1.0)


@pytest.mark.slow
def test_widens_to_backlash_on_backlash():
    found = []
    for seed in SEEDS:
        _, r = _run("backlash", seed)
        found.append(r.report["diagnosed_effects"])
    has = [any(e.startswith(("backlash", "load_backlash")) for e in f) for f in found]
    assert sum(has) >= len(found) - 1, found
    assert all(f[0] == "geometric" for f in found)


@pytest.mark.slow
def test_widens_nothing_on_clean_data():
    widened = []
    for seed in SEEDS:
        _, r = _run("geometric", seed)
        if r.report["diagnosed_effects"] != ["geometric"]:
            widened.append((seed, r.report["diagnoses"]))
    assert len(widened) <= 1, widened  # at most 1 episode in 20 with a false widening


def test_an_effect_the_lab_cannot_fit_from_the_buffer_is_not_kept():
    """The held-out test of an effect whose parameters the buffer's points do not determine
    (compliance about joint 1, which gravity never loads) gets an infinite RMS, so it is never
    kept, instead of the lab's refusal ending the whole diagnosis."""
    from lab import FitError, fit

    agent, _ = _run("geometric", 0, seconds=2.0)
    data = agent.buffer.to_measurements()
    cut = len(data) * 2 // 3
    train, test = data.subset(np.arange(cut)), data.subset(np.arange(cut, len(data)))
    with pytest.raises(FitError, match="identifiable"):
        fit(train, agent.model.robot, "geometric,compliance[1]", noise_mm=0.015)
    assert agent._held_out_rms(agent.model, ["compliance[1]"], train, test) == np.inf
    assert np.isfinite(agent._held_out_rms(agent.model, [], train, test))


def test_the_labs_path_widens_the_estimator_by_the_whole_family():
    """With the sequential test off, the lab's diagnosis names backlash on the joints its buffer
    shows (backlash[1] on this seed); the estimator takes backlash on every joint, as the
    sequential test adds it, so a joint that reverses later is already modelled."""
    _, r = _run("backlash", 1, select=False)
    lab = [d for d in r.report["diagnoses"] if d["kept"]]
    assert lab and all(d["method"] == "lab" for d in lab)
    assert any(k.startswith("backlash[") for k in lab[0]["kept"]), lab[0]
    assert "backlash" in r.report["diagnosed_effects"], r.report["diagnosed_effects"]


def test_the_settings_are_declared_and_every_bad_one_named_at_once():
    """The agent's own settings are a declared, frozen DiagnosisSettings: bad values are refused
    together, by the agent, by make_agent and by a config's check, in the same words."""
    from agents.registry import AgentError, check_settings
    from agents.self_diagnosis import DiagnosingMPCAgent, DiagnosisSettings

    with pytest.raises(ValueError) as info:
        DiagnosingMPCAgent(alpha=2.0, growth=0.5, holdout=0.7)
    for part in (
        "alpha must lie in (0, 1), got 2.0",
        "growth must be a number > 1, got 0.5",
        "holdout must lie in [0.1, 0.5], got 0.7",
    ):
        assert part in str(info.value)
    with pytest.raises(AgentError, match=r"alpha must lie in \(0, 1\), got 2.0"):
        check_settings("mpc-diagnose", {"alpha": 2.0})
    with pytest.raises(ValueError, match=r"window .* must be at least first_points"):
        DiagnosisSettings(window=12, first_points=20)
    agent = make_agent("mpc-diagnose", alpha=0.05, horizon=12)
    assert agent.settings == DiagnosisSettings(alpha=0.05)


@pytest.mark.parametrize("seed", [2, 9])
def test_on_cyclic_errors_the_labs_scan_finds_an_order_and_tracking_improves(seed):
    """The lab's diagnosis scans cyclic joint errors by default: on the `cyclic` scenario it
    names a joint and an order (these seeds: cyclic[2:23], cyclic[3:12]), and the settled
    tracking is better than the same agent's without the scan on the same episode."""
    without = candidate_effects()  # every effect tested whole: the catalogue but the scan
    _, r = _run("cyclic", seed)
    assert "cyclic" not in without
    _, r0 = _run("cyclic", seed, candidates=without)
    assert any(e.startswith("cyclic[") for e in r.report["diagnosed_effects"]), r.report
    assert not any(e.startswith("cyclic") for e in r0.report["diagnosed_effects"])
    settled = slice(len(r.true_error_mm) // 4, None)
    rms = np.sqrt(np.mean(r.true_error_mm[settled] ** 2))
    rms0 = np.sqrt(np.mean(r0.true_error_mm[settled] ** 2))
    assert rms < rms0


def test_the_labs_warnings_from_the_worker_thread_point_at_the_caller_not_threading():
    """The lab's cautions in a worker (a short buffer is a poor pose set) are kept with the job
    and issued when it is adopted, attributed to the code that runs the episode (here: this
    file), saying which job gave them; never to threading.py, where the worker's stack begins."""
    import types
    import warnings

    from agents.self_diagnosis import WORKER, Deferred
    from arm.errors import warn
    from lab import PoorPoseSetWarning

    def work(job, text: str) -> None:
        warn(text, PoorPoseSetWarning)  # as lab.identifiability does, from the worker thread
        job.cost_s = 1e-3

    jobs = Deferred(lag=3, label="")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        jobs.start(40, types.SimpleNamespace(cost_s=0.0), work, "poor set")  # a job
        jobs.join()
        assert not caught, "issued in the worker, before the job was adopted"
        job, _ = jobs.finish(dt=0.02)
    assert job.warnings == [("poor set", PoorPoseSetWarning)]
    assert [(w.category, str(w.message)) for w in caught] == [
        (PoorPoseSetWarning, f"{WORKER} at step 40: poor set")
    ]
    assert caught[0].filename == __file__


def test_the_labs_log_records_from_a_worker_thread_stay_the_agents(caplog):
    """Every module of the lab is quiet in the agent's worker threads (a short buffer's
    plausibility, outliers and domain lines are the agent's business), and speaks elsewhere."""
    import logging
    import threading

    from agents.self_diagnosis import WORKER

    def log_from_every_module():
        for name in ("lab.estimation", "lab.screening", "lab.domain", "lab.diagnosis"):
            logging.getLogger(name).warning("from %s", name)

    with caplog.at_level(logging.WARNING):
        t = threading.Thread(target=log_from_every_module, name=f"{WORKER} step 7")
        t.start()
        t.join()
        assert [r.getMessage() for r in caplog.records] == []
        log_from_every_module()  # the main thread: said
    assert [r.getMessage() for r in caplog.records] == [
        "from lab.estimation",
        "from lab.screening",
        "from lab.domain",
        "from lab.diagnosis",
    ]
