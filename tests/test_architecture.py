"""The import rules of docs/architecture.md hold: each package imports only the layers below it,
the arm model and the lab load no simulator, the task contract loads no plant, no module imports
another's private names, and no modules import each other in a circle."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("arm", "envs", "lab", "agents", "experiments")

# docs/architecture.md, "Layers": the project packages each package may import
ALLOWED = {
    "arm": set(),
    "lab": {"arm"},
    "envs": {"arm"},
    "agents": {"arm", "envs", "lab"},
    "experiments": {"arm", "envs", "lab", "agents"},
}
# ... and the simulators the arm model and the lab never import
NO_SIMULATOR = {"mujoco", "gymnasium"}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            parts = f.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts).removesuffix(".__init__")] = f
    return out


MODULES = _modules()


def _imports(path: Path) -> list[tuple[int, str, list[str]]]:
    """(line, module, names) of every absolute import in a file, at any depth (lazy imports in
    functions and TYPE_CHECKING blocks included); ``names`` empty for ``import x``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module, [a.name for a in node.names]))
    return out


def _project_module(name: str) -> str | None:
    """The project module an import resolves to (the longest known prefix), or None."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def test_the_module_walk_finds_every_package():
    assert {m.split(".")[0] for m in MODULES} == set(PACKAGES)
    assert "arm.errormodel" in MODULES and "envs.task" in MODULES


@pytest.mark.parametrize("pkg", PACKAGES)
def test_each_package_imports_only_the_layers_below_it(pkg):
    bad = []
    for mod, path in MODULES.items():
        if mod.split(".")[0] != pkg:
            continue
        for line, name, _ in _imports(path):
            top = name.split(".")[0]
            if top in PACKAGES and top != pkg and top not in ALLOWED[pkg]:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
            if pkg in ("arm", "lab") and top in NO_SIMULATOR:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    assert not bad, "\n".join(bad)


def test_no_module_imports_a_private_name_from_another():
    bad = []
    for path in [*MODULES.values(), *sorted((ROOT / "tests").glob("*.py"))]:
        for line, name, names in _imports(path):
            if name.split(".")[0] not in PACKAGES:
                continue
            for n in names:
                if n.startswith("_") and not n.startswith("__"):
                    bad.append(f"{path.relative_to(ROOT)}:{line} imports {n} from {name}")
    assert not bad, "\n".join(bad)


def test_no_import_circle():
    graph: dict[str, set[str]] = defaultdict(set)
    for mod, path in MODULES.items():
        for _, name, names in _imports(path):
            for target in [f"{name}.{n}" for n in names] or [name]:
                dep = _project_module(target)
                if dep is not None and dep != mod and dep != mod.split(".")[0]:
                    graph[mod].add(dep)
    # depth-first search for a back edge
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        path.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                return [*path[path.index(d) :], d]
            if d not in state and (cycle := visit(d)):
                return cycle
        state[m] = 2
        path.pop()
        return None

    for m in sorted(MODULES):
        if m not in state:
            cycle = visit(m)
            assert cycle is None, " -> ".join(cycle)


def _loaded_after(statement: str, modules: list[str]) -> list[str]:
    """The ``modules`` loaded by a fresh interpreter after ``statement``."""
    code = f"import sys\n{statement}\nprint(','.join(m for m in {modules!r} if m in sys.modules))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    return [m for m in out.stdout.strip().split(",") if m]


def test_arm_and_lab_load_neither_mujoco_nor_gymnasium():
    assert _loaded_after("import arm, lab", ["mujoco", "gymnasium"]) == []


def test_the_task_contract_loads_no_plant():
    loaded = _loaded_after("import envs.task", ["mujoco", "envs.plant", "envs.sixaxis_track_v0"])
    assert loaded == []


# docs/architecture.md, "Inside lab": each row builds only on the rows above it (and its own)
LAB_ORDER = [
    {"errors", "options", "text", "terms"},
    {
        "blocks",
        "identifiability",
        "selection",
        "plausibility",
        "repeatability",
        "observations",
        "domain",
    },
    {"solver", "registration", "result"},
    {"estimation", "sanity", "folds"},
    {"candidates", "spectral", "lumped_choice"},
    {"screening"},
    {"identification", "transfer"},
    {"uncertainty"},
    {"diagnosis", "discovery", "planning", "export", "update", "prediction"},
    {"urdf_export", "bagging"},
    {"report", "lab_report", "report_html", "plots"},
]


def test_the_lab_modules_build_only_on_those_above_them():
    row = {m: k for k, names in enumerate(LAB_ORDER) for m in names}
    assert set(row) == {m.split(".")[1] for m in MODULES if m.startswith("lab.")}
    for name, k in row.items():
        for line, imported, names in _imports(MODULES[f"lab.{name}"]):
            for target in [f"{imported}.{n}" for n in names] or [imported]:
                dep = _project_module(target)
                if dep is None or not dep.startswith("lab.") or dep == f"lab.{name}":
                    continue
                assert row[dep.split(".")[1]] <= k, f"lab/{name}.py:{line} imports {dep}"


# docs/architecture.md, `effects` in `arm`: one module a job, each building on the rows above it
EFFECTS_ORDER = [{"base"}, {"joint_angle", "chain", "lumped", "extra"}, {"registry"}, {"specs"}]


def test_the_effects_modules_build_only_on_those_above_them():
    row = {m: k for k, names in enumerate(EFFECTS_ORDER) for m in names}
    assert set(row) == {m.split(".")[2] for m in MODULES if m.startswith("arm.effects.")}
    for name, k in row.items():
        for line, imported, names in _imports(MODULES[f"arm.effects.{name}"]):
            for target in [f"{imported}.{n}" for n in names] or [imported]:
                dep = _project_module(target)
                if dep is None or not dep.startswith("arm.effects") or dep == f"arm.effects.{name}":
                    continue
                assert dep != "arm.effects", f"arm/effects/{name}.py:{line} imports the package"
                assert row[dep.split(".")[2]] <= k, f"arm/effects/{name}.py:{line} imports {dep}"


def test_the_lab_runs_no_code_made_of_text():
    """Discovery's terms are data (lab.terms): nothing in the lab ``eval``s, ``exec``s or
    compiles a string of code, so what it runs is what its modules say."""
    bad = []
    for mod, path in MODULES.items():
        if not mod.startswith("lab."):
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                if node.func.id in {"eval", "exec", "compile"}:
                    bad.append(f"{path.relative_to(ROOT)}:{node.lineno} calls {node.func.id}")
    assert not bad, "\n".join(bad)


LONGEST_FUNCTION = 120  # lines; issue 37 brought lab.estimation.fit_rows (127) under it


def test_no_function_of_the_packages_runs_past_a_screenful_or_two():
    """A function a reader can hold: none of the packages' is longer than LONGEST_FUNCTION
    lines (its decorators and docstring included)."""
    long = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    lines = node.end_lineno - node.lineno + 1  # type: ignore[operator]
                    if lines > LONGEST_FUNCTION:
                        long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({lines})")
    assert not long, long
