"""The lab's one path for a measurement: screening is one explicit step (``lab.screen``) whose
result every entry point takes and none screens again, and one vocabulary of options
(``lab.LabOptions``) that every entry point takes alike and refuses alike."""

from __future__ import annotations

import ast
import inspect
import math
import warnings
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

import lab
from arm.measurements import MeasurementSet
from lab import screening
from lab.options import LabOptions
from lab.report import build_report
from tests._lab_data import SIGMA, campaign

NOISE_MM = 1e3 * SIGMA
LAB = Path(lab.__file__).parent
ENTRY_POINTS = {
    "screen": lab.screen,
    "fit": lab.fit,
    "diagnose": lab.diagnose,
    "discover": lab.discover,
    "build_report": build_report,
}


@pytest.fixture(scope="module")
def dirty(seed) -> MeasurementSet:
    """200 poses of an arm with hidden compliance, three gross outliers and a copied row."""
    d = campaign(seed, "geometric,compliance", seed=501).measure(200)
    xyz = d.xyz.copy()
    xyz[[17, 90, 151]] += [[1e-3, 0, 0], [0, -1.5e-3, 0], [0, 0, 2e-3]]
    idx = np.r_[np.arange(200), 40]
    return MeasurementSet(d.q[idx], xyz[idx], {k: v[idx] for k, v in d.columns.items()}, "dirty")


