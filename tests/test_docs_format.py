"""docs/format.md stays true: it names every parameter family the catalogue has, with the unit
and typical magnitude the code uses; its seed-arm table is the shipped seed arm; its measurement
CSV table has every column the reader knows, with the reader's physical ranges; its robot TOML
tables have every key the writer emits; and each JSON section lists exactly the keys that the
command prints, nested objects included (the commands run on small generated data sets)."""

from __future__ import annotations

import json
import math
import re
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from arm.description import RobotDescription, seed_robot
from arm.effects import CATALOGUE, EFFECTS, Geometric, make_effect
from arm.extra_joints import ExtraJoint
from arm.measurements import (
    JOINTS,
    KNOWN,
    POSITION,
    MeasurementSet,
    write_measurements,
)
from arm.params import parameter_unit, parse_parameter_name
from arm.ranges import MAX_EXTRA, RANGES
from experiments.cli import app
from tests import _hidden_forms as hidden
from tests._lab_data import SIGMA, campaign

DOC = Path(__file__).resolve().parents[1] / "docs" / "format.md"
TEXT = DOC.read_text(encoding="utf-8")
runner = CliRunner()


# -- reading the page -------------------------------------------------------------------------------
def section(title: str) -> str:
    """The text under the heading ``title`` (any level), up to the next heading of that level or
    above (lines in fenced code blocks are not headings)."""
    start = level = None
    fenced = False
    lines = TEXT.splitlines()
    for k, line in enumerate(lines):
        if line.startswith("```"):
            fenced = not fenced
        m = None if fenced else re.match(r"(#+) (.*?)\s*$", line)
        if m is None:
            continue
        if start is None and m.group(2) == title:
            start, level = k + 1, len(m.group(1))
        elif start is not None and level is not None and len(m.group(1)) <= level:
            return "\n".join(lines[start:k])
    assert start is not None, f"docs/format.md has no heading {title!r}"
    return "\n".join(lines[start:])


def rows(text: str) -> list[list[str]]:
    """The body rows of every Markdown table in ``text``, as lists of cells."""
    out = []
    for line in text.splitlines():
        if not line.startswith("|") or re.fullmatch(r"\|[-| ]+\|", line.strip()):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        out.append(cells)
    return [r for r in out if not (r and r[0] in ("key", "effect", "column", "i"))]  # headers


def names(cell: str) -> list[str]:
    """The backticked names in a cell: ``outliers[].row``, ``q1``."""
    return re.findall(r"`([^`]+)`", cell)


def documented_keys(title: str) -> set[str]:
    return {n for r in rows(section(title)) for n in names(r[0])}


def json_keys(obj: dict) -> set[str]:
    """The keys of a JSON object, and ``key[].sub`` for the keys of objects in a list under
    ``key``. Maps of names to values (``parameters``, ``skipped``) are not objects with fixed
    keys and are not descended into."""
    out = set(obj)
    for k, v in obj.items():
        if isinstance(v, list):
            for item in v:
                if isinstance(item, dict):
                    out |= {f"{k}[].{s}" for s in item}
    return out


def number(text: str) -> float:
    return float(text.replace("−", "-").replace("+", ""))


# -- parameter names --------------------------------------------------------------------------------
def code_families() -> dict[str, tuple[str, str, tuple[float, float] | None]]:
    """family -> (effect, SI unit, typical range) for every parameter the catalogue names on the
    seed arm, with one target and with several."""
    seed = seed_robot()
    # an effect of extra joints names its parameters on an arm that has them: a column, a table
    on_column = replace(
        seed,
        extra_joints=(ExtraJoint("column", "prismatic"), ExtraJoint("table", "revolute")),
    )
    out: dict[str, tuple[str, str, tuple[float, float] | None]] = {}
    for name in CATALOGUE:
        effect = make_effect(EFFECTS[name].example or name)
        arm = on_column if effect.needs_extra_joints else seed
        for targets in ((0,), (0, 1)):
            names = effect.parameter_names(arm, targets)
            if isinstance(effect, Geometric):  # several stations, an orientation measured
                names += effect.parameter_names(seed, targets, (1, 2), True)
            for p in names:
                parsed = parse_parameter_name(p)
                assert parsed is not None, f"{p} of {name} is not in the name grammar"
                out[parsed.family] = (name, parameter_unit(p), effect.typical_range(p))
    return out


