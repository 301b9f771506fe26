"""The README's leaderboard section, written from ``leaderboard.json`` alone, and its
replacement between the README's markers."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from arm.files import atomic_write_text
from experiments.leaderboard.build import marks
from experiments.leaderboard.writers import (
    duration_text,
    interval_text,
    number_text,
    ordering_text,
    seeds_text,
)
from experiments.records import RecordError

__all__ = ["README_BEGIN", "README_END", "readme_block", "update_readme"]

README_BEGIN = "<!-- leaderboard:begin -->"
README_END = "<!-- leaderboard:end -->"


def readme_block(data: Mapping[str, Any]) -> str:
    """The README's leaderboard section, written from ``leaderboard.json`` alone (what
    :func:`to_json` wrote): the ranking table with each agent's aggregate, the orderings the
    paired intervals resolve, and sentences that claim no ordering they do not resolve.
    ``tests/test_readme_leaderboard.py`` checks that the README holds exactly this."""
    m0 = data["rank_by"]
    ref = data.get("reference")
    scen = list(data["scenarios"])
    cells, agg = data["cells"], data.get("aggregate") or {}
    compute = data.get("compute") or {}
    oracles, informed = set(data.get("oracles", [])), set(data.get("informed", []))
    order = [a for a in data["order"] if a in cells]
    commit = ", ".join(c[:10] for c in data.get("commits", []))

    def mark(a: str) -> str:
        return a + marks(a in oracles, a in informed) + seeds_text(compute.get(a))

    def mean(a: str, s: str, m: str = m0) -> float | None:
        return ((cells.get(a, {}).get(s) or {}).get(m) or {}).get("value")

    settle = data.get("settle_seconds")
    lines = [
        README_BEGIN,
        "<!-- written by `sixaxis leaderboard --readme` from results/leaderboard.json; "
        "tests/test_readme_leaderboard.py keeps the two equal -->",
        "",
        f"From {'clean ' if data.get('clean') else ''}commit {commit} "
        f"(`results/leaderboard.md`, with every interval): {data['episodes']} episodes per agent "
        "and scenario"
        + (", their seeds drawn when the sweep started" if data.get("drawn_seeds") else "")
        + f", {data['runs']} runs ({data['failed']} failed"
        + (
            f"; the sweep took {duration_text(data['sweep_wall_s'])} on "
            f"{len(data.get('hosts') or [])} host(s), {duration_text(data.get('runs_wall_s'))} of "
            "run time"
            if data.get("sweep_wall_s")
            else ""
        )
        + f"). Each cell is the geometric mean over the episodes of `{m0}` "
        + (f"(the tracking RMS after {settle:g} s, mm)" if isinstance(settle, (int, float)) else "")
        + "; **bold**: the best contender of the scenario; (oracle): given the plant's truth; "
        "(informed): told the scenario's effects."
        + (
            f" The last column is each agent's `{m0}` against `{ref}`'s on the same episodes, "
            "over every scenario: the IQM of the per-episode ratios [95 % interval]."
            if ref
            else ""
        ),
        "",
        "| agent | " + " | ".join(scen) + (f" | vs `{ref}` |" if ref else " |"),
        "|---|" + "---:|" * (len(scen) + (1 if ref else 0)),
    ]
    for a in order:
        row = []
        for s in scen:
            v = mean(a, s)
            text = number_text(v) if v is not None else ""
            row.append(f"**{text}**" if data["best"].get(s) == a and text else text)
        if ref:
            row.append(interval_text((agg.get(a) or {}).get("iqm")))
        lines.append(f"| {mark(a)} | " + " | ".join(row) + " |")
    lines += [
        "",
        "Each scenario's agents in that order, each against the next: `<` where the paired 95 % "
        "interval of their per-episode ratio resolves the step, `≈` where it does not:",
        "",
    ]
    lines += [f"- `{s}`: {ordering_text(data, s)}" for s in scen]
    lines += ["", *_readme_sentences(data), README_END]
    return "\n".join(lines) + "\n"


def _readme_sentences(data: Mapping[str, Any]) -> list[str]:
    """What the table says, claiming only resolved orderings."""
    oracles, informed = set(data.get("oracles", [])), set(data.get("informed", []))
    pairs = data.get("pairs", [])

    def pair(a: str, b: str, s: str) -> Mapping[str, Any] | None:
        return next(
            (p for p in pairs if p["scenario"] == s and {p["better"], p["worse"]} == {a, b}),
            None,
        )

    out = []
    for s in data["scenarios"]:
        best = data["best"].get(s)
        if best is None:
            continue
        rivals = [
            a for a in data["ranking"][s] if a != best and a not in oracles and a not in informed
        ]
        unresolved = [a for a in rivals if not (pair(best, a, s) or {}).get("resolved")]
        if not unresolved:
            out.append(
                f"- On `{s}`, `{best}` is the best contender, resolved against every other one."
            )
        else:
            names = ", ".join(f"`{a}`" for a in unresolved)
            out.append(
                f"- On `{s}`, `{best}` comes first among the contenders; not resolved from it: "
                f"{names}."
            )
    below: dict[tuple[str, str], list[str]] = {}
    for p in pairs:
        if p["resolved"] and p["worse"] in oracles and p["better"] not in oracles | informed:
            below.setdefault((p["better"], p["worse"]), []).append(p["scenario"])
    for (a, o), where in sorted(below.items()):
        out.append(
            f"- `{a}` tracks below `{o}` (oracle) on {', '.join(f'`{s}`' for s in where)} "
            "(resolved): the oracle's model knowledge is not a ceiling on the settled metric."
        )
    return out


def update_readme(path: str | Path, block: str) -> Path:
    """Replace the README's leaderboard section (between :data:`README_BEGIN` and
    :data:`README_END`, markers included) with ``block``; a README without both markers is
    refused, and nothing is written."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordError(f"{p}: cannot read: {exc}") from None
    i, j = text.find(README_BEGIN), text.find(README_END)
    if i < 0 or j < i:
        raise RecordError(
            f"{p}: no leaderboard section to rewrite (the lines {README_BEGIN} and {README_END})"
        )
    atomic_write_text(p, text[:i] + block.rstrip("\n") + text[j + len(README_END) :])
    return p
