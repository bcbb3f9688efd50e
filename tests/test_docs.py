"""The documentation stays current: every ``gcnt`` command it shows parses, every recipe and
source path it names exists, and it states facts rather than history."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from gcnt.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = [README, *sorted((ROOT / "docs").glob("*.md"))]
STALE_WORDS = ("this session", "previous version", "the issue")


def _code_lines(path: Path) -> list[str]:
    """The lines inside fenced code blocks, backslash continuations joined."""
    lines: list[str] = []
    fenced = False
    pending = ""
    for raw in path.read_text(encoding="utf-8").splitlines():
        if raw.lstrip().startswith("```"):
            fenced = not fenced
            pending = ""
            continue
        if not fenced:
            continue
        line = pending + raw.strip() if pending else raw
        if line.rstrip().endswith("\\"):
            pending = line.rstrip()[:-1].rstrip() + " "
            continue
        pending = ""
        lines.append(line)
    return lines


def _strip_comment(line: str) -> str:
    """``line`` without a trailing ``# comment`` (a ``#`` outside quotes after a space)."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars=False)
    lexer.whitespace_split = True
    lexer.commenters = "#"
    try:
        words = list(lexer)
    except ValueError:
        return line
    return shlex.join(words)


def _gcnt_commands() -> list[tuple[str, str]]:
    commands = []
    for path in DOCS:
        for line in _code_lines(path):
            line = line.strip()
            if line.startswith("$ "):
                line = line[2:].lstrip()
            if line.startswith("gcnt "):
                commands.append((path.name, _strip_comment(line)))
    return commands


COMMANDS = _gcnt_commands()


def test_docs_show_commands() -> None:
    assert len(COMMANDS) > 20


@pytest.mark.parametrize(("doc", "line"), COMMANDS, ids=[c[1][:60] for c in COMMANDS])
def test_command_parses(doc: str, line: str) -> None:
    argv = shlex.split(line)[1:]
    command = next((w for w in argv if not w.startswith("-")), None)
    parser = build_parser(only=command)
    try:
        parser.parse_args(argv)
    except SystemExit as exc:
        pytest.fail(f"{doc}: `{line}` is not accepted by the gcnt parser (exit {exc.code})")


def _all_text() -> dict[str, str]:
    return {p.name: p.read_text(encoding="utf-8") for p in DOCS}


def test_recipe_paths_exist() -> None:
    missing = []
    for name, text in _all_text().items():
        for path in set(re.findall(r"recipes/[\w./+-]*?\.yaml", text)):
            if "*" not in path and not (ROOT / path).is_file():
                missing.append(f"{name}: {path}")
    assert not missing, missing


def test_source_paths_exist() -> None:
    text = README.read_text(encoding="utf-8")
    paths = set(re.findall(r"src/gcnt/[\w./]*?\.py", text))
    assert paths
    missing = [p for p in sorted(paths) if not (ROOT / p).is_file()]
    assert not missing, missing


def test_docs_state_facts_not_history() -> None:
    found = [
        f"{name}: {word!r}"
        for name, text in _all_text().items()
        for word in STALE_WORDS
        if word in text.lower()
    ]
    assert not found, found


def test_docs_links_exist() -> None:
    text = README.read_text(encoding="utf-8")
    for link in ("docs/experiments.md", "docs/deviations.md", "docs/performance.md"):
        assert f"({link})" in text, link
        assert (ROOT / link).is_file(), link


def test_one_place_states_the_expected_quick_start_results() -> None:
    """docs/performance.md's "Expected quick-start results" is the one place with the quick
    starts' numbers; the README, the other docs and the quick-start recipes point there."""
    perf = (ROOT / "docs" / "performance.md").read_text(encoding="utf-8")
    assert "## Expected quick-start results" in perf
    section = perf.split("## Expected quick-start results", 1)[1].split("\n## ", 1)[0]
    assert "gcnt train quickstart" in section and "gcnt train unimal/quickstart" in section
    pointers = [README, ROOT / "recipes/quickstart.yaml", ROOT / "recipes/unimal/quickstart.yaml"]
    for path in pointers:
        assert "expected-quick-start-results" in path.read_text().lower().replace(" ", "-"), path
    number = r"-?−?\d+(\.\d+)?"
    result = re.compile(  # a return or an evaluation next to a seed and a number
        rf"(evaluation|return)[^.\n]*{number}[^.\n]*seeds? [01]\b"
        rf"|seeds? [01]\b[^.\n]*(evaluation|return)[^.\n]*{number}"
        rf"|{number} \(seed [01]\)"
    )
    others = [*DOCS, *sorted((ROOT / "recipes").rglob("quickstart.yaml"))]
    stated = [
        f"{p.name}: {m.group(0)}"
        for p in others
        if p.name not in ("performance.md", "performance-history.md")
        for m in result.finditer(p.read_text(encoding="utf-8"))
    ]
    assert not stated, stated


#: the README is the front door: what gcnt is, its set-up, quick starts, main commands, links
README_MAX_LINES = 250


def test_the_readme_is_a_front_door() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines"
    text = "\n".join(lines)
    assert "make train" in text and "make test" in text


def _anchors(path: Path) -> set[str]:
    """The anchors of a Markdown file's headings, as GitHub makes them."""
    out = set()
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            slug = re.sub(r"[^\w\- ]", "", title).replace(" ", "-")
            out.add(slug)
    return out


def test_every_relative_link_resolves() -> None:
    """Every relative link of README.md and docs/*.md names a file or folder that exists, and a
    heading of it where the link names one."""
    broken = []
    for path in DOCS:
        text = re.sub(r"```.*?```", "", path.read_text(encoding="utf-8"), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):  # https:, mailto:
                continue
            file, _, anchor = target.partition("#")
            where = (path.parent / file).resolve() if file else path
            if not where.exists():
                broken.append(f"{path.name}: {target}")
            elif anchor and where.suffix == ".md" and anchor not in _anchors(where):
                broken.append(f"{path.name}: {target} (no such heading)")
    assert not broken, broken