def doc_families() -> dict[str, tuple[str, str, tuple[float, float]]]:
    out = {}
    for r in rows(section("Parameter names")):
        effect, families, _, unit, _, typical = r
        lo, hi = typical.split(" to ")
        for fam in names(families):
            out[fam] = (names(effect)[0], unit, (number(lo), number(hi)))
    return out


def test_every_parameter_family_is_documented_with_its_effect_unit_and_typical_size():
    code, doc = code_families(), doc_families()
    assert set(code) == set(doc), (set(code) - set(doc), set(doc) - set(code))
    for fam, (effect, unit, typical) in code.items():
        d_effect, d_unit, d_typical = doc[fam]
        assert d_effect == effect, fam
        assert d_unit == unit, (fam, d_unit, unit)
        assert typical is not None and np.allclose(d_typical, typical, rtol=1e-12), fam
    assert {n for r in rows(section("Parameter names")) for n in names(r[0])} == set(CATALOGUE)


def test_the_seed_arm_table_is_the_shipped_seed_arm():
    seed = seed_robot()
    table = rows(section("The seed arm"))
    assert [int(r[0]) for r in table] == [1, 2, 3, 4, 5, 6]
    for joint, (_, alpha, a, d, limits, mass, com) in zip(seed.joints, table, strict=True):
        alpha_deg = 0.0 if alpha == "0" else number(alpha.rstrip("°"))
        assert math.isclose(math.degrees(joint.alpha), alpha_deg, abs_tol=1e-9)
        assert math.isclose(joint.a, number(a), abs_tol=1e-12)
        assert math.isclose(joint.d, number(d), abs_tol=1e-12)
        lo, hi = (number(v) for v in limits.strip("[]").split(","))
        assert (joint.lower, joint.upper) == (lo, hi)
        assert joint.mass == number(mass)
        assert joint.com == tuple(number(v) for v in com.strip("()").split(","))
        assert joint.theta_offset == 0.0
    assert seed.tool_points.tolist() == [[0.0, 0.0, 0.05]]
    assert "(0, 0, 0.050) m in frame 6" in TEXT
    assert seed.gravity == (0.0, 0.0, -9.81) and "(0, 0, -9.81) m/s²" in TEXT


# -- the measurement CSV ----------------------------------------------------------------------------
def _columns(cell: str) -> list[str]:
    """``q1 … q6`` -> q1..q6; ``x``, ``y``, ``z`` -> x, y, z."""
    found = names(cell)
    if "…" in cell:
        (a, b) = found
        stem = a.rstrip("0123456789")
        return [f"{stem}{i}" for i in range(int(a[len(stem) :]), int(b[len(stem) :]) + 1)]
    return found


def _bounds(cell: str) -> tuple[float, float] | None:
    """The physical range as written: ``abs(q) ≤ 100 rad``, ``0 to 10000 kg``; None for ±1."""
    if m := re.match(r"abs\(\w+\) ≤ (\S+)", cell):
        return -number(m.group(1)), number(m.group(1))
    if m := re.match(r"(\S+) to (\S+)", cell):
        return number(m.group(1)), number(m.group(2))
    return None


def test_every_measurement_column_is_documented_with_the_readers_range():
    table = rows(section("The measurement CSV"))
    doc = {c: r for r in table for c in _columns(r[0])}
    assert set(doc) == set(KNOWN), (set(KNOWN) - set(doc), set(doc) - set(KNOWN))
    for c in KNOWN:
        _, _, required, _, physical = doc[c]
        assert (required == "yes") == (c in (*JOINTS, *POSITION)), c
        bounds = _bounds(physical)
        if c.startswith("dir"):
            assert bounds is None and physical == "-1 or +1"
        else:
            assert bounds == (RANGES[c].low, RANGES[c].high), (c, bounds)
            assert physical.endswith("above 0") == RANGES[c].open_low, c
    assert f"abs(v) ≤ {MAX_EXTRA:g}".replace("+", "") in section("The measurement CSV")


