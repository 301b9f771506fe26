"""Runs the fenced blocks of a markdown page the way a reader would type them, and compares the
output the page quotes with the output the program prints.

The conventions of README.md and docs/*.md (the runner enforces them):

- A ```python block is run, in order, in one namespace per page (a later block may use an earlier
  block's names, as a reader's session would). A line that is an expression (not an assignment)
  whose comment starts with a Python literal states the expression's value:
  ``d.verdict, d.hints[0].variable  # 'compliance', 'tau2'`` is compared (strings exactly, numbers
  to the digits shown); a comment in words is not.
- In any block, a line ``$ sixaxis ...`` (or ``$ python ...``) is a command; a trailing ``\\``
  continues it on the next line, ``# ...`` after it is a comment. The lines after it, up to the
  next ``$ `` line or the end of the block, are its quoted output. A command line without the
  ``$ `` prompt (a line starting ``sixaxis ``) is refused: it would escape the test.
- Quoted output is compared with what the command prints: each quoted line must appear, in order,
  among the printed lines (a page may quote a few rows of a table; ``...`` lines stand for the
  rows left out). Words and table rules must match exactly (whitespace aside); numbers must match
  to the digits the page shows (1.5 units of the last digit, or 1e-3 relative, whichever is
  larger; a whole number, a count, exactly). Times and sizes (``in 32.9 s``, ``(1019 KB)``) are
  not compared.
- Quoted output that starts with ``{`` is a JSON object, compared key by key with the one the
  command prints: ``{...}`` and ``[...]`` stand for a value not shown, a final ``...`` for the keys
  left out (without it the keys must be the same); numbers to the digits shown.
- ``<!-- docs: skip: REASON -->`` on the line before a block's fence skips the block (the test
  counts and reports these; the reason is required).
- ``<!-- docs: time column: NAME -->`` before a block: the table column headed NAME (the header
  as the table prints it, drawn with rules or without) holds times, not compared.

Every page is run in a fresh temporary folder holding links to the repository's ``data/`` and
``examples/``, so the pages' commands find the shipped data sets and files that earlier blocks made.
Commands run as a user's would, each in its own process (``sixaxis`` as ``python -m
experiments.cli``, ``python`` as this interpreter), 300 columns wide.
"""

from __future__ import annotations

import ast
import hashlib
import io
import json
import math
import os
import re
import shlex
import subprocess
import sys
import tokenize
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ("data", "examples")  # linked into every page's folder
MARKER = re.compile(r"^<!--\s*docs:\s*(.*?)\s*-->\s*$")
FENCE = re.compile(r"^```(\S*)\s*$")
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
TIMES = (
    (re.compile(r"\bin \d+(?:\.\d+)? ?(?:s|ms|min)\b"), "in <time>"),
    (re.compile(r"\(\d+(?:\.\d+)? ?[kKMG]B\)"), "(<size>)"),
)


class DocError(AssertionError):
    """A page does not do what it says: names the page and line."""


@dataclass
class Command:
    line: int  # 1-based line of the ``$ `` in the page
    argv: list[str]
    quoted: list[tuple[int, str]] = field(default_factory=list)  # (line, text) of quoted output


@dataclass
class Block:
    page: str
    line: int  # 1-based line of the opening fence
    lang: str
    text: str
    skip: str | None = None  # the reason
    time_columns: tuple[str, ...] = ()
    commands: list[Command] = field(default_factory=list)

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"

    @property
    def runnable(self) -> bool:
        return self.lang == "python" or bool(self.commands)


def _marker(lines: list[str], fence: int, page: str) -> tuple[str | None, tuple[str, ...]]:
    """(the skip reason, the time columns) that the marker before the fence states."""
    k = fence - 1
    while k >= 0 and not lines[k].strip():
        k -= 1
    m = MARKER.match(lines[k].strip()) if k >= 0 else None
    if m is None:
        return None, ()
    key, _, value = m.group(1).partition(":")
    if key == "skip" and value.strip():
        return value.strip(), ()
    if key == "time column" and value.strip():
        return None, tuple(c.strip() for c in value.split(","))
    raise DocError(
        f"{page}:{k + 1}: unknown docs marker {m.group(1)!r} (use 'skip: REASON' or "
        "'time column: NAME')"
    )


