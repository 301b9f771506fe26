"""The docs run: every python block and every ``$ sixaxis ...`` command of README.md and
docs/*.md runs, in order, in a temporary folder, and prints what the page quotes (numbers to the
digits shown, times aside). Blocks that cannot run here are marked ``<!-- docs: skip: REASON -->``
in the page, and counted here. The conventions are in tests/_docs_runner.py."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from tests._docs_runner import (
    ROOT,
    Cache,
    Command,
    DocError,
    compare,
    line_matches,
    parse,
    run_command,
    run_page,
)

PAGES = ["README.md", *sorted(f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md"))]
# the two pages that tour the lab on the same collected campaigns: run in one test, so that the
# second page's collect (the same command, the same seed) is the first one's files
TOURS = ["README.md", "docs/lab.md"]
# the skipped blocks, each with its reason in the page; a new skip must be added here on purpose
SKIPPED = {
    # the full leaderboard sweep and training; your own agent's shell steps (mkdir, cat), which
    # tests/test_experiments_user_agent.py runs from a blank folder
    "docs/agents.md": 1,  # training 5 seeds of a policy (hours)
    "docs/benchmark.md": 2,
    # the Rokae data set is not shipped (no licence); lab update's new session and --predict's
    # program are the user's; the arm on a column's campaign, which tests/test_extra_joints.py
    # writes and fits
    "docs/lab.md": 4,
}


def _check(page: str, folder: Path, cache: Cache | None = None) -> None:
    report = run_page(ROOT / page, folder, page, cache)
    print(
        f"{page}: {len(report.ran)} blocks run, {report.commands} commands, "
        f"{report.compared_lines} quoted lines or values compared, {len(report.skipped)} skipped"
    )
    for where, reason in report.skipped:
        print(f"  skipped {where}: {reason}")
    assert len(report.skipped) == SKIPPED.get(page, 0), report.skipped


@pytest.mark.parametrize("page", [p for p in PAGES if p not in TOURS])
def test_the_page_runs(page, tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT))
    _check(page, tmp_path)


@pytest.mark.slow  # about 40 s of CPU, two thirds of it collecting the campaigns on the plant
def test_the_tours_run(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT))
    cache: Cache = {}
    for page in TOURS:
        (tmp_path / page).mkdir(parents=True)
        _check(page, tmp_path / page, cache)


def test_every_page_follows_the_conventions():
    """Every page parses (no bare ``sixaxis`` command line, no unknown marker, every skip with a
    reason) and the pages hold runnable blocks, so the tests above test something."""
    blocks = [b for p in PAGES for b in parse(ROOT / p, p)]
    runnable = [b for b in blocks if b.runnable and b.skip is None]
    assert sum(len(b.commands) for b in runnable) >= 15
    assert sum(b.lang == "python" for b in runnable) >= 6
    skipped = {}
    for b in blocks:
        if b.runnable and b.skip is not None:
            skipped[b.page] = skipped.get(b.page, 0) + 1
    assert skipped == SKIPPED


# -- a planted drift fails ---------------------------------------------------------------------------
def _page(tmp_path: Path, text: str) -> Path:
    page = tmp_path / "page.md"
    page.write_text(text, encoding="utf-8")
    work = tmp_path / "work"
    work.mkdir()
    return page


ROBOT_SHOW = """```text
$ sixaxis lab fit data/ur5/test.csv --robot ur5_robot --noise-mm 0.1
fit of geometric to 20 points (linear loss): RMS {before} mm -> {after} mm, max 0.1145 mm, 5 iterations
```
"""


def test_a_quoted_number_that_drifted_fails(tmp_path):
    """The same command passes with the numbers it prints and fails with one changed in its
    third shown digit; a time in the line is not compared."""
    good = ROBOT_SHOW.format(before="0.5160", after="0.0789")
    bad = ROBOT_SHOW.format(before="0.5160", after="0.0799")
    page = _page(tmp_path, good)
    try:
        run_page(page, tmp_path / "work")
    except DocError as exc:  # the quote itself must be right for the planted drift to mean anything
        pytest.fail(f"the undrifted page fails: {exc}")
    page.write_text(bad, encoding="utf-8")
    with pytest.raises(DocError, match=r"page.md:3: the page quotes"):
        run_page(page, tmp_path / "work")


def test_a_python_block_with_an_undefined_name_fails(tmp_path):
    page = _page(tmp_path, "```python\nimport lab\n\nresult = lab.fit(held_out)\n```\n")
    with pytest.raises(DocError, match=r"page.md:4: the python block fails: NameError"):
        run_page(page, tmp_path / "work")


def test_a_stated_value_that_drifted_fails(tmp_path):
    """``expr  # literal`` is compared; ``expr  # words`` is not."""
    text = "```python\nx = [0.0269, 'tau2']\nx  # [{v}, 'tau2']\nx  # the held-out RMS\n```\n"
    page = _page(tmp_path, text.format(v="0.0269"))
    assert run_page(page, tmp_path / "work").compared_lines == 1
    page.write_text(text.format(v="0.0279"), encoding="utf-8")
    with pytest.raises(DocError, match=r"page.md:3: the page states \[0.0279, 'tau2'\]"):
        run_page(page, tmp_path / "work")


