"""One error tree (arm/errors.py's docstring): the packages raise no bare built-in exception
(``raise ValueError(...)``) outside the listed exceptions below, every exception class they define
derives from ``SixAxisError`` (a caution from ``SixAxisWarning``), the lab's from the lab's bases,
and the classes live in the packages' ``errors`` modules.

The walk reads the source (AST), so it sees every raise, in every function, whether a test runs
it or not. Exceptions of other libraries (``typer.Exit``, numpy's ``LinAlgError`` caught by the
solver) are not built-ins, and mean what their library says."""

from __future__ import annotations

import ast
import builtins
import importlib
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from arm.errors import SixAxisError, SixAxisWarning
from lab.errors import LabError, LabWarning

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("arm", "lab", "envs", "agents", "experiments")
BUILTIN_ERRORS = {
    name
    for name, obj in vars(builtins).items()
    if isinstance(obj, type) and issubclass(obj, BaseException)
}

# The built-in raises that stay, each with its reason. By rule (any module):
# - ``raise`` alone re-raises what was caught: not a new error (not a Raise with an argument).
# - ``NotImplementedError`` as the whole body of a method: an abstract method's, for a subclass.
# - ``AttributeError`` in a module's ``__getattr__``: the protocol of module attributes (PEP 562).
# - ``StopIteration``: the iterator protocol.
PROTOCOL = {"StopIteration"}
# ... and by place, (module, function, exception): reason.
ALLOWED = {
    ("agents/isolation.py", "_read_exact", "TimeoutError"): (
        "the wire's signal to its reader that the agent's process did not answer in time; "
        "caught in the same module and turned into TimeLimitExceeded or AgentFailure"
    ),
    ("agents/isolation.py", "_read_exact", "EOFError"): (
        "the wire's signal that the agent's process closed its end; caught in the same module"
    ),
    ("agents/isolation.py", "_receive", "EOFError"): (
        "a reply longer than the limit is treated as a broken wire; caught in the same module"
    ),
    ("experiments/cli_lab.py", "_terminated", "SystemExit"): (
        "the signal handler's exit status, 128 + the signal, as a shell reports a killed command"
    ),
}


def _files() -> list[Path]:
    return [f for pkg in PACKAGES for f in sorted((ROOT / pkg).rglob("*.py"))]


def _raised_name(node: ast.Raise) -> str | None:
    """The name a ``raise`` raises (``ValueError`` of ``raise ValueError(...)``), or None."""
    exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
    return exc.id if isinstance(exc, ast.Name) else None


def _abstract(func: ast.AST) -> bool:
    """A method whose body is a docstring (maybe) and ``raise NotImplementedError``."""
    if not isinstance(func, ast.FunctionDef | ast.AsyncFunctionDef):
        return False
    body = func.body[1:] if ast.get_docstring(func) is not None else func.body
    return len(body) == 1 and isinstance(body[0], ast.Raise)


def _walk(node: ast.AST, func: ast.AST | None = None) -> Iterator[tuple[ast.AST, ast.AST | None]]:
    """Every node with the function that holds it (None at module level)."""
    for child in ast.iter_child_nodes(node):
        yield child, func
        inner = child if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef) else func
        yield from _walk(child, inner)


def bare_raises(source: str, rel: str) -> Iterator[tuple[int, str, str]]:
    """(line, function, exception) of every raise of a built-in exception in ``source`` that no
    rule or entry of the allow-list covers; a built-in passed to ``arm.constraints.refuse`` as
    the error to raise counts as one."""
    for node, func in _walk(ast.parse(source, rel)):
        name = getattr(func, "name", "<module>")
        if isinstance(node, ast.Raise) and node.exc is not None:
            exc = _raised_name(node)
        elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == "refuse":
            exc = next((a.id for a in node.args[1:2] if isinstance(a, ast.Name)), None)
        else:
            continue
        if exc not in BUILTIN_ERRORS or exc in PROTOCOL:
            continue
        if exc == "NotImplementedError" and func is not None and _abstract(func):
            continue
        if exc == "AttributeError" and name == "__getattr__":
            continue
        if (rel, name, exc) not in ALLOWED:
            yield node.lineno, name, exc


def test_the_walk_finds_a_bare_raise_and_lets_the_listed_ones_through():
    code = (
        "def f(x):\n    if x:\n        raise ValueError('x must be 1')\n    refuse([], KeyError)\n"
        "class A:\n    def g(self):\n        '''abstract'''\n        raise NotImplementedError\n"
        "    def h(self):\n        x = 1\n        raise NotImplementedError(x)\n"
        "def __getattr__(name):\n    raise AttributeError(name)\n"
        "def _read_exact():\n    raise TimeoutError\n"
    )
    found = list(bare_raises(code, "agents/isolation.py"))
    assert found == [(3, "f", "ValueError"), (4, "f", "KeyError"), (11, "h", "NotImplementedError")]
    assert list(bare_raises(code, "agents/other.py"))[-1] == (15, "_read_exact", "TimeoutError")


def test_no_package_raises_a_bare_builtin_error():
    bad = [
        f"{f.relative_to(ROOT)}:{line} ({func}) raises a bare {exc}: raise a project error "
        "(the package's errors.py) that keeps it as a parent"
        for f in _files()
        for line, func, exc in bare_raises(f.read_text(), str(f.relative_to(ROOT)))
    ]
    assert not bad, "\n".join(bad)


