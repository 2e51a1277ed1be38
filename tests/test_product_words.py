"""The product speaks of the library, not of how it was built.

README, docs, code, configs, tests, benchmarks, scripts and the Makefile must not use process words: "session"
(pytest's ``scope="session"`` is an API name and allowed), "issue #<n>", "lent" (a machine), or "turn" as a unit of
work ("this turn", "turn #3"; the physical turn of a knob is fine).
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHECKED = ("README.md", "Makefile", "pyproject.toml", "docs", "dexmots_rl", "configs", "tests", "benchmarks", "scripts")
SKIPPED_DIRS = {".git", ".venv", "__pycache__", ".pytest_cache", "runs", "tables", "build", "dist"}
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".cfg", ".ini", ".json", ".xml", ".sh", ".csv", ""}

PROCESS_WORDS = re.compile(
    r"\bsessions?\b"
    r"|\bissue\s*#\s*\d"
    r"|\blent\b"
    r"|\b(?:this|that|previous|next|earlier|later|current) turn\b"
    r"|\bturns?\s*#\s*\d",
    re.IGNORECASE,
)
ALLOWED = re.compile(r"""scope\s*=\s*["']session["']""")


def product_files():
    for name in CHECKED:
        path = ROOT / name
        if path.is_file():
            yield path
        elif path.is_dir():
            for file in sorted(path.rglob("*")):
                if file.is_file() and file.suffix in TEXT_SUFFIXES and not SKIPPED_DIRS & set(file.relative_to(ROOT).parts):
                    yield file


def process_word_lines(text: str) -> list[tuple[int, str]]:
    """``(line number, line)`` of every line that uses a process word outside the allowed API names."""
    hits = []
    for number, line in enumerate(text.splitlines(), 1):
        if PROCESS_WORDS.search(ALLOWED.sub("", line)):
            hits.append((number, line.strip()))
    return hits


def test_the_pattern_catches_process_words_and_allows_api_names():
    assert process_word_lines("measured in session 12")
    assert process_word_lines("see Issue #16.7")
    assert process_word_lines("no GPU was lent")
    assert process_word_lines("done in this turn")
    assert not process_word_lines('@pytest.fixture(scope="session")')
    assert not process_word_lines("turn the knob by 1.5 rad; the turn about x")


def test_no_process_words_in_the_product():
    this_file = Path(__file__).resolve()
    found = []
    for path in product_files():
        if path.resolve() == this_file:  # the pattern's own examples
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        found += [f"{path.relative_to(ROOT)}:{n}: {line}" for n, line in process_word_lines(text)]
    assert not found, "process words in the product:\n" + "\n".join(found)