JSON = """```text
$ sixaxis lab fit data/ur5/test.csv --robot ur5_robot --noise-mm 0.1 --json
{{"schema_version": 1, "effects": ["geometric"], "n_points": {n}, "rms_mm": {rms},
 "parameters": {{...}}, "unidentifiable": [...], {more}}}
```
"""


def test_a_quoted_json_object_is_compared_key_by_key(tmp_path, monkeypatch):
    """A JSON excerpt passes as quoted and fails with a drifted number, count or key, or without
    its final '...' for the keys it leaves out."""
    page = _page(tmp_path, JSON.format(n=20, rms="0.07890", more="..."))
    monkeypatch.chdir(tmp_path / "work")
    (tmp_path / "work" / "data").symlink_to(ROOT / "data")
    command = parse(page)[0].commands[0]
    printed = run_command(command, "page.md:1")
    compare(command, printed, "page.md:1")
    for n, rms, more in [
        (21, "0.07890", "..."),
        (20, "0.0799", "..."),
        (20, "0.07890", '"rmsmm": 1'),
    ]:
        page.write_text(JSON.format(n=n, rms=rms, more=more), encoding="utf-8")
        with pytest.raises(DocError, match=r"page.md:3: the page quotes"):
            compare(parse(page)[0].commands[0], printed, "page.md:1")


def test_a_command_that_fails_or_a_bare_command_line_fails(tmp_path):
    page = _page(tmp_path, "```text\n$ sixaxis lab fit missing.csv\n```\n")
    with pytest.raises(DocError, match=r"page.md:2: 'sixaxis lab fit missing.csv' exits with 2"):
        run_page(page, tmp_path / "work")
    page.write_text("```bash\nsixaxis lab fit missing.csv\n```\n", encoding="utf-8")
    with pytest.raises(DocError, match=r"page.md:2: write a command as '\$ sixaxis \.\.\.'"):
        parse(page)
    page.write_text("<!-- docs: skip -->\n```python\nx\n```\n", encoding="utf-8")
    with pytest.raises(DocError, match=r"page.md:1: unknown docs marker 'skip'"):
        parse(page)


def test_a_command_run_on_another_page_is_reused_with_its_files(tmp_path):
    """The tours' shared cache: the same command on the same files runs once; the second page's
    folder gets the files it wrote and the same output."""
    runs = tmp_path / "runs.txt"
    script = f"open('x.csv', 'w').write('1'); open({str(runs)!r}, 'a').write('run')"
    page = _page(tmp_path, f'```text\n$ python -c "{script}"\n```\n')
    cache: Cache = {}
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        assert run_page(page, tmp_path / folder, cache=cache).commands == 1
        assert (tmp_path / folder / "x.csv").read_text() == "1"
    assert runs.read_text() == "run"