def test_the_poses_and_joints_files_are_as_documented(tmp_path):
    from arm.measurements import write_poses

    write_poses(np.zeros((2, 6)), tmp_path / "p.csv")
    first, header = (tmp_path / "p.csv").read_text().splitlines()[:2]
    text = section("The poses file")
    assert first in text and header in text


# -- the robot TOML ---------------------------------------------------------------------------------
def test_the_robot_toml_tables_name_every_key_the_writer_emits():
    """A description with every optional part (a standard-DH arm folded to modified, so it has a
    flange, and a URDF's flange transform; beta; a base; effect values; a domain) written by the
    writer `export` uses."""
    std = replace(seed_robot(), convention="standard", name="full", payload=1.0)
    full = replace(
        std.to_modified(),
        joints=tuple(replace(j, beta=1e-3, theta_offset=0.1) for j in std.to_modified().joints),
        base_translation=(0.1, 0.0, 0.0),
        base_rotation=(0.0, 0.0, 0.2),
        flange_translation=(0.0, 0.01, 0.0),  # a URDF's tip link
        flange_rotation=(0.0, 0.3, 0.0),
        effects={"compliance": {"c2": 6e-6}},
        nominal=seed_robot(),  # what `lab export` records
        stations=((1, (0.1, 0.0, 0.0), (0.0, 0.0, 0.2)), (2, (3.0, 1.0, 0.0), (0.0, 0.0, 1.0))),
        domain={"n_poses": 40, "q1": (-1.0, 1.0), "temperature": (20.5, 20.9)},
        couplings=((3, 2, -1.0),),  # FANUC's J3 from the horizon
        extra_joints=(ExtraJoint("column", "prismatic", default=0.3),),  # an arm on a column
        mount_translation=(0.0, 0.0, 0.05),
        uncertainty={  # what `lab export` records of a calibration of two sessions
            "parameters": ["da2", "c2"],
            "values": {"da2": 1e-4, "c2": 6e-6, "dtheta6": 0.0},
            "covariance": [[1e-12, 0.0], [0.0, 1e-16]],
            "sigma": 2e-5,
            "sessions": 2,
            "spread": [3e-5, 0.0],
            "unmeasured": ["c2"],
        },
    )
    assert isinstance(full, RobotDescription)
    back = RobotDescription.from_toml(full.to_toml())
    assert back.domain == full.domain  # the domain an export records reads back
    doc = tomllib.loads(full.to_toml())
    text = section("The robot TOML")
    top, joint = rows(text.split("Keys of each")[0]), rows(text.split("Keys of each")[1])
    documented_top = {re.sub(r"[\[\]]|\.NAME", "", names(r[0])[0]): r for r in top}
    assert set(documented_top) == set(doc), set(doc) ^ set(documented_top)
    assert {names(r[0])[0] for r in joint} == set(doc["joints"][0])
    for key in (
        "tools",
        "base",
        "flange",
        "stations",
        "couplings",
        "uncertainty",
        "extra_joints",
        "mount",
    ):
        value = doc[key][0] if isinstance(doc[key], list) else doc[key]
        for sub in value:
            assert f"`{sub}" in documented_top[key][2], (key, sub)