# -- one step ---------------------------------------------------------------------------------------
def test_screening_takes_no_callbacks_into_identification():
    """The rule calls the fit of the rows (lab.estimation.fit_rows) itself: no function of the
    screening module takes a function as an argument."""
    tree = ast.parse((LAB / "screening.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            for a in [*node.args.args, *node.args.kwonlyargs]:
                hint = ast.unparse(a.annotation) if a.annotation is not None else ""
                assert "Callable" not in hint, (node.name, a.arg)
    imported = {
        (n.module, a.name) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names
    }
    assert ("lab.estimation", "fit_rows") in imported


def test_diagnose_and_build_report_screen_nothing_themselves(seed, dirty, monkeypatch):
    """Given a screen, the diagnosis and the report use its rows: with every step of the rule
    made to fail, both still run, and give what they give on the data."""
    rows = lab.screen(dirty, seed, "geometric", noise_mm=NOISE_MM)
    assert len(rows.fit.outlier_list) == 3 and len(rows.fit.duplicates) == 1
    whole = lab.diagnose(dirty, seed, "geometric", noise_mm=NOISE_MM).to_dict()

    def screened_again(*args, **kwargs):
        raise AssertionError("screened again")

    for name in ("judge", "duplicate_rows", "_fit_outliers", "_untested", "_screen"):
        monkeypatch.setattr(screening, name, screened_again)
    d = lab.diagnose(rows)
    assert d.to_dict() == whole
    assert d.verdict == "compliance" and list(d.outliers) == [17, 90, 151]
    report = build_report(rows)
    assert [r.label for r in report.runs][:2] == ["nominal", "geometric"]
    assert [o.index for o in report.outliers] == [17, 90, 151] and len(report.duplicates) == 1
    # and their modules import nothing of the rule but the screen and its helpers
    for module in ("diagnosis.py", "report.py"):
        tree = ast.parse((LAB / module).read_text())
        names = {
            a.name
            for n in ast.walk(tree)
            if isinstance(n, ast.ImportFrom) and n.module == "lab.screening"
            for a in n.names
        }
        assert names <= {"Screen", "screened", "annotate"}, (module, names)


def test_the_fit_of_a_screen_is_the_fit_of_the_data(seed, dirty):
    direct = lab.fit(dirty, seed, "geometric")
    rows = lab.screen(dirty, seed, "geometric", tests=False)
    assert lab.fit(rows).to_dict() == direct.to_dict()
    assert rows.fit.to_dict() == direct.to_dict()
    assert len(rows.kept) == 200 - 3 and rows.fit.n_rows == 201
    # another model on the same rows: nothing more left out, the rows compare pose by pose
    wider = lab.fit(rows, effects="geometric,compliance")
    assert wider.n_points == 197 and wider.outliers_mode == "keep"
    assert wider.rms_mm < direct.rms_mm


def test_a_screen_carries_its_options(seed, dirty):
    rows = lab.screen(dirty, seed, "geometric", noise_mm=NOISE_MM, tests=False)
    assert lab.fit(rows, noise_mm=NOISE_MM).to_dict() == rows.fit.to_dict()
    with pytest.raises(lab.FitError, match=r"other options than noise_mm=0\.02"):
        lab.fit(rows, noise_mm=0.02)
    with pytest.raises(lab.FitError, match="robot"):
        lab.fit(rows, seed)
    with pytest.raises(lab.FitError, match="tests=True"):
        lab.diagnose(rows)


# -- one vocabulary ---------------------------------------------------------------------------------
def test_every_entry_point_takes_the_same_options():
    # data, robot, effects, then options= or the fields of LabOptions as keywords, typed once
    # (OptionFields), which must not drift from the options themselves: the same names, in the
    # same order, with the same types
    from lab.options import OptionFields

    declared = {f.name: f.type for f in fields(LabOptions)}
    assert list(OptionFields.__annotations__) == list(declared)
    for name, kind in OptionFields.__annotations__.items():
        assert getattr(kind, "__forward_arg__", kind) == declared[name], name
    for label, f in ENTRY_POINTS.items():
        params = inspect.signature(f).parameters
        assert list(params)[:3] == ["data", "robot", "effects"], label
        assert [p.default for p in list(params.values())[1:3]] == [None, None], label
        assert params["options"].kind is inspect.Parameter.KEYWORD_ONLY, label
        assert params["keywords"].kind is inspect.Parameter.VAR_KEYWORD, label
        assert not declared.keys() & params.keys(), label  # spelled out nowhere else


@pytest.mark.parametrize("bad", [-1, 0, math.nan, math.inf])
def test_a_bad_noise_is_refused_alike_everywhere(seed, bad):
    """lab.fit once accepted noise_mm=-1, 0 and NaN, lab.diagnose accepted inf: now every entry
    point refuses each, with one message, before any work (0 states no noise without a
    distance term: arm.noise's rule)."""
    data = campaign(seed, "geometric", seed=3).measure(40)
    messages = set()
    for f in ENTRY_POINTS.values():
        with pytest.raises(lab.FitError) as info:
            f(data, seed, "geometric", noise_mm=bad)
        messages.add(str(info.value))
    if bad == 0:
        assert len(messages) == 1 and "noise_mm 0 without noise_ppm" in messages.pop()
    else:
        assert messages == {f"noise_mm must be >= 0 (mm), got {bad!r}"}


def test_every_bad_option_is_named_at_once():
    with pytest.raises(lab.FitError) as info:
        LabOptions(noise_mm=-1, loss="l2", outliers="drop", max_evaluations=0, accept_large=1)
    text = str(info.value)
    for part in (
        "noise_mm must be >= 0 (mm), got -1",
        "loss must be one of linear, huber, soft_l1, got 'l2'",
        "outliers must be one of auto, keep, got 'drop'",
        "accept_large must be true or false, got 1",
        "max_evaluations must be an integer >= 1, got 0",
    ):
        assert part in text


def test_options_are_given_once(seed):
    data = campaign(seed, "geometric", seed=3).measure(40)
    opts = LabOptions(noise_mm=NOISE_MM)
    with pytest.raises(lab.FitError, match="noise_mm given both as a keyword and in options="):
        lab.fit(data, seed, options=opts, noise_mm=0.02)
    by_object = lab.fit(data, seed, options=opts).to_dict()
    assert by_object == lab.fit(data, seed, noise_mm=NOISE_MM).to_dict()


def test_one_fit_resolves_its_options_and_parses_its_effects_once(seed, dirty, monkeypatch):
    # the outlier rule fits the model several times (dirty has three gross outliers): the
    # options are resolved by the entry point, the effects parsed once for all those fits
    import arm.effects.specs as specs
    import lab.identification
    import lab.options

    resolved, parsed = [], []
    resolve, make = lab.options.resolve, specs.make_effect

    def counted_resolve(*args, **kw):
        resolved.append(1)
        return resolve(*args, **kw)

    def counted_make(spec):
        if isinstance(spec, str):
            parsed.append(spec)
        return make(spec)

    for module in (lab.identification, screening):
        monkeypatch.setattr(module, "resolve", counted_resolve, raising=False)
    monkeypatch.setattr(specs, "make_effect", counted_make)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = lab.fit(dirty, seed, "geometric,compliance[2,3]", noise_mm=NOISE_MM)
    assert len(result.outlier_list) == 3  # the rule refitted
    assert len(resolved) == 1
    assert parsed == ["geometric", "compliance[2,3]"]


def test_an_unknown_option_is_refused(seed):
    data = campaign(seed, "geometric", seed=3).measure(40)
    with pytest.raises(TypeError, match="noise_nm"):
        lab.fit(data, seed, noise_nm=0.015)
    with pytest.raises(TypeError, match="noise_nm"):
        lab.fit(data, seed, options=LabOptions(), noise_nm=0.015)


# -- cautions ---------------------------------------------------------------------------------------
def test_cautions_are_warnings_pointing_at_the_callers_line(seed, dirty, caplog):
    with pytest.warns(lab.RowsLeftOutWarning) as caught:
        lab.fit(dirty, seed, "geometric")
    texts = [str(w.message) for w in caught]
    assert any("repeat an earlier row exactly" in t for t in texts)
    assert any("3 outlier(s) left out of the fit (row 18, row 91, row 152)" in t for t in texts)
    assert {w.filename for w in caught} == {__file__}
    assert "3 outlier(s) left out of the fit" in caplog.text  # and still in the log
    c = campaign(seed, "geometric", seed=3)
    q = c.measure(60).q
    huddled = c.measure(q[:1] + 0.05 * (q - q[:1]))  # 60 poses within 5 % of one posture
    with warnings.catch_warnings():
        warnings.simplefilter("error", lab.PoorPoseSetWarning)  # a user refusing poor poses
        with pytest.raises(lab.PoorPoseSetWarning, match="poor pose set"):
            lab.fit(huddled, seed, "geometric")