def test_a_skipped_block_is_counted_not_run(tmp_path):
    page = _page(
        tmp_path, "<!-- docs: skip: needs the real arm -->\n```python\nraise SystemExit(1)\n```\n"
    )
    report = run_page(page, tmp_path / "work")
    assert report.skipped == [("page.md:2", "needs the real arm")] and report.ran == []


TABLE = """┏━━━━━━━━━━━━┳━━━━━━━━┳━━━━━━━━━━━━━━━━━━━━━━┓
┃ scenario   ┃ rms_mm ┃ solve_time_median_ms ┃
┡━━━━━━━━━━━━╇━━━━━━━━╇━━━━━━━━━━━━━━━━━━━━━━┩
│ compliance │ {rms} │ {time}               │
└────────────┴────────┴──────────────────────┘"""


def test_a_time_column_is_not_compared_and_the_others_are():
    shown = TABLE.format(rms="0.3644", time="0.0383")
    command = Command(1, ["sixaxis"], [(2 + k, s) for k, s in enumerate(shown.splitlines())])
    times = ("solve_time_median_ms",)
    compare(command, TABLE.format(rms="0.3644", time="0.0512"), "page.md:1", times)
    with pytest.raises(DocError, match=r"page.md:5: the page quotes"):
        compare(command, TABLE.format(rms="0.3649", time="0.0383"), "page.md:1", times)
    with pytest.raises(DocError, match=r"page.md:5: the page quotes"):  # a time, unmarked
        compare(command, TABLE.format(rms="0.3644", time="0.0512"), "page.md:1")


PLAIN = """ scenario     seed   settled   ms/step
 ───────────────────────────────────────
 compliance      0    {rms}      {time}"""


def test_a_time_column_of_a_table_without_rules_is_blanked_by_its_header():
    """`sixaxis evaluate` draws its table without `┃`: the README's column is found by the header
    as printed, and a machine twice as slow still matches."""
    shown = PLAIN.format(rms="0.1301", time="0.04")
    command = Command(1, ["sixaxis"], [(2 + k, s) for k, s in enumerate(shown.splitlines())])
    times = ("ms/step",)
    compare(command, PLAIN.format(rms="0.1301", time="0.08"), "page.md:1", times)
    compare(command, PLAIN.format(rms="0.1301", time="12.5"), "page.md:1", times)
    with pytest.raises(DocError, match=r"page.md:4: the page quotes"):
        compare(command, PLAIN.format(rms="0.1309", time="0.04"), "page.md:1", times)
    with pytest.raises(DocError, match=r"page.md:4: the page quotes"):  # a time, unmarked
        compare(command, PLAIN.format(rms="0.1301", time="0.08"), "page.md:1")


@pytest.mark.parametrize(
    ("shown", "got", "same"),
    [
        ("RMS 0.0242 mm", "RMS 0.02421 mm", True),  # within the shown digits
        ("RMS 0.0242 mm", "RMS 0.0245 mm", False),
        ("c2 +8.51e-06", "c2 +8.487e-06", False),  # the README's old plant value
        ("c2 +8.487e-06", "c2 +8.4871e-06", True),
        ("wrote 200 measurements in 32.9 s", "wrote 200 measurements in 47.7 s", True),  # a time
        ("wrote report.html (1019 KB) in 1.4 s", "wrote report.html (998 KB) in 3 s", True),
        ("│ compliance[2]   │ 0.0309 │", "│ compliance[2,3,4,5] │ 0.0309 │", False),  # the name
        ("verdict: compliance", "verdict:   compliance", True),  # whitespace aside
        ("27 of 35 parameters", "28 of 35 parameters", False),  # a count, exactly
    ],
)
def test_line_matching(shown, got, same):
    assert line_matches(shown, got) is same


if __name__ == "__main__":  # one page by hand: python -m tests.test_docs_run docs/lab.md DIR
    print(run_page(ROOT / sys.argv[1], Path(sys.argv[2]), sys.argv[1]))