def test_every_entry_of_the_allow_list_is_still_needed():
    used = set()
    for rel, func, exc in ALLOWED:
        tree = ast.parse((ROOT / rel).read_text())
        for node, holder in _walk(tree):
            if isinstance(node, ast.Raise) and node.exc is not None:
                if _raised_name(node) == exc and getattr(holder, "name", None) == func:
                    used.add((rel, func, exc))
    assert used == set(ALLOWED), f"stale entries: {set(ALLOWED) - used}"


# -- the classes ---------------------------------------------------------------------------------
def _exception_classes() -> list[tuple[str, str, type[BaseException]]]:
    """(module, qualified name, class) of every exception class the packages define at module
    level; a class defined inside a function would escape the walk, and is refused."""
    out = []
    for f in _files():
        rel = f.relative_to(ROOT).with_suffix("")
        module = ".".join(rel.parts).removesuffix(".__init__")
        tree = ast.parse(f.read_text())
        nested = [
            n.name
            for n, holder in _walk(tree)
            if isinstance(n, ast.ClassDef) and holder is not None
        ]
        assert not [n for n in nested if n.endswith(("Error", "Warning", "Exception"))], (
            f"{rel}: exception classes inside a function: define them in errors.py"
        )
        tops = [n.name for n in tree.body if isinstance(n, ast.ClassDef)]
        if not tops:
            continue
        mod = importlib.import_module(module)
        for name in tops:
            cls = getattr(mod, name)
            if isinstance(cls, type) and issubclass(cls, BaseException):
                out.append((module, name, cls))
    return out


CLASSES = _exception_classes()
# where an exception class may be defined besides the packages' errors modules, with the reason
ELSEWHERE = {
    "experiments.cli_inputs.DeclaredError": (
        "a refused command-line value is a typer.BadParameter; experiments/errors.py imports "
        "no typer (configs, sweeps and records are used without the command line)"
    ),
}


def test_the_walk_finds_the_classes():
    names = {name for _, name, _ in CLASSES}
    assert {"SixAxisError", "LabError", "FitError", "MeasurementError", "ScenarioError"} <= names
    assert {"AgentFailure", "ConfigError", "DeclaredError", "OutOfDomainWarning"} <= names


@pytest.mark.parametrize(("module", "name", "cls"), CLASSES, ids=lambda v: str(v))
def test_every_exception_class_is_in_the_tree(module, name, cls):
    if issubclass(cls, Warning):
        assert issubclass(cls, SixAxisWarning), f"{module}.{name} is not a SixAxisWarning"
    else:
        assert issubclass(cls, SixAxisError), f"{module}.{name} is not a SixAxisError"
    if module.startswith("lab."):
        base = LabWarning if issubclass(cls, Warning) else LabError
        if cls not in (LabWarning, LabError):
            assert issubclass(cls, base), f"{module}.{name} does not derive from {base.__name__}"
    if module.rpartition(".")[2] != "errors":
        assert f"{module}.{name}" in ELSEWHERE, f"{module}.{name}: define it in errors.py"


def test_every_class_outside_the_errors_modules_is_still_there():
    where = {f"{module}.{name}" for module, name, _ in CLASSES}
    assert set(ELSEWHERE) <= where


@pytest.mark.parametrize("pkg", PACKAGES)
def test_each_package_keeps_its_errors_module_short(pkg):
    """Few classes, each saying when it is raised: one line of docstring or a few."""
    path = ROOT / pkg / "errors.py"
    tree = ast.parse(path.read_text())
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    assert classes and all(ast.get_docstring(c) for c in classes)
    assert len(classes) <= 20


def test_the_old_import_paths_still_work():
    import agents.errors
    import arm.errors
    import envs.errors
    import experiments.errors
    import lab.errors
    from agents.runner import AgentFailure, TimeLimitExceeded
    from arm.measurements import MeasurementError
    from envs.scenarios import ScenarioError
    from experiments.config import ConfigError
    from lab.export import CompensationError, ExportError

    assert MeasurementError is arm.errors.MeasurementError
    assert (
        ExportError is lab.errors.ExportError and CompensationError is lab.errors.CompensationError
    )
    assert ScenarioError is envs.errors.ScenarioError
    assert AgentFailure is agents.errors.AgentFailure
    assert TimeLimitExceeded is agents.errors.TimeLimitExceeded
    assert ConfigError is experiments.errors.ConfigError
    assert issubclass(ExportError, LabError) and issubclass(ExportError, ValueError)


@pytest.mark.parametrize("pkg", PACKAGES)
def test_docs_architecture_lists_every_class_of_each_errors_module(pkg):
    """The table of docs/architecture.md, "Errors": each errors module's row names its classes
    (the lab's cautions as "the cautions under it")."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith(f"| `{pkg}.errors` |"))
    named = set(re.findall(r"`(\w+)`", row.split("|")[2]))
    module = importlib.import_module(f"{pkg}.errors")
    defined = {
        name
        for name, obj in vars(module).items()
        if isinstance(obj, type)
        and issubclass(obj, BaseException)
        and obj.__module__ == module.__name__
    }
    if pkg == "lab":  # the cautions are named as a group
        defined = {n for n in defined if not issubclass(getattr(module, n), Warning)} | {
            "LabWarning"
        }
    assert defined <= named, f"docs/architecture.md does not name {sorted(defined - named)}"