def _commands(block: Block, body: list[str]) -> list[Command]:
    out: list[Command] = []
    k = 0
    while k < len(body):
        text = body[k]
        at = block.line + 1 + k
        if text.startswith("sixaxis "):
            raise DocError(f"{block.page}:{at}: write a command as '$ {text.split()[0]} ...'")
        if not text.startswith("$ "):
            if out:
                out[-1].quoted.append((at, text))
            k += 1
            continue
        cmd = text[2:]
        while cmd.rstrip().endswith("\\") and k + 1 < len(body):
            k += 1
            cmd = cmd.rstrip()[:-1] + " " + body[k].strip()
        out.append(Command(at, shlex.split(cmd, comments=True)))
        k += 1
    return out


def parse(path: Path, name: str | None = None) -> list[Block]:
    """The fenced blocks of a page, with their markers and commands."""
    page = name or path.name
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks: list[Block] = []
    k = 0
    while k < len(lines):
        m = FENCE.match(lines[k])
        if m is None:
            k += 1
            continue
        end = k + 1
        while end < len(lines) and lines[end].rstrip() != "```":
            end += 1
        if end == len(lines):
            raise DocError(f"{page}:{k + 1}: the block is never closed")
        skip, times = _marker(lines, k, page)
        body = lines[k + 1 : end]
        block = Block(page, k + 1, m.group(1), "\n".join(body) + "\n", skip, times)
        block.commands = _commands(block, body)
        blocks.append(block)
        k = end + 1
    return blocks


# -- comparing output --------------------------------------------------------------------------------
def _norm(line: str) -> str:
    for pattern, repl in TIMES:
        line = pattern.sub(repl, line)
    return " ".join(line.split())


def _close(shown: str, got: str) -> bool:
    """``got`` is ``shown`` to the digits shown: 1.5 units of the last digit (a rounding on
    another machine's kernels) or 1e-3 relative; a whole number (a count) exactly."""
    a, b = float(shown), float(got)
    if not (math.isfinite(a) and math.isfinite(b)):
        return a == b
    mantissa, _, exponent = shown.lower().partition("e")
    if "." not in mantissa and not exponent:
        return abs(a - b) <= 1e-3 * abs(a)
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    unit = 10.0 ** (int(exponent or 0) - decimals)
    return abs(a - b) <= max(1.5 * unit, 1e-3 * abs(a))


def line_matches(shown: str, got: str) -> bool:
    """``got`` says what ``shown`` says: the same words, numbers to the digits shown."""
    s, g = _norm(shown), _norm(got)
    sn, gn = NUMBER.findall(s), NUMBER.findall(g)
    if len(sn) != len(gn) or NUMBER.sub("#", s) != NUMBER.sub("#", g):
        return False
    return all(_close(x, y) for x, y in zip(sn, gn, strict=True))


@dataclass(frozen=True)
class _TimeCells:
    """Where a table's time columns are, read off its header as it is drawn: by cell (a box
    table, header cells between ``┃``, rows' between ``│``) or by span of characters (a table
    drawn without rules: columns apart by two or more spaces, each value under its header)."""

    cells: frozenset[int] = frozenset()
    spans: tuple[tuple[int, int], ...] = ()

    @classmethod
    def of(cls, header: str, names: tuple[str, ...]) -> _TimeCells | None:
        """The time columns of ``header``, if it is a table's header naming one of ``names``."""
        if "┃" in header:
            cells = {i for i, c in enumerate(header.split("┃")) if c.strip() in names}
            return cls(cells=frozenset(cells)) if cells else None
        spans = tuple(m.span() for m in re.finditer(r"\S+(?: \S+)*", header) if m.group() in names)
        return cls(spans=spans) if spans else None

    def blank(self, row: str) -> str:
        """``row`` with the time columns' values emptied."""
        if self.cells and "│" in row:
            parts = row.split("│")
            return "│".join("" if i in self.cells else c for i, c in enumerate(parts))
        words = re.finditer(r"\S+", row)  # every word that reaches into a header's span
        cut = [
            m.span() for m in words if any(m.start() < hi and m.end() > lo for lo, hi in self.spans)
        ]
        for lo, hi in reversed(cut):
            row = row[:lo] + " " * (hi - lo) + row[hi:]
        return row


class _Number(str):
    """A number as the page writes it (its digits say how close the printed one must be)."""