# -- the lab's JSON ---------------------------------------------------------------------------------
def lab_json(*args: object) -> dict:
    res = runner.invoke(app, ["lab", *map(str, args), "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


@pytest.fixture(scope="module")
def outputs(tmp_path_factory) -> dict[str, dict]:
    """The JSON of every command with --json, on data that make its lists non-empty: a gross
    outlier and a repeated row (fit, diagnose), lengths 5 % too long (implausible, accepted), a
    hidden 2nd harmonic (discover)."""
    d = tmp_path_factory.mktemp("docs_format")
    seed = seed_robot()
    data = campaign(seed, "geometric", seed=3).measure(120)
    xyz = data.xyz.copy()
    xyz[7] += 0.002  # a gross outlier
    q = np.vstack([data.q, data.q[:1]])  # and a copy of the first row
    xyz = np.vstack([xyz, xyz[:1]])
    cols = {k: np.append(v, v[0]) for k, v in data.columns.items()}
    write_measurements(MeasurementSet(q, xyz, cols), d / "data.csv")
    write_measurements(campaign(seed, "geometric", seed=3).measure(60), d / "val.csv")
    long = MeasurementSet(data.q, 1.05 * data.xyz, data.columns)
    write_measurements(long, d / "long.csv")
    h = hidden.campaign(seed, "harmonic2_q2", seed=11, n=200, n_validation=100)
    write_measurements(h.data, d / "h2.csv")
    write_measurements(h.validation, d / "h2_val.csv")
    write_measurements(data.subset(np.arange(5)), d / "targets.csv")

    noise = str(1e3 * SIGMA)
    out = {
        "fit": lab_json("fit", d / "data.csv", "--validate", d / "val.csv"),
        "fit_large": lab_json("fit", d / "long.csv", "--accept-large"),
        "diagnose": lab_json("diagnose", d / "data.csv", "--noise-mm", noise),
        "discover": lab_json(
            "discover",
            d / "h2.csv",
            "--noise-mm",
            noise,
            "--validate",
            d / "h2_val.csv",
            "-o",
            d / "found.py",
        ),
        "plan": lab_json("plan", "--n", 12, "--candidates", 200, "-o", d / "poses.csv"),
    }
    res = runner.invoke(app, ["lab", "export", str(d / "data.csv"), "-o", str(d / "cal.toml")])
    assert res.exit_code == 0, res.output
    out["compensate"] = lab_json(
        "compensate", d / "targets.csv", "--robot", d / "cal.toml", "-o", d / "joints.csv"
    )
    out["joints_csv"] = {"text": (d / "joints.csv").read_text()}
    out["update"] = lab_json("update", d / "cal.toml", d / "val.csv", "--validate", d / "val.csv")
    return out


def test_the_generated_outputs_fill_every_list(outputs):
    """The data make the lists that carry nested objects non-empty, so their keys are checked."""
    assert outputs["fit"]["outliers"] and outputs["fit"]["duplicates"]
    assert outputs["fit_large"]["implausible"]
    assert outputs["diagnose"]["candidates"] and outputs["diagnose"]["hints"]
    assert outputs["diagnose"]["outliers"] and outputs["diagnose"]["duplicates"]
    assert outputs["discover"]["verdict"] == "discovered" and outputs["discover"]["terms"]


@pytest.mark.parametrize(
    ("title", "runs"),
    [
        ("fit", ("fit", "fit_large")),
        ("diagnose", ("diagnose",)),
        ("discover", ("discover",)),
        ("plan", ("plan",)),
        ("compensate", ("compensate",)),
    ],
)
def test_each_json_section_lists_exactly_the_keys_the_command_prints(outputs, title, runs):
    printed = set().union(*(json_keys(outputs[r]) for r in runs))
    doc = documented_keys(title)
    assert printed - doc == set(), f"printed by lab {title} --json, not in docs/format.md"
    assert doc - printed == set(), f"in docs/format.md, not printed by lab {title} --json"
    assert all(outputs[r]["schema_version"] == 1 for r in runs)


def expanded(text: str) -> set[str]:
    """The backticked names of ``text``, ``q1..q6`` expanded to q1, ..., q6."""
    out = set()
    for n in names(text):
        if m := re.fullmatch(r"([a-z]+)(\d)\.\.\1?(\d)", n):
            out |= {f"{m.group(1)}{i}" for i in range(int(m.group(2)), int(m.group(3)) + 1)}
        else:
            out.add(n)
    return out


def test_the_update_section_lists_the_keys_update_adds_to_fit(outputs):
    printed = json_keys(outputs["update"])
    documented = documented_keys("fit") | documented_keys("update")
    # fit's lists of objects (outliers, duplicates, implausible) are empty in an update: its
    # object is fit's, every key of it documented, and the one key it adds is update's
    assert printed - documented == set(), printed - documented
    assert {k for k in documented if "[]" not in k} - printed == set()
    assert set(outputs["update"]) - set(outputs["fit"]) == documented_keys("update")


def test_the_joints_file_is_as_documented(outputs):
    first, header = outputs["joints_csv"]["text"].splitlines()[:2]
    text = section("The targets and joints files (compensate)")
    joints = text[text.index("**Joints**") :]
    assert f"`{first}`" in joints
    assert set(header.split(",")) <= expanded(joints), set(header.split(",")) - expanded(joints)


def test_no_tracked_file_sends_a_reader_outside_the_repository():
    """The reference is docs/format.md: no tracked file names a spec outside the repository."""
    import subprocess

    root = DOC.parents[1]
    found = subprocess.run(
        # (the patterns are split so that this file does not match them itself)
        ["git", "grep", "-n", "-e", "/wo" + "rk/", "-e", "../sha" + "red", "-e", "SP" + "EC"],
        cwd=root,
        capture_output=True,
        text=True,
    )
    if found.returncode not in (0, 1):
        pytest.skip(f"not a git checkout: {found.stderr.strip()}")
    # the old specification by its name, not a word that contains it (a licence's "SPECIAL")
    spec = re.compile(r"\b" + "SP" + r"EC\b")
    hits = [
        line
        for line in found.stdout.splitlines()
        if "/wo" + "rk/" in line or "../sha" + "red" in line or spec.search(line.split(":", 2)[2])
    ]
    assert not hits, (
        "tracked files name a path outside the repository or its old specification (point to "
        "docs/format.md instead; name a run's spec otherwise, e.g. RunSpec):\n" + "\n".join(hits)
    )


def test_links_into_the_page_name_its_headings():
    """Every ``docs/format.md#anchor`` link in the README and docs/ names a heading of the page
    (GitHub's anchors: lower case, punctuation dropped, spaces as hyphens)."""
    root = DOC.parents[1]
    anchors = set()
    fenced = False
    for line in TEXT.splitlines():
        fenced = fenced != line.startswith("```")
        if not fenced and (m := re.match(r"#+ (.*)", line)):
            anchors.add(re.sub(r"[^\w\- ]", "", m.group(1).lower()).replace(" ", "-"))
    links = []
    for path in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        links += re.findall(r"format\.md#([\w\-]+)", path.read_text(encoding="utf-8"))
    assert links, "the README links no section of docs/format.md"
    assert set(links) <= anchors, set(links) - anchors


# -- URDF in and out --------------------------------------------------------------------------------
def test_the_urdf_options_are_load_robots():
    """The option table of "A URDF as the robot" names exactly load_robot's URDF keywords."""
    import inspect

    from arm.description import load_robot

    table = rows(section("A URDF as the robot"))
    documented = {n for r in table for n in names(r[0])}
    params = inspect.signature(load_robot).parameters
    keywords = {f"{n}=" for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}
    assert {d for d in documented if d.endswith("=") and d[0] != "#"} == keywords
    assert {d.lstrip("#") for d in documented if d[0] == "#"} == keywords == {"tip=", "base="}


def test_the_metrology_file_keys_are_documented(tmp_path):
    """Every key the calibrated URDF's metrology file holds is in "The calibrated URDF"."""
    from arm.description import load_robot
    from lab import fit
    from lab.urdf_export import export_urdf

    robot = load_robot("ur5_robot")
    data = campaign(robot, "geometric,compliance[2,3]", seed=3).measure(150)
    out = export_urdf(fit(data, robot, "geometric,compliance[2,3]"), tmp_path / "arm.urdf")
    doc = tomllib.loads(out.metrology.read_text())
    documented = {
        re.sub(r"[\[\]]|\.NAME", "", n)
        for r in rows(section("The calibrated URDF"))
        for n in names(r[0])
    }
    assert set(doc) <= documented, set(doc) - documented
    # a campaign of other kinds, an effect outside the catalogue
    assert documented - set(doc) <= {"stations", "tool_frame", "effect_modules"}
    for key in ("tracker", "fit"):
        text = next(
            r[1]
            for r in rows(section("The calibrated URDF"))
            if f"`[{key}]`" in r[0] or f"`{key}`" in r[0]
        )
        for sub in doc[key]:
            assert f"`{sub}`" in text, (key, sub)


def test_the_real_data_options_and_keys_are_documented():
    """Every option of the UR5 converter and of benchmarks/real_data.py, and every key of
    results/real_data.json, is in "Real data"."""
    import json
    import subprocess
    import sys

    root = DOC.parents[1]
    text = section("Real data")
    table = [r for r in rows(text) if len(r) == 3 and r[0] != "option"]
    for script in (
        "examples/convert_ur5_serial_robots.py",
        "examples/convert_ur10_ipa.py",
        "benchmarks/real_data.py",
    ):
        out = subprocess.run(
            [sys.executable, str(root / script), "--help"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        flags = set(re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]+)", out)) - {"--help"}
        name = Path(script).name
        documented = {n for r in table if name in r[1] for n in names(r[0]) if n.startswith("--")}
        assert flags == documented, (script, flags ^ documented)
    report = json.loads((root / "results" / "real_data.json").read_text())
    keys = {n.split(".")[-1] for r in rows(text) for c in r[:2] for n in names(c)}
    assert set(report) - {"datasets"} <= keys
    for ds in report["datasets"]:
        assert set(ds) <= keys, set(ds) - keys
        for row in ds["rows"]:
            assert set(row) <= keys, set(row) - keys


# -- the lab's options ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "command", ["fit", "diagnose", "discover", "plan", "collect", "report", "update"]
)
def test_every_option_of_the_lab_commands_is_documented(command):
    """Each ``--option`` of the command is named in docs/format.md as a whole word (``--stations``
    is not ``--stations-x``)."""
    from typer.main import get_command

    lab_group = get_command(app).commands["lab"]  # type: ignore[attr-defined]
    params = lab_group.commands[command].params
    flags = {o for p in params for o in p.opts if o.startswith("--")} - {"--help"}
    missing = sorted(f for f in flags if not re.search(re.escape(f) + r"(?![\w-])", TEXT))
    assert not missing, f"lab {command}: {missing} not in docs/format.md"


def test_the_export_formats_are_documented():
    """`sixaxis lab export --format` takes exactly the formats "The calibrated URDF" names."""
    from lab.options import EXPORT_FORMATS

    res = runner.invoke(app, ["lab", "export", "--help"])
    assert "--format" in res.output
    text = section("The calibrated URDF")
    assert "--format urdf" in text and EXPORT_FORMATS == ("toml", "urdf")


def _anchors(text: str) -> set[str]:
    """GitHub's anchors of a page's headings (lower case, punctuation dropped, spaces as hyphens)."""
    out, fenced = set(), False
    for line in text.splitlines():
        fenced = fenced != line.startswith("```")
        if not fenced and (m := re.match(r"#+ (.*)", line)):
            out.add(re.sub(r"[^\w\- ]", "", m.group(1).lower()).replace(" ", "-"))
    return out


def test_every_link_of_the_readme_and_docs_leads_somewhere():
    """The README is a door to docs/: every relative link of the README and of docs/*.md names
    a file of the repository, and every ``page.md#anchor`` a heading of that page; every docs
    page is linked from the README."""
    root = DOC.parents[1]
    pages = [root / "README.md", *sorted((root / "docs").glob("*.md"))]
    bad = []
    for page in pages:
        text = page.read_text(encoding="utf-8")
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+://", target) or target.startswith("#"):
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve()
            if not dest.exists():
                bad.append(f"{page.name}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest.read_text()):
                bad.append(f"{page.name}: {target} (no such heading)")
    assert not bad, "\n".join(bad)
    readme = (root / "README.md").read_text(encoding="utf-8")
    for doc in sorted((root / "docs").glob("*.md")):
        assert f"docs/{doc.name}" in readme, f"the README does not link docs/{doc.name}"
