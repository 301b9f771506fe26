"""One error family: every error the project raises on purpose derives from SixAxisError and keeps
its built-in parent, and the CLI turns any of them into one ``error:`` line with exit code 2."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from arm.effect_api import EffectError
from arm.errors import SixAxisError
from experiments.cli import app
from lab.errors import LabError

PACKAGES = ("arm", "envs", "lab", "agents", "experiments")
ROOT = Path(__file__).resolve().parent.parent


def _project_errors() -> list[type[BaseException]]:
    found = []
    for pkg in PACKAGES:
        for info in pkgutil.walk_packages([str(ROOT / pkg)], prefix=f"{pkg}."):
            module = importlib.import_module(info.name)
            for _, obj in inspect.getmembers(module, inspect.isclass):
                if (
                    issubclass(obj, BaseException)
                    and not issubclass(obj, Warning)  # cautions, not errors
                    and obj.__module__ == module.__name__
                ):
                    found.append(obj)
    return found


ERRORS = _project_errors()


def test_the_project_has_its_error_classes():
    names = {e.__name__ for e in ERRORS}
    # a sample of the family across the layers: if these vanish, the walk above finds nothing
    assert {"DescriptionError", "MeasurementError", "FitError", "ScenarioError"} <= names
    assert {"AgentError", "ConfigError", "SweepError", "CollectError"} <= names


@pytest.mark.parametrize("cls", ERRORS, ids=lambda c: f"{c.__module__}.{c.__name__}")
def test_every_error_is_a_sixaxis_error_with_its_builtin_parent(cls):
    if cls is SixAxisError or cls is LabError:  # the bases: no built-in parent of their own
        return
    assert issubclass(cls, SixAxisError), f"{cls.__name__} does not derive from SixAxisError"
    builtin = [
        b
        for b in cls.__mro__
        if b.__module__ == "builtins" and b not in (Exception, BaseException, object)
    ]
    assert builtin, f"{cls.__name__} has no built-in parent (ValueError, RuntimeError...)"


def test_the_known_parents_are_kept():
    by_name = {e.__name__: e for e in ERRORS}
    assert issubclass(by_name["SweepError"], RuntimeError)
    for name in ("DescriptionError", "EffectError", "MeasurementError", "FitError", "ConfigError"):
        assert issubclass(by_name[name], ValueError)


def test_the_cli_reports_any_project_error_as_one_line(tmp_path):
    # a SweepError (a RuntimeError, not a ValueError): an unknown backend
    config = ROOT / "experiments" / "configs" / "quick.toml"
    res = CliRunner().invoke(
        app, ["sweep", str(config), "--backend", "nope", "--out", str(tmp_path / "runs")]
    )
    assert res.exit_code == 2, res.output
    assert "error: unknown backend 'nope'" in res.output
    assert "Traceback" not in res.output


@pytest.mark.parametrize(
    ("spec", "said"),
    [
        ("geometric,compliance[2,3", "an unclosed '['"),
        ("geometric,compliance]2,3[", "a ']' without its '['"),
        ("cyclic[[2:17]]", "a '[' inside another"),
    ],
)
def test_an_effect_specification_with_unbalanced_brackets_says_so(spec, said):
    """Not 'bad effect specification '2'' (the fragment a split left), but what is wrong."""
    from arm.effects import parse_effects

    with pytest.raises(EffectError, match=re.escape(f"bad effect specification {spec!r}: {said}")):
        parse_effects(spec)
    assert [e.name for e in parse_effects("geometric,compliance[2,3]")] == [
        "geometric",
        "compliance",
    ]


def test_collected_warnings_take_this_threads_warnings_alone():
    import threading
    import warnings

    from arm.errors import SixAxisWarning, collected_warnings, warn

    with warnings.catch_warnings(record=True) as issued:
        warnings.simplefilter("always")
        with collected_warnings() as mine:
            warn("kept")
            other = threading.Thread(target=warn, args=("from another thread",))
            other.start()
            other.join()
        warn("issued again")
    assert mine == [("kept", SixAxisWarning)]
    assert [str(w.message) for w in issued] == ["from another thread", "issued again"]
    assert issued[1].filename == __file__