ANY = "\u2026 a value the page does not show"


def _json_matches(shown: object, got: object) -> bool:
    if shown == ANY:
        return True
    if isinstance(shown, _Number):
        return (
            isinstance(got, int | float) and not isinstance(got, bool) and _close(shown, repr(got))
        )
    if isinstance(shown, dict):
        more = shown.pop("\u2026", None) is not None
        return (
            isinstance(got, dict)
            and (set(shown) <= set(got) if more else set(shown) == set(got))
            and all(_json_matches(v, got[k]) for k, v in shown.items())
        )
    if isinstance(shown, list):
        return (
            isinstance(got, list)
            and len(shown) == len(got)
            and all(_json_matches(s, g) for s, g in zip(shown, got, strict=True))
        )
    return shown == got


def compare_json(command: Command, output: str, where: str) -> None:
    """The quoted JSON object (an excerpt) is the one the command prints on stdout."""
    text = "\n".join(s for _, s in command.quoted)
    text = re.sub(r"\{\.\.\.\}|\[\.\.\.\]", lambda _: json.dumps(ANY), text)
    text = re.sub(r",\s*\.\.\.\s*\}\s*$", ', "\u2026": 0}', text)
    shown = json.loads(text, parse_float=_Number, parse_int=_Number)
    try:
        got, _ = json.JSONDecoder().raw_decode(output[output.index("{") :])
    except ValueError as exc:
        raise DocError(f"{where}: '{' '.join(command.argv)}' prints no JSON object") from exc
    if not _json_matches(shown, got):
        raise DocError(
            f"{where.split(':')[0]}:{command.quoted[0][0]}: the page quotes\n{text}\n"
            f"but '{' '.join(command.argv)}' prints\n{json.dumps(got)}"
        )


def compare(command: Command, output: str, where: str, time_columns: tuple[str, ...] = ()) -> None:
    """Every quoted line appears, in order, among the printed lines."""
    if command.quoted and command.quoted[0][1].lstrip().startswith("{"):
        compare_json(command, output, where)
        return
    printed = output.splitlines()
    # the time columns of the last table header quoted, as the page draws it and as printed
    page_times: _TimeCells | None = None
    printed_times: _TimeCells | None = None
    k = 0
    for at, shown in command.quoted:
        if not _norm(shown) or _norm(shown).strip("│ ") == "...":
            continue
        header = _TimeCells.of(shown, time_columns)
        if header is not None:
            page_times = header
        elif page_times is not None:
            shown = page_times.blank(shown)
        while k < len(printed):
            if header is not None:
                if line_matches(shown, printed[k]):
                    printed_times = _TimeCells.of(printed[k], time_columns)
                    break
            elif line_matches(
                shown, printed_times.blank(printed[k]) if printed_times else printed[k]
            ):
                break
            k += 1
        if k == len(printed):
            raise DocError(
                f"{where.split(':')[0]}:{at}: the page quotes\n    {shown.strip()}\n"
                f"but '{' '.join(command.argv)}' prints (after the previous quoted line)\n"
                + "\n".join("    " + p for p in printed)
            )
        k += 1


# -- python blocks ---------------------------------------------------------------------------------
def _stated(comment: str) -> tuple[str, object] | None:
    """The literal a comment starts with (its text and value), or None for a comment in words."""
    text = comment.lstrip("#").strip()
    for end in range(len(text), 0, -1):
        try:
            return text[:end], ast.literal_eval(text[:end])
        except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
            continue
    return None


def _same(shown: object, got: object) -> bool:
    """The value ``got`` is the literal ``shown``: strings exactly, numbers to the digits shown."""
    if isinstance(shown, tuple | list):
        got = list(got) if isinstance(got, tuple | list) else got
        return (
            isinstance(got, list)
            and len(got) == len(shown)
            and all(_same(s, g) for s, g in zip(shown, got, strict=True))
        )
    if isinstance(shown, bool) or not isinstance(shown, int | float):
        return shown == got
    try:
        return _close(repr(shown), repr(float(got)))
    except (TypeError, ValueError):
        return False


def run_python(block: Block, namespace: dict[str, object]) -> int:
    """Runs a python block statement by statement; returns how many stated values it compared."""
    comments = {
        tok.start[0]: tok.string
        for tok in tokenize.generate_tokens(io.StringIO(block.text).readline)
        if tok.type == tokenize.COMMENT
    }
    compared = 0
    for node in ast.parse(block.text).body:
        at = f"{block.page}:{block.line + node.lineno}"
        stated = (
            _stated(comments.get(node.end_lineno or 0, "")) if isinstance(node, ast.Expr) else None
        )
        try:
            if stated is None:
                exec(compile(ast.Module([node], []), at, "exec"), namespace)
                continue
            value = eval(compile(ast.Expression(node.value), at, "eval"), namespace)
        except Exception as exc:
            raise DocError(f"{at}: the python block fails: {exc!r}") from exc
        text, shown = stated
        if not _same(shown, value):
            raise DocError(f"{at}: the page states {text} but the expression is {value!r}")
        compared += 1
    return compared


# -- running a page ----------------------------------------------------------------------------------
@dataclass
class Report:
    ran: list[str] = field(default_factory=list)  # where of each block run
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (where, reason)
    commands: int = 0
    compared_lines: int = 0


@contextmanager
def _inside(folder: Path) -> Iterator[None]:
    old = Path.cwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(old)


def _files(folder: Path) -> dict[str, tuple[int, int]]:
    return {
        str(f.relative_to(folder)): (f.stat().st_mtime_ns, f.stat().st_size)
        for f in folder.rglob("*")
        if f.is_file() and not f.is_symlink() and f.relative_to(folder).parts[0] not in SHARED
    }


def _key(argv: list[str]) -> tuple[str, ...]:
    """The command and the contents of the files it names."""
    named = [a for a in argv if Path(a).is_file()]
    return (*argv, *(hashlib.sha256(Path(a).read_bytes()).hexdigest() for a in named))


Cache = dict[tuple[str, ...], tuple[str, dict[str, bytes]]]


def _run_cached(command: Command, where: str, cache: Cache | None) -> str:
    """A command run before on the same files (another page's tour) is not run again: its output
    and the files it wrote are the first run's (the same seed gives the same numbers)."""
    if cache is None:
        return run_command(command, where)
    key = _key(command.argv)
    if key in cache:
        output, written = cache[key]
        for name, data in written.items():
            Path(name).parent.mkdir(parents=True, exist_ok=True)
            Path(name).write_bytes(data)
        return output
    folder = Path.cwd()
    before = _files(folder)
    output = run_command(command, where)
    after = _files(folder)
    cache[key] = (
        output,
        {n: (folder / n).read_bytes() for n in after if after[n] != before.get(n)},
    )
    return output


def run_command(command: Command, where: str) -> str:
    env = os.environ | {"COLUMNS": "300", "NO_COLOR": "1", "TERM": "dumb"}
    argv = list(command.argv)
    if argv[0] not in ("sixaxis", "python"):
        raise DocError(f"{where.split(':')[0]}:{command.line}: runs '$ sixaxis' or '$ python' only")
    if argv[0] == "python":
        argv[0] = sys.executable
    else:
        argv = [sys.executable, "-m", "experiments.cli", *argv[1:]]
    res = subprocess.run(argv, capture_output=True, text=True, env=env, check=False)
    output = res.stdout + res.stderr
    if res.returncode != 0:
        raise DocError(
            f"{where.split(':')[0]}:{command.line}: '{' '.join(command.argv)}' exits with "
            f"{res.returncode}:\n{output}"
        )
    return output


def run_page(
    path: Path, folder: Path, name: str | None = None, cache: Cache | None = None
) -> Report:
    """Runs every block of the page at ``path`` in ``folder``; raises DocError at the first
    block that fails or prints other than it quotes. ``cache``: commands already run on another
    page, by their arguments and input files."""
    report = Report()
    for d in SHARED:
        if not (folder / d).exists():
            (folder / d).symlink_to(ROOT / d)
    namespace: dict[str, object] = {"__name__": "__docs__"}
    with _inside(folder):
        for block in parse(path, name):
            if not block.runnable:
                continue
            if block.skip is not None:
                report.skipped.append((block.where, block.skip))
                continue
            if block.lang == "python":
                report.compared_lines += run_python(block, namespace)
            for command in block.commands:
                output = _run_cached(command, block.where, cache)
                report.commands += 1
                compare(command, output, block.where, block.time_columns)
                report.compared_lines += len(command.quoted)
            report.ran.append(block.where)
    return report
